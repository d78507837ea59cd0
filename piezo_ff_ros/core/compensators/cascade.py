"""The complete compensator: the three stages in cascade (paper Fig. 3) or commuted (Fig. 16).

Paper order:    Y_R → C(s) → Y_L → creep⁻¹ (Eq. 12) → Y_H → hysteresis⁻¹ (Eq. 6) → U.
Commuted order: Y_R → hysteresis linearizer → C(s) → creep⁻¹ → Dp⁻¹ → U.  With the paper's parameters the
hysteresis stage is used in its length-to-length form (``Dp·U_h``, i.e. ``Y_R + h``) so that every stage keeps its
units; with stages identified on the commuted intermediate systems (Fig. 16) the same code applies.
Each stage can be switched off (then it is the identity, and the hysteresis stage reduces to ``Dp⁻¹``).
The cascade is a :class:`~piezo_ff_ros.core.chain.Chain`: in paper order its stages run as one fused compiled pass.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..chain import Chain
from ..lti import static_gain
from ..config import PiezoConfig
from .creep import CreepCompensator
from .hysteresis import HysteresisCompensator
from .vibration import VibrationCompensator
from ..stage import Stage, StageState, as_block

if TYPE_CHECKING:
    from ..synthesis.hinf import HinfDesign

__all__ = ["CompensatorCascade"]


class _Gain:
    """A static matrix (stateless stage)."""

    def __init__(self, M: ArrayLike) -> None:
        self.M = np.asarray(M, float)

    @property
    def n_in(self) -> int:
        return int(self.M.shape[1])

    @property
    def n_out(self) -> int:
        return int(self.M.shape[0])

    def reset(self) -> None:
        pass

    def process(self, x: np.ndarray) -> np.ndarray:
        y: np.ndarray = static_gain(x, self.M)
        return y

    def state(self) -> dict[str, np.ndarray]:
        return {}

    def load_state(self, state: StageState) -> None:
        pass


class _Linearizer:
    """Hysteresis compensator followed by Dp: ``Y_b = Dp·U_h`` (length in, length out)."""

    def __init__(self, comp: HysteresisCompensator) -> None:
        self.comp = comp
        self.Dp = np.array(comp.cfg.Dp, float)

    @property
    def n_in(self) -> int:
        return self.comp.n_in

    @property
    def n_out(self) -> int:
        return int(self.Dp.shape[0])

    def reset(self) -> None:
        self.comp.reset()

    def process(self, x: np.ndarray) -> np.ndarray:
        y: np.ndarray = static_gain(self.comp.process(x), self.Dp)
        return y

    def state(self) -> dict[str, np.ndarray]:
        return self.comp.state()

    def load_state(self, state: StageState) -> None:
        self.comp.load_state(state)


class CompensatorCascade(Chain):
    """Streaming ``Y_R [m] → U [V]``.

    Parameters
    ----------
    cfg : PiezoConfig
        Models, cascade switches/order and sample rate.
    controller : tuple (A, B, C, D) or object with ``.controller`` (a ``control.StateSpace``), optional
        The vibration compensator C(s).  When the vibration stage is enabled and none is given, it comes from
        ``cfg.vibration.controller`` or else is synthesised (H∞, then balanced truncation).

    Notes
    -----
    Stage names (taps of :meth:`process_with_taps`, :attr:`tap_names`): ``yl``, ``yh``, ``u`` in paper order;
    ``yb``, ``ya``, ``yh``, ``u`` commuted.  :meth:`state` and :meth:`load_state` use the stage names of
    :attr:`STAGES` instead (``vibration``, ``creep``, ``hysteresis``).
    """

    def __init__(self, cfg: PiezoConfig, controller: Any = None) -> None:
        self.cfg = cfg
        dt = cfg.dt
        cc = cfg.cascade
        self.design: HinfDesign | None = None
        self.vibration: VibrationCompensator | None = None
        if cc.vibration:
            A, B, C, D = self._controller_matrices(cfg, controller)
            self.vibration = VibrationCompensator(A, B, C, D, dt)
        self.creep = CreepCompensator(cfg.creep, dt) if cc.creep else None
        lim = dict(voltage_limit=cfg.limits.voltage, slew_per_sample=cfg.limits.slew * dt) if cc.respect_limits else {}
        self.hysteresis = HysteresisCompensator(cfg.hysteresis, cc.hysteresis_loop, **lim) if cc.hysteresis else None
        Dp_pinv = np.linalg.pinv(np.array(cfg.hysteresis.Dp, float))
        if cc.order == "paper":
            chain: list[Stage | None] = [self.vibration, self.creep,
                                         self.hysteresis if self.hysteresis else _Gain(Dp_pinv)]
            self.tap_names = ["yl", "yh", "u"]
        else:
            chain = [_Linearizer(self.hysteresis) if self.hysteresis else None, self.vibration, self.creep,
                     _Gain(Dp_pinv)]
            self.tap_names = ["yb", "ya", "yh", "u"]
        super().__init__(list(zip(self.tap_names, chain)), n_in=cfg.n_axes, n_out=cfg.n_axes)

    def _controller_matrices(self, cfg: PiezoConfig, controller: Any) -> tuple[ArrayLike, ...]:
        if controller is None and cfg.vibration.controller is not None:
            c = cfg.vibration.controller
            return tuple(np.atleast_2d(np.asarray(c[k], float)) for k in ("A", "B", "C", "D"))
        if controller is None:
            from ..synthesis.cache import cached_synthesis

            self.design = cached_synthesis(cfg.dynamics.G_L, cfg.vibration)   # the same design when built before
            controller = self.design
        if hasattr(controller, "controller"):
            self.design = controller
            controller = controller.controller
        if hasattr(controller, "A"):
            return controller.A, controller.B, controller.C, controller.D   # a control.StateSpace
        return tuple(controller)

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return self.cfg.n_axes

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.cfg.n_axes

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.cfg.n_axes

    def stages(self) -> dict[str, Stage]:
        """The enabled compensator stages by name (``vibration``, ``creep``, ``hysteresis``)."""
        return {k: getattr(self, k) for k in self.STAGES if getattr(self, k) is not None}

    STAGES = ("vibration", "creep", "hysteresis")

    def state(self, names: Sequence[str] = STAGES) -> dict[str, StageState]:
        """The state of every enabled stage among ``names`` (``{stage: {array name: copy}}``)."""
        return {k: st.state() for k, st in self.stages().items() if k in names}

    def load_state(self, state: Mapping[str, StageState]) -> None:
        """Load :meth:`state`'s result (``{stage: {array name: array}}``) into the enabled stages."""
        for k, st_state in state.items():
            getattr(self, k).load_state(st_state)

    #: the stages whose state describes the plant (re-synchronised on the applied voltage)
    PLANT_STAGES = ("creep", "hysteresis")

    @property
    def can_follow(self) -> bool:
        """True when :meth:`follow_applied` can re-derive the plant-side states (paper order, square Dp)."""
        dp = np.asarray(self.cfg.hysteresis.Dp, float)
        return self.cfg.cascade.order == "paper" and dp.shape[0] == dp.shape[1]

    def follow_applied(self, u: np.ndarray) -> None:
        """Advance the hysteresis and creep stages as if the cascade had output the voltages ``u``.

        The hysteresis inverse's ``h`` and last voltage become the Bouc-Wen state for ``u``, and the creep inverse's
        Cr state is driven by ``Y_H = Dp·U − h`` — the signal the plant's creep receives.  The vibration stage (a
        function of the reference alone) is left as it is.  Paper order only (:attr:`can_follow`).
        """
        if not self.can_follow:
            raise ValueError("re-synchronisation on the applied voltage needs cascade.order = paper and a square Dp")
        u = np.ascontiguousarray(u, dtype=float)
        if self.hysteresis is not None:
            yh = self.hysteresis.follow(u)
        else:
            yh = static_gain(u, self.cfg.hysteresis.Dp)
        if self.creep is not None:
            self.creep.follow(yh)

    def last_voltage(self) -> np.ndarray | None:
        """The last output voltage known to the hysteresis stage (None without one or before the first sample)."""
        h = self.hysteresis
        if h is None or not h.bw_state.started[0]:
            return None
        return h.bw_state.u_prev.copy()

    def _check(self, block: np.ndarray) -> np.ndarray:
        x = as_block(block, self.n_axes, "reference")
        return x

    def process_front(self, yr: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Every stage but the last (paper order: ``Y_R → Y_H``); returns the signal and the taps so far."""
        return self.head(len(self.entries) - 1).process_with_taps(self._check(yr))
