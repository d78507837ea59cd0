"""MIMO dynamics ``G_L(s)`` (paper Eq. 13–14), each SISO entry ZOH-discretised on its own.

G_L is strictly proper: the displacement at sample k depends on the inputs up to k − 1.
"""
from __future__ import annotations

from ..config import DynamicsConfig
from ..lti import DiscreteModalSS, FilterStage, LTIFilter

__all__ = ["DynamicsModel", "discretise_dynamics"]


def discretise_dynamics(cfg: DynamicsConfig, dt: float) -> DiscreteModalSS:
    """Exact zero-order hold of ``G_L(s)`` at the sample time ``dt`` (each SISO entry on its own, modal form)."""
    return DiscreteModalSS.zoh_from_tf_matrix(cfg.G_L, dt)


class DynamicsModel(FilterStage):
    """Streaming ``Y_L [m] → Y [m]``."""

    def __init__(self, cfg: DynamicsConfig, dt: float):
        self.cfg = cfg
        self.dt = dt
        self.filter = LTIFilter(discretise_dynamics(cfg, dt))
