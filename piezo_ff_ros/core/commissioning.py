"""One commissioning sequence (paper Fig. 3) over a small rig interface: characterise, identify, synthesise, verify.

The sequence is written once, here; where the signals come from is the rig's business:

- :class:`SimRig` — a core simulated plant (no ROS): ``piezo-ff commission --sim-only``;
- :class:`piezo_ff_ros.ros.graph_rig.GraphRig` — the running node graph (simulated driver or any hardware
  backend): ``piezo-ff commission``.

A rig does three things (:class:`Rig`): ``configure`` the compensator in front of the plant (which stages, with
which identified parameters, or bypass: voltages straight in), ``play`` planned runs and return what was applied and
measured, and ``run_experiments`` (the paper's verification tests).  Stage by stage, each stage is characterised on
the system the previous compensators leave (S0 → S_H → S_L), identified on its ``fit`` runs and scored on held-out
runs; the Bouc-Wen is refitted once creep is known; the whole identified plant is scored on a held-out voltage
record; the H∞ compensator is synthesised on the identified G_L.

Pure: no ROS import.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol, Sequence

import numpy as np

from .characterisation import (CharacterisationSettings, creep_trajectories, dynamics_trajectories,
                               hysteresis_trajectories, plant_validation_trajectory, run_open_loop)
from .config import PiezoConfig, load_config
from .jsonable import JsonResult, jsonable
from .identification.bouc_wen import identify_bouc_wen
from .identification.creep import identify_creep
from .identification.dynamics import identify_dynamics
from .identification.pipeline import (REFIT_TAG, build_config, fits_report, plant_fit, refit_hysteresis_without_creep,
                                      simulate_plant, with_hinf_controller)
from .recording.run import RunData
from .stage import Processor, Stage
from .trajectories import Trajectory

if TYPE_CHECKING:  # imported where used (the simulation and the evaluation are loaded on demand)
    from .experiments import Experiment, Recorded
    from .reproduce import ReproduceResult

__all__ = ["CommissioningError", "PoorFitError", "FIT_FLOOR_PERCENT", "PlannedRun", "Rig", "RigLimits", "SimRig", "CommissionResult", "CommissionReport",
           "below_floor", "characterisation_plan", "check_voltage_runs", "commission", "commission_sim", "part_fits", "verify",
           "save_config", "save_report"]

Progress = Callable[[str], None]


class CommissioningError(RuntimeError):
    """Commissioning cannot start or go on (no sensor, a run outside the limits, a configuration refused…)."""


class PoorFitError(CommissioningError):
    """An identified stage predicts its held-out record worse than the floor (:data:`FIT_FLOOR_PERCENT`): the
    identification is refused before it is applied or written."""


#: Held-out fit [%] (MATLAB ``compare``: 100·(1 − ‖y − ŷ‖/‖y − ȳ‖)) below which an identified stage is refused.
#: 0 % is a model no better than predicting the record's mean; at 50 % the model misses half of the motion (rms),
#: more than the hysteresis (15–20 % of the range, paper Table I) or the overshoot the compensators exist to remove,
#: so a compensator built on it cannot be trusted to do better than none.  Sound identifications of these stages
#: score above 90 % (sim and graph, one to three axes, one or more sine periods, sensor noise of a few nm: a noise
#: of 1 % of the motion costs a fit about 1 point), so the floor sits far below them and far above a broken one.
FIT_FLOOR_PERCENT = 50.0

#: what the user can do when a stage's held-out fit is below the floor
_FIT_ADVICE = {
    "hysteresis": "record more of the hysteresis (more sine periods, --sine-periods, or a lower --sine-frequency) "
                  "and check the sensor",
    "creep": "record longer creep steps (--creep-duration) and check the sensor's drift",
    "dynamics": "check the dynamics step (--step-um) against the sensor's noise and bandwidth",
    "plant": "the identified stages do not reproduce the plant: check the stage fits and the sensor",
}


def below_floor(stage: str, fits: Mapping[str, float | None], keys: Sequence[str],
                floor: float = FIT_FLOOR_PERCENT, label: str | None = None) -> str | None:
    """One line naming the entries of ``fits`` below ``floor`` (or undefined), None when all are at or above it.

    Parameters
    ----------
    stage : str
        ``hysteresis``, ``creep``, ``dynamics`` or ``plant``.
    fits : mapping
        Held-out fit [%] per axis or entry (None: not finite).
    keys : sequence of str
        The entries that are checked (the axes; the diagonal ``xx``, ``yy``… for creep and G_L).
    floor : float
        The lowest acceptable fit [%].
    label : str, optional
        How the line names the stage (default: ``stage``; ``dynamics (G_L)`` for ``dynamics``).

    Returns
    -------
    str or None
        e.g. ``hysteresis held-out fit y: -9776542.385 % (floor 50 %)``.
    """
    bad = [(k, fits.get(k)) for k in keys]
    bad = [(k, v) for k, v in bad if v is None or not np.isfinite(v) or v < floor]
    if not bad:
        return None
    what = ", ".join(f"{k}: {'undefined' if v is None or not np.isfinite(v) else f'{v:.3f} %'}" for k, v in bad)
    label = label or {"dynamics": "dynamics (G_L)"}.get(stage, stage)
    return f"{label} held-out fit {what} (floor {floor:g} %)"


@dataclass(frozen=True)
class PlannedRun:
    """One characterisation run.

    ``role``: ``fit`` (identified on), ``validation`` (only scored on) or ``split`` (fitted on ``[0, score_start_s)``,
    the whole run scored from ``score_start_s`` on).  ``input`` is ``voltage`` (compensator bypassed, the trajectory
    is in volts) or ``position`` (through the compensators configured for the stage, in metres).
    """

    name: str
    trajectory: Trajectory
    stage: str
    role: str
    score_start_s: float = 0.0
    input: str = "position"


class Rig(Protocol):
    """What the commissioning sequence needs from a positioner and its compensator."""

    sample_rate: float
    axes: tuple[str, ...]

    @property
    def has_sensor(self) -> bool:
        """True when the rig measures the displacement (commissioning needs it)."""

    @property
    def voltage_limit(self) -> float:
        """±V the driver enforces."""

    @property
    def slew_limit(self) -> float:
        """V/s the driver enforces."""

    def configure(self, cfg: PiezoConfig | None, stages: frozenset[str], bypass: bool = False) -> None:
        """Put ``stages`` of ``cfg`` (None: keep the parameters that run) in front of the plant, or bypass it.

        Raises :class:`CommissioningError` when the compensator refuses the configuration.
        """

    def play(self, runs: Sequence[PlannedRun], meta: Mapping[str, object] | None = None) -> dict[str, RunData]:
        """Play ``runs`` from rest one after the other; ``{name: RunData}`` with ``u`` the voltage applied,
        ``y`` the measured displacement, ``reference`` the trajectory's samples, all at :attr:`sample_rate`."""

    def run_experiments(self, cfg: PiezoConfig, design: object, experiments: Sequence[Experiment],
                        progress: Progress) -> Mapping[str, tuple[Any, ...]]:
        """The paper's verification experiments: ``{name: (t, reference, u, y)}``."""


