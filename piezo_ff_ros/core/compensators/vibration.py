"""Vibration compensator: a continuous MIMO controller C(s) (the H∞ feedforward of Eq. 15–23) run at the sample
rate after exact zero-order-hold discretisation (modal form, carried state)."""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..lti import DiscreteModalSS, FilterStage, LTIFilter, transfer_linear_state

__all__ = ["VibrationCompensator"]


class VibrationCompensator(FilterStage):
    """Streaming ``Y_R [m] → Y_L [m]`` through C(s) given as a continuous state space (A, B, C, D)."""

    def __init__(self, A: ArrayLike, B: ArrayLike, C: ArrayLike, D: ArrayLike, dt: float) -> None:
        Ac, Bc, Cc, Dc = (np.atleast_2d(np.asarray(m, float)) for m in (A, B, C, D))
        self.continuous = (Ac, Bc, Cc, Dc)
        self.dt = dt
        self.ss = DiscreteModalSS.zoh_from_ss(Ac, Bc, Cc, Dc, dt)
        self.filter = LTIFilter(self.ss)

    @staticmethod
    def from_control(sys: Any, dt: float) -> "VibrationCompensator":
        """The compensator for a python-control system (anything ``control.ss`` accepts).

        Parameters
        ----------
        sys : control.StateSpace or control.TransferFunction
            The continuous controller C(s).
        dt : float
            Sample time [s].

        Returns
        -------
        VibrationCompensator
        """
        import control

        s = control.ss(sys)
        return VibrationCompensator(s.A, s.B, s.C, s.D, dt)

    @property
    def order(self) -> int:
        """Number of states of the discretised C(s)."""
        return self.ss.n_states

    def continue_from(self, old: "VibrationCompensator", u_last: np.ndarray | None = None) -> None:
        """Bumpless takeover from ``old`` (see :func:`~piezo_ff_ros.core.lti.transfer_linear_state`)."""
        self.filter.x[:] = transfer_linear_state(old.ss, old.filter.x, self.ss, u_last)[0]
