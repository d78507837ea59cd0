"""Unmodelled effects as streaming stages: the vocabulary of the sim-to-real gap diagnosis (issue 5).

Each effect is a physically meaningful extension of the nominal chain with few parameters.  It is either a stage
inserted before the chain on the voltage (``pre``: amplifier and timing effects), after it on the displacement
(``post``: sensor/structure/thermal effects), or a replacement of the hysteresis part (generalized or rate-dependent
Bouc-Wen).  Every stage has ``process(block[N, axes]) -> block`` and ``reset()``, carries its state between blocks
and gives bit-identical output whatever the block split.

:func:`build_plant` assembles ``Plant(cfg, pre=[...], post=[...])`` from a list of ``(name, params)``; the
per-effect parameter names, units and positions are in :data:`EFFECTS`.

Units are SI: volts, metres, seconds, hertz.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .._jit import njit
from ..config import BoucWenConfig, PiezoConfig
from ..stage import Processor
from .plant import Plant
from ..kernels.bouc_wen import bw_model_rate_run, params_of  # the model loop (one source)
from ..kernels.limits import limit_run  # the driver guard's limiter (one source)

__all__ = [
    "InputDelay", "AmplifierSlewLimit", "AmplifierSaturation", "AmplifierBandwidth", "GainMismatch",
    "ThermalDrift", "CreepNonlinearity", "UnmodelledMode", "AmplitudeDependentDynamics", "BranchEvenTerm",
    "HysteresisStage", "EffectSpec", "EFFECTS", "AsymmetricSaturation", "RelaxedHysteresisStage", "PlayWidthTerm",
    "CubicAmplitudeDynamics",
    "EFFECT_NAMES", "build_plant", "RATE_REF", "CREEP_TAUS", "CREEP_YREF",
]

#: reference voltage rate of the rate-dependent hysteresis [V/s]: A grows by ``alpha·tanh(|dU/dt|/RATE_REF)``
RATE_REF = 1.0e4
#: time constant of the smoothing of |dU/dt| in the rate-dependent hysteresis [s] (measured voltages are noisy)
RATE_SMOOTHING = 1.0e-3
#: relaxation times of the extra (logarithmic) creep, one per decade [s]
CREEP_TAUS = (0.1, 1.0, 10.0, 100.0)
#: reference displacement of the amplitude-dependent creep term [m]
CREEP_YREF = 10e-6
#: level of the amplitude-dependent dynamics: |Y| low-passed over LEVEL_TAU [s], in units of LEVEL_REF [m]
LEVEL_TAU = 0.05
LEVEL_REF = 10e-6
#: direction of motion of the asymmetric loop's even term: sign of Y minus Y low-passed over this [s]
DIRECTION_TAU = 2e-3


def _block(x: ArrayLike, n: int | None = None) -> np.ndarray:
    x = np.ascontiguousarray(x, dtype=float)
    if x.ndim != 2 or (n is not None and x.shape[1] != n):
        raise ValueError(f"expected a block of shape [N, {n if n is not None else 'axes'}], got {x.shape}")
    return x


def _per_axis(value: Any, n: int, name: str) -> np.ndarray:
    a = np.atleast_1d(np.asarray(value, dtype=float))
    if a.size == 1:
        a = np.full(n, float(a[0]))
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected {n} finite value(s), got {value!r}")
    return a


# --------------------------------------------------------------------------------------------------------------
# Voltage-side (amplifier / timing) stages
# --------------------------------------------------------------------------------------------------------------

class InputDelay:
    """Pure (fractional) delay of the voltage: ``U_out(t) = U(t − delay)`` by linear interpolation between samples.

    Before the first sample the voltage is held at its first value (the actuator was at rest there).
    """

    def __init__(self, delay: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(delay) and delay >= 0):
            raise ValueError(f"input_delay.delay: must be >= 0 s, got {delay!r}")
        self.delay, self.dt, self.n = float(delay), float(dt), n_axes
        d = self.delay / self.dt
        self._m = int(math.floor(d))
        self._frac = d - self._m
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._hist: np.ndarray | None = None  # last m + 1 input samples, oldest first

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.n)
        m = self._m
        if self._hist is None:
            if len(u) == 0:
                return u.copy()
            self._hist = np.repeat(u[:1], m + 1, axis=0)
        out = np.empty_like(u)
        self._hist = _frac_delay_run(self._hist, u, self._frac, out)
        return out


class AmplifierSlewLimit:
    """Amplifier slew-rate limit: the voltage changes by at most ``rate·dt`` per sample [V/s]."""

    def __init__(self, rate: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"amplifier_slew_limit.rate: must be > 0 V/s, got {rate!r}")
        self.rate, self.dt, self.n = float(rate), float(dt), n_axes
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._prev = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.n)
        out = np.empty_like(u)
        limit_run(u, self._prev, self._started, np.inf, self.rate * self.dt, out, np.zeros(2, np.int64))
        return out


class AmplifierSaturation:
    """Amplifier output rails: the voltage is clipped to ``[−limit, +limit]`` [V] (memoryless)."""

    def __init__(self, limit: float, n_axes: int = 2):
        if not (math.isfinite(limit) and limit > 0):
            raise ValueError(f"amplifier_saturation.limit: must be > 0 V, got {limit!r}")
        self.limit, self.n = float(limit), n_axes

    def reset(self) -> None:
        """All states back to rest."""
        pass

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        res: np.ndarray = np.clip(_block(u, self.n), -self.limit, self.limit)
        return res


@njit
def _ap2_run(u: np.ndarray, state: np.ndarray, started: np.ndarray, g: np.ndarray, a1: np.ndarray, a2: np.ndarray,
             out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Per column j: ``y[k] = g_j·u[k] − a1_j·y[k−1] − a2_j·y[k−2]``, started settled at the first input."""
    N, n = u.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                state[0, j] = u[t, j]
                state[1, j] = u[t, j]
            y = g[j] * u[t, j] - a1[j] * state[0, j] - a2[j] * state[1, j]
            state[1, j] = state[0, j]
            state[0, j] = y
            out[t, j] = y
        started[0] = True