def characterisation_plan(settings: CharacterisationSettings, axes: Sequence[str]) -> dict[str, list[PlannedRun]]:
    """The characterisation runs per stage (hysteresis, plant, creep, dynamics), the paper's defaults."""
    axes = tuple(axes)
    ht = hysteresis_trajectories(settings, axes)
    plan: dict[str, list[PlannedRun]] = {"hysteresis": [], "plant": [], "creep": [], "dynamics": []}
    for role in ("fit", "validation"):
        plan["hysteresis"] += [PlannedRun(n, tr, "hysteresis", role, input="voltage") for n, tr in ht[role]]
    plan["plant"].append(PlannedRun("plant_validation", plant_validation_trajectory(settings, axes), "plant",
                                    "validation", input="voltage"))
    for stage, fn in (("creep", creep_trajectories), ("dynamics", dynamics_trajectories)):
        plan[stage] = [PlannedRun(n, tr, stage, "split", float(t)) for n, tr, t in fn(settings, axes)]
    return plan


def check_voltage_runs(runs: Sequence[PlannedRun], voltage_limit: float, slew_limit: float, fs: float) -> None:
    """Refuse voltage-input runs that would leave the rig's limits (the driver would clip them: a wrong fit)."""
    for r in runs:
        if r.input != "voltage":
            continue
        _, v = r.trajectory.sample(fs)
        peak = float(np.max(np.abs(v))) if v.size else 0.0
        if peak > voltage_limit * (1 + 1e-9):
            raise CommissioningError(f"{r.name}: peak {peak:.4g} V exceeds the rig's voltage limit "
                                     f"±{voltage_limit:g} V (lower the characterisation amplitude)")
        # (a run that starts away from 0 V is the rig's to reach from rest: the graph rig ramps to it)
        slew = float(np.max(np.abs(np.diff(v, axis=0)))) * fs if len(v) > 1 else 0.0
        if slew > slew_limit * (1 + 1e-9):
            raise CommissioningError(f"{r.name}: slew {slew:.4g} V/s exceeds the rig's slew limit "
                                     f"{slew_limit:g} V/s")


