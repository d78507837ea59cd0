"""The graph cases of ``piezo-ff track --graph``: the 20 µm circle at 10 Hz through the ROS node graph, recorded,
replayed — cascade, + preview, and + a correction learned through the graph.

The stage is the one ``--config`` describes (default the paper's; on another stage the benchmark's 20 µm, 10 Hz
case of its axes: a sine on one axis, the circle in the plane of the first two with the others at rest).
Driver (simulated positioner: the printed model for the ``nominal`` truth, or the ``asymmetric`` truth given to
the driver as its own config file while the compensator keeps the printed model), compensator (cascade, the
preview and the learned correction as runtime parameters ``preview.enabled`` / ``learning.file``), trajectory
(lockstep, reference fed ``preview_s`` ahead) and recorder run as processes on a private domain
(:class:`~piezo_ff_ros.ros.launcher.GraphLauncher`).  The reference is the benchmark's own (0.1 s smoothstep
lead-in, then 4 revolutions; :func:`~piezo_ff_ros.core.tracking.benchmark.reference_with_lead_in`), played from a
table file sample-exactly as one experiment segment.  The MCAP is read back with
:func:`~piezo_ff_ros.core.recording.load_run` and cut by the existing analysis
(:func:`~piezo_ff_ros.core.analysis.segment_signals`); the recorded reference is the one fed ahead, which is checked
sample by sample against the table shifted by the preview (so the alignment the learning relies on is verified on
every trial).  Errors are read on the benchmark's window (the last revolution).

Learning through the graph (:func:`run_graph_learning`) is the commissioning procedure: each trial plays the
trajectory through the graph with ``learning.file`` = the current correction Δ_j (none for the first: the preview
alone), the *measured* displacement (the driver's sensor topic, from the MCAP) gives ``e_j = r − y_j``, and the
update ``Δ_{j+1} = Q·(Δ_j + γ·T̂⁻¹·e_j)`` (:class:`~piezo_ff_ros.core.tracking.ilc.IterativeLearning`, with its
guard) is stored per trajectory (:func:`~piezo_ff_ros.core.tracking.ilc.save_correction`).  The best correction is
then played by the compensator node from its file, the sensor unused by anything but the error report.
"""
from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

if TYPE_CHECKING:
    from ..core.config import PiezoConfig
    from ..core.experiments import Recorded
    from ..core.tracking.benchmark import Case
    from ..ros.graph_session import GraphClient
    from ..ros.launcher import GraphLauncher

SEGMENT = "circle20_10hz"
GRAPH_TRUTHS = ("nominal", "asymmetric")


@dataclass
class GraphRun:
    """One play of the reference through the graph, on the compensator's stream index (0 = its first sample)."""

    y: np.ndarray            #: measured displacement [N, axes] [m]
    u: np.ndarray            #: voltage [N, axes] [V]
    mcap: Path
    preview_s: float
    seconds: float


def graph_case(cfg: PiezoConfig | None = None) -> tuple[Case, np.ndarray, np.ndarray]:
    """The benchmark case played through the graph on the stage of ``cfg`` (default the paper's) and its reference:
    ``(case, r [N, axes], mask [N])``.

    On the paper's two axes the 20 µm circle at 10 Hz (as it always was, bit for bit); on other axes the benchmark's
    20 µm, 10 Hz case of those axes (:func:`~piezo_ff_ros.core.tracking.benchmark.benchmark_cases`).
    """
    from ..core.config import load_config
    from ..core.tracking.benchmark import Case, benchmark_cases, evaluation_window, reference_with_lead_in
    from ..core.trajectories import Circle

    cfg = cfg if cfg is not None else load_config(None, None)
    fs = cfg.sample_rate
    if tuple(cfg.axes) == ("x", "y"):
        case = Case("circle", 20, 10.0, Circle(radius=20e-6, frequency=10.0, revolutions=4))
    else:
        case = next(c for c in benchmark_cases(True, cfg.axes) if c.frequency_hz == 10 and c.size_um == 20)
    r, n_lead = reference_with_lead_in(case, fs)
    return case, r, evaluation_window(case, r, n_lead, fs)