def _pole_matched(cutoff: float, order: int, damping: float, dt: float) -> tuple[float, float, float]:
    """Unit-DC-gain all-pole discretisation (poles ``e^{pT}``) of a 1st/2nd-order low-pass: (g, a1, a2).

    As the cutoff grows beyond the sample rate the poles go to 0 and the filter to the identity, so "no bandwidth
    limit" is a point of the parameter space (unlike a ZOH or bilinear discretisation)."""
    w = 2.0 * math.pi * cutoff
    if order == 1:
        a = math.exp(-w * dt)
        return 1.0 - a, -a, 0.0
    z = damping
    if z < 1.0:
        r = math.exp(-z * w * dt)
        a1 = -2.0 * r * math.cos(w * dt * math.sqrt(1.0 - z * z))
        a2 = r * r
    else:
        s = math.sqrt(z * z - 1.0)
        p1, p2 = -w * (z - s), -w * (z + s)
        a1 = -(math.exp(p1 * dt) + math.exp(p2 * dt))
        a2 = math.exp((p1 + p2) * dt)
    return 1.0 + a1 + a2, a1, a2


class AmplifierBandwidth:
    """Amplifier roll-off on the voltage: first order ``1/(s/ωc + 1)`` or second order
    ``ωc²/(s² + 2ζωc·s + ωc²)`` (``order=2``, damping ``ζ``), with a cutoff per axis or shared.

    Pole-matched, unit DC gain, started settled at the first voltage it sees.  Unlike a pure delay it attenuates
    (≈ (f/fc)²/2 at order 1) and rounds steps instead of shifting them.
    """

    def __init__(self, cutoff: ArrayLike, dt: float, n_axes: int = 2, order: int = 1,
                 damping: float = 1 / math.sqrt(2)) -> None:
        c = _per_axis(cutoff, n_axes, "amplifier_bandwidth.cutoff")
        if not np.all(c > 0):
            raise ValueError(f"amplifier_bandwidth.cutoff: must be > 0 Hz, got {cutoff!r}")
        if int(order) not in (1, 2):
            raise ValueError(f"amplifier_bandwidth.order: must be 1 or 2, got {order!r}")
        if not (math.isfinite(damping) and damping > 0):
            raise ValueError(f"amplifier_bandwidth.damping: must be > 0, got {damping!r}")
        self.cutoff, self.dt, self.n = c, float(dt), n_axes
        self.order, self.damping = int(order), float(damping)
        co = np.array([_pole_matched(float(f), self.order, self.damping, self.dt) for f in c])
        self._g, self._a1, self._a2 = (np.ascontiguousarray(co[:, i]) for i in range(3))
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._state = np.zeros((2, self.n))
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.n)
        out = np.empty_like(u)
        _ap2_run(u, self._state, self._started, self._g, self._a1, self._a2, out)
        return out


# --------------------------------------------------------------------------------------------------------------
# Displacement-side stages
# --------------------------------------------------------------------------------------------------------------

class GainMismatch:
    """Gain error of the whole chain (piezo coefficient, amplifier gains, sensor calibration and cross-talk):
    ``Y_i ← g_i·Y_i + Σ_{j≠i} c_ij·Y_j``.

    ``gains`` per axis; ``cross_gains`` an n×n matrix whose diagonal is ignored (default none).
    """

    def __init__(self, gains: ArrayLike, n_axes: int = 2, cross_gains: ArrayLike | None = None) -> None:
        self.n = n_axes
        self.gains = _per_axis(gains, n_axes, "gain_mismatch.gains")
        C = np.zeros((n_axes, n_axes)) if cross_gains is None else np.asarray(cross_gains, float)
        if C.shape != (n_axes, n_axes) or not np.all(np.isfinite(C)):
            raise ValueError(f"gain_mismatch.cross_gains: expected a finite {n_axes}x{n_axes} matrix, got "
                             f"{cross_gains!r}")
        self.G = C.copy()
        np.fill_diagonal(self.G, self.gains)
        self._diag = not np.any(C - np.diag(np.diag(C)))

    def reset(self) -> None:
        """All states back to rest."""
        pass

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        res: np.ndarray = y * self.gains if self._diag else y @ self.G.T
        return res


class ThermalDrift:
    """Thermal expansion after switch-on: ``Y_i += a_i·(1 − exp(−t/τ))`` with t counted from the first sample.

    ``amplitudes`` [m] per axis, ``time_constant`` τ [s].
    """

    def __init__(self, amplitudes: ArrayLike, time_constant: float, dt: float, n_axes: int = 2) -> None:
        if not (math.isfinite(time_constant) and time_constant > 0):
            raise ValueError(f"thermal_drift.time_constant: must be > 0 s, got {time_constant!r}")
        self.n, self.dt, self.tau = n_axes, float(dt), float(time_constant)
        self.amplitudes = _per_axis(amplitudes, n_axes, "thermal_drift.amplitudes")
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._k = 0

    def regressor(self, N: int, start: int = 0) -> np.ndarray:
        """The drift shape ``1 − exp(−t/τ)`` for samples ``start … start+N−1``."""
        t = (np.arange(start, start + N, dtype=float)) * self.dt
        return -np.expm1(-t / self.tau)

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        shape = self.regressor(len(y), self._k)
        self._k += len(y)
        res: np.ndarray = y + shape[:, None] * self.amplitudes
        return res


