"""Fault injection into the node graph: each test injects one kind of fault into running
node processes over real DDS, then states — with numbers, asserted — what was lost and what the driver did, and
checks that the recording stays readable (piezo-ff's reader, the ``mcap`` reader, ``rosbags``).

Faults: recorder disk full (``RLIMIT_FSIZE``, SIGXFSZ ignored so that the write fails with EFBIG); kill -9 and
restart of the recorder (``piezo-ff recover`` on its file), of the compensator, of the driver and of the trajectory
node (realtime, and the compensator in a lockstep run); a stalled compensator (SIGSTOP … SIGCONT); wall-clock steps
forward and backward in the realtime trajectory node.  Run with ``-s`` for the figures; docs/faults.md has the
table.
"""
from __future__ import annotations

import json
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import AXES, DT_NS, FS, Probe, child_env, stop_node  # noqa: E402


@pytest.fixture()
def probe():
    p = Probe("fault_probe")
    yield p
    p.close()


def start(name: str, *ros_args: str, log_dir: Path, preexec_fn=None, tag: str = "",
          env: dict | None = None, script: Path | None = None) -> subprocess.Popen:
    """``start_node`` of test_nodes_integration with a ``preexec_fn`` (resource limits), a log tag (a restarted
    node writes a second log), extra environment variables and optionally a wrapper ``script`` instead of the
    node's module."""
    log_path = log_dir / f"{name}{tag}.log"
    log = open(log_path, "wb")
    e = child_env()
    e["PYTHONUNBUFFERED"] = "1"
    e.update(env or {})
    cmd = [str(script)] if script is not None else ["-m", f"piezo_ff_ros.nodes.{name}"]
    p = subprocess.Popen([sys.executable, *cmd, "--ros-args", *ros_args],
                         env=e, stdout=log, stderr=subprocess.STDOUT, preexec_fn=preexec_fn)
    p.log_path = log_path  # type: ignore[attr-defined]
    return p


def kill9(p: subprocess.Popen) -> None:
    p.send_signal(signal.SIGKILL)
    p.wait(10)


def log_of(p) -> str:
    return Path(p.log_path).read_text(errors="replace")


def _level(s) -> int:
    return ord(s.level) if isinstance(s.level, bytes) else int(s.level)


def diagnostics_of(probe, suffix: str) -> list:
    """``[(level, message, {key: value})]`` of the /diagnostics statuses whose name ends with ``suffix``."""
    from diagnostic_msgs.msg import DiagnosticArray

    out = []
    probe.node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: out.extend(
        (_level(s), s.message, {kv.key: kv.value for kv in s.values}) for s in m.status
        if s.name.endswith(suffix)), 50)
    return out


def read_with_all_readers(path: Path) -> dict:
    """The recording through the three readers; ``{topic: message count}`` per reader (they must agree)."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    from piezo_ff_ros.core.recording.mcap_io import read_run, scan_mcap

    counts = {}
    with open(path, "rb") as f:
        c: dict = {}
        for _, channel, _ in make_reader(f).iter_messages():
            c[channel.topic] = c.get(channel.topic, 0) + 1
        counts["mcap"] = c
    with AnyReader([path]) as r:
        c = {}
        for conn, _, _ in r.messages():
            c[conn.topic] = c.get(conn.topic, 0) + 1
        counts["rosbags"] = c
    sc = scan_mcap(path)
    counts["piezo_ff"] = {t: len(m) for t, m in sc.messages.items() if m}
    counts["run"] = read_run(path, trim=False)
    return counts


# ------------------------------------------------------------------------------------------------------------------
# recorder: disk full

FSIZE_LIMIT = 1_500_000   # bytes: the recorder's file-size limit (the "disk")
BLOCK_DF = 2000           # samples per block: 32 000 bytes of random doubles, incompressible


def _fsize_limit():
    """preexec_fn: the child's files may not grow past FSIZE_LIMIT; SIGXFSZ ignored, so a write past it fails with
    EFBIG (errno 27) instead of killing the process — what a full disk looks like to the writer (ENOSPC)."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_LIMIT, FSIZE_LIMIT))


