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
from typing import Mapping, Sequence

import numpy as np

from .._jit import njit
from ..config import BoucWenConfig, PiezoConfig
from .plant import Plant
from .bouc_wen import _bw_increment  # the core increment (same maths, no per-sample allocation)

__all__ = [
    "InputDelay", "AmplifierSlewLimit", "AmplifierSaturation", "AmplifierBandwidth", "GainMismatch",
    "ThermalDrift", "CreepNonlinearity", "UnmodelledMode", "HysteresisStage", "EffectSpec", "EFFECTS",
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


def _block(x, n: int | None = None) -> np.ndarray:
    x = np.ascontiguousarray(x, dtype=float)
    if x.ndim != 2 or (n is not None and x.shape[1] != n):
        raise ValueError(f"expected a block of shape [N, {n if n is not None else 'axes'}], got {x.shape}")
    return x


def _per_axis(value, n: int, name: str) -> np.ndarray:
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
        self._hist = None  # last m + 1 input samples, oldest first

    def process(self, u):
        u = _block(u, self.n)
        m = self._m
        if self._hist is None:
            if len(u) == 0:
                return u.copy()
            self._hist = np.repeat(u[:1], m + 1, axis=0)
        ext = np.concatenate([self._hist, u])
        N = len(u)
        # output k uses ext[k+1] (= u[k-m]) and ext[k] (= u[k-m-1])
        a = ext[1:N + 1]
        b = ext[0:N]
        out = (1.0 - self._frac) * a + self._frac * b if self._frac > 0 else a.copy()
        self._hist = ext[len(ext) - (m + 1):].copy()
        return out


@njit
def _slew_run(u, y_prev, started, max_step, out):  # pragma: no cover - compiled
    N, n = u.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                y_prev[j] = u[t, j]
            d = u[t, j] - y_prev[j]
            if d > max_step:
                d = max_step
            elif d < -max_step:
                d = -max_step
            y_prev[j] += d
            out[t, j] = y_prev[j]
        started[0] = True


class AmplifierSlewLimit:
    """Amplifier slew-rate limit: the voltage changes by at most ``rate·dt`` per sample [V/s]."""

    def __init__(self, rate: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"amplifier_slew_limit.rate: must be > 0 V/s, got {rate!r}")
        self.rate, self.dt, self.n = float(rate), float(dt), n_axes
        self.reset()

    def reset(self) -> None:
        self._prev = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def process(self, u):
        u = _block(u, self.n)
        out = np.empty_like(u)
        _slew_run(u, self._prev, self._started, self.rate * self.dt, out)
        return out


class AmplifierSaturation:
    """Amplifier output rails: the voltage is clipped to ``[−limit, +limit]`` [V] (memoryless)."""

    def __init__(self, limit: float, n_axes: int = 2):
        if not (math.isfinite(limit) and limit > 0):
            raise ValueError(f"amplifier_saturation.limit: must be > 0 V, got {limit!r}")
        self.limit, self.n = float(limit), n_axes

    def reset(self) -> None:
        pass

    def process(self, u):
        return np.clip(_block(u, self.n), -self.limit, self.limit)


@njit
def _lp1_run(u, y_prev, started, a, out):  # pragma: no cover - compiled
    N, n = u.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                y_prev[j] = u[t, j]
            y_prev[j] = a * y_prev[j] + (1.0 - a) * u[t, j]
            out[t, j] = y_prev[j]
        started[0] = True


class AmplifierBandwidth:
    """First-order amplifier bandwidth ``1/(s/ωc + 1)`` on the voltage (pole-matched, unit DC gain).

    The filter starts settled at the first voltage it sees.
    """

    def __init__(self, cutoff: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(cutoff) and cutoff > 0):
            raise ValueError(f"amplifier_bandwidth.cutoff: must be > 0 Hz, got {cutoff!r}")
        self.cutoff, self.dt, self.n = float(cutoff), float(dt), n_axes
        self._a = math.exp(-2.0 * math.pi * self.cutoff * self.dt)
        self.reset()

    def reset(self) -> None:
        self._prev = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def process(self, u):
        u = _block(u, self.n)
        out = np.empty_like(u)
        _lp1_run(u, self._prev, self._started, self._a, out)
        return out


# --------------------------------------------------------------------------------------------------------------
# Displacement-side stages
# --------------------------------------------------------------------------------------------------------------

class GainMismatch:
    """Per-axis gain error of the whole chain (piezo coefficient, sensor calibration): ``Y_i ← g_i·Y_i``."""

    def __init__(self, gains, n_axes: int = 2):
        self.n = n_axes
        self.gains = _per_axis(gains, n_axes, "gain_mismatch.gains")

    def reset(self) -> None:
        pass

    def process(self, y):
        return _block(y, self.n) * self.gains


class ThermalDrift:
    """Thermal expansion after switch-on: ``Y_i += a_i·(1 − exp(−t/τ))`` with t counted from the first sample.

    ``amplitudes`` [m] per axis, ``time_constant`` τ [s].
    """

    def __init__(self, amplitudes, time_constant: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(time_constant) and time_constant > 0):
            raise ValueError(f"thermal_drift.time_constant: must be > 0 s, got {time_constant!r}")
        self.n, self.dt, self.tau = n_axes, float(dt), float(time_constant)
        self.amplitudes = _per_axis(amplitudes, n_axes, "thermal_drift.amplitudes")
        self.reset()

    def reset(self) -> None:
        self._k = 0

    def regressor(self, N: int, start: int = 0) -> np.ndarray:
        """The drift shape ``1 − exp(−t/τ)`` for samples ``start … start+N−1``."""
        t = (np.arange(start, start + N, dtype=float)) * self.dt
        return -np.expm1(-t / self.tau)

    def process(self, y):
        y = _block(y, self.n)
        shape = self.regressor(len(y), self._k)
        self._k += len(y)
        return y + shape[:, None] * self.amplitudes


@njit
def _lp_bank_run(x, a, state, out):  # pragma: no cover - compiled
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

    def __init__(self, gamma, beta: float, dt: float, n_axes: int = 2, taus: Sequence[float] = CREEP_TAUS):
        self.n, self.dt = n_axes, float(dt)
        self.gamma = _per_axis(gamma, n_axes, "creep_nonlinearity.gamma")
        if not math.isfinite(beta):
            raise ValueError(f"creep_nonlinearity.beta: must be finite, got {beta!r}")
        self.beta = float(beta)
        self._a = np.exp(-self.dt / np.asarray(taus, float))
        self.reset()

    def reset(self) -> None:
        self._state = np.zeros((len(self._a), self.n))
        self._started = False

    @staticmethod
    def level_input(y: np.ndarray, beta: float) -> np.ndarray:
        return y + beta * y * np.abs(y) / CREEP_YREF

    def process(self, y):
        y = _block(y, self.n)
        v = self.level_input(y, self.beta)
        out = np.empty_like(v)
        _lp_bank_run(v, self._a, self._state, out)
        return y + out * self.gamma


@njit
def _biquad_run(x, b0, b1, b2, a1, a2, z, out):  # pragma: no cover - compiled
    N, n = x.shape
    for t in range(N):
        for j in range(n):
            xi = x[t, j]
            yi = b0 * xi + z[0, j]
            z[0, j] = b1 * xi - a1 * yi + z[1, j]
            z[1, j] = b2 * xi - a2 * yi
            out[t, j] = yi


def _bandpass_coeffs(freq: float, damping: float, dt: float):
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


class UnmodelledMode:
    """A structural resonance the nominal G_L lacks: ``Y_i ← Y_i + g_i·BP(Y_i)``.

    ``BP(s) = 2ζωs/(s² + 2ζωs + ω²)``: no static effect, peak gain ``g_i`` at ``freq`` [Hz] with damping ``ζ``.
    """

    def __init__(self, freq: float, damping: float, gains, dt: float, n_axes: int = 2):
        if not (math.isfinite(freq) and 0 < freq < 0.5 / dt):
            raise ValueError(f"unmodelled_mode.freq: must be in (0, Nyquist={0.5 / dt:g}) Hz, got {freq!r}")
        if not (math.isfinite(damping) and 0 < damping < 5):
            raise ValueError(f"unmodelled_mode.damping: must be in (0, 5), got {damping!r}")
        self.n, self.dt, self.freq, self.damping = n_axes, float(dt), float(freq), float(damping)
        self.gains = _per_axis(gains, n_axes, "unmodelled_mode.gains")
        self._c = _bandpass_coeffs(self.freq, self.damping, self.dt)
        self.reset()

    def reset(self) -> None:
        self._z = np.zeros((2, self.n))

    def bandpass(self, y):
        y = _block(y, self.n)
        out = np.empty_like(y)
        _biquad_run(y, *self._c, self._z, out)
        return out

    def process(self, y):
        y = _block(y, self.n)
        return y + self.bandpass(y) * self.gains


# --------------------------------------------------------------------------------------------------------------
# Hysteresis replacement: generalized + rate-dependent Bouc-Wen
# --------------------------------------------------------------------------------------------------------------

@njit
def _bw_rate_run(Dp, A, B, G, D1, D2, P, alpha, rate_ref, a_smooth, dt,
                 h, u_prev, rate, started, u, y):  # pragma: no cover - compiled
    N = u.shape[0]
    k = u.shape[1]
    n = h.shape[0]
    du = np.zeros(k)
    dus = np.zeros(k)
    dh = np.zeros(n)
    duh = np.zeros(n)  # scratch of the core increment
    for t in range(N):
        if not started[0]:
            for j in range(k):
                u_prev[j] = u[t, j]
            started[0] = True
        for j in range(k):
            du[j] = u[t, j] - u_prev[j]
            rate[j] = a_smooth * rate[j] + (1.0 - a_smooth) * abs(du[j]) / dt
        if alpha != 0.0:
            # A·dU with A scaled by (1 + α·tanh(|u̇|/rate_ref)): the loop widens with the rate, up to (1 + α)
            for j in range(k):
                dus[j] = du[j] * (1.0 + alpha * math.tanh(rate[j] / rate_ref))
            # the rate only enlarges the A term: add it separately so B/Γ/Δ still see the true dU
            _bw_increment(A, B, G, D1, D2, P, h, du, dh, duh)
            for i in range(n):
                acc = 0.0
                for j in range(k):
                    acc += A[i, j] * (dus[j] - du[j])
                dh[i] += acc
        else:
            _bw_increment(A, B, G, D1, D2, P, h, du, dh, duh)
        for i in range(n):
            h[i] += dh[i]
        for j in range(k):
            u_prev[j] = u[t, j]
        for i in range(n):
            acc = 0.0
            for j in range(k):
                acc += Dp[i, j] * u[t, j]
            y[t, i] = acc - h[i]


class HysteresisStage:
    """Bouc-Wen hysteresis with the generalized (asymmetric) terms and an optional rate dependence.

    Replaces the nominal hysteresis part: ``Y_H = Dp·U − h``, ``dh = A·(1 + α·tanh(r/r_ref))∘dU − B(|dÛ|∘h) − Γ(dÛ∘|h|)
    − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)`` where r is |dU/dt| smoothed over :data:`RATE_SMOOTHING` and r_ref =
    :data:`RATE_REF`.  ``alpha = 0`` and zero Δ give exactly the nominal :class:`BoucWenModel`.
    """

    def __init__(self, cfg: BoucWenConfig, alpha: float = 0.0, dt: float = 5e-5):
        self.cfg = cfg
        p = cfg.arrays()
        self._p = (p["Dp"], p["A"], p["B"], p["Gamma"], p["Delta1"], p["Delta2"], p["P"])
        if not math.isfinite(alpha):
            raise ValueError(f"hysteresis_rate_dependence.alpha: must be finite, got {alpha!r}")
        self.alpha, self.dt = float(alpha), float(dt)
        self._a_smooth = math.exp(-self.dt / RATE_SMOOTHING)
        self.reset()

    def reset(self) -> None:
        self._h = np.zeros(self.cfg.n_out)
        self._u_prev = np.zeros(self.cfg.n_in)
        self._rate = np.zeros(self.cfg.n_in)
        self._started = np.zeros(1, np.bool_)

    def process(self, u):
        u = _block(u, self.cfg.n_in)
        y = np.empty((len(u), self.cfg.n_out))
        _bw_rate_run(*self._p, self.alpha, RATE_REF, self._a_smooth, self.dt,
                     self._h, self._u_prev, self._rate, self._started, u, y)
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
    params: Mapping[str, tuple]
    description: str
    signature: str


EFFECTS: dict[str, EffectSpec] = {s.name: s for s in [
    EffectSpec("hysteresis_asymmetry", "hysteresis", {"Delta1": ("1/V", True), "Delta2": ("1/V", True)},
               "generalized Bouc-Wen: ascending and descending branches not point-symmetric",
               "even harmonics in the residual (error correlates with U², not U)"),
    EffectSpec("hysteresis_rate_dependence", "hysteresis", {"alpha": ("-", False)},
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
    EffectSpec("amplifier_saturation", "pre", {"limit": ("V", False)},
               "amplifier output rails clip the voltage", "error only at the largest |U|"),
    EffectSpec("amplifier_bandwidth", "pre", {"cutoff": ("Hz", False)},
               "first-order amplifier bandwidth", "amplitude loss and phase lag at high frequency"),
    EffectSpec("unmodelled_mode", "post", {"freq": ("Hz", False), "damping": ("-", False), "gains": ("-", True)},
               "an extra lightly damped structural resonance", "a narrow peak in the residual spectrum"),
    EffectSpec("gain_mismatch", "post", {"gains": ("-", True)},
               "per-axis gain error (piezo coefficient, sensor calibration)",
               "residual ∝ Ŷ on each axis (a scaled copy of the prediction)"),
]}
EFFECT_NAMES = tuple(EFFECTS)


def _stage(name: str, p: Mapping, cfg: PiezoConfig):
    n, dt = cfg.n_axes, cfg.dt
    if name == "input_delay":
        return InputDelay(p["delay"], dt, n)
    if name == "amplifier_slew_limit":
        return AmplifierSlewLimit(p["rate"], dt, n)
    if name == "amplifier_saturation":
        return AmplifierSaturation(p["limit"], n)
    if name == "amplifier_bandwidth":
        return AmplifierBandwidth(p["cutoff"], dt, n)
    if name == "gain_mismatch":
        return GainMismatch(p["gains"], n)
    if name == "thermal_drift":
        return ThermalDrift(p["amplitudes"], p["time_constant"], dt, n)
    if name == "creep_nonlinearity":
        return CreepNonlinearity(p["gamma"], p.get("beta", 0.0), dt, n)
    if name == "unmodelled_mode":
        return UnmodelledMode(p["freq"], p["damping"], p["gains"], dt, n)
    raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")


def asymmetric_hysteresis_config(hcfg: BoucWenConfig, delta1, delta2) -> BoucWenConfig:
    """The nominal Bouc-Wen with diagonal generalized terms ``Δ1 = diag(delta1)``, ``Δ2 = diag(delta2)`` added."""
    n = hcfg.n_out
    p = hcfg.arrays()
    D1 = p["Delta1"] + np.diag(_per_axis(delta1, n, "hysteresis_asymmetry.Delta1"))
    D2 = p["Delta2"] + np.diag(_per_axis(delta2, n, "hysteresis_asymmetry.Delta2"))
    return replace(hcfg, Delta1=tuple(map(tuple, D1)), Delta2=tuple(map(tuple, D2)))


def build_plant(cfg: PiezoConfig, effects: Sequence[tuple[str, Mapping]] = (), noise_std: float = 0.0,
                seed: int = 0) -> Plant:
    """The nominal plant of ``cfg`` with ``effects`` = ``[(name, params), …]`` added (see :data:`EFFECTS`).

    Voltage-side effects are applied in the order given, then the hysteresis (generalized/rate-dependent when
    those effects are present), creep and dynamics, then the displacement-side effects in the order given.
    """
    pre, post = [], []
    hcfg, alpha, custom_h = cfg.hysteresis, 0.0, False
    for name, p in effects:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
        spec = EFFECTS[name]
        if name == "hysteresis_asymmetry":
            hcfg = asymmetric_hysteresis_config(hcfg, p["Delta1"], p.get("Delta2", 0.0))
            custom_h = True
        elif name == "hysteresis_rate_dependence":
            alpha += float(p["alpha"])
            custom_h = True
        elif spec.position == "pre":
            pre.append(_stage(name, p, cfg))
        else:
            post.append(_stage(name, p, cfg))
    if custom_h:
        pre.append(HysteresisStage(hcfg, alpha, cfg.dt))
        return Plant(cfg, pre=pre, post=post, noise_std=noise_std, seed=seed, stages=("creep", "dynamics"))
    return Plant(cfg, pre=pre, post=post, noise_std=noise_std, seed=seed)
