"""Characterisation experiments (paper §IV-A, §V-A, §VI-A) as trajectory presets, and a runner on the core sim.

Each stage is characterised on the system the previous identified compensators leave (Fig. 3):

- **hysteresis** on S0: a 0.1 Hz, 200 V sine on one axis at a time (paper), plus one run moving both axes at once
  (90° apart; with three axes or more one such run per pair of axes) — one-axis-at-a-time sines only determine
  ``Dp_ij − A_ij`` off the diagonal; held out: every axis at ``validation_fraction`` of the amplitude with another
  phase;
- **creep** on S_H (hysteresis compensator in front): a 20 µm step per axis held ``creep_duration`` (paper 600 s),
  then back to 0 for as long — fitted on the step up, scored on the step down;
- **dynamics** on S_L (hysteresis + creep compensators): a 20 µm step per axis held ``dynamics_duration`` (paper:
  < 200 ms of transient), then back down (held out).
- **plant validation** on S0 (nothing compensated, never fitted on): :func:`plant_validation_trajectory`, a
  two-level multisine in volts on both axes (0.1–84 Hz, different lines per axis) then a ramped step pair; the
  identified model of the whole plant is scored on it.

Every step rises and falls in ``step_ramp`` (2 ms: an amplifier's slew limit, 200 V/ms).  Why: the model is the
explicit discrete Bouc-Wen; a one-sample jump of several hundred volts *down from a loaded state* makes that
discrete form (plant and compensator alike) jump far outside the continuous model (B·|ΔU| > 1), so an identified
compensator that is 1 % off lands microns away; a real amplifier cannot do it anyway.

Every setting is a field of :class:`CharacterisationSettings` with the paper's value as default.  The signals are
:mod:`~piezo_ff_ros.core.trajectories` objects (``Sine``, ``Hold``, ``TrajectorySequence``) plus two small ones defined here
(:class:`Sum` of trajectories, here; :class:`~piezo_ff_ros.core.trajectories.Ramp`).  ``Sum`` is not in
``trajectories.TRAJECTORY_TYPES``: the node graph plays it through :mod:`.characterisation_graph`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence, cast

import numpy as np

from .config import ConfigError
from .recording.run import RunData
from .stage import Processor
from .trajectories import Hold, Ramp, Sine, Trajectory
from .trajectories import TrajectorySequence

__all__ = ["CharacterisationSettings", "Ramp", "Sum", "hysteresis_trajectories", "creep_trajectories", "dynamics_trajectories",
           "plant_validation_trajectory", "run_open_loop"]


@dataclass(frozen=True)
class CharacterisationSettings:
    sine_amplitude: float = 200.0        #: V (paper §IV-A)
    sine_frequency: float = 0.1          #: Hz
    sine_periods: int = 2
    validation_fraction: float = 0.75    #: held-out hysteresis run amplitude / sine_amplitude
    creep_step: float = 20e-6            #: m (paper §V-A)
    creep_duration: float = 600.0        #: s, each of step up / step down
    creep_lead: float = 0.5              #: s at rest before the step
    dynamics_step: float = 20e-6         #: m (paper §VI-A)
    dynamics_duration: float = 0.2       #: s, each of step up / step down
    dynamics_lead: float = 0.01          #: s
    step_ramp: float = 2e-3              #: s, rise/fall time of every step (an amplifier's slew limit: 200 V/ms)
    plant_validation_amplitude: float = 170.0  #: V, peak of the full-level validation multisine (sum of lines)
    plant_validation_duration: float = 20.0    #: s of the full-level multisine; half as long at half level
    plant_validation_step: float = 120.0       #: V, step of the validation step pair (x up, y down at 2/3)
    plant_validation_hold: float = 4.0         #: s, each of step up / step down

    def __post_init__(self) -> None:
        for name in ("sine_amplitude", "sine_frequency", "validation_fraction", "creep_step", "creep_duration",
                     "dynamics_step", "dynamics_duration",
                     "plant_validation_amplitude", "plant_validation_duration", "plant_validation_step",
                     "plant_validation_hold"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(name, f"must be a positive number, got {v!r}")
        for name in ("creep_lead", "dynamics_lead", "step_ramp"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(name, f"must be a non-negative number, got {v!r}")
        if int(self.sine_periods) < 1:
            raise ConfigError("sine_periods", f"must be >= 1, got {self.sine_periods!r}")
        if self.plant_validation_amplitude > 200.0 or self.plant_validation_step > 200.0:
            raise ConfigError("plant_validation_amplitude", "validation voltages must stay within ±200 V")
        if self.step_ramp >= min(self.creep_duration, self.dynamics_duration, self.plant_validation_hold):
            raise ConfigError("step_ramp", "must be shorter than the step durations")


def hysteresis_trajectories(s: CharacterisationSettings,
                            axes: Sequence[str] = ("x", "y")) -> dict[str, list[tuple[str, Trajectory]]]:
    """``{'fit': [(name, traj), …], 'validation': [...]}`` of voltage trajectories [V] for S0."""
    axes_t = tuple(axes)
    T = s.sine_periods / s.sine_frequency
    fit: list[tuple[str, Trajectory]] = [
        (f"sine_{a}", Sine(amplitude=s.sine_amplitude, frequency=s.sine_frequency, axis=a, duration=T, axes=axes_t))
        for a in axes]
    def together(moving: Sequence[str]) -> Sum:   # the axes of `moving` at once, a quarter period apart
        return _sum(axes, [Sine(amplitude=s.sine_amplitude, frequency=s.sine_frequency, axis=a, phase=i * np.pi / 2,
                                duration=T, axes=axes_t) for i, a in enumerate(moving)])

    if len(axes_t) == 2:
        fit.append(("sine_all", together(axes_t)))
    elif len(axes_t) > 2:
        # (one axis: its own sine is all there is) three sines of one frequency span a plane only: one run per pair
        # of axes, so every cross term is seen
        fit += [(f"sine_{a}{b}", together((a, b))) for i, a in enumerate(axes_t) for b in axes_t[i + 1:]]
    va = s.validation_fraction * s.sine_amplitude
    # held out: every axis at once at another amplitude and phase, a quarter period apart with two axes (a circle,
    # which the trajectory node plays sample-exactly: the same run on every rig), a 1/n period with n > 2
    spread = np.pi / 2 if len(axes_t) <= 2 else 2 * np.pi / len(axes_t)
    val = _sum(axes, [Sine(amplitude=va, frequency=s.sine_frequency, axis=a, phase=0.4 + spread * i,
                           duration=1.0 / s.sine_frequency, axes=axes_t) for i, a in enumerate(axes)])
    return {"fit": fit, "validation": [("sine_validation", val)]}


@dataclass(frozen=True)
class Sum(Trajectory):
    """Sum of trajectories with the same axes, each held at its last value after its own end."""

    parts: tuple[Any, ...] = ()   #: the Trajectory parts

    kind = "sum"

    def __post_init__(self) -> None:
        super().__post_init__()
        parts = tuple(self.parts)
        if not parts:
            raise ConfigError("parts", "a sum needs at least one trajectory")
        for i, p in enumerate(parts):
            if not isinstance(p, Trajectory) or p.axes != self.axes:
                raise ConfigError(f"parts[{i}]", f"expected a trajectory on axes {list(self.axes)}")
        object.__setattr__(self, "parts", parts)

    @property
    def duration(self) -> float:
        return float(max(p.duration for p in self.parts))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        return cast(np.ndarray, sum(p.at_index(k, fs) for p in self.parts))   # parts is never empty


def _sum(axes: Sequence[str], parts: Sequence[Trajectory]) -> Sum:
    return Sum(parts=tuple(parts), axes=tuple(axes))


def _up_down(step: float, duration: float, lead: float, axes: tuple[str, ...], a: str,
             ramp: float) -> tuple[TrajectorySequence, float]:
    """Rest ``lead`` s, ramp up to ``step`` on axis ``a``, hold, ramp down, rest: ``(sequence, down_start_s)``."""
    amp = tuple(step if b == a else 0.0 for b in axes)
    zero = tuple(0.0 for _ in axes)
    segs: list[tuple[str, Trajectory]] = []
    if lead > 0:
        segs.append(("lead", Hold(value=zero, duration=lead, axes=axes)))
    if ramp > 0:
        segs.append(("up", Ramp(start=zero, end=amp, duration=ramp, axes=axes)))
    segs.append(("hold_up", Hold(value=amp, duration=duration - ramp, axes=axes)))
    if ramp > 0:
        segs.append(("down", Ramp(start=amp, end=zero, duration=ramp, axes=axes)))
    segs.append(("hold_down", Hold(value=zero, duration=duration - ramp, axes=axes)))
    return TrajectorySequence(segs, axes=axes), lead + duration


def creep_trajectories(s: CharacterisationSettings,
                       axes: Sequence[str] = ("x", "y")) -> list[tuple[str, TrajectorySequence, float]]:
    """Step up/down per axis [m] for S_H: ``[(name, traj, score_start_seconds)]``."""
    return [(f"creep_step_{a}",) + _up_down(s.creep_step, s.creep_duration, s.creep_lead, tuple(axes), a, s.step_ramp)
            for a in axes]


def dynamics_trajectories(s: CharacterisationSettings,
                          axes: Sequence[str] = ("x", "y")) -> list[tuple[str, TrajectorySequence, float]]:
    """Step up/down per axis [m] for S_L: ``[(name, traj, score_start_seconds)]``."""
    return [(f"dynamics_step_{a}",) + _up_down(s.dynamics_step, s.dynamics_duration, s.dynamics_lead, tuple(axes), a,
                                                s.step_ramp) for a in axes]


#: Lines of the plant-validation multisine per axis: (frequency [Hz], relative amplitude).  Frequencies are multiples
#: of 0.1 Hz so every segment holds whole periods (starts and ends at 0 V); x and y use different lines so the
#: cross terms are seen apart from the direct ones.
PLANT_VALIDATION_LINES = {
    0: ((0.1, 0.50), (0.3, 0.22), (1.1, 0.12), (4.3, 0.07), (17.1, 0.04), (61.3, 0.03), (233.1, 0.02)),
    1: ((0.2, 0.50), (0.5, 0.22), (1.7, 0.12), (6.1, 0.07), (23.3, 0.04), (83.9, 0.03), (311.7, 0.02)),
}


def plant_validation_trajectory(s: CharacterisationSettings, axes: Sequence[str] = ("x", "y")) -> TrajectorySequence:
    """Held-out voltage record [V] for the identified model of the whole plant S0.

    A multisine on every axis at full level (``plant_validation_amplitude`` peak-sum, ``plant_validation_duration``
    s), the same at half level for half as long (hysteresis loops of another size), then a step pair ramped in
    ``step_ramp``: x to ``+plant_validation_step``, y to ``−2/3`` of it, held ``plant_validation_hold`` s, back to
    0 for as long (creep and G_L transients in both directions).  Nothing here is used for fitting.
    """
    axes = tuple(axes)
    n = len(axes)
    zero = tuple(0.0 for _ in axes)

    def multisine(level: float, duration: float) -> Sum:
        parts: list[Trajectory] = []
        for i, a in enumerate(axes):
            for f, rel in PLANT_VALIDATION_LINES[i % 2]:
                f_i = f + 0.1 * (i // 2)   # more than two axes: shift the lines so no two axes share one
                parts.append(Sine(amplitude=level * rel * s.plant_validation_amplitude / sum(
                    r for _, r in PLANT_VALIDATION_LINES[i % 2]), frequency=f_i, axis=a, duration=duration,
                    axes=axes))
        return _sum(axes, parts)

    T = round(s.plant_validation_duration, 1)
    step = tuple(s.plant_validation_step * (1.0 if i % 2 == 0 else -2.0 / 3.0) for i in range(n))
    segs: list[tuple[str, Trajectory]] = [("multisine_full", multisine(1.0, T)), ("multisine_half", multisine(0.5, round(T / 2, 1)))]
    if s.step_ramp > 0:
        segs.append(("step_up", Ramp(start=zero, end=step, duration=s.step_ramp, axes=axes)))
    segs.append(("hold_up", Hold(value=step, duration=s.plant_validation_hold, axes=axes)))
    if s.step_ramp > 0:
        segs.append(("step_down", Ramp(start=step, end=zero, duration=s.step_ramp, axes=axes)))
    segs.append(("hold_down", Hold(value=zero, duration=s.plant_validation_hold, axes=axes)))
    return TrajectorySequence(segs, axes=axes)


def run_open_loop(system: Processor, traj: Trajectory, fs: float, name: str, axes: Sequence[str],
                  block: int = 200_000, reference_is_input: bool = True, chain: Sequence[Processor] = ()) -> RunData:
    """Play ``traj`` through ``chain`` (compensator stages, each ``process``) then ``system`` (``process``).

    Returns a RunData with ``u`` = voltage reaching the system, ``y`` its output and ``reference`` = the trajectory
    (the input of the characterised system S0/S_H/S_L).
    """
    for st in chain:
        st.reset()
    system.reset()
    t, r = traj.sample(fs)
    us, ys = [], []
    for k in range(0, len(r), block):
        x = r[k:k + block]
        for st in chain:
            x = st.process(x)
        us.append(x)
        ys.append(system.process(x))
    return RunData(t=t, u=np.vstack(us), y=np.vstack(ys), axes=tuple(axes), reference=r, meta={"experiment": name})
