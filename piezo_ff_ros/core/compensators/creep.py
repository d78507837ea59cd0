"""Multivariable creep compensator, inverse multiplicative structure (paper Eq. 12, Fig. 9).

``Y_H[k] = K⁻¹·(Y_L[k] − (Cr·Y_H)[k])``.  The ZOH-discretised Cr is strictly proper, so ``(Cr·Y_H)[k]`` depends
on Y_H up to k − 1: that is the paper's ``Cr(s)·Y_H(t − Ts)``, and it makes the compensator the exact inverse of
the discrete creep model.  No transfer function is inverted; the parameters are the model's.
"""
from __future__ import annotations

import numpy as np

from .._jit import njit
from ..config import CreepConfig
from ..lti import DiscreteModalSS, LTIFilter
from ..models.creep import discretise_creep
from ..stage import StageState, transfer_linear_state

__all__ = ["CreepCompensator", "creep_inverse_poles"]


def creep_inverse_poles(cfg: CreepConfig, dt: float) -> np.ndarray:
    """Poles (z-plane) of the compensator loop: eigenvalues of ``A − B·K⁻¹·C``.

    Parameters
    ----------
    cfg : CreepConfig
        The creep model.
    dt : float
        Sample time [s].

    Returns
    -------
    numpy.ndarray
        The poles (complex); all inside the unit circle for a stable compensator.
    """
    ss = discretise_creep(cfg, dt)
    Kinv = np.linalg.inv(np.array(cfg.K, float))
    if ss.n_states == 0:
        return np.zeros(0)
    poles: np.ndarray = np.linalg.eigvals(ss.A - ss.B @ Kinv @ ss.C)
    return poles


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
        self._two_axis = self.ss.n_in == 2 and self.ss.n_out == 2 and self.ss.small_blocks
        self._io = self.ss.packed_io()
        self.x = np.zeros(self.ss.n_states)
        # the Cr filter alone on the same state array: advances x from a given Y_H (re-synchronisation)
        self._cr = LTIFilter(self.ss)
        self._cr.x = self.x

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return int(self.Kinv.shape[1])

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return int(self.Kinv.shape[0])

    def reset(self) -> None:
        """All states back to rest."""
        self.x[:] = 0.0

    def process(self, yl: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        yl = np.ascontiguousarray(yl, dtype=float)
        yh = np.empty_like(yl)
        if yl.ndim != 2 or yl.shape[1] != self.n_in:
            raise ValueError(f"expected a block of shape [N, {self.n_in}], got {yl.shape}")
        if self._two_axis:
            _inverse_affine_run_2x2(self.Kinv, self._Ablk, self._offsets, self.ss.sizes, self._io, self.x, yl, yh)
        else:
            _inverse_affine_run(self.Kinv, self._Ablk, self._offsets, self.ss.sizes, self.ss.B, self.ss.C, self.x,
                                yl, yh)
        return yh

    def state(self) -> dict[str, np.ndarray]:
        """The Cr filter state ``x`` (modal coordinates of :attr:`ss`), a copy."""
        return {"x": self.x.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        self.x[:] = state["x"]

    def follow(self, yh: np.ndarray) -> None:
        """Advance the state as if this stage had output ``yh`` (what the plant's creep actually received)."""
        self._cr.process(np.ascontiguousarray(yh, dtype=float))

    def continue_from(self, old: "CreepCompensator", u_last: np.ndarray | None = None) -> None:
        """Bumpless takeover from ``old``: Cr's modes keep their input history (see
        :func:`~piezo_ff_ros.core.stage.transfer_linear_state`)."""
        self.x[:] = transfer_linear_state(old.ss, old.x, self.ss, u_last)[0]


@njit
def _inverse_affine_run(Kinv: np.ndarray, Ablk: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, B: np.ndarray,
                        C: np.ndarray, x: np.ndarray, yl: np.ndarray, yh: np.ndarray) -> None:  # pragma: no cover - compiled
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


@njit
def _inverse_affine_run_2x2(Kinv: np.ndarray, Ablk: np.ndarray, offsets: np.ndarray, sizes: np.ndarray,
                            io: np.ndarray, x: np.ndarray, yl: np.ndarray, yh: np.ndarray) -> None:  # pragma: no cover - compiled
    """``_inverse_affine_run`` unrolled for two axes and 1×1 / 2×2 blocks (``io[i] = (B[i, :], C[:, i])``).

    Sums run in the generic kernel's order, so the results are the same numbers.
    """
    N = yl.shape[0]
    nb = sizes.shape[0]
    k00, k01, k10, k11 = Kinv[0, 0], Kinv[0, 1], Kinv[1, 0], Kinv[1, 1]
    for k in range(N):
        # (Cr·Y_H)[k] from the state alone (Cr strictly proper)
        s0 = 0.0
        s1 = 0.0
        for b in range(nb):
            off = offsets[b]
            x0 = x[off]
            s0 += io[off, 2] * x0
            s1 += io[off, 3] * x0
            if sizes[b] == 2:
                x1 = x[off + 1]
                s0 += io[off + 1, 2] * x1
                s1 += io[off + 1, 3] * x1
        c0 = yl[k, 0] - s0
        c1 = yl[k, 1] - s1
        v0 = 0.0 + k00 * c0 + k01 * c1
        v1 = 0.0 + k10 * c0 + k11 * c1
        yh[k, 0] = v0
        yh[k, 1] = v1
        for b in range(nb):
            off = offsets[b]
            if sizes[b] == 1:
                x[off] = Ablk[off, 0] * x[off] + io[off, 0] * v0 + io[off, 1] * v1
            else:
                x0 = x[off]
                x1 = x[off + 1]
                x[off] = Ablk[off, 0] * x0 + Ablk[off, 1] * x1 + io[off, 0] * v0 + io[off, 1] * v1
                x[off + 1] = Ablk[off + 1, 0] * x0 + Ablk[off + 1, 1] * x1 + io[off + 1, 0] * v0 + io[off + 1, 1] * v1
