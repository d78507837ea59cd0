"""Multivariable creep compensator, inverse multiplicative structure (paper Eq. 12, Fig. 9).

``Y_H[k] = K⁻¹·(Y_L[k] − (Cr·Y_H)[k])``.  The ZOH-discretised Cr is strictly proper, so ``(Cr·Y_H)[k]`` depends
on Y_H up to k − 1: that is the paper's ``Cr(s)·Y_H(t − Ts)``, and it makes the compensator the exact inverse of
the discrete creep model.  No transfer function is inverted; the parameters are the model's.
"""
from __future__ import annotations

import numpy as np

from .._jit import njit
from ..config import CreepConfig
from ..lti import DiscreteModalSS
from ..models.creep import discretise_creep

__all__ = ["CreepCompensator", "creep_inverse_poles"]


def creep_inverse_poles(cfg: CreepConfig, dt: float) -> np.ndarray:
    """Poles (z-plane) of the compensator loop: eigenvalues of ``A − B·K⁻¹·C``."""
    ss = discretise_creep(cfg, dt)
    Kinv = np.linalg.inv(np.array(cfg.K, float))
    if ss.n_states == 0:
        return np.zeros(0)
    return np.linalg.eigvals(ss.A - ss.B @ Kinv @ ss.C)


class CreepCompensator:
    """Streaming ``Y_L [m] → Y_H [m]``."""

    def __init__(self, cfg: CreepConfig, dt: float):
        self.cfg = cfg
        self.dt = dt
        self.Kinv = np.ascontiguousarray(np.linalg.inv(np.array(cfg.K, float)))
        self.ss: DiscreteModalSS = discretise_creep(cfg, dt)
        if not self.ss.strictly_proper:
            raise ValueError("creep.Cr must be strictly proper")
        self._Ablk, self._offsets = self.ss.packed()
        self.x = np.zeros(self.ss.n_states)

    @property
    def n_in(self) -> int:
        return self.Kinv.shape[1]

    @property
    def n_out(self) -> int:
        return self.Kinv.shape[0]

    def reset(self) -> None:
        self.x[:] = 0.0

    def process(self, yl: np.ndarray) -> np.ndarray:
        yl = np.ascontiguousarray(yl, dtype=float)
        yh = np.empty_like(yl)
        _inverse_affine_run(self.Kinv, self._Ablk, self._offsets, self.ss.sizes, self.ss.B, self.ss.C, self.x, yl, yh)
        return yh


@njit
def _inverse_affine_run(Kinv, Ablk, offsets, sizes, B, C, x, yl, yh):  # pragma: no cover - compiled
    N = yl.shape[0]
    n = yl.shape[1]
    ns = x.shape[0]
    nb = sizes.shape[0]
    xn = np.empty(ns)
    c = np.empty(n)
    for k in range(N):
        for o in range(n):
            acc = 0.0
            for i in range(ns):
                acc += C[o, i] * x[i]
            c[o] = yl[k, o] - acc
        for o in range(n):
            acc = 0.0
            for j in range(n):
                acc += Kinv[o, j] * c[j]
            yh[k, o] = acc
        for b in range(nb):
            off = offsets[b]
            s = sizes[b]
            for r in range(s):
                acc = 0.0
                for cc in range(s):
                    acc += Ablk[off + r, cc] * x[off + cc]
                for j in range(n):
                    acc += B[off + r, j] * yh[k, j]
                xn[off + r] = acc
        for i in range(ns):
            x[i] = xn[i]