class RigLimits:
    """The driver's limits a rig reports (shared by the rigs here)."""

    def __init__(self, voltage_limit: float, slew_limit: float) -> None:
        self._vlim, self._slim = float(voltage_limit), float(slew_limit)

    @property
    def voltage_limit(self) -> float:
        """±V the driver enforces."""
        return self._vlim

    @property
    def slew_limit(self) -> float:
        """V/s the driver enforces."""
        return self._slim


class SimRig(RigLimits):
    """A core simulated plant (``process``/``reset``, e.g. :class:`~piezo_ff_ros.core.models.plant.Plant`) with the
    compensators the commissioning configures in front of it."""

    def __init__(self, plant: Processor, sample_rate: float, axes: Sequence[str] = ("x", "y"),
                 voltage_limit: float = float("inf"), slew_limit: float = float("inf")) -> None:
        self.plant = plant
        self.sample_rate = float(sample_rate)
        self.axes = tuple(axes)
        super().__init__(voltage_limit, slew_limit)
        self._chain: list[Stage] = []

    @property
    def has_sensor(self) -> bool:
        """Always True: the simulation's output is the displacement."""
        return True

    def configure(self, cfg: PiezoConfig | None, stages: frozenset[str], bypass: bool = False) -> None:
        """Put the creep and/or hysteresis compensators of ``cfg`` in front of the plant (see :meth:`Rig.configure`).

        Parameters
        ----------
        cfg : PiezoConfig or None
            The compensators' parameters (required unless bypassed or no stage is asked for).
        stages : frozenset of str
            ``creep`` and/or ``hysteresis`` (the characterisation never runs through the vibration stage).
        bypass : bool
            Voltages go to the plant unchanged.

        Raises
        ------
        CommissioningError
            ``cfg`` is missing or a stage is not part of the sequence.
        """
        from .compensators.creep import CreepCompensator
        from .compensators.hysteresis import HysteresisCompensator

        if bypass or not stages:
            self._chain = []
            return
        if cfg is None:
            raise CommissioningError("the simulated rig needs the configuration to build its compensators")
        unknown = set(stages) - {"creep", "hysteresis"}
        if unknown:
            raise CommissioningError(f"characterisation through {sorted(unknown)} is not part of the sequence")
        chain: list[Stage] = []
        if "creep" in stages:
            chain.append(CreepCompensator(cfg.creep, 1.0 / self.sample_rate))
        if "hysteresis" in stages:
            chain.append(HysteresisCompensator(cfg.hysteresis))
        self._chain = chain

    def play(self, runs: Sequence[PlannedRun], meta: Mapping[str, object] | None = None) -> dict[str, RunData]:
        """Play each run from rest through the configured compensators and the plant (see :meth:`Rig.play`).

        Parameters
        ----------
        runs : sequence of PlannedRun
            What to play.
        meta : mapping, optional
            Unused here (the graph rig records it).

        Returns
        -------
        dict
            ``{name: RunData}``.
        """
        return {r.name: run_open_loop(self.plant, r.trajectory, self.sample_rate, r.name, self.axes,
                                      chain=self._chain) for r in runs}

    def run_experiments(self, cfg: PiezoConfig, design: object, experiments: Sequence[Experiment],
                        progress: Progress) -> dict[str, Recorded]:
        """The paper's verification experiments simulated on the plant with ``cfg``'s cascade.

        Parameters
        ----------
        cfg : PiezoConfig
            The cascade to verify.
        design : HinfDesign or None
            Its H∞ design (None: from ``cfg``).
        experiments : sequence of Experiment
            What to run.
        progress : callable
            Called with one line per experiment.

        Returns
        -------
        dict
            ``{name: (t, reference, u, y)}``.
        """
        from .experiments import simulate_experiments

        return simulate_experiments(cfg, design=design, plant=self.plant, experiments=list(experiments),
                                    progress=lambda name: progress(f"verify: {name}"))

    # only a simulation can tell the noise-free output (for the plant fit against the truth)
    def noise_free_output(self, u: np.ndarray) -> np.ndarray | None:
        """The plant's output without sensor noise for the voltages ``u`` [V], from rest.

        Parameters
        ----------
        u : array [N, axes]
            Voltages [V].

        Returns
        -------
        array [N, axes] or None
            Displacement [m]; None when the plant has no sensor noise (its output is already noise-free).
        """
        from .models.plant import Plant

        p = self.plant
        if not isinstance(p, Plant) or not float(getattr(p, "noise_std", 0.0) or 0.0) > 0:
            return None
        return Plant(p.cfg, pre=p.pre, post=p.post, noise_std=0.0, stages=p.stages).process(u)


