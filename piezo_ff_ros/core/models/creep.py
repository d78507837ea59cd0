"""Multivariable creep ``Y = [K + Cr(s)]·Y_H`` (paper Eq. 7–11).

Each SISO entry of Cr(s) is discretised on its own by exact zero-order hold at the sample rate; Cr is strictly
proper, so its output at sample k depends on Y_H up to k − 1, and K acts directly (the bank's feed-through D).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import CreepConfig
from ..lti import DiscreteModalSS, FilterStage, LTIFilter

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


class CreepModel(FilterStage):
    """Streaming ``Y_H [m] → Y [m]``: one modal bank, Cr's modes with K as its feed-through."""

    def __init__(self, cfg: CreepConfig, dt: float):
        self.cfg = cfg
        self.dt = dt
        self.K = np.array(cfg.K, float)
        self.filter = LTIFilter(replace(discretise_creep(cfg, dt), D=np.ascontiguousarray(self.K)))