def test_recorder_disk_full_stops_cleanly_with_an_error_and_a_readable_file(tmp_path, probe):
    """Disk full while recording.  Expected: the recorder does not die; it logs one ERROR, reports it on
    /diagnostics and ~/status, ends the file at its last complete chunk so that every reader opens it; what is
    lost is what came after the failure plus at most the chunk being written (≤ 512 KiB of records), and the part
    kept is contiguous (no gap inside).  The driver is not involved (it does not depend on the recorder)."""
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import String

    from piezo_ff_ros.nodes.common import BLOCK_QOS, LATCHED_QOS, pack_block
    from piezo_ff_ros.nodes.recorder import CHUNK_LIMIT

    out = tmp_path / "full.mcap"
    rec_diags = diagnostics_of(probe, "recorder")
    status = []
    probe.node.create_subscription(String, "/recorder/status", lambda m: status.append(json.loads(m.data)),
                                   LATCHED_QOS)
    pub = probe.node.create_publisher(PointCloud2, "reference", BLOCK_QOS)
    rec = start("recorder", "-p", f"output:={out}", "-p", "topics:=['reference']", "-p", "flush_interval:=0.2",
                log_dir=tmp_path, preexec_fn=_fsize_limit)
    rng = np.random.default_rng(1)
    n_sent = 0
    try:
        probe.spin_until(lambda: status and status[-1].get("publishers", {}).get("/reference", 0) >= 1, 60,
                         "recorder connected to /reference")
        probe.spin_for(1.0)
        n_blocks = int(2.5 * FSIZE_LIMIT / (BLOCK_DF * 16))   # 2.5× what fits
        for i in range(n_blocks):
            pub.publish(pack_block(rng.standard_normal((BLOCK_DF, 2)) * 1e-6, AXES, i * BLOCK_DF * DT_NS))
            n_sent += 1
            probe.spin_for(0.02)
        probe.spin_until(lambda: any(d[0] == 2 for d in rec_diags), 30, "the recorder's ERROR on /diagnostics")
        probe.spin_for(0.5)
        assert rec.poll() is None, "the recorder died on disk full:\n" + log_of(rec)[-3000:]
        err = next(d for d in rec_diags if d[0] == 2)
        assert "recording stopped" in err[1] and "File too large" in err[1], err
        assert status[-1].get("error"), status[-1]
    finally:
        code = stop_node(rec)
    log = log_of(rec)
    assert "Traceback" not in log, log[-3000:]
    assert code == 1, (code, log[-2000:])   # the recording is incomplete: said by the exit code too
    size = out.stat().st_size
    assert size <= FSIZE_LIMIT
    counts = read_with_all_readers(out)
    n_rec = counts["mcap"].get("/reference", 0)
    assert counts["rosbags"].get("/reference", 0) == n_rec == counts["piezo_ff"].get("/reference", 0)
    run = counts["run"]
    blocks = run.meta["blocks"]["reference"]
    assert blocks["gaps"] == [] and blocks["missing_samples"] == 0   # what is kept is contiguous, from block 0
    assert run.meta["k_offset"] == 0 and len(run) == n_rec * BLOCK_DF
    # what is lost: everything after the failure, and at most the chunk that did not fit (≤ CHUNK_LIMIT of records)
    per_block = BLOCK_DF * 16 + 300
    assert n_rec >= (FSIZE_LIMIT - CHUNK_LIMIT - 50_000) // per_block, (n_rec, size)
    print(f"disk full at {FSIZE_LIMIT} B: {n_rec} of {n_sent} blocks kept ({size} B, contiguous from sample 0), "
          f"{n_sent - n_rec} lost after the failure; recorder exit {code}")


# ------------------------------------------------------------------------------------------------------------------
# the full graph in realtime: kill -9 and restart of compensator, driver, trajectory

BLOCK_RT = 1000           # 50 ms blocks
STALE = 0.5               # the driver's limits.stale_timeout [s]
#: a 60 s circle, not looped: within one play the stamps are continuous (a loop re-reads the wall clock)
CIRCLE = json.dumps({"type": "circle", "radius": 1.0e-5, "frequency": 5.0, "revolutions": 300})
TOPICS = ("reference", "voltage", "displacement", "voltage_applied")


