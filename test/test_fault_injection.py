"""Fault injection into the node graph (issue 10, "Deliver also"): each test injects one kind of fault into running
node processes over real DDS, then states — with numbers, asserted — what was lost and what the driver did, and
checks that the recording stays readable (piezo-ff's reader, the ``mcap`` reader, ``rosbags``).

Faults: recorder disk full (``RLIMIT_FSIZE``, SIGXFSZ ignored so that the write fails with EFBIG); kill -9 and
restart of the recorder (``piezo-ff recover`` on its file), of the compensator, of the driver and of the trajectory
node; a stalled compensator (SIGSTOP … SIGCONT); wall-clock steps forward and backward in the realtime trajectory
node.  docs/faults.md has the table of the figures.
"""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_driver_node import _io, _stream  # noqa: E402
from test_nodes_integration import AXES, DT_NS, FS, ROOT, Probe, child_env, stop_node  # noqa: E402


@pytest.fixture()
def probe():
    p = Probe("fault_probe")
    yield p
    p.close()


def start(name: str, *ros_args: str, log_dir: Path, preexec_fn=None, tag: str = "",
          env: dict | None = None) -> subprocess.Popen:
    """``start_node`` of test_nodes_integration with a ``preexec_fn`` (resource limits), a log tag (a restarted
    node writes a second log) and extra environment variables."""
    log_path = log_dir / f"{name}{tag}.log"
    log = open(log_path, "wb")
    e = child_env()
    e["PYTHONUNBUFFERED"] = "1"
    e.update(env or {})
    p = subprocess.Popen([sys.executable, "-m", f"piezo_ff_ros.nodes.{name}", "--ros-args", *ros_args],
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
