"""One block codec: a node's decoding path and a reader's give the same verdict on the same hostile blocks, and the
one sample-period function refuses a rate without a whole-nanosecond period (at a node's start too)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from piezo_ff_ros.core.recording import blocks as B  # noqa: E402

AXES = ("x", "y")
DT = 50_000


def _msg(n=4, stamp=100 * DT, axes=AXES, values=None):
    from piezo_ff_ros.nodes.common import pack_block

    block = np.arange(n * len(axes), dtype=float).reshape(n, len(axes)) * 1e-7 if values is None else values
    return pack_block(block, axes, stamp)


def _hostile():
    """``{case: rclpy PointCloud2}``: one good block and the hostile ones."""
    from sensor_msgs.msg import PointField

    cases = {"good": _msg()}
    m = _msg()
    m.fields[1].count = 0
    cases["count 0"] = m
    m = _msg()
    m.fields = [m.fields[1], m.fields[0]]              # listed y@8, x@0: out of offset order
    cases["fields out of order"] = m
    m = _msg(axes=("x", "y", "z"))
    cases["extra field"] = m
    m = _msg()
    m.fields = [PointField(name="x", offset=0, datatype=8, count=1)]
    m.point_step, m.row_step, m.data = 8, 8 * 4, bytes(8 * 4)
    cases["missing field"] = m
    m = _msg()
    m.width, m.row_step, m.data = 0, 0, b""
    cases["width 0"] = m
    cases["off-grid stamp"] = _msg(stamp=100 * DT + 1)
    cases["NaN"] = _msg(values=np.array([[0.0, np.nan], [1e-6, 0.0]]))
    m = _msg()
    m.width, m.row_step = B.MAX_BLOCK_SAMPLES + 1, 16 * (B.MAX_BLOCK_SAMPLES + 1)
    m.data = bytes(16 * (B.MAX_BLOCK_SAMPLES + 1))
    cases["oversized"] = m
    m = _msg()
    m.is_bigendian = True
    cases["big-endian"] = m
    m = _msg()
    m.data = bytes(m.data)[:-8]
    cases["short data"] = m
    return cases


def _verdict(fn):
    try:
        fn()
    except ValueError as exc:
        return f"refused: {exc}"
    return "accepted"


@pytest.mark.parametrize("strict", [False, True], ids=["structure", "with grid and finite"])
def test_node_and_reader_give_the_same_verdict_on_every_hostile_block(strict):
    from rclpy.serialization import serialize_message

    from piezo_ff_ros.nodes.common import unpack_block

    kw = {"period_ns": DT, "finite": True} if strict else {}
    node, reader = {}, {}
    for name, msg in _hostile().items():
        node[name] = _verdict(lambda: unpack_block(msg, AXES, **kw))
        raw = serialize_message(msg)
        reader[name] = _verdict(lambda: B.deserialize_block(raw, AXES, **kw))
    assert node == reader
    assert node["good"] == "accepted"
    refused = {k for k, v in node.items() if v.startswith("refused")}
    expected = {"count 0", "fields out of order", "extra field", "missing field", "width 0", "oversized",
                "big-endian", "short data"}
    assert refused == (expected | {"off-grid stamp", "NaN"} if strict else expected)
    for k in refused:   # one line, naming the field
        assert "\n" not in node[k] and "block" in node[k], node[k]


def test_oversized_block_is_refused_before_its_data_is_read():
    class Exploding:
        """A message whose data must not be touched."""

        def __init__(self, msg):
            self._m = msg

        def __getattr__(self, name):
            if name == "data":
                raise AssertionError("data read")
            return getattr(self._m, name)

    m = _hostile()["oversized"]
    with pytest.raises(B.BlockFormatError, match="block.width"):
        B.decode_block(Exploding(m), AXES)


@pytest.mark.parametrize("fs, ok", [(20000.0, True), (10000.0, True), (25000.0, True), (30000.0, False),
                                    (3.0, False), (0.0, False), (float("nan"), False)])
def test_the_one_sample_period_function(fs, ok):
    from piezo_ff_ros.nodes.common import dt_ns

    if ok:
        assert dt_ns(fs) == B.sample_period_ns(fs) == round(1e9 / fs)
    else:
        with pytest.raises(ValueError, match="sample_rate"):
            dt_ns(fs)


def test_no_inline_sample_period_left():
    """Every node and core module takes the period from the codec's function, none computes it inline."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "piezo_ff_ros"
    inline = [str(p.relative_to(root)) for p in root.rglob("*.py")
              if "int(round(1e9" in p.read_text()]
    assert inline == [], inline


def test_trajectory_node_refuses_30_khz_with_one_line(tmp_path):
    from test_nodes_integration import child_env

    p = subprocess.run([sys.executable, "-m", "piezo_ff_ros.nodes.trajectory", "--ros-args", "-p",
                        "sample_rate:=30000.0"], env=child_env(), capture_output=True, text=True, timeout=120)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2, p.stderr
    assert len(lines) == 1 and "sample_rate" in lines[0] and "30000" in lines[0], lines


def test_a_recording_of_the_hostile_blocks_is_read_with_the_same_verdicts(tmp_path):
    """Every block a node refuses for its structure is a malformed block to the reader (``load_run``); the stamp
    off the grid is counted as such; the good blocks are read."""
    from rclpy.serialization import serialize_message

    from piezo_ff_ros.core.recording import load_run
    from piezo_ff_ros.core.recording.mcap_io import McapRecorder
    from piezo_ff_ros.nodes.common import pack_block, unpack_block

    hostile = _hostile()
    structural = []
    path = tmp_path / "hostile.mcap"
    k = 100
    with McapRecorder(path) as rec:
        rec.set_metadata({"sample_rate": 20000, "axes": list(AXES), "t0_ns": 0})
        rec.register_topic("/reference", B.BLOCK_TYPE)
        for name, msg in hostile.items():
            if name in ("good", "off-grid stamp", "NaN"):
                continue
            try:
                unpack_block(msg, AXES)
            except ValueError:
                structural.append(name)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * DT, 10**9)
            rec.write("/reference", serialize_message(msg), 0)
            k += 4
        for i in range(3):   # good blocks around the off-grid one
            rec.write("/reference", serialize_message(pack_block(np.ones((4, 2)) * 1e-6, AXES, (k + 4 * i) * DT)), 0)
        rec.write("/reference", serialize_message(pack_block(np.ones((4, 2)) * 1e-6, AXES, (k + 12) * DT + 1)), 0)
    run = load_run(path)
    info = run.meta["blocks"]["reference"]
    assert info["malformed"] == len(structural) == 8, (info, structural)
    assert info["off_grid"] == 1 and info["count"] == 4


@pytest.mark.parametrize("n, frame", [(1, "piezo"), (7, ""), (20_001, "a_longer_frame_id"), (3, "abc")])
def test_the_sample_count_is_read_from_the_first_bytes(n, frame):
    raw = B.serialize_block(np.zeros((n, 2)), 5 * DT, frame_id=frame)
    assert B.peek_block_samples(raw) == n
    assert B.peek_block_samples(raw[:10]) is None