@dataclass(frozen=True)
class CommissionReport(JsonResult):
    """Held-out fits, orders and timings of :func:`commission`.

    Attributes
    ----------
    fit_percent : dict
        Held-out fit [%] per stage (hysteresis, creep, dynamics, plant) and axis/entry.
    orders : dict
        ``{creep, dynamics}``: the model order per entry.
    plant_fit_basis : str
        What the whole-plant fit compares with (the measured output, with sensor noise or not).
    plant_fit_parts : dict
        Whole-plant fit [%] on each part of the validation record (multisine, step pair) per axis.
    timing_s : dict
        Wall time [s] per step and ``total``.
    plant_fit_noise_free : dict or None
        Whole-plant fit [%] against the noise-free truth (simulated rigs only; absent from the JSON when None).
    accepted_poor_fits : list of str or None
        The held-out fits below the floor that were kept on request (``accept_poor_fit``); absent when None.
    """

    fit_percent: dict[str, dict[str, float | None]]
    orders: dict[str, Any]
    plant_fit_basis: str
    plant_fit_parts: dict[str, dict[str, float]]
    timing_s: dict[str, float]
    plant_fit_noise_free: dict[str, float | None] | None = field(default=None, metadata={"omit_none": True})
    accepted_poor_fits: list[str] | None = field(default=None, metadata={"omit_none": True})

    def format_fits(self) -> str:
        """The held-out fits as the printed table of ``piezo-ff commission`` (sim-only and graph alike).

        Returns
        -------
        str
            One line per stage (``—`` where a fit is undefined), then the whole-plant basis and, for a simulated
            rig, the fit against the noise-free truth.
        """
        def f(v: float | None) -> str:
            return "—" if v is None else f"{v:8.3f}"
        lines = ["held-out fit [%] (MATLAB compare):"]
        lines += [f"  {stage:10s} " + "  ".join(f"{k}: {f(v)}" for k, v in d.items())
                  for stage, d in self.fit_percent.items()]
        lines.append(f"  (plant = identified whole-plant model vs the {self.plant_fit_basis}, held-out voltage record)")
        if self.plant_fit_noise_free is not None:
            lines.append("  plant vs the noise-free truth: " + "  ".join(
                f"{k}: {f(v)}" for k, v in self.plant_fit_noise_free.items()))
        for text in self.accepted_poor_fits or ():
            lines.append(f"  BELOW THE FLOOR, kept on request (accept poor fit): {text}")
        return "\n".join(lines)


def save_config(cfg: PiezoConfig, path: Path) -> None:
    """Write the identified ``cfg`` as YAML and load it back as the compensator node will (fails loudly if the file
    is not loadable).

    Parameters
    ----------
    cfg : PiezoConfig
        The identified configuration.
    path : Path
        The YAML file to write.
    """
    cfg.to_yaml(path)
    load_config(path)


def save_report(report: Mapping[str, Any], out_dir: Path, extra: str | None = None) -> None:
    """Write the commissioning report as ``out_dir/commission.json`` (and to ``extra`` too, when given).

    Parameters
    ----------
    report : mapping
        The report (any values :func:`~piezo_ff_ros.core.jsonable.jsonable` accepts).
    out_dir : Path
        The commissioning output directory.
    extra : str or None
        A second path (``--json``).
    """
    text = json.dumps(jsonable(report), indent=2)
    (out_dir / "commission.json").write_text(text)
    if extra:
        Path(extra).write_text(text)