def truth_config_file(truth: str, out_dir: Path, config_file: str = "") -> str:
    """The driver's config for ``truth``: ``config_file`` for ``nominal`` ('' = the packaged printed model) or a
    YAML file written to ``out_dir`` (the asymmetric truth of ``config_file``'s stage)."""
    if truth == "nominal":
        return config_file
    if truth not in GRAPH_TRUTHS:
        raise ValueError(f"graph truth: unknown {truth!r}; use one of {', '.join(GRAPH_TRUTHS)}")
    from ..core.config import load_config
    from ..core.reproduce import truth_plant

    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"truth_{truth}.yaml"
    path.write_text(truth_plant(load_config(config_file or None, None), truth).cfg.to_yaml())
    return str(path)


def play_graph(out_dir: Path, r: np.ndarray, preview: bool, learning_file: str = "", truth_file: str = "",
               noise_std: float = 0.0, seed: int = 0, say: Callable[[str], None] = lambda s: None,
               timeout: float = 300.0, domain_id: int | None = None, config_file: str = "") -> GraphRun:
    """Play the table ``r`` [N, axes] once through driver, compensator, trajectory and recorder; read the MCAP back.

    Parameters
    ----------
    out_dir : Path
        Receives ``reference.npy``, ``run.mcap`` and ``logs/``.
    r : ndarray
        The reference at the graph's sample rate, from rest.
    preview, learning_file
        The compensator's ``preview.enabled`` and ``learning.file``.
    truth_file : str
        The driver's ``config_file`` ('' = the packaged printed model: model = plant).
    noise_std, seed
        The simulated sensor's noise [m] and its seed (the driver's ``noise_std``, ``seed``).
    timeout : float
        Seconds for each phase, counted from its own start: the graph coming up (the compensator synthesises H∞),
        the play, the recording holding the whole segment.
    domain_id : int, optional
        ROS domain of the graph (default: derived by :func:`~piezo_ff_ros.ros.env.apply_ros_env_defaults`).
    config_file : str
        The stage's config ('' = the packaged paper's): the compensator's and the recorder's, and the driver's
        unless ``truth_file`` is given; its sample rate is the graph's.

    Returns
    -------
    GraphRun
        Displacement and voltage on the compensator's stream index.
    """
    from ..core.config import load_config
    from ..core.tracking.preview import PreviewConfig
    from ..ros.graph_session import GraphClient
    from ..ros.launcher import GraphLauncher

    stage_cfg = load_config(config_file or None, None)
    fs = stage_cfg.sample_rate
    L = PreviewConfig().preview_samples(fs) if preview else 0
    preview_s = L / fs
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table = out_dir / "reference.npy"
    np.save(table, np.asarray(r, float))
    mcap = out_dir / "run.mcap"
    if mcap.exists():
        mcap.unlink()
    spec = {"type": "sequence", "segments": [{"name": SEGMENT, "meta": {"input": "reference"}, "trajectory": {
        "type": "table", "file": str(table), "sample_rate": fs,
        **({"axes": list(stage_cfg.axes)} if config_file else {})}}]}
    comp = ["-p", f"preview.enabled:={'true' if preview else 'false'}"]
    if learning_file:
        comp += ["-p", f"learning.file:={learning_file}"]
    stage = ["-p", f"config_file:={config_file}"] if config_file else []
    # no autostart: the trajectory starts once the recorder has matched every block publisher (below)
    traj = ["-p", "mode:=lockstep", "-p", "min_subscribers:=2", "-p", f"preview_s:={preview_s}",
            "-p", f"lockstep_timeout:={float(timeout)}", "-p", f"trajectory:='{json.dumps(spec)}'"]
    # lockstep: the chain pauses whenever a process is descheduled (a loaded machine, a lazy JIT compilation); the
    # simulated driver must not take such a pause for a dead stream and ramp to its safe state in the middle of
    # the trial (its own samples would break the segment): the longest stale timeout the config allows
    drv = ["-p", "limits.stale_timeout:=60.0", "-p", f"noise_std:={float(noise_std)}", "-p", f"seed:={int(seed)}"]
    if truth_file or config_file:
        drv += ["-p", f"config_file:={truth_file or config_file}"]
    g = GraphLauncher({"recorder": ["-p", f"output:={mcap}"] + stage, "driver": drv, "compensator": comp + stage,
                       "trajectory": traj},
                      log_dir=out_dir / "logs", domain_id=domain_id)
    n = len(r)
    t0 = time.monotonic()
    g.start(timeout=timeout)
    client: GraphClient | None = None
    try:
        client = GraphClient("piezo_ff_track_graph", domain_id=int(g.env["ROS_DOMAIN_ID"]))
        _play_when_recorded(g, client, timeout)
        _wait_recorded(g, mcap, n, timeout)
    finally:
        if client is not None:
            client.close()
        g.stop()
    seg = _recorded_segment(mcap, n, strict=True)
    if seg is None or seg.reference is None:   # (strict: _recorded_segment raises instead)
        raise RuntimeError(f"graph case: segment {SEGMENT} not recorded")
    _, ref_ahead, u, y = seg
    if len(y) != n:
        raise RuntimeError(f"graph case: {len(y)} samples recorded, {n} played")
    # the recorded reference at stream index k carries r[k + L] (held at the end): the alignment the errors and the
    # learned correction (indexed from the compensator's first sample) rely on
    expected = r[np.minimum(np.arange(n) + L, n - 1)]
    off = float(np.max(np.abs(ref_ahead - expected)))
    if not off <= 1e-12:
        raise RuntimeError(f"graph case: the recorded reference is not the table shifted by {L} samples "
                           f"(max difference {off:.3g} m)")
    dt = time.monotonic() - t0
    say(f"graph {'preview' if preview else 'cascade'}{' + learning' if learning_file else ''}"
        f"{' (truth ' + Path(truth_file).stem + ')' if truth_file else ''}: {n} samples, {dt:.1f} s")
    return GraphRun(y=np.asarray(y, float), u=np.asarray(u, float), mcap=mcap, preview_s=preview_s, seconds=dt)


