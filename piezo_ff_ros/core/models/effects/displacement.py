"""Displacement-side effects without dynamics (``post`` stages): gain, thermal drift and nonlinear creep.

:class:`GainMismatch` (gain error and cross-talk of the whole chain, memoryless), :class:`ThermalDrift` (expansion
after switch-on) and :class:`CreepNonlinearity` (logarithmic-in-time creep growing with the level, a bank of
first-order relaxations, one per decade of :data:`~.common.CREEP_TAUS`).  A stage maps a displacement block
``[N, axes]`` [m] to a displacement block and carries its state between blocks.  The structural modes, also on the
displacement, are in :mod:`.modes`.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..._jit import njit
from ...lti import static_gain
from .common import CREEP_TAUS, CREEP_YREF, _block, _per_axis

__all__ = ["GainMismatch", "ThermalDrift", "CreepNonlinearity"]


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
        res: np.ndarray = y * self.gains if self._diag else static_gain(y, self.G)
        return res


class ThermalDrift:
    """Thermal expansion after switch-on: ``Y_i += a_i·(1 − exp(−t/τ))`` with t counted from the first sample.

    ``amplitudes`` [m] per axis, ``time_constant`` τ [s].  Optionally the two-body form (the stack heats fast, its
    mount slowly; each body's temperature a first-order response to the switch-on): a second shape with
    ``amplitudes2`` [m] and ``time_constant2`` [s], and the piezo gain following the temperature, ``gain_drift`` /
    ``gain_drift2`` (relative gain change per axis at the end of each shape): ``Y_i ← Y_i·(1 + g_i·s_1 + h_i·s_2) +
    a_i·s_1 + b_i·s_2``.
    """

    def __init__(self, amplitudes: ArrayLike, time_constant: float, dt: float, n_axes: int = 2,
                 amplitudes2: ArrayLike | None = None, time_constant2: float | None = None,
                 gain_drift: ArrayLike | None = None, gain_drift2: ArrayLike | None = None) -> None:
        for name, tau in (("time_constant", time_constant), ("time_constant2", time_constant2)):
            if tau is not None and not (math.isfinite(tau) and tau > 0):
                raise ValueError(f"thermal_drift.{name}: must be > 0 s, got {tau!r}")
        if (amplitudes2 is not None or gain_drift2 is not None) and time_constant2 is None:
            raise ValueError("thermal_drift.time_constant2: needed with amplitudes2 or gain_drift2")
        self.n, self.dt, self.tau = n_axes, float(dt), float(time_constant)
        self.tau2 = None if time_constant2 is None else float(time_constant2)
        self.amplitudes = _per_axis(amplitudes, n_axes, "thermal_drift.amplitudes")
        zero = np.zeros(n_axes)
        self.amplitudes2 = zero if amplitudes2 is None else _per_axis(amplitudes2, n_axes, "thermal_drift.amplitudes2")
        self.gain_drift = zero if gain_drift is None else _per_axis(gain_drift, n_axes, "thermal_drift.gain_drift")
        self.gain_drift2 = zero if gain_drift2 is None else _per_axis(gain_drift2, n_axes,
                                                                       "thermal_drift.gain_drift2")
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._k = 0

    def regressor(self, N: int, start: int = 0, tau: float | None = None) -> np.ndarray:
        """The drift shape ``1 − exp(−t/τ)`` for samples ``start … start+N−1`` (τ: the first time constant unless
        given)."""
        t = (np.arange(start, start + N, dtype=float)) * self.dt
        return -np.expm1(-t / (self.tau if tau is None else tau))

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        shape = self.regressor(len(y), self._k)
        if self.tau2 is None:
            self._k += len(y)
            res: np.ndarray = y + shape[:, None] * self.amplitudes
            if np.any(self.gain_drift):
                res = res + shape[:, None] * self.gain_drift * y
            return res
        shape2 = self.regressor(len(y), self._k, self.tau2)
        self._k += len(y)
        gain = shape[:, None] * self.gain_drift + shape2[:, None] * self.gain_drift2
        out: np.ndarray = y + gain * y + shape[:, None] * self.amplitudes + shape2[:, None] * self.amplitudes2
        return out


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


@njit
def _lp_bank_run_weighted(x: np.ndarray, a: np.ndarray, w: np.ndarray, state: np.ndarray,
                          out: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`_lp_bank_run` with a weight per low-pass and column (``Σ_i w[i, j]·LP_i``); ``w`` [len(a), n]."""
    N, n = x.shape
    m = a.shape[0]
    for t in range(N):
        for j in range(n):
            acc = 0.0
            for i in range(m):
                state[i, j] = a[i] * state[i, j] + (1.0 - a[i]) * x[t, j]
                acc += w[i, j] * state[i, j]
            out[t, j] = acc


class CreepNonlinearity:
    """Creep the linear first-order model misses: logarithmic in time and growing with the level.

    ``Y ← Y + γ·Σ_τ w_τ·LP_τ(Y + β·Y|Y|/Y_ref)``, one first-order relaxation per decade (τ in :data:`CREEP_TAUS`)
    and ``β`` the relative growth of the creep at ``Y_ref`` = 10 µm.  With ``w_τ = 1`` (no ``spectrum``) a step
    creeps by ≈ γ·Y per decade of time, the classical log-time law.  ``spectrum`` [len(taus)][axis] gives each
    relaxation its own weight per axis: a linear viscoelastic creep is a Prony series ``Σ J_τ·(1 − e^{−t/τ})``
    (generalised Kelvin–Voigt), so any creep law — fractional (∝ t^α), saturating, Andrade's — is such a spectrum
    over the bank's span.  ``beta_even`` adds ``β_e·Y²/Y_ref`` to the bank's input: a creep that grows with
    extension and shrinks with contraction (or the reverse).  ``gamma`` (per axis), ``beta``, ``beta_even`` and
    ``spectrum`` are dimensionless.
    """

    def __init__(self, gamma: ArrayLike, beta: float, dt: float, n_axes: int = 2,
                 taus: Sequence[float] = CREEP_TAUS, spectrum: ArrayLike | None = None,
                 beta_even: float = 0.0) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.gamma = _per_axis(gamma, n_axes, "creep_nonlinearity.gamma")
        for name, v in (("beta", beta), ("beta_even", beta_even)):
            if not math.isfinite(v):
                raise ValueError(f"creep_nonlinearity.{name}: must be finite, got {v!r}")
        self.beta = float(beta)
        self.beta_even = float(beta_even)
        self._a = np.exp(-self.dt / np.asarray(taus, float))
        self.spectrum: np.ndarray | None = None
        if spectrum is not None:
            w = np.asarray(spectrum, float)
            if w.ndim == 1:
                w = np.repeat(w[:, None], n_axes, axis=1)
            if w.shape != (len(self._a), n_axes) or not np.all(np.isfinite(w)):
                raise ValueError(f"creep_nonlinearity.spectrum: expected {len(self._a)}×{n_axes} finite weights "
                                 f"(relaxation × axis), got shape {w.shape}")
            self.spectrum = np.ascontiguousarray(w)
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
        if self.beta_even != 0.0:   # creep that grows on one side of the zero and shrinks on the other
            v = v + self.beta_even * y * y / CREEP_YREF
        out = np.empty_like(v)
        if self.spectrum is None:
            _lp_bank_run(v, self._a, self._state, out)
        else:
            _lp_bank_run_weighted(v, self._a, self.spectrum, self._state, out)
        res: np.ndarray = y + out * self.gamma
        return res