class RealtimeGraph:
    """driver + compensator + trajectory (realtime, autostart, waiting for 3 readers: compensator, recorder and
    this probe) + recorder as processes.  The probe logs every
    block it receives, ``arrivals[topic] = [(monotonic time, stamp, n)]``, and the driver's /diagnostics."""

    ARGS = {"recorder": lambda out: ["-p", f"output:={out}", "-p", "flush_interval:=0.2"],
            # stale_timeout 0.5 s: short, yet longer than the pauses a loaded 2-core machine gives the stream
            "driver": lambda out: ["-p", f"limits.stale_timeout:={STALE}", "-p", "diagnostics_period:=0.1"],
            "compensator": lambda out: ["-p", "cascade.vibration:=false"],
            "trajectory": lambda out: ["-p", "mode:=realtime", "-p", f"block_size:={BLOCK_RT}",
                                       "-p", "autostart:=true", "-p", "min_subscribers:=3",
                                       "-p", "lockstep_timeout:=120.0",   # also how long it waits for the graph
                                       "-p", f"trajectory:='{CIRCLE}'"]}

    def __init__(self, probe, tmp_path: Path, env: dict | None = None, args: dict | None = None,
                 script: dict | None = None):
        from sensor_msgs.msg import PointCloud2

        from piezo_ff_ros.nodes.common import BLOCK_QOS

        self.probe, self.tmp = probe, tmp_path
        self.out = tmp_path / "run.mcap"
        self.arrivals: dict[str, list] = {t: [] for t in TOPICS}
        self.subs = {t: probe.node.create_subscription(
            PointCloud2, t, lambda m, t=t: self.arrivals[t].append((time.monotonic(), _stamp(m), int(m.width))),
            BLOCK_QOS) for t in TOPICS}
        self.diags = diagnostics_of(probe, "driver")
        self.env = env or {}
        self.args = args or {}                 # extra ros args per node
        self.script = script or {}             # wrapper script per node
        self.procs: dict[str, subprocess.Popen] = {}
        self.starts: dict[str, int] = {}

    def start(self, name: str) -> None:
        n = self.starts.get(name, 0)
        self.starts[name] = n + 1
        self.procs[name] = start(name, *self.ARGS[name](self.out), *self.args.get(name, []), log_dir=self.tmp,
                                 tag=f".{n}" if n else "", env=self.env, script=self.script.get(name))

    def start_all(self) -> None:
        for name in ("recorder", "driver", "compensator", "trajectory"):
            self.start(name)

    def after(self, topic: str, t: float) -> list:
        return [a for a in self.arrivals[topic] if a[0] > t]

    def wait_blocks(self, topic: str, t: float, timeout: float, what: str, n: int = 5) -> list:
        """Until ``n`` blocks of ``topic`` arrived after monotonic time ``t``; those blocks."""
        self.probe.spin_until(lambda: len(self.after(topic, t)) >= n, timeout, what)
        return self.after(topic, t)

    def end_before(self, topic: str, t: float) -> int:
        """Stamp just past the last block of ``topic`` received before ``t``."""
        return max(s + n * DT_NS for w, s, n in self.arrivals[topic] if w <= t)

    def diag_after(self, pred, timeout: float, what: str) -> tuple:
        """The first driver status received from now on for which ``pred`` holds."""
        n0 = len(self.diags)
        self.probe.spin_until(lambda: any(pred(d) for d in self.diags[n0:]), timeout, what)
        return next(d for d in self.diags[n0:] if pred(d))

    def stop_all(self) -> dict:
        return {name: stop_node(self.procs[name]) for name in ("trajectory", "compensator", "driver", "recorder")
                if name in self.procs}


def _stamp(m) -> int:
    return int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)


def _gaps(run, role: str) -> list[int]:
    """Lengths [samples] of the gaps inside a recorded block topic, in time order."""
    return [int(b - a) for a, b in sorted(run.meta["blocks"][role]["gaps"])]


def wait_recorded(probe, directory: Path, topic: str, stamp: int, timeout: float, name: str = "run.mcap") -> None:
    """Until the recording (read while being written: our reader stops at the last flushed chunk) holds a block
    of ``topic`` stamped ``stamp`` or later."""
    from piezo_ff_ros.core.recording.blocks import deserialize_block
    from piezo_ff_ros.core.recording.mcap_io import scan_mcap

    def recorded() -> bool:
        try:
            msgs = scan_mcap(directory / name).messages.get(topic, [])
        except (OSError, ValueError):   # not there yet, or not even its header written yet
            return False
        return bool(msgs) and deserialize_block(msgs[-1][2])[0] >= stamp
    deadline = time.monotonic() + timeout
    while not recorded():
        assert time.monotonic() < deadline, f"{topic} from {stamp} never recorded"
        probe.spin_for(0.5)


def recorded_blocks(path: Path, topic: str) -> list:
    """The block arrays of ``topic`` in the recording, in file order."""
    from piezo_ff_ros.core.recording.blocks import deserialize_block
    from piezo_ff_ros.core.recording.mcap_io import scan_mcap

    return [deserialize_block(raw)[1] for _, _, raw in scan_mcap(path).messages.get(topic, [])]


#: the topic whose stream a node's death interrupts
OUTPUT = {"compensator": "voltage", "driver": "displacement", "trajectory": "reference"}