def _play_when_recorded(g: GraphLauncher, client: GraphClient, timeout: float) -> None:
    """Start the trajectory once the recorder and every block writer have matched (the trajectory's own check,
    ``min_subscribers``, sees readers discovered, not matched by the other nodes' writers: on a loaded machine the
    first blocks of the segment were lost for the recorder — seen in CI), and wait until it has played."""
    def alive(cond: Callable[[], bool]) -> Callable[[], bool]:
        def check() -> bool:
            g.check_alive()
            return cond()
        return check

    client.wait_recorder_connected(timeout, check=g.check_alive)
    n_before = len(client.states)
    client.trigger(client.start)
    ends = ("finished", "failed", "stopped")
    client.spin_until(alive(lambda: any(s["state"] in ends for s in client.states[n_before:])), timeout,
                      "the trajectory to finish")
    end = next(s for s in client.states[n_before:] if s["state"] in ends)
    if end["state"] != "finished" or end.get("unanswered_blocks", 0):
        raise RuntimeError(f"graph case: the trajectory {end['state']} ({end}):\n{g.procs['trajectory'].log()[-800:]}")


def _wait_recorded(g: GraphLauncher, mcap: Path, n: int, timeout: float, idle_s: float = 15.0) -> None:
    """Wait until the MCAP (flushed every second, readable while written) holds the whole segment.

    The trajectory has its last displacement back, the recorder may still be behind (it writes every message).  A
    segment whose recorded length stops changing for ``idle_s`` without being whole will never be (the file itself
    keeps growing with /diagnostics): the strict reading then says what is missing, at once rather than after
    ``timeout``.
    """
    t_rec = last_change = time.monotonic()
    progress: dict[str, int] = {}
    seen = None
    while _recorded_segment(mcap, n, progress=progress) is None:
        g.check_alive()
        now = time.monotonic()
        if progress.get("samples") != seen:
            seen, last_change = progress.get("samples"), now
        if now - last_change > idle_s:
            _recorded_segment(mcap, n, strict=True)   # raises, naming what is missing
        if now - t_rec > timeout:
            raise RuntimeError(f"graph case: the recording does not hold the whole segment after {timeout:g} s")
        time.sleep(0.5)


