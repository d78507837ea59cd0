"""Multivariable creep ``Y = [K + Cr(s)]·Y_H`` (paper Eq. 7–11).

Each SISO entry of Cr(s) is discretised on its own by exact zero-order hold at the sample rate; Cr is strictly
proper, so its output at sample k depends on Y_H up to k − 1, and K acts directly (the bank's feed-through D).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import CreepConfig
from ..kernels.fused import FusedPart
from ..lti import DiscreteModalSS, LTIFilter
from ..stage import StageState

__all__ = ["CreepModel", "discretise_creep"]


def discretise_creep(cfg: CreepConfig, dt: float) -> DiscreteModalSS:
    """Exact zero-order hold of ``Cr(s)`` at the sample time ``dt`` (each SISO entry on its own, modal form).

    Parameters
    ----------
    cfg : CreepConfig
        The creep model (``Cr`` is used; ``K`` acts directly and needs no discretisation).
    dt : float
        Sample time [s].

    Returns
    -------
    DiscreteModalSS
        The discrete realisation of ``Cr``.
    """
    return DiscreteModalSS.zoh_from_tf_matrix(cfg.Cr, dt)


class CreepModel:
    """Streaming ``Y_H [m] → Y [m]``: one modal bank, Cr's modes with K as its feed-through."""

    def __init__(self, cfg: CreepConfig, dt: float):
        self.cfg = cfg
        self.dt = dt
        self.K = np.array(cfg.K, float)
        self.filter = LTIFilter(replace(discretise_creep(cfg, dt), D=np.ascontiguousarray(self.K)))

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return int(self.K.shape[1])

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return int(self.K.shape[0])

    def reset(self) -> None:
        """All states back to rest."""
        self.filter.reset()

    def process(self, yh: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        return self.filter.process(yh)

    def state(self) -> dict[str, np.ndarray]:
        """The Cr state ``x`` (modal coordinates), a copy."""
        return {"x": self.filter.x.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        self.filter.x[:] = state["x"]

    def fused_part(self) -> FusedPart | None:
        """This stage's share of a fused pass (:mod:`~piezo_ff_ros.core.kernels.fused`), None if not fusable."""
        return self.filter.fused_part()