def test_kill9_and_restart_of_compensator_driver_and_trajectory(tmp_path, probe):
    """kill -9 of each node of the data path in turn, restarted at once, the recorder running throughout.

    What is lost is the dead node's output for its downtime, and nothing else: the gap in its output topic
    (``voltage`` / ``displacement`` / ``reference``) equals, in samples, the stamps between its last block and the
    restarted node's first, and is at most the downtime (kill → first new block) × fs + one block in flight; the
    recording has exactly that gap too (the recorder lost nothing more).  The driver:
    - compensator killed: no voltage; the driver ramps to its safe state after stale_timeout (``safe`` on
      /diagnostics) and resumes with the restarted compensator (``resumes`` + 1, ``active``);
    - driver killed: the new driver starts on the running stream (``active``, no resume: it never was safe);
    - trajectory killed: no reference, hence no voltage: the driver goes safe; the restarted trajectory's stamps
      follow the wall clock, so its stream starts further on by the downtime: the driver holds the jump (≤ max_gap
      1 s) or re-bases on it after one confirming block, and resumes.
    The recording (never interrupted) is read by the three readers."""
    g = RealtimeGraph(probe, tmp_path)
    g.start_all()
    faults = {}
    try:
        g.wait_blocks("displacement", 0.0, 90, "the graph running (displacement blocks)", n=10)
        probe.spin_until(lambda: g.diags and g.diags[-1][2].get("state") == "active", 30, "driver active")
        for name in ("compensator", "driver", "trajectory"):
            topic = OUTPUT[name]
            # the probe must be receiving that node's output before it dies (its writer discovers the probe's
            # reader on its own schedule: the fresh-clone CI once killed the compensator before any voltage came)
            g.wait_blocks(topic, 0.0, 60, f"{topic} blocks before the {name} is killed", n=3)
            resumes0 = int(g.diags[-1][2].get("resumes", 0))
            t_kill, wall_kill = time.monotonic(), time.time_ns()
            kill9(g.procs[name])
            end_old = g.end_before(topic, t_kill)
            if name != "driver":
                safe = g.diag_after(lambda d: d[2].get("state") == "safe", 30,
                                    f"the driver's safe state after the {name} was killed")
                assert "safe" in safe[1], safe
            else:
                probe.spin_for(0.3)
            g.start(name)
            new = g.wait_blocks(topic, time.monotonic(), 90, f"{topic} again after the {name}'s restart", n=3)
            t_back, first_new = new[0][0], min(s for _, s, _ in new)
            if name == "driver":
                d = g.diag_after(lambda d: d[2].get("state") == "active", 30, "the new driver active")
                assert int(d[2]["resumes"]) == 0
            else:
                d = g.diag_after(lambda d: int(d[2].get("resumes", 0)) > resumes0, 30,
                                 f"the driver resuming after the {name}'s restart")
                assert d[2]["state"] == "active"
            faults[name] = {"downtime_s": round(t_back - t_kill, 2), "lost_samples": (first_new - end_old) // DT_NS,
                            "in_flight_s": round((wall_kill - end_old) / 1e9, 3), "first_new": first_new,
                            "driver": {k: d[2].get(k) for k in ("state", "resumes", "gap_samples", "rebases")}}
        # the recorder discovers a restarted publisher on its own schedule: give it time before stopping
        wait_recorded(probe, g.out.parent, "/reference", faults["trajectory"]["first_new"], 30)
    finally:
        codes = g.stop_all()
    print("kill -9 + restart:", json.dumps(faults))
    assert codes == {"trajectory": 0, "compensator": 0, "driver": 0, "recorder": 0}, codes
    for name, f in faults.items():   # lost: the downtime and what was in flight when the node died, nothing more
        assert 0 < f["lost_samples"] <= (f["downtime_s"] + max(f["in_flight_s"], 0)) * FS + BLOCK_RT, (name, f)
        assert f["in_flight_s"] < 1.0, (name, f)
    counts = read_with_all_readers(g.out)
    for topic in ("/reference", "/voltage", "/displacement", "/voltage_applied"):
        assert counts["mcap"][topic] == counts["rosbags"][topic] == counts["piezo_ff"][topic] > 0, topic
    run = counts["run"]
    gaps = {role: sorted(run.meta["blocks"][role]["gaps"]) for role in ("reference", "voltage", "displacement")}
    print("gaps in the recording [samples]:", {r: [b - a for a, b in g] for r, g in gaps.items()})
    # each node's death is one gap of its output in the recording, found by *where* it ends (at that node's first
    # sample after the restart), not by its position in the list or its size: under load a restart can be short
    # enough for the driver to hold the gap (≤ max_gap) instead of leaving one in its own output.  The probe's
    # figure and the recording's differ by what each observer missed of the restarted publisher before discovering
    # it: the compensator's and the driver's writers do not wait for readers (a driver must not: its output goes on),
    # so the recorder may miss the first seconds of a restarted node's output — 2.8 s once on an idle 2-core host.
    discovery_lag = 5.0

    def gap_of(role: str, name: str) -> int:
        assert gaps[role], (role, gaps)
        k_new = (faults[name]["first_new"] - run.meta["t0_ns"]) // DT_NS
        a, b = min(gaps[role], key=lambda g: abs(g[1] - k_new))
        return int(b - a)

    ref_gaps = [b - a for a, b in gaps["reference"]]
    recorded = {"trajectory": gap_of("reference", "trajectory"), "compensator": gap_of("voltage", "compensator"),
                "driver": gap_of("displacement", "driver")}
    print("lost in the recording [s]:", {k: v / FS for k, v in recorded.items()})
    assert len(ref_gaps) == 1, gaps                       # only the trajectory's death leaves the reference a gap
    assert gap_of("voltage", "trajectory") == ref_gaps[0], gaps   # no voltage where there was no reference
    for name, f in faults.items():
        assert 0 < recorded[name] <= (f["downtime_s"] + max(f["in_flight_s"], 0) + discovery_lag) * FS, \
            (name, recorded, f)
        assert abs(recorded[name] - f["lost_samples"]) < discovery_lag * FS, (name, recorded, f)
    # the driver's voltage_applied: every sample it output once (its safe ramps included), gaps only where dead
    assert run.meta["blocks"]["displacement"]["duplicates"] == 0


