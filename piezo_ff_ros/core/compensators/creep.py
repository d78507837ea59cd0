"""Multivariable creep compensator, inverse multiplicative structure (paper Eq. 12, Fig. 9).

``Y_H[k] = K⁻¹·(Y_L[k] − (Cr·Y_H)[k])``.  The ZOH-discretised Cr is strictly proper, so ``(Cr·Y_H)[k]`` depends
on Y_H up to k − 1: that is the paper's ``Cr(s)·Y_H(t − Ts)``, and it makes the compensator the exact inverse of
the discrete creep model.  No transfer function is inverted; the parameters are the model's.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..config import CreepConfig
from ..kernels.fused import INVERSE, FusedPart
from ..kernels.modal import inverse_affine_run, inverse_affine_run_2x2, pad_to_2x2
from ..kernels.specialise import specialised_inverse_run
from ..lti import DiscreteModalSS, LTIFilter, transfer_linear_state
from ..models.creep import discretise_creep
from ..stage import StageState, as_block

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
        self.two_axis = self.ss.n_in == 2 and self.ss.n_out == 2 and self.ss.small_blocks
        if self.two_axis:
            self.W, self.feeds = pad_to_2x2(self._Ablk, self.ss.packed_io(), self._offsets, self.ss.sizes)
        self._run: Callable[..., None] | None = None  # the two-axis loop, specialised on first use
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
        yl = as_block(yl, self.n_in)
        yh = np.empty_like(yl)
        if self.two_axis:
            if self._run is None:
                self._run = specialised_inverse_run(self.Kinv, self.W, self.ss.sizes) or inverse_affine_run_2x2
            self._run(self.Kinv, self.W, self._offsets, self.ss.sizes, self.feeds, self.x, yl, yh)
        else:
            inverse_affine_run(self.Kinv, self._Ablk, self._offsets, self.ss.sizes, self.ss.B, self.ss.C, self.x,
                                yl, yh)
        return yh

    def state(self) -> dict[str, np.ndarray]:
        """The Cr filter state ``x`` (modal coordinates of :attr:`ss`), a copy."""
        return {"x": self.x.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        self.x[:] = state["x"]

    def fused_part(self) -> FusedPart | None:
        """This stage's share of a fused pass (:mod:`~piezo_ff_ros.core.kernels.fused`): two axes only."""
        if not self.two_axis:
            return None
        return FusedPart(INVERSE, (self.W, self.feeds, self.Kinv, self._offsets, self.ss.sizes), (self.x,))

    def follow(self, yh: np.ndarray) -> None:
        """Advance the state as if this stage had output ``yh`` (what the plant's creep actually received)."""
        self._cr.process(np.ascontiguousarray(yh, dtype=float))

    def continue_from(self, old: "CreepCompensator", u_last: np.ndarray | None = None) -> None:
        """Bumpless takeover from ``old``: Cr's modes keep their input history (see
        :func:`~piezo_ff_ros.core.lti.transfer_linear_state`)."""
        self.x[:] = transfer_linear_state(old.ss, old.x, self.ss, u_last)[0]
