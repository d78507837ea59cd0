"""Characterisation experiments (paper §IV-A, §V-A, §VI-A) as trajectory presets, and a runner on the core sim.

Each stage is characterised on the system the previous identified compensators leave (Fig. 3):

- **hysteresis** on S0: a 0.1 Hz, 200 V sine on one axis at a time (paper), plus one run moving both axes at once
  (90° apart) — one-axis-at-a-time sines only determine ``Dp_ij − A_ij`` off the diagonal; held out: both axes at
  ``validation_fraction`` of the amplitude with another phase;
- **creep** on S_H (hysteresis compensator in front): a 20 µm step per axis held ``creep_duration`` (paper 600 s),
  then back to 0 for as long — fitted on the step up, scored on the step down;
- **dynamics** on S_L (hysteresis + creep compensators): a 20 µm step per axis held ``dynamics_duration`` (paper:
  < 200 ms of transient), then back down (held out).

Every setting is a field of :class:`CharacterisationSettings` with the paper's value as default.  The signals are
:mod:`~piezo_ff_ros.core.trajectories` objects (``Sine``, ``Step``, ``Sequence``) so the node graph can play them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .recording.run import RunData
from .trajectories import Hold, Sequence, Sine, Step

__all__ = ["CharacterisationSettings", "hysteresis_trajectories", "creep_trajectories", "dynamics_trajectories",
           "run_open_loop"]


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


def hysteresis_trajectories(s: CharacterisationSettings, axes=("x", "y")) -> dict:
    """``{'fit': [(name, traj), …], 'validation': [...]}`` of voltage trajectories [V] for S0."""
    T = s.sine_periods / s.sine_frequency
    fit = [(f"sine_{a}", Sine(amplitude=s.sine_amplitude, frequency=s.sine_frequency, axis=a, duration=T, axes=axes))
           for a in axes]
    both = _sum(axes, [Sine(amplitude=s.sine_amplitude, frequency=s.sine_frequency, axis=a, phase=i * np.pi / 2,
                            duration=T, axes=axes) for i, a in enumerate(axes)])
    fit.append(("sine_all", both))
    va = s.validation_fraction * s.sine_amplitude
    val = _sum(axes, [Sine(amplitude=va, frequency=s.sine_frequency, axis=a, phase=0.4 + 1.2 * i,
                           duration=1.0 / s.sine_frequency, axes=axes) for i, a in enumerate(axes)])
    return {"fit": fit, "validation": [("sine_validation", val)]}


class _Sum:
    """Sum of trajectories with the same axes (a minimal adapter; trajectories are linear in value)."""

    def __init__(self, axes, parts):
        self.axes = tuple(axes)
        self.parts = parts
        self.duration = max(p.duration for p in parts)

    def n_samples(self, fs):
        return max(p.n_samples(fs) for p in self.parts)

    def sample(self, fs):
        n = self.n_samples(fs)
        return np.arange(n) / fs, sum(p.block(0, n, fs) for p in self.parts)

    def block(self, k0, n, fs):
        return sum(p.block(k0, n, fs) for p in self.parts)


def _sum(axes, parts):
    return _Sum(axes, parts)


def _up_down(step, duration, lead, axes, a):
    amp = tuple(step if b == a else 0.0 for b in axes)
    return Sequence([("up", Step(amplitude=amp, t_step=lead, hold=duration, axes=axes)),
                     ("down", Hold(value=0.0, duration=duration, axes=axes))], axes=axes)


def creep_trajectories(s: CharacterisationSettings, axes=("x", "y")) -> list:
    """Step up/down per axis [m] for S_H: ``[(name, traj, score_start_seconds)]``."""
    return [(f"creep_step_{a}", _up_down(s.creep_step, s.creep_duration, s.creep_lead, axes, a),
             s.creep_lead + s.creep_duration) for a in axes]


def dynamics_trajectories(s: CharacterisationSettings, axes=("x", "y")) -> list:
    """Step up/down per axis [m] for S_L: ``[(name, traj, score_start_seconds)]``."""
    return [(f"dynamics_step_{a}", _up_down(s.dynamics_step, s.dynamics_duration, s.dynamics_lead, axes, a),
             s.dynamics_lead + s.dynamics_duration) for a in axes]


def run_open_loop(system, traj, fs: float, name: str, axes, block: int = 200_000, reference_is_input=True,
                  chain=()) -> RunData:
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
