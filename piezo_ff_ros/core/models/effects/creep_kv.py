"""Creep of one Kelvin–Voigt element with its own retardation time, fed by the level and by the level's square:
``creep_nonlinearity`` with ``retardation`` given.

``Y_i ← Y_i + a_i·KV_τ(Y_i) + b_i·KV_τ(Y_i·|Y_i|/Y_ref)``, ``KV_τ`` the unit-DC first-order relaxation (a spring and
dashpot in parallel: retardation time τ), ``Y_ref`` = :data:`~.common.CREEP_YREF`.  The linear creep of a
viscoelastic element (``a``) and the voltage/level-dependent creep whose strength grows with the extension
(``b``: the creep rate ∝ the field, the field ∝ the level).  One element with a free τ is the parsimonious member of
the creep family beside the log law and the relaxation spectrum of :class:`~.displacement.CreepNonlinearity`, whose
relaxation times are fixed at the decades; a single retardation time between two decades needs both neighbours
there and extrapolates badly beyond the record.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from ..._jit import njit
from .common import CREEP_YREF, _block, _per_axis

__all__ = ["KelvinVoigtCreep"]


@njit
def _kv_run(y: np.ndarray, a: float, yref: float, lin: np.ndarray, lev: np.ndarray, state: np.ndarray,
            out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Per column j: ``s1 ← a·s1 + (1−a)·y``, ``s2 ← a·s2 + (1−a)·y|y|/yref``, ``out = y + lin_j·s1 + lev_j·s2``;
    ``state[2, n]`` carried between blocks (started at rest)."""
    N, n = y.shape
    for t in range(N):
        for j in range(n):
            x = y[t, j]
            state[0, j] = a * state[0, j] + (1.0 - a) * x
            state[1, j] = a * state[1, j] + (1.0 - a) * (x * abs(x) / yref)
            out[t, j] = x + lin[j] * state[0, j] + lev[j] * state[1, j]


class KelvinVoigtCreep:
    """One Kelvin–Voigt creep element, retardation time ``retardation`` [s], fed by the level (``kv_gains``, per
    axis, dimensionless) and by its signed square over ``CREEP_YREF`` (``kv_level_gains``, per axis)."""

    def __init__(self, retardation: float, kv_gains: ArrayLike, kv_level_gains: ArrayLike, dt: float,
                 n_axes: int = 2) -> None:
        if not (math.isfinite(retardation) and retardation > 0):
            raise ValueError(f"creep_nonlinearity.retardation: must be > 0 s, got {retardation!r}")
        self.n, self.dt, self.retardation = n_axes, float(dt), float(retardation)
        self.kv_gains = _per_axis(kv_gains, n_axes, "creep_nonlinearity.kv_gains")
        self.kv_level_gains = _per_axis(kv_level_gains, n_axes, "creep_nonlinearity.kv_level_gains")
        self._a = math.exp(-self.dt / self.retardation)
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._state = np.zeros((2, self.n))

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = np.ascontiguousarray(_block(y, self.n), dtype=float)
        out = np.empty_like(y)
        _kv_run(y, self._a, CREEP_YREF, self.kv_gains, self.kv_level_gains, self._state, out)
        return out
