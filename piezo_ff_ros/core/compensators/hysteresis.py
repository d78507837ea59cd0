"""Multivariable hysteresis compensator, inverse multiplicative structure (paper Eq. 5–6, Fig. 5).

``U = Dp⁻¹(Y_H + h)`` with ``h = H(U)`` the Bouc-Wen state driven by the compensator's own output: no inversion
of the nonlinear operator, the compensator's parameters are the model's.

In discrete time ``h[k]`` depends on ``U[k]`` (through ``dU = U[k] − U[k−1]``), so Eq. 6 is implicit at every
sample.  ``loop='exact'`` solves it: given the signs of ``dÛ`` the increment of h is linear in dU, so each of the
2ⁿ sign patterns gives a linear system and the consistent one is kept (n = 2 → at most four 2×2 solves; the
previous pattern is tried first).  The compensator is then the exact inverse of the discrete model
(``model ∘ compensator = identity`` to rounding).  ``loop='delayed'`` uses ``h[k−1]``, i.e. a unit delay in the
loop as a Simulink implementation would have; its error is one sample's increment of h.
"""
from __future__ import annotations

import numpy as np

from ..config import BoucWenConfig
from ..kernels.fused import COMP, FusedPart
from ..kernels.bouc_wen import (N_COUNTERS, FALLBACKS, SATURATED, CompOptions, CompState, bw_comp_run,
                                bw_comp_run_2x2, bw_model_run, bw_model_run_2x2, comp_coeffs_2x2, coeffs_2x2,
                                params_of)
from ..models.bouc_wen import BoucWenState
from ..stage import StageState, as_block

__all__ = ["HysteresisCompensator"]


class HysteresisCompensator:
    """Streaming ``Y_H [m] → U [V]``; ``process(block[N, n]) -> block[N, k]``."""

    def __init__(self, cfg: BoucWenConfig, loop: str = "exact", voltage_limit: float | None = None,
                 slew_per_sample: float | None = None):
        if loop not in ("exact", "delayed"):
            raise ValueError("loop must be 'exact' or 'delayed'")
        if loop == "exact" and cfg.n_in != cfg.n_out:
            loop = "delayed"  # the exact per-sample solve needs a square system
        self.cfg = cfg
        self.loop = loop
        self.params = params_of(cfg.arrays())
        self._Dp_pinv = np.ascontiguousarray(np.linalg.pinv(self.params.Dp))
        self.two_axis = cfg.n_in == 2 and cfg.n_out == 2
        self.coeffs = coeffs_2x2(self.params) if self.two_axis else np.zeros(0)
        self.comp_coeffs = comp_coeffs_2x2(self.params, self._Dp_pinv) if self.two_axis else np.zeros(0)
        self.bw_state = BoucWenState(cfg.n_out, cfg.n_in)
        self._signs = np.ones(cfg.n_out)
        self.fallbacks = 0  #: samples where no sign pattern was consistent (delayed formula used instead)
        # Saturating here (as the amplifier will) keeps the internal h equal to the plant's even when a reference
        # asks for more than the actuator can give.
        self.voltage_limit = float(voltage_limit) if voltage_limit is not None else np.inf
        self.saturated = 0  #: samples clamped to the voltage limit or held back by the slew limit
        # The driver's guard's own rule (core/kernels/limits.py): clamp to ±limit, then at most this many volts per
        # sample.
        self.slew_per_sample = float(slew_per_sample) if slew_per_sample is not None else np.inf

    @property
    def options(self) -> CompOptions:
        """How the kernel solves Eq. 6 and limits the output."""
        return CompOptions(self.loop == "exact", self.voltage_limit, self.slew_per_sample)

    def comp_state(self) -> CompState:
        """The carried state as the kernels take it (views, not copies)."""
        s = self.bw_state
        return CompState(s.h, s.u_prev, s.started, self._signs)

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.cfg.n_out

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.cfg.n_in

    def reset(self) -> None:
        """All states back to rest."""
        self.bw_state.clear()
        self._signs[:] = 1.0
        self.fallbacks = 0
        self.saturated = 0

    def process(self, yh: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        yh = as_block(yh, self.n_in)
        u = np.empty((yh.shape[0], self.n_out))
        counters = np.zeros(N_COUNTERS, np.int64)
        if self.two_axis:
            bw_comp_run_2x2(self.comp_coeffs, self.comp_state(), self.options, yh, u, counters)
        else:
            bw_comp_run(self.params, self._Dp_pinv, self.comp_state(), self.options, yh, u, counters)
        self.count(counters)
        return u

    def fused_part(self) -> FusedPart | None:
        """This stage's share of a fused pass (:mod:`~piezo_ff_ros.core.kernels.fused`): two axes only.

        The loop and the limits are read when the pass is planned (they are fixed at construction)."""
        if not self.two_axis:
            return None
        s = self.bw_state
        return FusedPart(COMP, (self.comp_coeffs, self.loop == "exact", self.voltage_limit, self.slew_per_sample),
                         (s.h, s.u_prev, s.started, self._signs), self.count)

    def count(self, counters: np.ndarray) -> None:
        """Add a kernel's counters (indexed by ``FALLBACKS``, ``SATURATED``) to :attr:`fallbacks`, :attr:`saturated`."""
        self.fallbacks += int(counters[FALLBACKS])
        self.saturated += int(counters[SATURATED])

    @property
    def h(self) -> np.ndarray:
        """The hysteresis state h (a copy)."""
        return self.bw_state.h.copy()

    # ``state`` is the Stage method; the Bouc-Wen state object itself is ``bw_state``
    def state(self) -> dict[str, np.ndarray]:
        """``h``, the last output voltage, whether a sample was seen, and the last sign pattern (copies)."""
        s = self.bw_state
        return {"h": s.h.copy(), "u_prev": s.u_prev.copy(), "started": s.started.copy(), "signs": self._signs.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        s = self.bw_state
        s.h[:] = state["h"]
        s.u_prev[:] = state["u_prev"]
        s.started[:] = state["started"]
        self._signs[:] = state["signs"]

    def continue_from(self, old: "HysteresisCompensator") -> None:
        """Take over ``old``'s state: h and the last voltage describe the plant, whatever the new parameters."""
        self.load_state(old.state())

    def follow(self, u: np.ndarray) -> np.ndarray:
        """Advance the state as if this stage had output the voltages ``u`` (e.g. what the driver applied);
        returns ``Y_H = Dp·U − h`` consistent with them (the input the creep stage before it should have seen)."""
        u = np.ascontiguousarray(u, dtype=float)
        y = np.empty((u.shape[0], self.n_in))
        hs = np.empty((u.shape[0], self.n_in))
        s = self.bw_state
        if self.two_axis:
            bw_model_run_2x2(self.coeffs, s.h, s.u_prev, s.started, u, y, hs)
        else:
            bw_model_run(self.params, s.h, s.u_prev, s.started, u, y, hs)
        return y