@dataclass(frozen=True)
class CommissionResult:
    """What :func:`commission` identified.

    Attributes
    ----------
    config : PiezoConfig
        The complete identified config (the H∞ controller stored in it).
    design : HinfDesign or None
        The H∞ design (None when not synthesised).
    hinf_note : str or None
        Why ``vibration.gamma_max`` was raised, if it was.
    report : CommissionReport
        Held-out fits per stage and of the whole plant, orders, timings.
    runs : list of RunData
        The recorded runs, tagged with their stage and role.
    """

    config: PiezoConfig
    design: object
    hinf_note: str | None
    report: CommissionReport
    runs: list[RunData] = field(default_factory=list)


def _tagged(recorded: Mapping[str, RunData], planned: Sequence[PlannedRun], fs: float,
            extra: Mapping[str, object] | None = None) -> tuple[list[RunData], list[RunData]]:
    """Split the recorded runs into fit and validation records as their plan says."""
    fit, val = [], []
    for p in planned:
        r = recorded[p.name]
        r.meta.update(extra or {})
        if p.role == "split":
            k = int(round(p.score_start_s * fs))
            f = r.slice(0, k)
            f.meta.update(stage=p.stage, role="fit")
            r.meta.update(stage=p.stage, role="validation", score_start=k)
            fit.append(f)
            val.append(r)
        else:
            r.meta.update(stage=p.stage, role=p.role)
            (val if p.role == "validation" else fit).append(r)
    return fit, val


