"""MIMO dynamics ``G_L(s)`` (paper Eq. 13–14), each SISO entry ZOH-discretised on its own.

G_L is strictly proper: the displacement at sample k depends on the inputs up to k − 1.
"""
from __future__ import annotations

import numpy as np

from ..config import DynamicsConfig
from ..lti import DiscreteModalSS, LTIFilter

__all__ = ["DynamicsModel", "discretise_dynamics"]


def discretise_dynamics(cfg: DynamicsConfig, dt: float) -> DiscreteModalSS:
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
