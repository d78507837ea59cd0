"""The compensated stage as a linear system, for the preview and learning stages.

With every compensator exact (model = plant), the cascade of paper Fig. 3 followed by the plant is linear from the
cascade's input Y_R to the displacement: hysteresis and creep are inverted exactly, so ``Y = G_L·C·Y_R`` (the H∞
model matching makes it ≈ W_r·Y_R).  :class:`CompensatedModel` gives that map ``T = G_L·C`` and the linear part of
the voltage ``U_lin = Dp⁻¹·creep⁻¹·C·Y_R`` as impulse responses (computed by running the very streaming stages the
cascade uses) and frequency responses; :class:`CascadeReplica` runs the whole nonlinear cascade (no limits) plus
G_L, so that a candidate reference can be checked for the voltage it will ask before it is sent.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import scipy.linalg

from ..compensators.creep import CreepCompensator
from ..compensators.hysteresis import HysteresisCompensator
from ..compensators.vibration import VibrationCompensator
from ..config import PiezoConfig
from ..models.dynamics import DynamicsModel

__all__ = ["CompensatedModel", "CascadeReplica", "controller_matrices", "ControllerABCD"]

#: C(s) as continuous state-space matrices ``(A, B, C, D)``.
ControllerABCD = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def controller_matrices(cascade: Any) -> ControllerABCD | None:
    """The continuous ``(A, B, C, D)`` of a :class:`~..compensators.cascade.CompensatorCascade`'s C(s), or None."""
    vib = getattr(cascade, "vibration", None)
    if vib is None:
        return None
    abcd: ControllerABCD = vib.continuous
    return abcd


def _impulse_response(make_chain: Callable[[], Sequence[Any]], n_axes: int, n: int) -> np.ndarray:
    """``h[k, i, j]``: output i at sample k for a unit impulse on input j at sample 0 (fresh chain per input)."""
    h = np.zeros((n, n_axes, n_axes))
    for j in range(n_axes):
        u = np.zeros((n, n_axes))
        u[0, j] = 1.0
        x = u
        for stage in make_chain():
            x = stage.process(x)
        h[:, :, j] = x
    return h


@dataclass
class CompensatedModel:
    """Impulse responses of the compensated stage, from the model config and the cascade's C(s).

    Attributes
    ----------
    T : ndarray [n, axes, axes]
        Cascade input → displacement, ``G_L·C`` (strictly proper: ``T[0] = 0``).
    V : ndarray [n, axes, axes]
        Cascade input → linear part of the voltage, ``Dp⁻¹·creep⁻¹·C`` [V/m].
    dt : float
        Sample period [s].
    """

    T: np.ndarray
    V: np.ndarray
    dt: float

    @staticmethod
    def from_config(cfg: PiezoConfig, controller: ControllerABCD | None, n: int = 1 << 15) -> "CompensatedModel":
        """Build from a config and C(s) as continuous ``(A, B, C, D)`` (None: no vibration stage, C = I).

        ``n`` samples of impulse response; the creep inverse carries a near-integrator (|z| = 1 − 1e-10), so
        ``V`` is truncated, not decayed, at n: it is only used over short horizons.
        """
        dt = cfg.dt
        na = cfg.n_axes
        Dp_pinv = np.linalg.pinv(np.array(cfg.hysteresis.Dp, float))

        def vib() -> list[Any]:
            return [VibrationCompensator(*controller, dt)] if controller is not None else []

        class _Gain:
            def process(self, x: np.ndarray) -> np.ndarray:
                y: np.ndarray = x @ Dp_pinv.T
                return y

        T = _impulse_response(lambda: vib() + [DynamicsModel(cfg.dynamics, dt)], na, n)
        V = _impulse_response(lambda: vib() + ([CreepCompensator(cfg.creep, dt)] if cfg.cascade.creep else [])
                              + [_Gain()], na, n)
        return CompensatedModel(T, V, dt)

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return int(self.T.shape[1])

    def frequency_response(self, n_fft: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(f [Hz], T(e^{jωT}) [len(f), axes, axes])`` on the rfft grid of ``n_fft`` points (default len(T))."""
        n_fft = n_fft or len(self.T)
        return np.fft.rfftfreq(n_fft, self.dt), np.fft.rfft(self.T, n=n_fft, axis=0)

    def lifted(self, which: str, n: int) -> np.ndarray:
        """Block-Toeplitz matrix ``[n·axes, n·axes]`` (sample-major: row ``k·axes + i``) of ``T`` or ``V``."""
        h = {"T": self.T, "V": self.V}[which][:n]
        na = self.n_axes
        out = np.zeros((n * na, n * na))
        zeros = np.zeros(n)
        for i in range(na):
            for j in range(na):
                out[i::na, j::na] = scipy.linalg.toeplitz(h[:, i, j], zeros)
        return out


class CascadeReplica:
    """The cascade (C(s) → creep⁻¹ → hysteresis⁻¹, no limits) plus G_L: ``process(Y_R) -> (U, Y)``.

    Driven with the preview stage's own output it knows the exact voltage its past asked (model = plant);
    :meth:`predict` runs a copy on a candidate continuation without touching the state.
    """

    def __init__(self, cfg: PiezoConfig, controller: ControllerABCD | None) -> None:
        dt = cfg.dt
        self.vibration = VibrationCompensator(*controller, dt) if controller is not None else None
        self.creep = CreepCompensator(cfg.creep, dt) if cfg.cascade.creep else None
        self.hysteresis = HysteresisCompensator(cfg.hysteresis, cfg.cascade.hysteresis_loop)
        self.dynamics = DynamicsModel(cfg.dynamics, dt)
        self.u_last = np.zeros(cfg.n_axes)

    def reset(self) -> None:
        """Back to rest (every stage and the last voltage)."""
        for st in (self.vibration, self.creep, self.hysteresis, self.dynamics):
            if st is not None:
                st.reset()
        self.u_last[:] = 0.0

    def process(self, yr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feed a cascade input block; returns ``(U [V], Y [m])`` and advances the state."""
        yl = self.vibration.process(yr) if self.vibration is not None else np.ascontiguousarray(yr, float)
        yh = self.creep.process(yl) if self.creep is not None else yl
        u = self.hysteresis.process(yh)
        y = self.dynamics.process(yl)   # exact compensators: the plant sees Y_L back at the creep model's output
        if len(u):
            self.u_last = u[-1].copy()
        return u, y

    def predict(self, yr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``process`` on a copy: the state is left as it was."""
        return copy.deepcopy(self).process(yr)