def _recorded_segment(mcap: Path, n: int, strict: bool = False,
                      progress: dict[str, int] | None = None) -> Recorded | None:
    """The recorded segment ``(t, reference, u, y)`` when the MCAP holds all its ``n`` samples, else None (or, with
    ``strict``, a RuntimeError saying what is missing); ``progress["samples"]`` gets the samples recorded so far."""
    from ..core.analysis import segment_signals
    from ..core.recording import load_run

    try:
        recorded, warnings = segment_signals(load_run(mcap))
    except Exception as exc:  # noqa: BLE001 - a file still being written may end anywhere
        if strict:
            raise RuntimeError(f"graph case: {mcap}: {exc}") from None
        return None
    seg = recorded.get(SEGMENT)
    if progress is not None:
        progress["samples"] = -1 if seg is None else len(seg[3])
    if seg is None or len(seg[3]) != n or not all(a is not None and np.all(np.isfinite(a)) for a in seg[1:]):
        if strict:
            got = "absent" if seg is None else f"{len(seg[3])} of {n} samples"
            raise RuntimeError(f"graph case: segment {SEGMENT} not recorded whole ({got}; {warnings})")
        return None
    return seg


def _row(run: GraphRun, method: str, truth: str, r: np.ndarray, mask: np.ndarray, case: Case | None = None,
         cfg: PiezoConfig | None = None) -> dict:
    """A case row; ``case``/``cfg`` None: the paper's circle on the paper's stage (the row as it always was)."""
    from ..core.tracking.benchmark import tracking_metrics

    head = ({"trajectory": "circle", "size_um": 20, "frequency_hz": 10.0} if case is None else
            {"trajectory": case.trajectory, "size_um": case.size_um, "frequency_hz": float(case.frequency_hz)})
    fs = 20000.0 if cfg is None else cfg.sample_rate
    axes = {} if cfg is None or tuple(cfg.axes) == ("x", "y") else {"axes": list(cfg.axes)}
    return {**head, "method": method, "truth": truth, "graph": True, **axes,
            **tracking_metrics(run.y, r, run.u, mask, fs), "mcap": str(run.mcap),
            "preview_s": run.preview_s, "window_samples": int(mask.sum())}



def run_graph_case(out_dir: Path, preview: bool, say: Callable[[str], None] = lambda s: None, timeout: float = 300.0,
                   domain_id: int | None = None, truth: str = "nominal", config_file: str = "") -> dict:
    """Play the 20 µm case at 10 Hz of the stage of ``config_file`` ('' = the paper's circle) through the graph,
    cascade alone or + preview; returns a case row (``graph: true``; ``axes`` when not the paper's)."""
    from ..core.config import load_config

    cfg = load_config(config_file or None, None)
    case, r, mask = graph_case(cfg)
    out_dir = Path(out_dir)
    run = play_graph(out_dir, r, preview, truth_file=truth_config_file(truth, out_dir, config_file), say=say,
                     timeout=timeout, domain_id=domain_id, config_file=config_file)
    return _row(run, "preview" if preview else "cascade", truth, r, mask, case, cfg)


