"""Multivariable Bouc-Wen hysteresis (paper Eq. 1–3), classical and generalized, integrated along the voltage path.

``dh = A·dU − B(|dÛ|∘h) − Γ(dÛ∘|h|) − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)``, ``dÛ = P·dU``, ``h[0] = 0``, ``Y = Dp·U − h``.

Bouc-Wen is rate independent, so h after a sample depends only on the straight path from the previous voltage to
this one.  A small step (``κ = σ·max|dÛ| ≤ 1e-3``, σ the largest row sum of ``|B| + |Γ| + |Δ1| + |Δ2|``: 0.11 V per
sample on the paper's tube) is one explicit step, ``h[k+1] = h[k] + dh(h[k], dU)``, exactly as the paper's discrete
form; a larger one is integrated exactly along its straight path (linear in h within each sign orthant of h,
:func:`~piezo_ff_ros.core.kernels.bouc_wen.bw_path_increment`; blended with the one step up to κ = 2e-3 so that h is
continuous in the step), so that 100 V steps at a DAC's rate are not tens of per cent off and the model gives the
same h at 100 Hz as at 20 kHz.

The first sample a fresh model sees defines its starting voltage (dU = 0 there), so ``h`` is exactly the state the
definition ``h[0] = 0`` gives.  The recursion runs in a compiled loop (:mod:`~piezo_ff_ros.core.kernels.bouc_wen`)
with the state carried between blocks: results are bit-identical whatever the block split.
"""
from __future__ import annotations

import numpy as np

from ..config import BoucWenConfig
from ..kernels.fused import MODEL, FusedPart
from ..kernels.bouc_wen import bw_model_run, bw_model_run_2x2, coeffs_2x2, params_of
from ..stage import StageState, as_block

__all__ = ["BoucWenModel", "BoucWenState"]


class BoucWenState:
    """Carried state: the hysteresis vector ``h``, the previous voltage and whether a sample was seen."""

    __slots__ = ("h", "u_prev", "started")

    def __init__(self, n_out: int, n_in: int):
        self.h = np.zeros(n_out)
        self.u_prev = np.zeros(n_in)
        self.started = np.zeros(1, np.bool_)

    def clear(self) -> None:
        """Back to rest, in place (the arrays stay the same objects)."""
        self.h[:] = 0.0
        self.u_prev[:] = 0.0
        self.started[:] = False

    def copy(self) -> "BoucWenState":
        """An independent copy (hysteretic state and previous input)."""
        s = BoucWenState(len(self.h), len(self.u_prev))
        s.h[:] = self.h
        s.u_prev[:] = self.u_prev
        s.started[:] = self.started
        return s


class BoucWenModel:
    """Streaming Bouc-Wen model: ``process(U[N, k]) -> Y[N, n]`` with ``Y = Dp·U − h`` (metres, volts)."""

    def __init__(self, cfg: BoucWenConfig):
        self.cfg = cfg
        self.params = params_of(cfg.arrays())
        self.two_axis = cfg.n_in == 2 and cfg.n_out == 2
        self.coeffs = coeffs_2x2(self.params) if self.two_axis else np.zeros(0)
        self.bw_state = BoucWenState(cfg.n_out, cfg.n_in)

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.cfg.n_in

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.cfg.n_out

    def reset(self) -> None:
        """All states back to rest."""
        self.bw_state.clear()

    def state(self) -> dict[str, np.ndarray]:
        """``h``, the last voltage and whether a sample was seen (copies)."""
        s = self.bw_state
        return {"h": s.h.copy(), "u_prev": s.u_prev.copy(), "started": s.started.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        s = self.bw_state
        s.h[:] = state["h"]
        s.u_prev[:] = state["u_prev"]
        s.started[:] = state["started"]

    def fused_part(self) -> FusedPart | None:
        """This stage's share of a fused pass (:mod:`~piezo_ff_ros.core.kernels.fused`): two axes only."""
        if not self.two_axis:
            return None
        s = self.bw_state
        return FusedPart(MODEL, (self.coeffs,), (s.h, s.u_prev, s.started))

    def process(self, u: np.ndarray) -> np.ndarray:
        """Displacements ``y = Dp·u − h`` [N, n_out] (metres) for the voltage block ``u`` [N, n_in] (volts)."""
        return self.process_with_taps(u)[0]

    def process_with_taps(self, u: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`process`, also returning the hysteresis term ``{"h": h [N, n_out]}``.

        Parameters
        ----------
        u : ndarray
            Voltages [V], shape [N, n_in].

        Returns
        -------
        y : ndarray
            [N, n_out] metres.
        taps : dict
            ``h`` [N, n_out] metres.
        """
        u = as_block(u, self.n_in)
        y = np.empty((u.shape[0], self.n_out))
        hs = np.empty((u.shape[0], self.n_out))
        s = self.bw_state
        if self.two_axis:
            bw_model_run_2x2(self.coeffs, s.h, s.u_prev, s.started, u, y, hs)
        else:
            bw_model_run(self.params, s.h, s.u_prev, s.started, u, y, hs)
        return y, {"h": hs}
