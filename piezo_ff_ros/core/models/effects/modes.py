"""Structural-mode effects (``post`` stages): resonances the nominal dynamics ``G_L`` lacks, fixed or level-dependent.

:class:`UnmodelledMode` adds band-pass and high-pass terms of one or several pole pairs (bilinear, prewarped
biquads), :class:`AmplitudeDependentDynamics` adds terms modulated by the motion's level (|Y| low-passed over
:data:`~.common.LEVEL_TAU`, per :data:`~.common.LEVEL_REF`), and :class:`CubicAmplitudeDynamics` an instantaneous
(cubic-spring) stiffness term on top.  The biquad coefficients (``_bandpass_coeffs``, ``_highpass_coeffs``) are also
used by the diagnosis's mode fit.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from ..._jit import njit
from ...lti import static_gain
from .common import LEVEL_REF, LEVEL_TAU, _block, _per_axis

__all__ = ["UnmodelledMode", "AmplitudeDependentDynamics", "CubicAmplitudeDynamics", "BaseExcitedNonlinearMode",
           "MIN_STIFFNESS_FACTOR", "RK4_OMEGA_STEP", "base_excited_deflections"]


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

    ``lp_gains`` (default 0, ``[K][n][n]``): ``+ Σ_m Σ_j l_mij·LP_m(Y_j)`` with ``LP_m(s) = ω_m²/(s² + 2ζ_mω_m·s +
    ω_m²)`` (= 1 − BP_m − HP_m): a resonance with a static gain, as a lightly damped mode in an off-diagonal
    (cross-coupling) path has — y driven by x's motion through ``k·ω²/(s² + 2ζωs + ω²)``.  In a direct path a
    static term would be a gain error, so the fit uses it for i ≠ j only.
    """

    def __init__(self, freq: ArrayLike, damping: ArrayLike, gains: ArrayLike, dt: float, n_axes: int = 2,
                 hp_gains: ArrayLike | None = None, lp_gains: ArrayLike | None = None) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.freqs, self.dampings = _modes_spec(freq, damping, self.dt, "unmodelled_mode")
        self.freq, self.damping = float(self.freqs[0]), float(self.dampings[0])
        K = len(self.freqs)
        self.G = _mode_gains(gains, K, n_axes, "unmodelled_mode.gains")
        self.H = np.zeros_like(self.G) if hp_gains is None else _mode_gains(hp_gains, K, n_axes,
                                                                            "unmodelled_mode.hp_gains")
        self.L = np.zeros_like(self.G) if lp_gains is None else _mode_gains(lp_gains, K, n_axes,
                                                                            "unmodelled_mode.lp_gains")
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
        y = np.ascontiguousarray(_block(y, self.n), dtype=float)
        out = y.copy()
        for m in range(len(self._c)):
            bp = self.bandpass(y, m)
            with_hp = bool(np.any(self.H[m]) or np.any(self.L[m]))
            hp = self.highpass(y, m) if with_hp else bp
            _add_mode_terms(y, bp, hp, self.G[m], self.H[m], self.L[m], with_hp, bool(np.any(self.L[m])), out)
        return out