def run_graph_learning(out_dir: Path, truth: str = "asymmetric", iterations: int = 2, noise_std: float = 0.0,
                       say: Callable[[str], None] = lambda s: None, timeout: float = 300.0,
                       domain_id: int | None = None, config_file: str = "") -> list[dict]:
    """Learn a correction through the graph (trials measured by the driver's sensor) and play it from its file.

    Parameters
    ----------
    out_dir : Path
        ``trial_<j>/`` per trial (correction, reference table, MCAP, logs), ``play/`` for the final play and
        ``correction.npz`` (the stored correction).
    truth : str
        The driver's plant: ``nominal`` or ``asymmetric`` (the compensator keeps the printed model).
    iterations : int
        Learning updates (trials = iterations + 1, more when the guard steps in).
    noise_std : float
        Sensor noise in the learning trials [m]; the final play is noise-free, so that its figures are of the
        true displacement.
    config_file : str
        The stage's config ('' = the paper's): the compensator's model and the truth's stage.

    Returns
    -------
    list of dict
        Two case rows (``graph: true``): ``preview`` (the first trial: Δ = 0) and ``learning`` (the stored
        correction played by the compensator node), the latter with ``rms_history_um`` per trial and
        ``correction_file``.
    """
    from ..core.config import load_config
    from ..core.tracking.benchmark import TrackingModel
    from ..core.tracking.ilc import ILCConfig, IterativeLearning, save_correction
    from ..core.tracking.preview import PreviewConfig

    if isinstance(iterations, bool) or not isinstance(iterations, int) or not 1 <= iterations <= 20:
        raise ValueError(f"graph learning iterations: expected an integer in 1…20, got {iterations!r}")
    out_dir = Path(out_dir)
    printed = load_config(config_file or None, None)
    case, r, mask = graph_case(printed)
    truth_file = truth_config_file(truth, out_dir, config_file)
    say("graph learning: build the model's compensated stage (the learning operator T̂⁻¹)")
    model = TrackingModel.build(printed, PreviewConfig())
    spec = {"trajectory": case.traj.to_dict(), "lead_in_s": 0.1}
    trials: list[tuple[np.ndarray, GraphRun]] = []

    def run_trial(delta: np.ndarray) -> np.ndarray:
        j = len(trials)
        d = out_dir / f"trial_{j}"
        d.mkdir(parents=True, exist_ok=True)
        lf = "" if not np.any(delta) else str(save_correction(d / "correction.npz", delta, printed.sample_rate, spec,
                                                                 {"truth": truth, "trial": j, "source": "graph"}))
        run = play_graph(d, r, True, learning_file=lf, truth_file=truth_file, noise_std=noise_std, seed=j,
                         say=say, timeout=timeout, domain_id=domain_id, config_file=config_file)
        trials.append((np.array(delta, float), run))
        return run.y

    learner = IterativeLearning(model.compensated, dataclasses.replace(ILCConfig(), iterations=iterations))
    res = learner.learn(run_trial, r)
    stored = save_correction(out_dir / "correction.npz", res.correction, printed.sample_rate, spec,
                             {"truth": truth, "source": "graph", "trials": len(trials), **res.to_json()})
    play = next((run for delta, run in trials if noise_std == 0.0 and np.array_equal(delta, res.correction)
                 and np.any(delta)), None)
    if play is None:   # noisy trials (or the best is Δ = 0): one more play, sensor noise off
        play = play_graph(out_dir / "play", r, True, learning_file=str(stored), truth_file=truth_file, say=say,
                          timeout=timeout, domain_id=domain_id, config_file=config_file)
    preview_row = _row(trials[0][1], "preview", truth, r, mask, case, printed)
    learn_row = {**_row(play, "learning", truth, r, mask, case, printed), "correction_file": str(stored),
                 "trials": len(trials), "iterations": iterations, "learning": res.to_json()}
    return [preview_row, learn_row]
