"""The paper's experiments as data, and their simulation with the core cascade and a simulated plant (no ROS).

Each :class:`Experiment` says which system it measures (S0, S_H, S_L, T of Fig. 3, or the open loop), which
compensator stages are on, what drives it (a voltage applied directly, or a reference through the cascade), its
trajectory, and which metric (Section VII-A) is read from it.  The same list drives

* :func:`simulate_experiments` — core cascade + :class:`~piezo_ff_ros.core.models.plant.Plant`, in blocks;
* the ROS demo (another package part) — :func:`experiment_sequence` gives a named :class:`~.trajectories.TrajectorySequence` whose segment
  ``meta`` carries everything a node needs (``Experiment.meta()``);
* :func:`piezo_ff_ros.core.reproduce.evaluate` — the tables from recorded signals, whatever produced them.

Recorded signals per experiment are ``Recorded(t, reference, u, y)``: ``t`` [s] from the experiment's start,
``reference`` [N, axes] the trajectory (volts for ``input='voltage'`` experiments, metres otherwise), ``u`` [V]
the voltage applied, ``y`` [m] the displacement.

Experiment names (a contract with the demo and the analysis):

==================  ======  ======  ============================================  ==========
name                paper   system  drive                                          metric
==================  ======  ======  ============================================  ==========
hyst_S0_<a>         IV-A    S0      200 V, 0.1 Hz sine on U_a, no compensator      hysteresis
hyst_SH_<a>         IV-C    S_H     20 µm, 0.1 Hz sine through hysteresis⁻¹        hysteresis
creep_SH_<a>        V-A     S_H     20 µm step on axis a, ``creep_duration`` s     creep
creep_SL_<a>        V-C     S_L     20 µm step through creep⁻¹ + hysteresis⁻¹      creep
step_SL_<a>         VI-A    S_L     20 µm step, 0.5 s                              overshoot
step_T_<a>          VI-C    T       20 µm step through the full cascade            overshoot
circle<r>_T         VII-B   T       circle of radius r µm through the full cascade tracking
circle<r>_open      VII-B   open    same circle, voltage = Dp⁻¹·reference          tracking
==================  ======  ======  ============================================  ==========
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple
from typing import Sequence as Seq

import numpy as np

from .compensators.cascade import CompensatorCascade
from .config import PiezoConfig
from .models.plant import Plant
from .trajectories import Circle, PerAxis, Sine, Step, Trajectory, TrajectorySequence
from .stage import Processor
from .units import UM

__all__ = ["Experiment", "Recorded", "paper_experiments", "select_experiments", "experiment_sequence", "simulate_experiments",
           "run_experiment", "STAGE_SETS"]

#: compensator stages on, per system of Fig. 3 ("open": none, the cascade reduces to Dp⁻¹)
STAGE_SETS = {"S0": (), "open": (), "S_H": ("hysteresis",), "S_L": ("hysteresis", "creep"),
              "T": ("hysteresis", "creep", "vibration")}

T_STEP = 0.05          #: [s] rest before each step (gives the pre-step level)
STEP_HOLD = 0.5        #: [s] vibration step records (the transient lasts < 200 ms)
HYST_FREQUENCY = 0.1   #: [Hz] paper IV-A / IV-C
HYST_VOLTAGE = 200.0   #: [V] paper IV-A
AMPLITUDE = 20 * UM    #: [m] steps and compensated sines (IV-C, V, VI)


class Recorded(NamedTuple):
    """One experiment's signals: ``t`` [N] s, ``reference`` [N, axes], ``u`` [N, axes] V, ``y`` [N, axes] m.

    ``reference`` is None only for a recorded segment without one (:func:`~piezo_ff_ros.core.analysis.segment_signals`
    with ``complete_only=False``)."""

    t: np.ndarray
    reference: np.ndarray | None
    u: np.ndarray
    y: np.ndarray


@dataclass(frozen=True)
class Experiment:
    """One experiment of the paper, as data.

    Attributes
    ----------
    name : str
        Unique name (see the module table).
    section : str
        Paper section (``"IV-A"`` …).
    system : str
        ``"S0"``, ``"S_H"``, ``"S_L"``, ``"T"`` (Fig. 3) or ``"open"`` (uncompensated, ``U = Dp⁻¹·Y_R``).
    input : str
        ``"voltage"`` — the trajectory is the voltage U itself (S0); ``"reference"`` — it goes through the
        compensator cascade with ``stages`` on.
    trajectory : Trajectory
        What is played, from the experiment's own t = 0.
    metric : str
        ``"hysteresis"``, ``"creep"``, ``"overshoot"`` or ``"tracking"``.
    axis : str or None
        The driven axis (None: both, e.g. a circle).
    params : dict
        Metric parameters: ``period`` [s] (hysteresis), ``t_step`` [s] (creep/overshoot), ``t_creep`` [s],
        ``skip`` [s] (tracking: start-up excluded), ``radius`` [m].
    record_decimation : int
        In simulation, record one sample per ``record_decimation`` samples — their mean, stamped at the centre
        of the block (long, slow experiments; the mean is what a block-averaging recorder would keep).
    """

    name: str
    section: str
    system: str
    input: str
    trajectory: Trajectory
    metric: str
    axis: str | None = None
    params: dict[str, Any] = field(default_factory=dict)
    record_decimation: int = 1
    description: str = ""

    @property
    def stages(self) -> tuple[str, ...]:
        """Compensator stages switched on (``()`` for S0 and the open loop)."""
        return STAGE_SETS[self.system]

    def meta(self) -> dict[str, Any]:
        """Plain-dict description for a :class:`~.trajectories.TrajectorySequence` segment / ROS parameters (no trajectory)."""
        return {"experiment": self.name, "section": self.section, "system": self.system, "input": self.input,
                "stages": list(self.stages), "metric": self.metric, "axis": self.axis,
                "params": dict(self.params), "reset_before": True, "description": self.description}


def select_experiments(experiments: Seq[Experiment], only: str | None) -> list[Experiment]:
    """The experiments named in ``only`` (comma-separated, the ``--only`` option), in their own order.

    Parameters
    ----------
    experiments : sequence of Experiment
        All of them (e.g. :func:`paper_experiments`).
    only : str or None
        ``"name1,name2"``; None or empty keeps all.

    Returns
    -------
    list of Experiment

    Raises
    ------
    ValueError
        ``--only: unknown experiment(s) …``, naming them and the known ones.
    """
    if not only:
        return list(experiments)
    wanted = [s.strip() for s in only.split(",") if s.strip()]
    unknown = set(wanted) - {e.name for e in experiments}
    if unknown:
        raise ValueError(f"--only: unknown experiment(s) {sorted(unknown)}; have {[e.name for e in experiments]}")
    return [e for e in experiments if e.name in wanted]


def paper_experiments(cfg: PiezoConfig | None = None, creep_duration: float = 600.0, hysteresis_periods: int = 2,
                      circle_radii: Seq[float] = (20 * UM, 30 * UM), circle_frequency: float = 1.0,
                      circle_revolutions: float = 2.0, step_hold: float = STEP_HOLD,
                      axes: Seq[str] | None = None) -> list[Experiment]:
    """The paper's experiment list (Sections IV-A/C, V-A/C, VI-A/C, VII-B), in the paper's order.

    Parameters
    ----------
    cfg : PiezoConfig, optional
        Gives the axis names (default ``('x', 'y')``).  Every axis gets its hysteresis, creep and step
        experiments; the circles (two axes or more) are drawn in the plane of the first two axes, the others held
        at rest; a single axis has no circle.
    creep_duration : float
        Creep observation time after the step [s] (paper: 600 s).
    hysteresis_periods : int
        Periods of the 0.1 Hz sines; the metric uses the last one (the first contains the virgin curve).
    circle_radii, circle_frequency, circle_revolutions
        VII-B circles (the paper does not give the frequency; 1 Hz by default).  Tracking is read over the last
        revolution.
    step_hold : float
        Duration of the vibration step records after the step [s].
    axes : sequence of str, optional
        The axis names when no ``cfg`` gives them (e.g. a recording's).
    """
    axes = tuple(cfg.axes) if cfg is not None else (tuple(axes) if axes is not None else ("x", "y"))
    if not creep_duration > 1.0:
        raise ValueError(f"creep_duration must be > 1 s (the creep A_f is read 0.2 s after the step), "
                         f"got {creep_duration}")
    if int(hysteresis_periods) < 1:
        raise ValueError(f"hysteresis_periods must be >= 1, got {hysteresis_periods}")
    period = 1.0 / HYST_FREQUENCY
    hyst_T = period * int(hysteresis_periods)
    exps: list[Experiment] = []
    def sine(amplitude: float) -> Callable[[str], Trajectory]:
        return lambda a: Sine(amplitude=amplitude, frequency=HYST_FREQUENCY, axis=a, duration=hyst_T, axes=axes)

    def step(hold: float) -> Callable[[str], Trajectory]:  # 20 µm on the driven axis, 0 on the others
        return lambda a: Step(amplitude={a: AMPLITUDE}, t_step=T_STEP, hold=hold, axes=axes)

    f = f"{HYST_FREQUENCY:g} Hz"
    creep_params = {"t_step": T_STEP, "t_creep": creep_duration}
    # name prefix, section, system, input, trajectory per driven axis, metric, params, decimation, description
    rows: list[tuple[str, str, str, str, Callable[[str], Trajectory], str, dict[str, float], int, str]] = [
        ("hyst_S0", "IV-A", "S0", "voltage", sine(HYST_VOLTAGE), "hysteresis", {"period": period}, 10,
         f"{HYST_VOLTAGE:g} V {f} sine on U_{{a}}, no compensation (Fig. 4)"),
        ("hyst_SH", "IV-C", "S_H", "reference", sine(AMPLITUDE), "hysteresis", {"period": period}, 10,
         f"20 µm {f} sine on {{a}}_h through the hysteresis compensator (Fig. 6)"),
        ("creep_SH", "V-A", "S_H", "reference", step(creep_duration), "creep", creep_params, 20,
         f"20 µm step on {{a}}_h for {creep_duration:g} s, hysteresis compensated (Fig. 7)"),
        ("creep_SL", "V-C", "S_L", "reference", step(creep_duration), "creep", creep_params, 20,
         f"20 µm step on {{a}}_l for {creep_duration:g} s through creep and hysteresis compensators (Fig. 10)"),
        ("step_SL", "VI-A", "S_L", "reference", step(step_hold), "overshoot", {"t_step": T_STEP}, 1,
         "20 µm step on {a}_l, hysteresis and creep compensated (Fig. 11)"),
        ("step_T", "VI-C", "T", "reference", step(step_hold), "overshoot", {"t_step": T_STEP}, 1,
         "20 µm step on {a}_r through the complete compensator (Fig. 14)"),
    ]
    for prefix, section, system, kind, trajectory, metric, params, decimate, text in rows:
        for a in axes:
            exps.append(Experiment(f"{prefix}_{a}", section, system, kind, trajectory(a), metric, a, dict(params),
                                   decimate, text.format(a=a)))
    if len(axes) >= 2:
        for r in circle_radii:
            tag = f"{r / UM:g}".replace(".", "p")
            circle: Trajectory = Circle(radius=r, frequency=circle_frequency, revolutions=circle_revolutions,
                                        axes=axes[:2])
            if len(axes) > 2:   # in the plane of the first two axes, the others at rest
                circle = PerAxis([circle], axes=axes)
            skip = circle.duration - 1.0 / circle_frequency
            for system in ("T", "open"):
                exps.append(Experiment(
                    f"circle{tag}_{system}", "VII-B", system, "reference", circle, "tracking", None,
                    {"skip": skip, "radius": r}, 1,
                    f"circle of radius {r / UM:g} µm at {circle_frequency:g} Hz, "
                    + ("complete compensation" if system == "T" else "no compensation (U = Dp⁻¹·Y_R)")
                    + " (Fig. 15)"))
    return exps


def experiment_sequence(experiments: list[Experiment]) -> TrajectorySequence:
    """The experiments as one named :class:`TrajectorySequence` (segment meta = :meth:`Experiment.meta`)."""
    return TrajectorySequence([(e.name, e.trajectory, e.meta()) for e in experiments])


def _stage_config(cfg: PiezoConfig, exp: Experiment) -> PiezoConfig:
    on = set(exp.stages)
    cascade = dataclasses.replace(cfg.cascade, hysteresis="hysteresis" in on, creep="creep" in on,
                                  vibration="vibration" in on)
    return dataclasses.replace(cfg, cascade=cascade)


def run_experiment(exp: Experiment, cfg: PiezoConfig, plant: Processor, design: Any = None, block: int = 20000,
                   cascade: CompensatorCascade | None = None) -> Recorded:
    """Play one experiment from rest through its compensators into ``plant`` (reset first); return the record.

    ``cfg`` is the compensators' (nominal) model; ``plant`` may be a different truth.  ``design`` (an
    ``HinfDesign`` or ``(A, B, C, D)``) is the vibration compensator when the experiment uses it.
    """
    fs = cfg.sample_rate
    n_samples = exp.trajectory.n_samples(fs)
    if math.isinf(n_samples):
        raise ValueError(f"{exp.name}: endless trajectory cannot be simulated")
    n_total = int(n_samples)
    dec = max(1, int(exp.record_decimation))
    block = max(dec, (int(block) // dec) * dec)
    if exp.input == "voltage":
        comp = None
    elif cascade is not None:
        comp = cascade
    else:
        comp = CompensatorCascade(_stage_config(cfg, exp), controller=design if "vibration" in exp.stages else None)
    plant.reset()
    if comp is not None:
        comp.reset()
    n_keep = (n_total + dec - 1) // dec
    n_ax = cfg.n_axes
    R = np.empty((n_keep, n_ax))
    U = np.empty((n_keep, n_ax))
    Y = np.empty((n_keep, n_ax))
    T = np.empty(n_keep)
    j = 0
    for k0 in range(0, n_total, block):
        n = min(block, n_total - k0)
        r = exp.trajectory.block(k0, n, fs)
        u = r if comp is None else comp.process(r)
        y = plant.process(u)
        if dec == 1:
            m = n
            R[j:j + m], U[j:j + m], Y[j:j + m] = r, u, y
            T[j:j + m] = (k0 + np.arange(n)) / fs
        else:
            # one averaged sample per `dec` samples (a recorder's block average: sensor noise averages out),
            # stamped at the centre of its block
            starts = np.arange(0, n, dec)
            counts = np.minimum(dec, n - starts)[:, None]
            m = len(starts)
            R[j:j + m] = np.add.reduceat(r, starts, axis=0) / counts
            U[j:j + m] = np.add.reduceat(u, starts, axis=0) / counts
            Y[j:j + m] = np.add.reduceat(y, starts, axis=0) / counts
            T[j:j + m] = (k0 + starts + 0.5 * (counts[:, 0] - 1)) / fs
        j += m
    return Recorded(T, R, U, Y)


def simulate_experiments(cfg: PiezoConfig, design: Any = None, plant: Processor | None = None, experiments: list[Experiment] | None = None,
                         creep_duration: float = 600.0, block: int = 20000,
                         progress: Callable[[str], None] | None = None) -> dict[str, Recorded]:
    """Run the paper's experiments on the core cascade + a simulated plant (no ROS).

    Parameters
    ----------
    cfg : PiezoConfig
        The compensators' model (and the nominal plant when ``plant`` is None), sample rate.
    design : HinfDesign or (A, B, C, D), optional
        Vibration compensator; synthesised once from ``cfg`` (``synthesize_hinf``) when an experiment needs it
        and none is given (or ``cfg.vibration.controller`` holds one).
    plant : Plant, optional
        The truth (e.g. with sensor noise or asymmetric hysteresis); reset before every experiment.
    experiments : list of Experiment, optional
        Default: :func:`paper_experiments` with ``creep_duration``.
    block : int
        Samples per processing block.
    progress : callable, optional
        Called with each experiment's name before it runs.

    Returns
    -------
    dict
        ``{name: Recorded(t, reference, u, y)}`` in the experiments' order.
    """
    exps = experiments if experiments is not None else paper_experiments(cfg, creep_duration=creep_duration)
    if plant is None:
        plant = Plant(cfg)
    if design is None and cfg.vibration.controller is None and any("vibration" in e.stages for e in exps):
        from .synthesis.hinf import synthesize_hinf

        design = synthesize_hinf(cfg.dynamics.G_L, cfg.vibration)
    out: dict[str, Recorded] = {}
    for exp in exps:
        if progress is not None:
            progress(exp.name)
        out[exp.name] = run_experiment(exp, cfg, plant, design, block=block)
    return out
