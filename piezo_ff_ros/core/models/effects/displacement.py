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