# ------------------------------------------------------------------------------------------------------------------
# stalled compensator: SIGSTOP … SIGCONT

STALL_S = 1.5


def test_stalled_compensator_driver_goes_safe_and_resumes(tmp_path, probe):
    """The compensator process is frozen (SIGSTOP) for 1.5 s, then continued (SIGCONT).

    The driver gets no voltage: after ``limits.stale_timeout`` (0.5 s) it ramps to its safe state (0 V within the
    ``safe_ramp``: 1000 samples) — ``safe`` on /diagnostics.  The reference blocks queue in DDS meanwhile (reliable,
    depth 100 = 5 s of 50 ms blocks: none is lost in a 1.5 s stall); on SIGCONT the compensator works through the
    backlog and the driver resumes (``resumes`` 1).  Lost: the voltage blocks whose stamps the safe ramp already
    used — the ramp's 1000 samples, dropped as late and counted (``late_samples``) — and nothing else: the recorded
    ``voltage`` has no gap, ``displacement`` none either (the ramp fills the place of the dropped block)."""
    g = RealtimeGraph(probe, tmp_path)
    g.start_all()
    try:
        g.wait_blocks("displacement", 0.0, 90, "the graph running (displacement blocks)", n=10)
        d0 = g.diag_after(lambda d: d[2].get("state") == "active", 30, "driver active")
        late0 = int(d0[2]["late_samples"])
        comp = g.procs["compensator"]
        t_stop = time.monotonic()
        comp.send_signal(signal.SIGSTOP)
        try:
            safe = g.diag_after(lambda d: d[2].get("state") == "safe", 30, "the driver's safe state")
            t_safe = time.monotonic()
            probe.spin_for(max(0.0, STALL_S - (t_safe - t_stop)))
        finally:
            comp.send_signal(signal.SIGCONT)
        t_cont = time.monotonic()
        d = g.diag_after(lambda d: int(d[2].get("resumes", 0)) >= 1, 30, "the driver resuming")
        g.wait_blocks("displacement", time.monotonic(), 30, "displacement after the stall", n=10)
        d = g.diag_after(lambda d: d[2].get("state") == "active", 30, "driver active")
    finally:
        codes = g.stop_all()
    assert codes == {"trajectory": 0, "compensator": 0, "driver": 0, "recorder": 0}, codes
    late = int(d[2]["late_samples"]) - late0
    ramp_applied = [s for w, s, n in g.arrivals["voltage_applied"] if t_stop < w < t_cont]
    report = {"stall_s": round(t_cont - t_stop, 2), "safe_after_s": round(t_safe - t_stop, 2),
              "late_samples": late, "resumes": int(d[2]["resumes"]), "gap_samples": int(d[2]["gap_samples"]),
              "level_when_safe": safe[0], "message_when_safe": safe[1]}
    print("SIGSTOP compensator:", json.dumps(report))
    # ≥ stale_timeout; the upper bound is loose: the probe sees it through the diagnostics period, DDS and its own
    # scheduling (1.06 s over on an idle 2-core host once)
    assert STALE <= report["safe_after_s"] < STALE + 3.0
    assert ramp_applied, "no voltage_applied during the stall (the safe ramp)"
    assert late == 1000 and report["gap_samples"] == 0, report   # exactly the ramp's samples, no gap
    run = read_with_all_readers(g.out)["run"]
    assert _gaps(run, "voltage") == [] and _gaps(run, "reference") == [], run.meta["blocks"]
    assert _gaps(run, "displacement") == [], run.meta["blocks"]["displacement"]
    # the safe ramp is in the recording: a voltage_applied block that ends at the safe voltage, 0 V
    assert any(np.all(b[-1] == 0.0) for b in recorded_blocks(g.out, "/voltage_applied"))