@njit
def _add_mode_terms(y: np.ndarray, bp: np.ndarray, hp: np.ndarray, G: np.ndarray, H: np.ndarray, L: np.ndarray,
                    with_hp: bool, with_lp: bool, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out += static_gain(bp, G)``, then (``with_hp``) ``+= static_gain(hp, H)``, then (``with_lp``)
    ``+= static_gain(y − bp − hp, L)``, in one pass: the same sums in the same order as
    :func:`~piezo_ff_ros.core.lti.static_gain` (input by input), without its block-sized temporaries."""
    N, n_in = y.shape
    n_out = G.shape[0]
    for t in range(N):
        for i in range(n_out):
            acc = bp[t, 0] * G[i, 0]
            for j in range(1, n_in):
                acc += bp[t, j] * G[i, j]
            o = out[t, i] + acc
            if with_hp:
                acc = hp[t, 0] * H[i, 0]
                for j in range(1, n_in):
                    acc += hp[t, j] * H[i, j]
                o = o + acc
                if with_lp:
                    acc = (y[t, 0] - bp[t, 0] - hp[t, 0]) * L[i, 0]
                    for j in range(1, n_in):
                        acc += (y[t, j] - bp[t, j] - hp[t, j]) * L[i, j]
                    o = o + acc
            out[t, i] = o


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
                 n_axes: int = 2, hp_gains: ArrayLike | None = None, level_hp_gains: ArrayLike | None = None,
                 lp_gains: ArrayLike | None = None) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.freqs, self.dampings = _modes_spec(freq, damping, self.dt, "amplitude_dependent_dynamics")
        K = len(self.freqs)
        name = "amplitude_dependent_dynamics"
        self.base = UnmodelledMode(self.freqs, self.dampings,
                                   _mode_gains(gains, K, n_axes, f"{name}.gains"), dt, n_axes,
                                   None if hp_gains is None else _mode_gains(hp_gains, K, n_axes, f"{name}.hp_gains"),
                                   None if lp_gains is None else _mode_gains(lp_gains, K, n_axes, f"{name}.lp_gains"))

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
            out += static_gain(bp, b.G[m]) + static_gain(hp, b.H[m]) + lev * (bp * self.Kl[m] + hp * self.Kh[m])
            if np.any(b.L[m]):
                out += static_gain(y - bp - hp, b.L[m])
        return out


#: the cubic term of the amplitude-dependent dynamics acts on (Y/LEVEL_REF)²·Y
class CubicAmplitudeDynamics(AmplitudeDependentDynamics):
    """:class:`AmplitudeDependentDynamics` plus an instantaneous stiffness change of each mode with the level:
    ``+ Σ_m (c_mi·BP_m + d_mi·HP_m)(Y_i·(Y_i/LEVEL_REF)²)`` — to first order, what a cubic (hardening or
    softening) spring of the mode adds, where the slow-envelope term cannot follow a stiffness that changes
    within each cycle.  ``cubic_gains``/``cubic_hp_gains``: ``[K][n]``."""

    def __init__(self, freq: ArrayLike, damping: ArrayLike, gains: ArrayLike, level_gains: ArrayLike, dt: float,
                 n_axes: int = 2, hp_gains: ArrayLike | None = None, level_hp_gains: ArrayLike | None = None,
                 cubic_gains: ArrayLike = 0.0, cubic_hp_gains: ArrayLike | None = None,
                 lp_gains: ArrayLike | None = None) -> None:
        super().__init__(freq, damping, gains, level_gains, dt, n_axes, hp_gains, level_hp_gains, lp_gains)
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


#: a softening spring's stiffness factor 1 + c·(d/LEVEL_REF)² is held at or above this share of the linear stiffness
#: (a cubic spring's range of validity: beyond it the mode would snap through, which no positioner does)
MIN_STIFFNESS_FACTOR = 0.2
#: the base-excited mode is integrated in RK4 sub-steps of at most this many radians of its natural frequency
RK4_OMEGA_STEP = 0.25


@njit(inline="always")
def _base_excited_accel(xs: float, vs: float, w: float, z: float, c3: float, c2: float, ref: float,
                        linear: bool) -> float:  # pragma: no cover - compiled
    """The relative acceleration of a base-excited mode at deflection ``xs``, velocity ``vs`` (between the base's
    velocity steps).  ``linear`` (c = q = 0): the same number without the cubic and quadratic factors (exactly 1).

    Both are computed and one is selected (no branch: the lanes of :func:`_base_excited_run` then run in SIMD
    registers); each is the expression it is alone, so the number is the same."""
    lin_accel = -2.0 * z * w * vs - w * w * xs
    nonlin_accel = (-2.0 * z * w * (1.0 + c2 * abs(vs) / (w * ref)) * vs
                    - w * w * xs * max(MIN_STIFFNESS_FACTOR, 1.0 + c3 * (xs / ref) ** 2))
    return lin_accel if linear else nonlin_accel


@njit(inline="always")
def _rk4_lanes(X: np.ndarray, V: np.ndarray, zl: np.ndarray, c3l: np.ndarray, c2l: np.ndarray, lin: np.ndarray,
               w: float, h: float, ref: float, linear_only: bool) -> None:  # pragma: no cover - compiled
    """One RK4 sub-step of every lane (deflection ``X``, velocity ``V``): a flat loop without branches.
    ``linear_only``: every lane is a linear twin (the accelerations are then the linear ones only)."""
    for lane in range(X.shape[0]):
        x = X[lane]
        v = V[lane]
        z = zl[lane]
        if linear_only:
            k_v = -2.0 * z * w * v - w * w * x
            kx = 0.0 + 1.0 * v
            kv = 0.0 + 1.0 * k_v
            xs, vs = x + 0.5 * h * v, v + 0.5 * h * k_v
            k_v = -2.0 * z * w * vs - w * w * xs
            kx += 2.0 * vs
            kv += 2.0 * k_v
            xs, vs = x + 0.5 * h * vs, v + 0.5 * h * k_v
            k_v = -2.0 * z * w * vs - w * w * xs
            kx += 2.0 * vs
            kv += 2.0 * k_v
            xs, vs = x + h * vs, v + h * k_v
            k_v = -2.0 * z * w * vs - w * w * xs
        else:
            c3 = c3l[lane]
            c2 = c2l[lane]
            ln = lin[lane]
            k_v = _base_excited_accel(x, v, w, z, c3, c2, ref, ln)
            kx = 0.0 + 1.0 * v
            kv = 0.0 + 1.0 * k_v
            xs, vs = x + 0.5 * h * v, v + 0.5 * h * k_v
            k_v = _base_excited_accel(xs, vs, w, z, c3, c2, ref, ln)
            kx += 2.0 * vs
            kv += 2.0 * k_v
            xs, vs = x + 0.5 * h * vs, v + 0.5 * h * k_v
            k_v = _base_excited_accel(xs, vs, w, z, c3, c2, ref, ln)
            kx += 2.0 * vs
            kv += 2.0 * k_v
            xs, vs = x + h * vs, v + h * k_v
            k_v = _base_excited_accel(xs, vs, w, z, c3, c2, ref, ln)
        kx += 1.0 * vs
        kv += 1.0 * k_v
        X[lane] = x + h * kx / 6.0
        V[lane] = v + h * kv / 6.0


@njit
def _base_excited_run(y: np.ndarray, w: float, zeta: np.ndarray, kc: np.ndarray, kq: np.ndarray, ref: float,
                      dt: float, osc: np.ndarray, hist: np.ndarray,
                      out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Deflections of K base-excited modes of one natural frequency, shaken by the same base ``y``: oscillator k has
    the damping ``zeta[k]``, the cubic spring ``kc[k]`` and the quadratic damping ``kq[k]`` (per axis; both 0: the
    linear twin), RK4 per sample; the base piecewise linear between samples (its velocity step, from the last three
    samples, an impulse at the interval's start).  ``out[k, t, j]`` = oscillator k's deflection.
    ``osc[k, j]`` = (d, d'), ``hist[j]`` = (y[k−1], y[k−2], samples seen).

    The oscillators share the base but not their states: each gets the numbers it gets alone.  Every (oscillator,
    axis) is one lane of a flat loop without branches (:func:`_base_excited_accel` selects the linear twin's
    acceleration), so that the compiler runs the lanes' RK4 sub-steps side by side in SIMD registers instead of
    one serial chain at a time (``test/test_diagnosis_speed6_base_excited.py``: the numbers of the plain loop
    oscillator by oscillator)."""
    N, n = y.shape
    K = kc.shape[0]
    L = K * n
    # RK4 sub-steps of at most RK4_OMEGA_STEP radians of the mode (its phase error then stays below ~1e-5 a step)
    sub = max(1, int(math.ceil(w * dt / RK4_OMEGA_STEP)))
    h = dt / sub
    lin = np.empty(L, np.bool_)
    zl = np.empty(L)
    c3l = np.empty(L)
    c2l = np.empty(L)
    for k in range(K):
        for j in range(n):
            lane = k * n + j
            lin[lane] = kc[k, j] == 0.0 and kq[k, j] == 0.0
            zl[lane] = zeta[k]
            c3l[lane] = kc[k, j]
            c2l[lane] = kq[k, j]
    all_linear = True
    for lane in range(L):
        all_linear = all_linear and lin[lane]
    X = np.empty(L)
    V = np.empty(L)
    dv = np.empty(n)
    for t in range(N):
        for j in range(n):
            yk = y[t, j]
            seen = hist[j, 2]
            if seen < 1.0:
                hist[j, 0] = yk
                hist[j, 1] = yk
            elif seen < 2.0:
                hist[j, 1] = hist[j, 0]
            # the base's velocity steps at the sample it starts the interval from (a piecewise-linear base): an
            # impulse on the relative velocity, then the mode moves freely over the interval
            dv[j] = (yk - 2.0 * hist[j, 0] + hist[j, 1]) / dt if seen >= 1.0 else 0.0
            hist[j, 1] = hist[j, 0]
            hist[j, 0] = yk
            hist[j, 2] = seen + 1.0
        for k in range(K):
            for j in range(n):
                X[k * n + j] = osc[k, j, 0]
                V[k * n + j] = osc[k, j, 1] - dv[j]
        if all_linear:  # linear twins only (a refinement's): the nonlinear expression is not computed at all
            for _ in range(sub):
                _rk4_lanes(X, V, zl, zl, zl, lin, w, h, ref, True)
        else:
            for _ in range(sub):
                _rk4_lanes(X, V, zl, c3l, c2l, lin, w, h, ref, False)
        for k in range(K):
            for j in range(n):
                osc[k, j, 0] = X[k * n + j]
                osc[k, j, 1] = V[k * n + j]
                out[k, t, j] = X[k * n + j]


def base_excited_deflections(y: np.ndarray, freq: float, damping: ArrayLike, cubic: ArrayLike,
                             quadratic_damping: ArrayLike, dt: float) -> np.ndarray:
    """Deflections ``[K, N, n]`` of K base-excited modes (``cubic``, ``quadratic_damping``: ``[K, n]``; a row of
    zeros is the linear twin; ``damping``: one for all or ``[K]``) from rest, shaken by the block ``y [N, n]``: what
    :meth:`BaseExcitedNonlinearMode.deflection_change` subtracts, for several coefficient sets in one pass over
    the base (the same numbers as one pass each)."""
    y = np.ascontiguousarray(y, dtype=float)
    kc = np.ascontiguousarray(np.atleast_2d(np.asarray(cubic, float)))
    kq = np.ascontiguousarray(np.atleast_2d(np.asarray(quadratic_damping, float)))
    K, n = kc.shape
    out = np.empty((K,) + y.shape)
    zeta = np.ascontiguousarray(np.broadcast_to(np.asarray(damping, float), (K,)))
    _base_excited_run(y, 2 * math.pi * float(freq), zeta, kc, kq, LEVEL_REF, float(dt),
                      np.zeros((K, n, 2)), np.zeros((n, 3)), out)
    return out


class BaseExcitedNonlinearMode:
    """One lightly damped mode shaken by the motion it carries, with a cubic spring and a quadratic
    (amplitude-dependent) damping; what its nonlinearity adds to the output: ``Y_i ← Y_i + d_i − d_lin,i``, where
    ``d`` is the mode's relative deflection,
    ``d'' + 2ζω(1 + q_i·|d'|/(ω·LEVEL_REF))·d' + ω²·d·max(MIN_STIFFNESS_FACTOR, 1 + c_i·(d/LEVEL_REF)²) = −Y_i''``,
    and ``d_lin`` its linear twin (c = q = 0) — a first bending mode whose linear part the nominal dynamics already
    hold.  ``cubic`` c_i (> 0 stiffening, < 0 softening) and ``quadratic_damping`` q_i per axis, dimensionless at
    :data:`~.common.LEVEL_REF`; ``freq`` [Hz] and ``damping`` shared.  Integrated by RK4 (sub-steps of :data:`RK4_OMEGA_STEP` rad), the base
    piecewise linear between samples (each velocity step an impulse on the relative velocity).  ``participation`` (per axis, default 1): how much
    of the mode's motion the output sees."""

    def __init__(self, freq: float, damping: float, cubic: ArrayLike, quadratic_damping: ArrayLike, dt: float,
                 n_axes: int = 2, participation: ArrayLike = 1.0) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.freq, self.damping = float(freq), float(damping)
        name = "amplitude_dependent_dynamics"
        if not (0 < self.freq < 0.5 / self.dt) or not (0 < self.damping <= 2.0):
            raise ValueError(f"{name}: base-excited mode needs 0 < freq < fs/2 and 0 < damping <= 2, got "
                             f"freq={freq!r}, damping={damping!r}")
        self.cubic = _per_axis(cubic, n_axes, f"{name}.cubic")
        self.quadratic_damping = _per_axis(quadratic_damping, n_axes, f"{name}.quadratic_damping")
        self.participation = _per_axis(participation, n_axes, f"{name}.participation")
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        # the nonlinear mode and its linear twin: (d, d') per axis; the base's last two samples and their count
        self._osc = np.zeros((2, self.n, 2))
        self._hist = np.zeros((self.n, 3))
        self._kc = np.ascontiguousarray(np.stack([self.cubic, np.zeros(self.n)]))
        self._kq = np.ascontiguousarray(np.stack([self.quadratic_damping, np.zeros(self.n)]))
        self._zeta = np.full(2, self.damping)

    def deflection_change(self, y: np.ndarray) -> np.ndarray:
        """``participation·(d − d_lin)`` of every column of one block (advances the state)."""
        y = np.ascontiguousarray(_block(y, self.n), dtype=float)
        out = np.empty((2,) + y.shape)
        _base_excited_run(y, 2 * math.pi * self.freq, self._zeta, self._kc, self._kq, LEVEL_REF, self.dt,
                          self._osc, self._hist, out)
        scaled: np.ndarray = (out[0] - out[1]) * self.participation
        return scaled

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        out: np.ndarray = y + self.deflection_change(y)
        return out