@njit
def _lp_bank_run(x: np.ndarray, a: np.ndarray, state: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Sum over a bank of unit-DC first-order low-passes (coefficients ``a``), per column; state [len(a), n]."""
    N, n = x.shape
    m = a.shape[0]
    for t in range(N):
        for j in range(n):
            acc = 0.0
            for i in range(m):
                state[i, j] = a[i] * state[i, j] + (1.0 - a[i]) * x[t, j]
                acc += state[i, j]
            out[t, j] = acc


class CreepNonlinearity:
    """Creep the linear first-order model misses: logarithmic in time and growing with the level.

    ``Y ← Y + γ·Σ_τ LP_τ(Y + β·Y|Y|/Y_ref)``, one first-order relaxation per decade (τ in :data:`CREEP_TAUS`, so a
    step creeps by ≈ γ·Y per decade of time, the classical log-time law) and ``β`` the relative growth of the creep
    at ``Y_ref`` = 10 µm.  ``gamma`` (per axis) is dimensionless, ``beta`` dimensionless.
    """

    def __init__(self, gamma: ArrayLike, beta: float, dt: float, n_axes: int = 2,
                 taus: Sequence[float] = CREEP_TAUS) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.gamma = _per_axis(gamma, n_axes, "creep_nonlinearity.gamma")
        if not math.isfinite(beta):
            raise ValueError(f"creep_nonlinearity.beta: must be finite, got {beta!r}")
        self.beta = float(beta)
        self._a = np.exp(-self.dt / np.asarray(taus, float))
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._state = np.zeros((len(self._a), self.n))
        self._started = False

    @staticmethod
    def level_input(y: np.ndarray, beta: float) -> np.ndarray:
        """The level-dependent input of the creep bank: ``y + beta·y·|y| / CREEP_YREF``."""
        res: np.ndarray = y + beta * y * np.abs(y) / CREEP_YREF
        return res

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        v = self.level_input(y, self.beta)
        out = np.empty_like(v)
        _lp_bank_run(v, self._a, self._state, out)
        res: np.ndarray = y + out * self.gamma
        return res


@njit
def _biquad_run(x: np.ndarray, b0: float, b1: float, b2: float, a1: float, a2: float, z: np.ndarray,
                out: np.ndarray) -> None:  # pragma: no cover - compiled
    N, n = x.shape
    for t in range(N):
        for j in range(n):
            xi = x[t, j]
            yi = b0 * xi + z[0, j]
            z[0, j] = b1 * xi - a1 * yi + z[1, j]
            z[1, j] = b2 * xi - a2 * yi
            out[t, j] = yi


def _bandpass_coeffs(freq: float, damping: float, dt: float) -> tuple[float, float, float, float, float]:
    """Bilinear (prewarped at ω) discretisation of ``2ζωs/(s² + 2ζωs + ω²)`` (unit gain at the peak)."""
    w = 2 * math.pi * freq
    K = w / math.tan(w * dt / 2)
    a0 = K * K + 2 * damping * w * K + w * w
    b0 = 2 * damping * w * K / a0
    b1 = 0.0
    b2 = -b0
    a1 = (2 * w * w - 2 * K * K) / a0
    a2 = (K * K - 2 * damping * w * K + w * w) / a0
    return b0, b1, b2, a1, a2


def _highpass_coeffs(freq: float, damping: float, dt: float) -> tuple[float, float, float, float, float]:
    """Bilinear (prewarped at ω) discretisation of ``s²/(s² + 2ζωs + ω²)`` (0 at DC, 1 far above ω)."""
    w = 2 * math.pi * freq
    K = w / math.tan(w * dt / 2)
    a0 = K * K + 2 * damping * w * K + w * w
    b0 = K * K / a0
    a1 = (2 * w * w - 2 * K * K) / a0
    a2 = (K * K - 2 * damping * w * K + w * w) / a0
    return b0, -2.0 * b0, b0, a1, a2


def _modes_spec(freq: ArrayLike, damping: ArrayLike, dt: float, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Validated lists of mode frequencies and dampings (scalars mean one mode)."""
    f = np.atleast_1d(np.asarray(freq, float)).reshape(-1)
    z = np.atleast_1d(np.asarray(damping, float)).reshape(-1)
    if z.size == 1 and f.size > 1:
        z = np.full(f.size, float(z[0]))
    if f.size == 0 or z.size != f.size:
        raise ValueError(f"{name}.damping: expected {f.size} value(s), got {damping!r}")
    for fi in f:
        if not (math.isfinite(fi) and 0 < fi < 0.5 / dt):
            raise ValueError(f"{name}.freq: must be in (0, Nyquist={0.5 / dt:g}) Hz, got {freq!r}")
    for zi in z:
        if not (math.isfinite(zi) and 0 < zi < 5):
            raise ValueError(f"{name}.damping: must be in (0, 5), got {damping!r}")
    return f, z


def _mode_gains(gains: ArrayLike, K: int, n: int, name: str) -> np.ndarray:
    """Gains as [K, n, n] (output i, input j); a per-axis list (one mode) or [K][n] means diagonal."""
    g = np.asarray(gains, float)
    if g.ndim <= 1 and K == 1:
        return np.diag(_per_axis(g, n, name))[None]
    if g.ndim == 2 and g.shape == (K, n):
        return np.stack([np.diag(row) for row in g])
    if g.shape == (K, n, n) and np.all(np.isfinite(g)):
        return g
    raise ValueError(f"{name}: expected {n} per-axis gains (one mode), [{K}][{n}] or [{K}][{n}][{n}], got "
                     f"shape {g.shape}")


class UnmodelledMode:
    """Structural resonances the nominal G_L lacks: ``Y_i ← Y_i + Σ_m Σ_j (g_mij·BP_m + h_mij·HP_m)(Y_j)``.

    ``BP_m(s) = 2ζ_mω_m·s/(s² + 2ζ_mω_m·s + ω_m²)``: unit peak gain at ``freq[m]`` [Hz];
    ``HP_m(s) = s²/(s² + 2ζ_mω_m·s + ω_m²)``.  Both vanish at DC, so together they are any second-order correction
    with that pole pair and no static effect — a resonance, or a pole–zero pair (anti-resonance) in series, which
    leaves a gain change above it.  ``freq``/``damping``: scalars (one mode) or lists (several); ``gains`` and
    ``hp_gains`` (default 0): per axis (one mode), ``[K][n]`` or ``[K][n][n]`` (output i through axis j:
    cross-coupled modes).
    """

    def __init__(self, freq: ArrayLike, damping: ArrayLike, gains: ArrayLike, dt: float, n_axes: int = 2,
                 hp_gains: ArrayLike | None = None) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.freqs, self.dampings = _modes_spec(freq, damping, self.dt, "unmodelled_mode")
        self.freq, self.damping = float(self.freqs[0]), float(self.dampings[0])
        K = len(self.freqs)
        self.G = _mode_gains(gains, K, n_axes, "unmodelled_mode.gains")
        self.H = np.zeros_like(self.G) if hp_gains is None else _mode_gains(hp_gains, K, n_axes,
                                                                            "unmodelled_mode.hp_gains")
        self._c = [_bandpass_coeffs(float(f), float(z), self.dt) for f, z in zip(self.freqs, self.dampings)]
        self._ch = [_highpass_coeffs(float(f), float(z), self.dt) for f, z in zip(self.freqs, self.dampings)]
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._z = [np.zeros((2, self.n)) for _ in self._c]
        self._zh = [np.zeros((2, self.n)) for _ in self._c]

    def highpass(self, y: np.ndarray, m: int = 0) -> np.ndarray:
        """``HP_m`` of every column of ``y`` (advances mode ``m``'s high-pass state)."""
        y = _block(y, self.n)
        out = np.empty_like(y)
        _biquad_run(y, *self._ch[m], self._zh[m], out)
        return out

    def bandpass(self, y: np.ndarray, m: int = 0) -> np.ndarray:
        """``BP_m`` of every column of ``y`` (advances mode ``m``'s state)."""
        y = _block(y, self.n)
        out = np.empty_like(y)
        _biquad_run(y, *self._c[m], self._z[m], out)
        return out

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        out = y.copy()
        for m in range(len(self._c)):
            out += self.bandpass(y, m) @ self.G[m].T
            if np.any(self.H[m]):
                out += self.highpass(y, m) @ self.H[m].T
        return out


@njit
def _level_run(y: np.ndarray, a: float, state: np.ndarray, started: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    N, n = y.shape
    for t in range(N):
        for j in range(n):
            v = abs(y[t, j])
            if not started[0]:
                state[j] = v
            state[j] = a * state[j] + (1.0 - a) * v
            out[t, j] = state[j]
        started[0] = True


class AmplitudeDependentDynamics:
    """Resonances whose shape moves with the motion's level (softening/hardening, damping growing with
    amplitude): the :class:`UnmodelledMode` correction plus level-modulated terms,
    ``Y_i ← Y_i + Σ_m Σ_j (g_mij·BP_m + h_mij·HP_m)(Y_j) + Σ_m A_i(t)·(k_mi·BP_m + l_mi·HP_m)(Y_i)``.

    ``A_i(t)`` = the level of axis i, ``|Y_i|`` low-passed over :data:`LEVEL_TAU` and divided by
    :data:`LEVEL_REF` (dimensionless).  A pole pair shifted by δω, δζ at level A changes the response, to first
    order, by A times a combination of the band-pass and high-pass terms around ω — the ``k``, ``l`` terms.
    ``gains``/``hp_gains``: as for :class:`UnmodelledMode`; ``level_gains``/``level_hp_gains``: ``[K][n]``.
    """

    def __init__(self, freq: ArrayLike, damping: ArrayLike, gains: ArrayLike, level_gains: ArrayLike, dt: float,
                 n_axes: int = 2, hp_gains: ArrayLike | None = None, level_hp_gains: ArrayLike | None = None) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.freqs, self.dampings = _modes_spec(freq, damping, self.dt, "amplitude_dependent_dynamics")
        K = len(self.freqs)
        name = "amplitude_dependent_dynamics"
        self.base = UnmodelledMode(self.freqs, self.dampings,
                                   _mode_gains(gains, K, n_axes, f"{name}.gains"), dt, n_axes,
                                   None if hp_gains is None else _mode_gains(hp_gains, K, n_axes, f"{name}.hp_gains"))

        def diag(v: ArrayLike, what: str) -> np.ndarray:
            return np.diagonal(_mode_gains(v, K, n_axes, f"{name}.{what}"), axis1=1, axis2=2).copy()
        self.Kl = diag(level_gains, "level_gains")
        self.Kh = np.zeros_like(self.Kl) if level_hp_gains is None else diag(level_hp_gains, "level_hp_gains")
        self._a = math.exp(-self.dt / LEVEL_TAU)
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self.base.reset()
        self._lev = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def level(self, y: np.ndarray) -> np.ndarray:
        """``A(t)`` of every column (advances the level state)."""
        y = _block(y, self.n)
        out = np.empty_like(y)
        _level_run(y, self._a, self._lev, self._started, out)
        return out / LEVEL_REF

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        lev = self.level(y)
        out = y.copy()
        b = self.base
        for m in range(len(b._c)):
            bp = b.bandpass(y, m)
            hp = b.highpass(y, m)
            out += bp @ b.G[m].T + hp @ b.H[m].T + lev * (bp * self.Kl[m] + hp * self.Kh[m])
        return out


class BranchEvenTerm:
    """The even, branch-dependent part of an asymmetric loop: ``Y_i += (e_i + b_i·D_i(t))·Y_i²/LEVEL_REF`` with
    ``D_i = sign(Y_i − LP(Y_i))`` the direction of motion (LP over :data:`DIRECTION_TAU`): an ascending and a
    descending branch bent differently, which a point-symmetric loop cannot have.  Part of
    ``hysteresis_asymmetry`` (parameters ``even``, ``branch_even``)."""

    def __init__(self, even: ArrayLike, branch_even: ArrayLike, dt: float, n_axes: int = 2) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.even = _per_axis(even, n_axes, "hysteresis_asymmetry.even")
        self.branch = _per_axis(branch_even, n_axes, "hysteresis_asymmetry.branch_even")
        self._a = math.exp(-self.dt / DIRECTION_TAU)
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._lp = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def terms(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, D·q) of every column, q = Y²/LEVEL_REF (advances the direction state)."""
        y = _block(y, self.n)
        lp = np.empty_like(y)
        _lp1_run(y, self._lp, self._started, self._a, lp)
        q = y * y / LEVEL_REF
        return q, np.sign(y - lp) * q

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        q, dq = self.terms(y)
        res: np.ndarray = y + q * self.even + dq * self.branch
        return res


@njit
def _lp1_run(u: np.ndarray, y_prev: np.ndarray, started: np.ndarray, a: float, out: np.ndarray) -> None:  # pragma: no cover - compiled
    N, n = u.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                y_prev[j] = u[t, j]
            y_prev[j] = a * y_prev[j] + (1.0 - a) * u[t, j]
            out[t, j] = y_prev[j]
        started[0] = True


# --------------------------------------------------------------------------------------------------------------
# Hysteresis replacement: generalized + rate-dependent Bouc-Wen
# --------------------------------------------------------------------------------------------------------------

class HysteresisStage:
    """Bouc-Wen hysteresis with the generalized (asymmetric) terms and an optional rate dependence.

    Replaces the nominal hysteresis part: ``Y_H = Dp·U − h``, ``dh = A·(1 + α·tanh(r/r_ref))∘dU − B(|dÛ|∘h) − Γ(dÛ∘|h|)
    − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)`` where r is |dU/dt| smoothed over :data:`RATE_SMOOTHING` and r_ref =
    :data:`RATE_REF`.  ``alpha = 0`` and zero Δ give exactly the nominal :class:`BoucWenModel`.
    """

    def __init__(self, cfg: BoucWenConfig, alpha: float = 0.0, dt: float = 5e-5):
        self.cfg = cfg
        self._p = params_of(cfg.arrays())
        if not math.isfinite(alpha):
            raise ValueError(f"hysteresis_rate_dependence.alpha: must be finite, got {alpha!r}")
        self.alpha, self.dt = float(alpha), float(dt)
        self._a_smooth = math.exp(-self.dt / RATE_SMOOTHING)
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._h = np.zeros(self.cfg.n_out)
        self._u_prev = np.zeros(self.cfg.n_in)
        self._rate = np.zeros(self.cfg.n_in)
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.cfg.n_in)
        y = np.empty((len(u), self.cfg.n_out))
        bw_model_rate_run(self._p, self.alpha, RATE_REF, self._a_smooth, self.dt, self._rate, self._h,
                          self._u_prev, self._started, u, y, np.empty_like(y))
        return y


# --------------------------------------------------------------------------------------------------------------
# Registry and plant builder
# --------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EffectSpec:
    """Name, position and parameters of one candidate effect.

    ``params`` maps parameter name → (unit, per_axis).  ``position`` is 'pre' (voltage), 'post' (displacement) or
    'hysteresis' (replaces the nominal Bouc-Wen).
    """

    name: str
    position: str
    params: Mapping[str, tuple[str, bool]]
    description: str
    signature: str


EFFECTS: dict[str, EffectSpec] = {s.name: s for s in [
    EffectSpec("hysteresis_asymmetry", "hysteresis", {"Delta1": ("1/V", True), "Delta2": ("1/V", True),
                                                      "even": ("-", True), "branch_even": ("-", True),
                                                      "play_radii": ("m", False), "play_gains": ("-", True)},
               "generalized Bouc-Wen (+ an even, branch-dependent term): ascending and descending branches not "
               "point-symmetric",
               "even harmonics in the residual (error correlates with U², not U)"),
    EffectSpec("hysteresis_rate_dependence", "hysteresis", {"alpha": ("-", False), "relaxation": ("s", False)},
               f"loop width grows with the voltage rate (A·(1 + α·tanh(|dU/dt|/{RATE_REF:g} V/s)))",
               "loop-width error grows with frequency (error correlates with sign(dU/dt)·|dU/dt|)"),
    EffectSpec("creep_nonlinearity", "post", {"gamma": ("-", True), "beta": ("-", False)},
               "logarithmic-in-time creep growing with the level (γ per decade, β at 10 µm)",
               "slow residual after level changes, linear in log-time"),
    EffectSpec("thermal_drift", "post", {"amplitudes": ("m", True), "time_constant": ("s", False)},
               "thermal expansion after switch-on, a_i·(1 − exp(−t/τ))",
               "residual trend over the whole run, uncorrelated with the voltage"),
    EffectSpec("input_delay", "pre", {"delay": ("s", False)},
               "pure delay between the commanded and the acting voltage",
               "residual ∝ −delay·dŶ/dt: phase lag growing linearly with frequency"),
    EffectSpec("amplifier_slew_limit", "pre", {"rate": ("V/s", False)},
               "amplifier slew-rate limit", "error concentrated where |dU/dt| is large (steps, fast ramps)"),
    EffectSpec("amplifier_saturation", "pre", {"limit": ("V", False), "lower_limit": ("V", False)},
               "amplifier output rails clip the voltage", "error only at the largest |U|"),
    EffectSpec("amplifier_bandwidth", "pre", {"cutoff": ("Hz", True), "order": ("-", False),
                                              "damping": ("-", False)},
               "first- or second-order amplifier roll-off (cutoff per axis)",
               "amplitude loss and phase lag at high frequency; steps rounded, not shifted"),
    EffectSpec("unmodelled_mode", "post", {"freq": ("Hz", False), "damping": ("-", False), "gains": ("-", True),
                                          "hp_gains": ("-", True)},
               "extra lightly damped structural resonances (one or several, per axis and cross-coupled)",
               "narrow peaks in the residual spectrum"),
    EffectSpec("amplitude_dependent_dynamics", "post",
               {"freq": ("Hz", False), "damping": ("-", False), "gains": ("-", True), "hp_gains": ("-", True),
                "level_gains": ("-", True), "level_hp_gains": ("-", True), "cubic_gains": ("-", True),
                "cubic_hp_gains": ("-", True)},
               f"resonances whose strength moves with the level (|Y| over {LEVEL_TAU:g} s per {LEVEL_REF:g} m)",
               "dynamics-band residual growing with the motion's amplitude"),
    EffectSpec("gain_mismatch", "post", {"gains": ("-", True), "cross_gains": ("-", True)},
               "gain error per axis and cross-talk between axes (piezo coefficient, amplifier, sensor calibration)",
               "residual ∝ Ŷ on each axis (a scaled copy of the prediction)"),
]}
EFFECT_NAMES = tuple(EFFECTS)


def _stage(name: str, p: Mapping[str, Any], cfg: PiezoConfig) -> Processor:
    n, dt = cfg.n_axes, cfg.dt
    if name == "input_delay":
        return InputDelay(p["delay"], dt, n)
    if name == "amplifier_slew_limit":
        return AmplifierSlewLimit(p["rate"], dt, n)
    if name == "amplifier_saturation":
        if p.get("lower_limit") is not None:
            return AsymmetricSaturation(p["limit"], p["lower_limit"], n)
        return AmplifierSaturation(p["limit"], n)
    if name == "amplifier_bandwidth":
        return AmplifierBandwidth(p["cutoff"], dt, n, int(p.get("order", 1)), float(p.get("damping", 2 ** -0.5)))
    if name == "gain_mismatch":
        return GainMismatch(p["gains"], n, p.get("cross_gains"))
    if name == "thermal_drift":
        return ThermalDrift(p["amplitudes"], p["time_constant"], dt, n)
    if name == "creep_nonlinearity":
        return CreepNonlinearity(p["gamma"], p.get("beta", 0.0), dt, n)
    if name == "unmodelled_mode":
        return UnmodelledMode(p["freq"], p["damping"], p["gains"], dt, n, p.get("hp_gains"))
    if name == "amplitude_dependent_dynamics":
        if p.get("cubic_gains") is not None:
            return CubicAmplitudeDynamics(p["freq"], p["damping"], p["gains"], p["level_gains"], dt, n,
                                          p.get("hp_gains"), p.get("level_hp_gains"), p["cubic_gains"],
                                          p.get("cubic_hp_gains"))
        return AmplitudeDependentDynamics(p["freq"], p["damping"], p["gains"], p["level_gains"], dt, n,
                                          p.get("hp_gains"), p.get("level_hp_gains"))
    raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")


def asymmetric_hysteresis_config(hcfg: BoucWenConfig, delta1: ArrayLike, delta2: ArrayLike) -> BoucWenConfig:
    """The nominal Bouc-Wen with diagonal generalized terms ``Δ1 = diag(delta1)``, ``Δ2 = diag(delta2)`` added."""
    n = hcfg.n_out
    p = hcfg.arrays()
    D1 = p["Delta1"] + np.diag(_per_axis(delta1, n, "hysteresis_asymmetry.Delta1"))
    D2 = p["Delta2"] + np.diag(_per_axis(delta2, n, "hysteresis_asymmetry.Delta2"))
    return replace(hcfg, Delta1=tuple(map(tuple, D1)), Delta2=tuple(map(tuple, D2)))


def build_plant(cfg: PiezoConfig, effects: Sequence[tuple[str, Mapping[str, Any]]] = (), noise_std: float = 0.0,
                seed: int = 0) -> Plant:
    """The nominal plant of ``cfg`` with ``effects`` = ``[(name, params), …]`` added (see :data:`EFFECTS`).

    Voltage-side effects are applied in the order given, then the hysteresis (generalized/rate-dependent when
    those effects are present), creep and dynamics, then the displacement-side effects in the order given.
    """
    pre: list[Processor] = []
    post: list[Processor] = []
    hcfg, alpha, custom_h = cfg.hysteresis, 0.0, False
    relax = 0.0
    for name, p in effects:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
        spec = EFFECTS[name]
        if name == "hysteresis_asymmetry":
            hcfg = asymmetric_hysteresis_config(hcfg, p["Delta1"], p.get("Delta2", 0.0))
            custom_h = True
            if "even" in p or "branch_even" in p:
                post.append(BranchEvenTerm(p.get("even", 0.0), p.get("branch_even", 0.0), cfg.dt, cfg.n_axes))
            if p.get("play_radii"):
                post.append(PlayWidthTerm(p["play_radii"], p["play_gains"], cfg.n_axes))
        elif name == "hysteresis_rate_dependence":
            alpha += float(p["alpha"])
            custom_h = True
            if p.get("relaxation") is not None:
                r = float(p["relaxation"])
                if not (math.isfinite(r) and r >= 0):
                    raise ValueError(f"hysteresis_rate_dependence.relaxation: must be >= 0 s, got {r!r}")
                relax = max(relax, r)
        elif spec.position == "pre":
            pre.append(_stage(name, p, cfg))
        else:
            post.append(_stage(name, p, cfg))
    if custom_h:
        pre.append(HysteresisStage(hcfg, alpha, cfg.dt) if relax <= 0 else
                   RelaxedHysteresisStage(hcfg, alpha, cfg.dt, relax))
        return Plant(cfg, pre=pre, post=post, noise_std=noise_std, seed=seed, stages=("creep", "dynamics"))
    return Plant(cfg, pre=pre, post=post, noise_std=noise_std, seed=seed)


@njit
def _frac_delay_run(hist: np.ndarray, u: np.ndarray, frac: float, out: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """:class:`InputDelay` on one block without the temporaries: output k = (1 − frac)·ext[k+1] + frac·ext[k] of
    ``ext = [hist; u]`` (``hist`` = the last m + 1 inputs); returns the new history."""
    h = hist.shape[0]
    N, n = u.shape
    for k in range(N):
        for j in range(n):
            i1 = k + 1
            a = hist[i1, j] if i1 < h else u[i1 - h, j]
            if frac > 0:
                b = hist[k, j] if k < h else u[k - h, j]
                out[k, j] = (1.0 - frac) * a + frac * b
            else:
                out[k, j] = a
    new = np.empty_like(hist)
    for r in range(h):
        i = N + r  # ext index of the kept sample: the last h of ext (length h + N)
        for j in range(n):
            new[r, j] = hist[i, j] if i < h else u[i - h, j]
    return new


# --------------------------------------------------------------------------------------------------------------
# Richer forms of four candidates (issue 8): asymmetric rails, a relaxing hysteretic state, a play-operator loop
# width correction, an instantaneous (cubic) stiffness term of the modes
# --------------------------------------------------------------------------------------------------------------

class AsymmetricSaturation:
    """Amplifier rails that differ by sign: the voltage is clipped to ``[−lower_limit, +limit]`` [V]
    (``amplifier_saturation`` with ``lower_limit`` given; memoryless)."""

    def __init__(self, limit: float, lower_limit: float, n_axes: int = 2):
        for v, what in ((limit, "limit"), (lower_limit, "lower_limit")):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"amplifier_saturation.{what}: must be > 0 V, got {v!r}")
        self.limit, self.lower_limit, self.n = float(limit), float(lower_limit), n_axes

    def reset(self) -> None:
        """All states back to rest."""
        pass

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``."""
        res: np.ndarray = np.clip(_block(u, self.n), -self.lower_limit, self.limit)
        return res


@njit
def _relax2_run(x: np.ndarray, a: float, s1: np.ndarray, s2: np.ndarray, started: np.ndarray,
                out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Two cascaded unit-DC first-order relaxations (critically damped, pole ``a`` twice), per column; started
    settled at the first input."""
    N, n = x.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                s1[j] = x[t, j]
                s2[j] = x[t, j]
            s1[j] = a * s1[j] + (1.0 - a) * x[t, j]
            s2[j] = a * s2[j] + (1.0 - a) * s1[j]
            out[t, j] = s2[j]
        started[0] = True


class RelaxedHysteresisStage(HysteresisStage):
    """:class:`HysteresisStage` whose hysteretic state reaches the output through a critically damped relaxation
    ``1/(1 + s·τ)²`` (τ = ``relaxation`` [s]): ``Y_H = Dp·U − R_τ(h)``.  A viscous loop — it widens and turns with
    the frequency, unlike the ``alpha`` term, which widens it with the voltage rate.  Part of
    ``hysteresis_rate_dependence`` (parameter ``relaxation``)."""

    def __init__(self, cfg: BoucWenConfig, alpha: float = 0.0, dt: float = 5e-5, relaxation: float = 0.0):
        if not (math.isfinite(relaxation) and relaxation > 0):
            raise ValueError(f"hysteresis_rate_dependence.relaxation: must be > 0 s, got {relaxation!r}")
        self.relaxation = float(relaxation)
        self._a_relax = math.exp(-dt / self.relaxation)
        super().__init__(cfg, alpha, dt)

    def reset(self) -> None:
        """All states back to rest."""
        super().reset()
        self._r1 = np.zeros(self.cfg.n_out)
        self._r2 = np.zeros(self.cfg.n_out)
        self._r_started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.cfg.n_in)
        y = super().process(u)
        lin = u @ np.asarray(self._p[0], float).T  # Dp·U
        h = lin - y
        hr = np.empty_like(h)
        _relax2_run(h, self._a_relax, self._r1, self._r2, self._r_started, hr)
        res: np.ndarray = lin - hr
        return res


@njit
def _play_run(y: np.ndarray, radii: np.ndarray, z: np.ndarray, started: np.ndarray,
              out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Classical (symmetric) play operators of every column: out[t, k, j] = z_kj − y_j, z_kj clipped to
    [y_j − r_k, y_j + r_k]; started at z = y."""
    N, n = y.shape
    K = radii.shape[0]
    for t in range(N):
        for j in range(n):
            v = y[t, j]
            for k in range(K):
                if not started[0]:
                    z[k, j] = v
                zk = z[k, j]
                if zk < v - radii[k]:
                    zk = v - radii[k]
                elif zk > v + radii[k]:
                    zk = v + radii[k]
                z[k, j] = zk
                out[t, k, j] = zk - v
        started[0] = True


class PlayWidthTerm:
    """Loop-width correction of the asymmetric hysteresis candidate: ``Y_i += Σ_k w_ki·(P_k(Y_i) − Y_i)``, with
    ``P_k`` the classical play operator of radius ``play_radii[k]`` [m] on the displacement (each term is ±r_k on
    the branches, and changes sides over a reversal of 2·r_k): a loop wider or narrower than the nominal
    Bouc-Wen's, by an amount that depends on how far the motion has gone since it last reversed.  ``play_gains``:
    [K][n] (or one value per radius, shared by the axes)."""

    def __init__(self, play_radii: ArrayLike, play_gains: ArrayLike, n_axes: int = 2) -> None:
        r = np.atleast_1d(np.asarray(play_radii, float)).reshape(-1)
        if r.size == 0 or not np.all(np.isfinite(r)) or np.any(r <= 0):
            raise ValueError(f"hysteresis_asymmetry.play_radii: expected positive radii [m], got {play_radii!r}")
        g = np.asarray(play_gains, float)
        if g.ndim <= 1:
            g = np.repeat(np.atleast_1d(g).reshape(-1, 1), n_axes, axis=1) if g.size == r.size else g
        if g.shape != (r.size, n_axes) or not np.all(np.isfinite(g)):
            raise ValueError(f"hysteresis_asymmetry.play_gains: expected [{r.size}][{n_axes}] finite values, got "
                             f"{play_gains!r}")
        self.radii, self.gains, self.n = r, g, n_axes
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._z = np.zeros((self.radii.size, self.n))
        self._started = np.zeros(1, np.bool_)

    def terms(self, y: np.ndarray) -> np.ndarray:
        """``P_k(Y) − Y`` as [N, K, n] (advances the operators' state)."""
        y = _block(y, self.n)
        out = np.empty((len(y), self.radii.size, self.n))
        _play_run(y, self.radii, self._z, self._started, out)
        return out

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        res: np.ndarray = y + np.einsum("tkj,kj->tj", self.terms(y), self.gains)
        return res


#: the cubic term of the amplitude-dependent dynamics acts on (Y/LEVEL_REF)²·Y
class CubicAmplitudeDynamics(AmplitudeDependentDynamics):
    """:class:`AmplitudeDependentDynamics` plus an instantaneous stiffness change of each mode with the level:
    ``+ Σ_m (c_mi·BP_m + d_mi·HP_m)(Y_i·(Y_i/LEVEL_REF)²)`` — to first order, what a cubic (hardening or
    softening) spring of the mode adds, where the slow-envelope term cannot follow a stiffness that changes
    within each cycle.  ``cubic_gains``/``cubic_hp_gains``: ``[K][n]``."""

    def __init__(self, freq: ArrayLike, damping: ArrayLike, gains: ArrayLike, level_gains: ArrayLike, dt: float,
                 n_axes: int = 2, hp_gains: ArrayLike | None = None, level_hp_gains: ArrayLike | None = None,
                 cubic_gains: ArrayLike = 0.0, cubic_hp_gains: ArrayLike | None = None) -> None:
        super().__init__(freq, damping, gains, level_gains, dt, n_axes, hp_gains, level_hp_gains)
        K = len(self.freqs)
        name = "amplitude_dependent_dynamics"

        def diag(v: ArrayLike, what: str) -> np.ndarray:
            return np.diagonal(_mode_gains(v, K, n_axes, f"{name}.{what}"), axis1=1, axis2=2).copy()
        self.Kc = diag(cubic_gains, "cubic_gains")
        self.Hc = np.zeros_like(self.Kc) if cubic_hp_gains is None else diag(cubic_hp_gains, "cubic_hp_gains")
        self._cubic = UnmodelledMode(self.freqs, self.dampings, np.zeros((K, n_axes, n_axes)), dt, n_axes)

    def reset(self) -> None:
        """All states back to rest."""
        super().reset()
        if hasattr(self, "_cubic"):
            self._cubic.reset()

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        out = super().process(y)
        c = y * (y / LEVEL_REF) ** 2
        for m in range(len(self.freqs)):
            out += self._cubic.bandpass(c, m) * self.Kc[m] + self._cubic.highpass(c, m) * self.Hc[m]
        return out
