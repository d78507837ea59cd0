"""The running node graph as a commissioning rig (:class:`~piezo_ff_ros.core.commissioning.Rig`).

Whatever backend the driver runs (the simulator or hardware), the rig only talks to the graph: it pushes the
compensator's parameters and stage switches (``set_parameters_atomically``), plays each run through the trajectory
node (driver and compensator reset to rest before each), and reads what was applied and measured back from the
recorder's MCAP — the identification always fits the voltages the driver actually applied.

Import this module only after the ROS environment is set (:func:`piezo_ff_ros.ros.env.apply_ros_env_defaults`).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence, TypeVar

import numpy as np

from ..core.characterisation_graph import FROM_REST_S, graph_run_trajectory
from ..core.commissioning import CommissioningError, PlannedRun, RigLimits
from ..core.config import PiezoConfig
from ..core.param_map import config_to_params
from ..core.recording.run import RunData
from .graph_session import GraphClient, displacement_present

if TYPE_CHECKING:
    from ..core.experiments import Experiment, Recorded
    from .launcher import GraphLauncher

_T = TypeVar("_T")

#: which flat parameters each stage's switch needs pushed with it
_STAGE_PARAMS = {"hysteresis": ("hysteresis.",), "creep": ("creep.",), "vibration": ("dynamics.", "vibration.")}


class GraphRig(RigLimits):
    """A :class:`~piezo_ff_ros.core.commissioning.Rig` over a running graph recorded to ``mcap_path``.

    Parameters
    ----------
    client : GraphClient
        The command's rclpy client on the graph's domain.
    graph : GraphLauncher or None
        The nodes this command started (checked for liveness while waiting), None if all were running already.
    mcap_path : Path
        The recorder's output file.
    sample_rate, axes, voltage_limit, slew_limit
        What the driver runs with.
    say : callable
        Progress lines.
    """

    def __init__(self, client: GraphClient, graph: GraphLauncher | None, mcap_path: Path, sample_rate: float, axes: Sequence[str],
                 voltage_limit: float, slew_limit: float, say: Callable[[str], None] = lambda m: None) -> None:
        self.client = client
        self.graph = graph
        self.mcap_path = Path(mcap_path)
        self.sample_rate = float(sample_rate)
        self.axes = tuple(axes)
        super().__init__(voltage_limit, slew_limit)
        self.say = say

    @property
    def has_sensor(self) -> bool:
        """A driver whose backend measures publishes ``/displacement``."""
        return displacement_present(self.client)

    def configure(self, cfg: PiezoConfig | None, stages: frozenset[str], bypass: bool = False) -> None:
        params = None
        if cfg is not None and not bypass:
            prefixes = tuple(p for st in stages for p in _STAGE_PARAMS[st])
            params = {k: v for k, v in config_to_params(cfg).items() if k.startswith(prefixes)}
        if not self.client.configure(stages, bypass=bypass, params=params, say=self.say):
            raise CommissioningError(f"the compensator did not build the configuration {sorted(stages)}: "
                                     f"{self.client.comp_diag.get('last_error', '?')}")

    def play(self, runs: Sequence[PlannedRun], meta: Mapping[str, object] | None = None) -> dict[str, RunData]:
        fs = self.sample_rate
        played = {}
        for r in runs:
            # from rest (a ramp to the first sample, part of the run); a signal with no graph type travels as a
            # .npy table beside the recording: played sample-exactly
            traj = graph_run_trajectory(r.name, r.trajectory, fs, self.mcap_path.parent / "tables", FROM_REST_S)
            played[r.name] = int(traj.n_samples(fs))
            dt = self.client.play(r.name, traj, {**(meta or {}), "role": r.role})
            self.say(f"  {r.name}: {traj.n_samples(fs) / fs:.1f} s of signal in {dt:.1f} s")
        return self._wait_segments(played)

    def run_experiments(self, cfg: PiezoConfig, design: object, experiments: Sequence[Experiment],
                        progress: Callable[[str], None]) -> dict[str, Recorded]:
        from ..core.analysis import segment_signals

        fs = self.sample_rate
        for exp in experiments:
            if self.graph is not None:
                self.graph.check_alive()
            if not self.client.configure(exp.stages, bypass=exp.input == "voltage", say=progress):
                raise CommissioningError(f"{exp.name}: compensator configuration not built: "
                                         f"{self.client.comp_diag.get('last_error', '?')}")
            dt = self.client.play(exp.name, exp.trajectory, exp.meta())
            progress(f"  {exp.name:<16} {exp.trajectory.n_samples(fs) / fs:7.2f} s of signal in {dt:5.1f} s")
        names = [e.name for e in experiments]
        # complete = every experiment's segment is there with all its samples on disk (the recorder writes the
        # displacement answering the last voltage block after the trajectory has finished)
        need = {e.name: e.trajectory.n_samples(fs) for e in experiments}

        def complete(got: tuple[dict[str, Any], list[str]]) -> bool:
            return all(n in got[0] and len(got[0][n][0]) >= need[n]
                       and not any(np.isnan(np.asarray(x)).any() for x in got[0][n]) for n in names)

        rec, warnings = self._poll(lambda run: segment_signals(run), complete,
                                   lambda got: f"missing {[n for n in names if n not in got[0]]} ({got[1]})")
        return rec

    def _poll(self, extract: Callable[[RunData], _T], complete: Callable[[_T], bool], describe: Callable[[_T], str],
              timeout: float = 120.0) -> _T:
        """Read the recording until ``complete(extract(run))`` (the recorder writes it as blocks arrive)."""
        from ..core.recording.mcap_io import read_run

        deadline = time.monotonic() + timeout
        last = "nothing recorded yet"
        while True:
            self.client.spin_for(0.5)
            if self.graph is not None:
                self.graph.check_alive()
            try:
                got = extract(read_run(self.mcap_path))
            except (ValueError, OSError) as exc:   # the recorder has not flushed a readable chunk yet
                last = str(exc)
            else:
                if complete(got):
                    return got
                last = describe(got)
            if time.monotonic() > deadline:
                raise CommissioningError(f"the recording {self.mcap_path} does not hold the runs after "
                                         f"{timeout:g} s: {last}")

    def _wait_segments(self, wanted: Mapping[str, int]) -> dict[str, RunData]:
        """``{name: RunData}`` for the played runs (``wanted[name]`` samples each) once they are fully on disk."""
        def extract(run: RunData) -> dict[str, RunData]:
            out: dict[str, RunData] = {}
            if run.reference is None:   # not (yet) a recording of the trajectory node: keep waiting
                return out
            for seg in run.meta.get("segments", []):
                name = seg["name"]
                if name not in wanted or name in out:
                    continue
                n, a = wanted[name], seg["start"]
                if a < 0 or seg["stop"] - a < n:
                    continue
                u, y, r = run.u[a:a + n], run.y[a:a + n], run.reference[a:a + n]
                if np.isnan(u).any() or np.isnan(y).any() or np.isnan(r).any():
                    continue
                out[name] = RunData(t=np.arange(n) / run.sample_rate, u=u.copy(), y=y.copy(), axes=run.axes,
                                    reference=r.copy(), meta={"experiment": name})
            return out

        return self._poll(extract, lambda got: len(got) == len(wanted),
                          lambda got: f"have {sorted(got)} of {sorted(wanted)}")