def commission(rig: Rig, base: PiezoConfig | None = None, settings: CharacterisationSettings | None = None,
               generalized: bool = False, creep_order: int | str = "auto", dynamics_order: int | str = "auto",
               refine_hysteresis: bool = True, synthesize: bool = True,
               progress: Progress | None = None, fit_floor: float = FIT_FLOOR_PERCENT,
               accept_poor_fit: bool = False) -> CommissionResult:
    """Characterise and identify ``rig`` stage by stage (paper Fig. 3), then synthesise the H∞ compensator.

    Parameters
    ----------
    rig : Rig
        Where the signals come from (:class:`SimRig`, the ROS graph's ``GraphRig``, …). Must have a sensor.
    base : PiezoConfig, optional
        Weights, cascade options and limits kept in the identified config (default: the paper's config).
    settings : CharacterisationSettings, optional
        Amplitudes, durations, frequencies of the characterisation (default: the paper's).
    generalized : bool
        Identify the asymmetric (generalized) Bouc-Wen.
    creep_order, dynamics_order : int or "auto"
        Model orders (``auto``: chosen on held-out fit).
    refine_hysteresis : bool
        Refit the Bouc-Wen once creep is known (before S_L is characterised through it).
    synthesize : bool
        Synthesise the H∞ compensator and store it in the config.
    progress : callable, optional
        Called with one line per step.
    fit_floor : float
        Lowest acceptable held-out fit [%] of the hysteresis (per axis), creep and G_L (diagonal) and the whole
        plant (per axis); default :data:`FIT_FLOOR_PERCENT`.  Each stage is checked as soon as it is identified,
        before it is put in front of the plant.
    accept_poor_fit : bool
        Keep a stage below ``fit_floor`` anyway (a warning line, and ``report.accepted_poor_fits``).

    Returns
    -------
    CommissionResult

    Raises
    ------
    PoorFitError
        A held-out fit is below ``fit_floor`` (and ``accept_poor_fit`` is False): one line naming the stage, the
        entries, their figures and what to do.
    CommissioningError
        The rig has no sensor, ``base`` has other axes than the rig, a voltage run would leave its limits, or its
        compensator refused a configuration.
    """
    say = progress or (lambda s: None)
    if not rig.has_sensor:
        raise CommissioningError("the rig has no displacement sensor: commissioning identifies the plant from "
                                 "measured displacements (use a metrology rig, or load a config)")
    s = settings or CharacterisationSettings()
    base = base or load_config()
    fs, axes = rig.sample_rate, tuple(rig.axes)
    if tuple(base.axes) != axes:   # the identified config would describe another stage than the one measured
        raise CommissioningError(f"the starting config {base.name!r} has axes {list(base.axes)} but the rig has "
                                 f"{list(axes)}: start from a config of the rig's axes (--config)")
    plan = characterisation_plan(s, axes)
    check_voltage_runs([r for runs in plan.values() for r in runs], rig.voltage_limit, rig.slew_limit, fs)
    timing: dict[str, float] = {}
    t_all = time.perf_counter()
    runs: list[RunData] = []
    accepted: list[str] = []
    diagonal = [a + a for a in axes]

    def gate(stage: str, fits: Mapping[str, float | None], keys: Sequence[str], label: str | None = None) -> None:
        """Refuse (or, on request, keep with a warning) a stage whose held-out fit is below the floor."""
        text = below_floor(stage, fits, keys, fit_floor, label)
        if text is None:
            return
        if not accept_poor_fit:
            raise PoorFitError(f"{text}: the identified model cannot be trusted, nothing was applied or written; "
                               f"{_FIT_ADVICE[stage]} (or accept it anyway: --accept-poor-fit)")
        say(f"warning: {text}: kept on request (accept poor fit)")
        accepted.append(text)

    def hysteresis_fits(fit: Any) -> dict[str, float | None]:
        v = fit.fit_validation if fit.fit_validation is not None else fit.fit_train
        return {a: float(x) for a, x in zip(axes, v)}

    def characterise(stage: str, extra: Mapping[str, object] | None = None) -> tuple[list[RunData], list[RunData]]:
        t0 = time.perf_counter()
        recorded = rig.play(plan[stage], {"stage": stage, **(extra or {})})
        fit, val = _tagged(recorded, plan[stage], fs, extra)
        runs.extend(fit + val)
        timing[f"characterise_{stage}"] = time.perf_counter() - t0
        return fit, val

    say("characterise hysteresis on S0 (compensator bypassed: sines in volts)")
    rig.configure(None, frozenset(), bypass=True)
    hfit, hval = characterise("hysteresis")
    t0 = time.perf_counter()
    hf = identify_bouc_wen(hfit, hval, generalized=generalized, progress=say)
    timing["identify_hysteresis"] = time.perf_counter() - t0
    gate("hysteresis", hysteresis_fits(hf), axes)   # before it is put in front of the plant
    say("held-out whole-plant voltage record (multisine + step pair, never fitted on), still bypassed")
    _, plant_runs = characterise("plant")

    say(f"characterise creep on S_H ({s.creep_duration:g} s steps up and down per axis) through the identified "
        "hysteresis compensator")
    rig.configure(replace(base, hysteresis=hf.config), frozenset({"hysteresis"}))
    cfit, cval = characterise("creep")
    t0 = time.perf_counter()
    cf = identify_creep(cfit, cval, order=creep_order, axes=axes, progress=say)
    timing["identify_creep"] = time.perf_counter() - t0
    gate("creep", cf.fit_validation or cf.fit_train, diagonal)

    extra: dict[str, object] = {}
    if refine_hysteresis:
        t0 = time.perf_counter()
        say("hysteresis: refit Bouc-Wen on S0 with the identified creep removed from the output")
        hf = refit_hysteresis_without_creep(hfit + hval, cf.config, generalized=generalized, init=hf, progress=say)
        timing["identify_hysteresis_refit"] = time.perf_counter() - t0
        extra["hysteresis_compensator"] = REFIT_TAG
        gate("hysteresis", hysteresis_fits(hf), axes, "hysteresis (refitted once creep is known)")

    say("characterise dynamics on S_L through the creep and hysteresis compensators")
    rig.configure(replace(base, hysteresis=hf.config, creep=cf.config), frozenset({"creep", "hysteresis"}))
    dfit, dval = characterise("dynamics", extra)
    t0 = time.perf_counter()
    df = identify_dynamics(dfit, dval, order=dynamics_order, axes=axes, progress=say)
    timing["identify_dynamics"] = time.perf_counter() - t0
    gate("dynamics", df.fit_validation or df.fit_train, diagonal)
    cfg = build_config(base, hf, cf, df, fs, axes)
    fits = fits_report(hf, cf, df, axes)

    say("plant: held-out fit of the identified whole-plant model on the recorded voltage record")
    t0 = time.perf_counter()
    pv = plant_runs[0]
    fits["plant"] = plant_fit(cfg, plant_runs)
    gate("plant", fits["plant"], axes)
    noise_free = getattr(rig, "noise_free_output", lambda u: None)(pv.u)
    fit_noise_free = plant_fit(cfg, [pv], [noise_free]) if noise_free is not None else None
    parts = part_fits(cfg, pv, pv.y if noise_free is None else noise_free, plan["plant"][0].trajectory, axes)
    timing["plant_fit"] = time.perf_counter() - t0

    design, note = None, None
    if synthesize:
        t0 = time.perf_counter()
        cfg, design, note = with_hinf_controller(cfg, say)
        timing["hinf"] = time.perf_counter() - t0
    timing["total"] = time.perf_counter() - t_all
    report = CommissionReport(fit_percent=fits, orders={"creep": cf.orders, "dynamics": df.orders},
                              plant_fit_basis="measured output" + (" (with sensor noise)" if noise_free is not None
                                                                   else ""),
                              plant_fit_parts=parts, timing_s=timing, plant_fit_noise_free=fit_noise_free,
                              accepted_poor_fits=accepted or None)
    return CommissionResult(config=cfg, design=design, hinf_note=note, report=report, runs=runs)


