"""Multivariable creep ``Y = [K + Cr(s)]·Y_H`` (paper Eq. 7–11).

Each SISO entry of Cr(s) is discretised on its own by exact zero-order hold at the sample rate; Cr is strictly
proper, so its output at sample k depends on Y_H up to k − 1, and K acts directly.
"""
from __future__ import annotations

import numpy as np

from ..config import CreepConfig
from ..lti import DiscreteModalSS, LTIFilter

__all__ = ["CreepModel", "discretise_creep"]


def discretise_creep(cfg: CreepConfig, dt: float) -> DiscreteModalSS:
    return DiscreteModalSS.zoh_from_tf_matrix(cfg.Cr, dt)


class CreepModel:
    """Streaming ``Y_H [m] → Y [m]``."""

    def __init__(self, cfg: CreepConfig, dt: float):
        self.cfg = cfg
        self.dt = dt
        self.K = np.array(cfg.K, float)
        self.cr = LTIFilter(discretise_creep(cfg, dt))

    @property
    def n_in(self) -> int:
        return self.K.shape[1]

    @property
    def n_out(self) -> int:
        return self.K.shape[0]

    def reset(self) -> None:
        self.cr.reset()

    def process(self, yh: np.ndarray) -> np.ndarray:
        yh = np.ascontiguousarray(yh, dtype=float)
        return yh @ self.K.T + self.cr.process(yh)
