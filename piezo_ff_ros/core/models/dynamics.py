"""MIMO dynamics ``G_L(s)`` (paper Eq. 13–14), each SISO entry ZOH-discretised on its own.

G_L is strictly proper: the displacement at sample k depends on the inputs up to k − 1.
"""
from __future__ import annotations

import numpy as np

from ..config import DynamicsConfig
from ..kernels.fused import FusedPart
from ..lti import DiscreteModalSS, LTIFilter
from ..stage import StageState

__all__ = ["DynamicsModel", "discretise_dynamics"]


def discretise_dynamics(cfg: DynamicsConfig, dt: float) -> DiscreteModalSS:
    """Exact zero-order hold of ``G_L(s)`` at the sample time ``dt`` (each SISO entry on its own, modal form)."""
    return DiscreteModalSS.zoh_from_tf_matrix(cfg.G_L, dt)


class DynamicsModel:
    """Streaming ``Y_L [m] → Y [m]``."""

    def __init__(self, cfg: DynamicsConfig, dt: float):
        self.cfg = cfg
        self.dt = dt
        self.filter = LTIFilter(discretise_dynamics(cfg, dt))

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.filter.n_in

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.filter.n_out

    def reset(self) -> None:
        """All states back to rest."""
        self.filter.reset()

    def process(self, yl: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        return self.filter.process(yl)

    def state(self) -> dict[str, np.ndarray]:
        """The filter state ``x`` (modal coordinates), a copy."""
        return {"x": self.filter.x.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        self.filter.x[:] = state["x"]

    def fused_part(self) -> FusedPart | None:
        """This stage's share of a fused pass (:mod:`~piezo_ff_ros.core.kernels.fused`), None if not fusable."""
        return self.filter.fused_part()