# ------------------------------------------------------------------------------------------------------------------
# wall-clock steps in the realtime trajectory node

#: runs the trajectory node with ``time.time_ns`` = the wall clock + the offset [ns] in $PIEZO_FF_CLOCK_OFFSET_FILE:
#: what a wall-clock step (NTP, an operator) does to the node.  Its pacing uses the monotonic clock (a step does
#: not touch it); its stamps follow ``time.time_ns`` when a play starts — and at every loop of a looping trajectory.
CLOCK_WRAPPER = """
import os, sys, time
from pathlib import Path
_real, _file = time.time_ns, Path(os.environ["PIEZO_FF_CLOCK_OFFSET_FILE"])
def _stepped():
    try:
        return _real() + int(_file.read_text() or 0)
    except (OSError, ValueError):
        return _real()
time.time_ns = _stepped
from piezo_ff_ros.nodes.trajectory import main
sys.exit(main())
"""
LOOP = json.dumps({"type": "circle", "radius": 1.0e-5, "frequency": 5.0, "revolutions": 5})   # 1 s per loop


def test_wall_clock_steps_in_the_realtime_trajectory(tmp_path, probe):
    """The trajectory node's wall clock steps +0.5 s, then +3 s more, then back −3 s, while it loops a 1 s circle.

    Each step shows at the next loop (stamps = wall clock at the loop's start, never going back: ``k_stream`` only
    grows).  Forward +0.5 s (< max_gap 1 s): the stream's stamps jump 0.5 s; the driver holds its last voltage for
    the missing samples (``gap_samples`` + the jump, WARN).  Forward +3 s (> max_gap): the driver holds the block
    back, the next one confirms the jump and the map is re-based (``rebases`` + 1; no hold, nothing lost on the
    device; it went safe after stale_timeout meanwhile only if the stream paused — it did not).  Backward −3 s:
    the stamps go on from where they were: nothing dropped (``late_samples`` unchanged), no gap.  Lost: no sample
    of the trajectory (each loop plays whole); the stamps jump by the step (+ the loop's own lag)."""
    wrapper = tmp_path / "clock_step_trajectory.py"
    wrapper.write_text(CLOCK_WRAPPER)
    offset = tmp_path / "clock_offset_ns"
    offset.write_text("0")
    g = RealtimeGraph(probe, tmp_path, env={"PIEZO_FF_CLOCK_OFFSET_FILE": str(offset)},
                      args={"trajectory": ["-p", "loop:=true", "-p", f"trajectory:='{LOOP}'"]},
                      script={"trajectory": wrapper})
    g.start_all()
    steps = [0.5, 3.0, -3.0]
    seen = []
    try:
        g.wait_blocks("displacement", 0.0, 90, "the graph running (displacement blocks)", n=10)
        for step in steps:
            d0 = g.diag_after(lambda d: d[2].get("state") == "active", 30, "driver active")
            t = time.monotonic()
            offset.write_text(str(int(offset.read_text()) + int(step * 1e9)))
            g.wait_blocks("reference", t, 30, "two loops after the step", n=int(2.5 * FS / BLOCK_RT))
            d1 = g.diag_after(lambda d: d[2].get("state") == "active", 30, "driver active")
            seen.append((step, t, d0[2], d1[2]))
    finally:
        codes = g.stop_all()
    assert codes == {"trajectory": 0, "compensator": 0, "driver": 0, "recorder": 0}, codes
    ref = sorted((s, n) for _, s, n in g.arrivals["reference"])
    jumps = [(s1 - (s0 + n0 * DT_NS)) // DT_NS for (s0, n0), (s1, _) in zip(ref, ref[1:])]
    assert min(jumps) >= 0, "the reference stamps went back"
    report = []
    for step, t, d0, d1 in seen:
        after = sorted((s, n) for w, s, n in g.arrivals["reference"] if w > t)
        i = ref.index(after[0])
        jump = max(jumps[max(i - 1, 0):i + int(2.5 * FS / BLOCK_RT)])   # the largest jump in two loops [samples]
        delta = {k: int(d1[k]) - int(d0[k]) for k in ("gap_samples", "rebases", "late_samples", "resumes")}
        report.append({"step_s": step, "stamp_jump_s": round(jump / FS, 3), "stamp_jump": jump, **delta})
    print("clock steps:", json.dumps(report))
    fwd_small, fwd_big, back = report
    # the jump is the step, less what the stream led the clock by (its blocks are stamped ahead, ≤ 0.2 s here),
    # plus the loop's lag
    assert 0.5 - 0.2 <= fwd_small["stamp_jump_s"] < 0.5 + 0.3, fwd_small
    assert fwd_small["rebases"] == 0 and fwd_small["gap_samples"] >= fwd_small["stamp_jump"], fwd_small
    assert fwd_small["gap_samples"] <= fwd_small["stamp_jump"] + 0.1 * FS, fwd_small   # held, counted
    assert 3.0 - 0.2 <= fwd_big["stamp_jump_s"] < 3.0 + 0.3 and fwd_big["rebases"] == 1, fwd_big   # re-based
    assert fwd_big["gap_samples"] < 0.3 * FS, fwd_big
    assert back["stamp_jump_s"] < 0.3 and back["late_samples"] == 0 and back["rebases"] == 0, back
    for r in report:
        assert r["late_samples"] == 0, r   # no block dropped by any step
    run = read_with_all_readers(g.out)["run"]
    # the recording shows the stream as played: the re-based jump as a gap, the small jump held (no hole on the
    # device, but no reference either: a gap in reference and voltage as well)
    assert any(abs(gp - fwd_big["stamp_jump_s"] * FS) < 0.3 * FS for gp in _gaps(run, "reference"))


# ------------------------------------------------------------------------------------------------------------------
# recorder: kill -9, piezo-ff recover, restart

def test_recorder_kill9_recover_and_restart(tmp_path, probe):
    """kill -9 of the recorder while the graph runs, then a new recorder on a new file.

    The driver does not notice (it does not depend on the recorder: still ``active``, no resume, no gap).  The killed
    file has no summary and no footer: ``piezo-ff recover`` rewrites it as a complete file that the three readers
    open.  Lost from the recording: the messages after its last flushed chunk (``flush_interval`` 0.2 s: at most
    that and one chunk in the making) and the recorder's downtime; the second file starts at its restart."""
    from piezo_ff_ros.cli import main as cli_main

    g = RealtimeGraph(probe, tmp_path, args={"driver": ["-p", "limits.stale_timeout:=2.0"]})   # no load stall
    g.start_all()
    try:
        g.wait_blocks("displacement", 0.0, 90, "the graph running (displacement blocks)", n=10)
        # both block topics in the file: under load the recorder may match one publisher seconds after the other
        for topic in ("/displacement", "/voltage"):
            wait_recorded(probe, tmp_path, topic, 0, 30)
        probe.spin_for(1.5)
        d0 = g.diag_after(lambda d: d[2].get("state") == "active", 30, "driver active")
        t_kill = time.monotonic()
        kill9(g.procs["recorder"])
        last_sent = g.end_before("displacement", t_kill)
        g.args["recorder"] = ["-p", f"output:={tmp_path / 'run2.mcap'}"]
        g.start("recorder")
        t_up = time.monotonic()
        probe.spin_until(lambda: (tmp_path / "run2.mcap").exists(), 60, "the second recording")
        for topic in ("/displacement", "/voltage"):
            wait_recorded(probe, tmp_path, topic, 0, 60, name="run2.mcap")
        t_rec = time.monotonic()
        probe.spin_for(1.0)
        d1 = g.diag_after(lambda d: True, 30, "driver status")
    finally:
        codes = g.stop_all()
    assert codes == {"trajectory": 0, "compensator": 0, "driver": 0, "recorder": 0}, codes
    assert d1[2]["state"] == "active" and d1[2]["resumes"] == d0[2]["resumes"], d1
    assert d1[2]["gap_samples"] == d0[2]["gap_samples"] and d1[2]["late_samples"] == d0[2]["late_samples"], d1
    killed = g.out
    from mcap.reader import make_reader
    with open(killed, "rb") as f, pytest.raises(Exception):
        list(make_reader(f).iter_messages())          # what the recover command is for
    fixed = tmp_path / "fixed.mcap"
    assert cli_main(["recover", str(killed), "--out", str(fixed)]) == 0
    first = read_with_all_readers(fixed)
    second = read_with_all_readers(tmp_path / "run2.mcap")
    for c in (first, second):
        assert c["mcap"]["/displacement"] == c["rosbags"]["/displacement"] == c["piezo_ff"]["/displacement"] > 0
    run1, run2 = first["run"], second["run"]
    end1 = run1.meta["t0_ns"] + (run1.meta["k_offset"] + len(run1)) * DT_NS   # stamp past the last recorded sample
    start2 = run2.meta["t0_ns"] + run2.meta["k_offset"] * DT_NS
    lost_tail = (last_sent - end1) / 1e9          # sent before the kill, not in the killed file
    between = (start2 - end1) / 1e9               # not in either file
    print("recorder kill -9:", json.dumps({"lost_before_kill_s": round(lost_tail, 3), "lost_between_files_s":
                                           round(between, 3), "restart_to_recording_s": round(t_rec - t_up, 2),
                                           "displacement_blocks": [first["mcap"]["/displacement"],
                                                                   second["mcap"]["/displacement"]]}))
    for run in (run1, run2):
        assert _gaps(run, "displacement") == [] and _gaps(run, "voltage") == [], run.meta["blocks"]
    assert -0.1 <= lost_tail <= 0.2 + 0.5, lost_tail          # flush_interval + the chunk being built
    assert 0 < between <= lost_tail + (t_rec - t_kill) + 0.5, between


# ------------------------------------------------------------------------------------------------------------------
# lockstep: the trajectory waits for each block's displacement — a node's death must not end the run

def test_lockstep_run_survives_a_compensator_kill9_and_restart(tmp_path, probe):
    """Lockstep (at most ``window`` blocks in flight, the next one sent when a displacement comes back): the
    compensator is killed with -9 and restarted.  The blocks in flight died with it: they are never answered.
    Expected: the trajectory gives them up after ``ack_timeout`` (counted: ``unanswered_blocks`` in its state),
    keeps playing, and the run goes on with the restarted compensator — not a stall until ``lockstep_timeout``
    and a failed run.  The driver stays ``active`` meanwhile, its stale watchdog suspended (``stream_paced``: the
    lockstep simulator's time stands still between blocks, so no voltage is held in device time; it used to ramp
    to safe and then drop blocks in flight as late).  Lost: the blocks sent while the compensator was down (a
    window of 3 per ``ack_timeout``) — nothing else."""
    from std_msgs.msg import String

    from piezo_ff_ros.nodes.common import LATCHED_QOS

    states = []
    probe.node.create_subscription(String, "/trajectory/state", lambda m: states.append(json.loads(m.data)),
                                   LATCHED_QOS)
    g = RealtimeGraph(probe, tmp_path, args={"trajectory": ["-p", "mode:=lockstep", "-p", "window:=3",
                                                            "-p", "lockstep_timeout:=60.0", "-p", "ack_timeout:=1.0",
                                                            "-p", f"trajectory:='{LOOP}'", "-p", "loop:=true"]})
    g.start_all()
    try:
        g.wait_blocks("displacement", 0.0, 90, "the graph running (displacement blocks)", n=10)
        t_kill = time.monotonic()
        kill9(g.procs["compensator"])
        probe.spin_until(lambda: any(int(s.get("unanswered_blocks", 0)) >= 3 for s in states), 60,
                         "the trajectory giving up the blocks in flight")
        paused = g.diag_after(lambda d: True, 30, "a driver report while the compensator is down")
        assert paused[2]["state"] == "active" and paused[2]["stream_paced"] == "True", paused[2]
        g.start("compensator")
        g.wait_blocks("voltage", time.monotonic(), 90, "voltage from the restarted compensator", n=3)
        g.wait_blocks("displacement", time.monotonic(), 60, "the lockstep run going on", n=20)
        d = g.diag_after(lambda d: d[2].get("state") == "active", 30, "driver active")
        t_back = time.monotonic()
    finally:
        codes = g.stop_all()
    assert codes == {"trajectory": 0, "compensator": 0, "driver": 0, "recorder": 0}, codes
    playing = [s for s in states if s["state"] == "playing"]
    assert states and states[-1]["state"] in ("playing", "stopped"), states[-3:]
    lost = max(int(s.get("unanswered_blocks", 0)) for s in states)
    print("lockstep compensator kill -9:", json.dumps({"down_s": round(t_back - t_kill, 2), "unanswered_blocks": lost,
                                                      "driver_resumes": d[2]["resumes"],
                                                      "driver_late_samples": d[2]["late_samples"],
                                                      "states": [s["state"] for s in states][-4:]}))
    assert playing and 3 <= lost <= 3 * (1 + (t_back - t_kill) / 1.0), lost
    assert int(d[2]["resumes"]) == 0 and int(d[2]["late_samples"]) == 0, d[2]     # never went safe, nothing late
    run = read_with_all_readers(g.out)["run"]
    assert run.meta["blocks"]["displacement"]["duplicates"] == 0