def commission_sim(plant: Processor, fs: float, axes: Sequence[str] = ("x", "y"),
                   settings: CharacterisationSettings | None = None, base: PiezoConfig | None = None,
                   generalized: bool = False, creep_order: int | str = "auto", dynamics_order: int | str = "auto",
                   refine_hysteresis: bool = True, progress: Progress | None = None,
                   accept_poor_fit: bool = False) -> tuple[PiezoConfig, CommissionReport, list[RunData]]:
    """Characterise and identify stage by stage on a sim plant (``process``/``reset``), as in Fig. 3.

    The sequence of :func:`commission` on a :class:`SimRig`, without the H∞ synthesis.  Returns ``(config, report,
    runs)``; ``runs`` are tagged so :func:`~.identification.pipeline.identify_all` can redo the identification.
    """

    res = commission(SimRig(plant, fs, axes), base=base, settings=settings, generalized=generalized,
                     creep_order=creep_order, dynamics_order=dynamics_order, refine_hysteresis=refine_hysteresis,
                     synthesize=False, progress=progress, accept_poor_fit=accept_poor_fit)
    return res.config, res.report, res.runs


def part_fits(cfg: PiezoConfig, run: RunData, y_ref: np.ndarray, traj: Trajectory,
              axes: Sequence[str]) -> dict[str, dict[str, float]]:
    """Whole-plant fit on each part of the validation record (multisine: hysteresis loops and G_L in the band;
    step pair: creep and the G_L transients), to see which stage limits the whole-record figure."""
    from .identification.goodness_of_fit import fit_percent
    from .trajectories import TrajectorySequence

    if not isinstance(traj, TrajectorySequence):
        raise ValueError(f"part_fits: the validation record must be a sequence of named parts, got {traj.kind}")
    y_model = simulate_plant(cfg, run.u, run.sample_rate)
    segs = {seg.name: seg for seg in traj.segments(run.sample_rate)}
    parts = {"multisine": (segs["multisine_full"].start, segs["multisine_half"].stop),
             "step_pair": (segs["multisine_half"].stop, len(run))}
    out = {}
    for name, (k0, k1) in parts.items():
        f = fit_percent(y_ref[k0:k1], y_model[k0:k1])
        out[name] = {a: round(float(v), 3) for a, v in zip(axes, f)}
    return out


def verify(rig: Rig, cfg: PiezoConfig, design: object, experiments: Sequence[Experiment],
           conditions: Mapping[str, Any], robust: bool = False, progress: Progress | None = None) -> ReproduceResult:
    """The paper's tests played on ``rig`` with ``cfg``'s cascade; Tables I/II (:func:`~.reproduce.evaluate`)."""
    from .reproduce import evaluate

    say = progress or (lambda s: None)
    rec = rig.run_experiments(cfg, design, experiments, say)
    missing = [e.name for e in experiments if e.name not in rec]
    if missing:
        raise CommissioningError(f"verification runs missing: {missing}")
    return evaluate({e.name: rec[e.name] for e in experiments}, list(experiments), design=design, robust=robust,
                    conditions=dict(conditions), reference_model_tau=cfg.vibration.t_r / 3.0)
