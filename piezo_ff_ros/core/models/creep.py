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
    """Streaming ``Y_H [m] → Y [m]``."""

    def __init__(self, cfg: CreepConfig, dt: float):
        self.cfg = cfg
        self.dt = dt
        self.K = np.array(cfg.K, float)
        self.cr = LTIFilter(discretise_creep(cfg, dt))

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
        self.cr.reset()

    def process(self, yh: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        yh = np.ascontiguousarray(yh, dtype=float)
        y: np.ndarray = yh @ self.K.T + self.cr.process(yh)
        return y
