"""Recording layer without ROS: block codec, rosbag2-profile MCAP writer, read_run (ours, rosbags-written,
truncated, garbage), gap/duplicate detection."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.core.recording import blocks as B
from piezo_ff_ros.core.recording import load_run
from piezo_ff_ros.core.recording.mcap_io import (METADATA_NAME, McapRecorder, block_qos_profile, read_run,
                                                 ros2msg_definition, scan_mcap, type_hash)

FS = 20000
DT_NS = 50_000
T0 = 1_763_800_000_123_450_000  # on the 50 µs grid
N = 200
ROLES = ("reference", "voltage", "displacement")


def _signals(n_samples: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    ref = rng.standard_normal((n_samples, 2)) * 1e-6
    u = rng.uniform(-150, 150, (n_samples, 2))
    y = ref + 1e-8 * rng.standard_normal((n_samples, 2))
    return {"reference": ref, "voltage": u, "displacement": y}


def _write_run(path, sig, *, block=N, skip=(), dup=(), markers=(), chunk_size=64 * 1024, diag=True,
               metadata=True, ns=""):
    """Synthetic recording: ``skip``/``dup`` = {(role, k0)} blocks to drop / send twice."""
    n_samples = len(sig["reference"])
    with McapRecorder(path, chunk_size=chunk_size) as rec:
        if metadata:
            rec.set_metadata({"sample_rate": FS, "t0_ns": T0, "axes": ["x", "y"], "block_size": block})
        for role in ROLES:
            rec.register_topic(f"{ns}/{role}", B.BLOCK_TYPE, [block_qos_profile()])
        rec.register_topic(f"{ns}/experiment", "std_msgs/msg/String")
        if diag:
            rec.register_topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        marks = dict(markers)
        for k0 in range(0, n_samples, block):
            stamp = B.stamp_for_index(k0, T0, DT_NS)
            if k0 in marks:
                txt = json.dumps({"name": marks[k0], "k0": k0, "stages": ["hysteresis"]})
                rec.write(f"{ns}/experiment", B.serialize_message({"data": txt}, "std_msgs/msg/String"), stamp)
            for role in ROLES:
                if (role, k0) in skip:
                    continue
                raw = B.serialize_block(sig[role][k0:k0 + block], stamp)
                for _ in range(2 if (role, k0) in dup else 1):
                    rec.write(f"{ns}/{role}", raw, stamp + 30_000, stamp)
            if diag and k0 % (block * 10) == 0:
                d = {"header": {"stamp": B.ns_to_stamp(stamp), "frame_id": ""},
                     "status": [{"level": b"\x00", "name": "driver", "message": "ok", "hardware_id": "sim",
                                 "values": [{"key": "saturated_samples", "value": str(k0 // block)}]}]}
                rec.write("/diagnostics", B.serialize_message(d, "diagnostic_msgs/msg/DiagnosticArray"), stamp)
    return path


# ---------------------------------------------------------------------------------------------------------------
# block codec

def test_block_roundtrip_dict_and_cdr_exact():
    rng = np.random.default_rng(1)
    block = rng.standard_normal((37, 2))
    msg = B.encode_block(block, T0 + 7 * DT_NS)
    assert msg["fields"][1] == {"name": "y", "offset": 8, "datatype": 8, "count": 1}
    assert (msg["point_step"], msg["row_step"], msg["width"], msg["height"]) == (16, 16 * 37, 37, 1)
    stamp, back = B.decode_block(msg)
    assert stamp == T0 + 7 * DT_NS and np.array_equal(back, block)
    stamp2, back2, axes = B.deserialize_block(B.serialize_block(block, stamp))
    assert stamp2 == stamp and axes == ("x", "y") and np.array_equal(back2, block)
    # column selection by field name
    _, yx = B.decode_block(msg, axes=("y", "x"))
    assert np.array_equal(yx, block[:, ::-1])


def test_block_decode_rejects_contract_violations():
    msg = B.encode_block(np.zeros((4, 2)), T0)
    bad = dict(msg, fields=[dict(msg["fields"][0], datatype=7), msg["fields"][1]])
    with pytest.raises(ValueError, match="FLOAT64"):
        B.decode_block(bad)
    with pytest.raises(ValueError, match="block.data"):
        B.decode_block(dict(msg, data=msg["data"][:-8]))
    with pytest.raises(ValueError, match="row_step"):
        B.decode_block(dict(msg, row_step=3))
    with pytest.raises(ValueError, match="do not name the axes"):
        B.decode_block(msg, axes=("z",))
    with pytest.raises(ValueError, match="cannot decode"):
        B.deserialize_block(b"\x00\x01\x00\x00garbage")


def test_stamp_index_helpers_exact():
    assert B.sample_period_ns(20000) == 50_000
    with pytest.raises(ValueError, match="sample_rate"):
        B.sample_period_ns(30000)  # 33 333.3 ns: not whole
    k = 123_456_789
    s = B.stamp_for_index(k, T0, DT_NS)
    assert B.index_for_stamp(s, T0, DT_NS) == k
    with pytest.raises(ValueError, match="not on the sample grid"):
        B.index_for_stamp(s + 1, T0, DT_NS)
    assert B.index_for_stamp(s + 30_000, T0, DT_NS, strict=False) == k + 1
    assert B.stamp_to_ns(B.ns_to_stamp(s)) == s


def test_schema_text_as_rosbag2_builds_it():
    text = ros2msg_definition(B.BLOCK_TYPE)
    parts = text.split("\n" + "=" * 80 + "\nMSG: ")
    assert [p.split("\n", 1)[0] for p in parts[1:]] == ["sensor_msgs/PointField", "std_msgs/Header",
                                                         "builtin_interfaces/Time"]
    assert parts[0].startswith(Path(os.sys.prefix, "share/sensor_msgs/msg/PointCloud2.msg").read_text()[:40])
    assert type_hash(B.BLOCK_TYPE).startswith("RIHS01_") and len(type_hash(B.BLOCK_TYPE)) == 7 + 64


# ---------------------------------------------------------------------------------------------------------------
# writer → readers

def test_recording_read_by_mcap_ros2_and_rosbags_sample_exact(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    sig = _signals(20 * N)
    path = _write_run(tmp_path / "run.mcap", sig, markers={0: "hyst_x"})

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
        assert summary.statistics.message_count == 3 * 20 + 1 + 2
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            assert ch.metadata["topic_type_hash"].startswith("RIHS01_")
            assert "offered_qos_profiles" in ch.metadata
        qos = next(c for c in summary.channels.values() if c.topic == "/voltage").metadata["offered_qos_profiles"]
        assert "reliability: reliable" in qos and "depth: 100" in qos
        md = [m for m in reader.iter_metadata() if m.name == METADATA_NAME]
        assert json.loads(md[0].metadata["sample_rate"]) == FS
        got = {r: [] for r in ROLES}
        for _, channel, _, msg in reader.iter_decoded_messages(topics=[f"/{r}" for r in ROLES]):
            stamp, block = B.decode_block(msg)
            got[channel.topic[1:]].append((stamp, block))
    for role in ROLES:
        stamps = [s for s, _ in got[role]]
        assert stamps == [T0 + k * DT_NS for k in range(0, 20 * N, N)]
        assert np.array_equal(np.concatenate([b for _, b in got[role]]), sig[role])

    with AnyReader([Path(path)]) as ar:
        conns = [c for c in ar.connections if c.topic == "/displacement"]
        blocks = [B.decode_block(ar.deserialize(raw, c.msgtype))[1] for c, _, raw in ar.messages(connections=conns)]
    assert np.array_equal(np.concatenate(blocks), sig["displacement"])

    run = read_run(path)
    assert np.array_equal(run.reference, sig["reference"])
    assert np.array_equal(run.u, sig["voltage"])
    assert np.array_equal(run.y, sig["displacement"])
    assert run.t[1] - run.t[0] == pytest.approx(1 / FS) and run.meta["t0_ns"] == T0
    assert run.meta["segments"][0]["name"] == "hyst_x" and run.meta["segments"][0]["complete"]
    assert run.meta["diagnostics"]["messages"] == 2
    assert run.meta["diagnostics"]["status"]["driver"]["values"]["saturated_samples"] == "10"
    assert not run.meta["truncated"] and all(i["missing_samples"] == 0 for i in run.meta["blocks"].values())


def test_rosbags_written_bag_read_by_read_run(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer

    sig = _signals(10 * 150, seed=3)
    bag = tmp_path / "bag"
    w = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
    w.open()
    conns = {r: w.add_connection(f"/piezo/{r}", B.BLOCK_TYPE, msgdef=ros2msg_definition(B.BLOCK_TYPE),
                                 rihs01=type_hash(B.BLOCK_TYPE)) for r in ROLES}
    exp = w.add_connection("/piezo/experiment", "std_msgs/msg/String",
                           msgdef=ros2msg_definition("std_msgs/msg/String"), rihs01=type_hash("std_msgs/msg/String"))
    t0 = 5 * 10**9
    w.write(exp, t0, B.serialize_message({"data": json.dumps({"name": "circle", "k0": 0})}, "std_msgs/msg/String"))
    for k0 in range(0, 1500, 150):
        stamp = t0 + k0 * DT_NS
        for r in ROLES:
            w.write(conns[r], stamp + 1000, B.serialize_block(sig[r][k0:k0 + 150], stamp))
    w.close()
    for path in (bag, next(bag.glob("*.mcap"))):  # the directory and the bare inner file
        run = load_run(path)  # no metadata record: fs and t0 inferred from the stamps
        assert run.meta["sample_rate"] == FS and run.meta["t0_ns"] == t0
        assert np.array_equal(run.y, sig["displacement"]) and np.array_equal(run.reference, sig["reference"])
        assert [s["name"] for s in run.meta["segments"]] == ["circle"]


def test_gaps_duplicates_and_trimming_detected(tmp_path):
    sig = _signals(30 * N, seed=2)
    skip = {("displacement", 5 * N), ("displacement", 6 * N), ("voltage", 12 * N), ("reference", 0)}
    path = _write_run(tmp_path / "gaps.mcap", sig, skip=skip, dup={("displacement", 8 * N)},
                      markers={0: "a", 10 * N: "b", 20 * N: "c"})
    run = read_run(path)
    blocks = run.meta["blocks"]
    assert blocks["displacement"]["gaps"] == [(5 * N, 7 * N)]
    assert blocks["displacement"]["missing_blocks"] == 2 and blocks["displacement"]["duplicates"] == 1
    assert blocks["displacement"]["conflicts"] == 0
    assert blocks["voltage"]["gaps"] == [(12 * N, 13 * N)]
    # the reference starts one block late: the common span is trimmed to it
    assert run.meta["k_offset"] == N and len(run) == 29 * N
    assert np.isnan(run.y[4 * N:6 * N]).all() and np.isfinite(run.y[:4 * N]).all()
    assert np.array_equal(run.y[7 * N:], sig["displacement"][8 * N:])
    segs = {s["name"]: s for s in run.meta["segments"]}
    assert not segs["a"]["complete"] and segs["a"]["start"] == 0  # cut by the trimmed start, and gaps
    assert not segs["b"]["complete"]  # voltage gap inside
    assert segs["c"]["complete"] and (segs["c"]["start"], segs["c"]["stop"]) == (19 * N, 29 * N)


def test_namespaces_are_distinguished(tmp_path):
    sig = _signals(4 * N)
    path = tmp_path / "ns.mcap"
    _write_run(path, sig, ns="/tube1")
    assert np.array_equal(read_run(path, namespace="tube1").y, sig["displacement"])
    with pytest.raises(ValueError, match="no block topic"):
        read_run(path, namespace="tube2")


def test_truncated_file_gives_readable_prefix_or_clear_error(tmp_path):
    sig = _signals(40 * N, seed=4)
    path = _write_run(tmp_path / "full.mcap", sig, chunk_size=16 * 1024, diag=False)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])  # a recorder killed mid-run
    run = read_run(cut)
    assert run.meta["truncated"] and "ends early" in run.meta["truncation_error"]
    assert 0 < len(run) < 40 * N and len(run) % N == 0
    assert np.array_equal(run.y, sig["displacement"][: len(run)])  # the prefix is sample-exact
    cut.write_bytes(data[:-5])  # only the footer damaged: everything is still there
    assert len(read_run(cut)) == 40 * N
    cut.write_bytes(data[:40])  # nothing but the header
    with pytest.raises(ValueError, match="nothing recoverable"):
        read_run(cut)


def test_recorder_killed_without_close_leaves_readable_file(tmp_path):
    sig = _signals(10 * N)
    path = tmp_path / "killed.mcap"
    rec = McapRecorder(path, flush_interval=0.0)  # flush on every message: nothing is lost
    rec.register_topic("/displacement", B.BLOCK_TYPE)
    for k0 in range(0, 9 * N, N):  # an odd count: the last message must be on disk too
        rec.write("/displacement", B.serialize_block(sig["displacement"][k0:k0 + N], T0 + k0 * DT_NS), T0)
    # no close(): as after SIGKILL (the open file object is simply dropped)
    run = read_run(path)
    assert run.meta["truncated"] and np.array_equal(run.y, sig["displacement"][:9 * N])
    rec.close()


@pytest.mark.parametrize("content", [b"", b"not an mcap at all", os.urandom(4096), b"\x89MCAP0\r\n" + b"\x00" * 3])
def test_garbage_files_raise_value_error(tmp_path, content):
    p = tmp_path / "bad.mcap"
    p.write_bytes(content)
    with pytest.raises(ValueError, match="bad.mcap"):
        read_run(p)


def test_file_without_block_topics_is_a_clear_error(tmp_path):
    p = tmp_path / "other.mcap"
    with McapRecorder(p) as rec:
        rec.register_topic("/chatter", "std_msgs/msg/String")
        rec.write("/chatter", B.serialize_message({"data": "hi"}, "std_msgs/msg/String"), 1)
    with pytest.raises(ValueError, match="no block topic"):
        read_run(p)
    assert scan_mcap(p).topics == {"/chatter": "std_msgs/msg/String"}


def test_recorder_api_errors(tmp_path):
    rec = McapRecorder(tmp_path / "x.mcap")
    rec.register_topic("/voltage", B.BLOCK_TYPE)
    assert rec.register_topic("/voltage", B.BLOCK_TYPE) == rec.register_topic("/voltage", B.BLOCK_TYPE)
    with pytest.raises(ValueError, match="already registered"):
        rec.register_topic("/voltage", "std_msgs/msg/String")
    with pytest.raises(ValueError, match="not registered"):
        rec.write("/nope", b"", 0)
    rec.close()
    rec.close()
    with pytest.raises(ValueError, match="closed"):
        rec.write("/voltage", b"", 0)


@pytest.mark.parametrize("strict", [True, False])
def test_strict_chunks_stay_within_the_chunk_size(tmp_path, strict):
    """strict_chunks (the recorder node's chunks): every chunk holds at most chunk_size bytes of uncompressed records
    whatever the message sizes (a message larger than that alone in its chunk), and every message is read back in
    order; without it the MCAP writer closes a chunk only once it is over, so some chunk is larger."""
    from mcap.reader import make_reader

    limit = 16 * 1024
    rng = np.random.default_rng(3)
    sizes = [int(s) for s in rng.integers(10, 6000, 300)] + [40_000, 100, 7000]
    path = tmp_path / "chunks.mcap"
    with McapRecorder(path, chunk_size=limit, flush_interval=None, strict_chunks=strict) as rec:
        rec.register_topic("/t", "std_msgs/msg/String", [block_qos_profile()])
        for i, n in enumerate(sizes):
            rec.write("/t", bytes([i % 251]) * n, log_time_ns=1000 + i)
    with open(path, "rb") as f:
        reader = make_reader(f)
        chunks = reader.get_summary().chunk_indexes
        got = [len(m.data) for _, _, m in reader.iter_messages()]
    assert got == sizes
    over = [c.uncompressed_size for c in chunks if c.uncompressed_size > limit]
    if strict:
        assert over == [next(c.uncompressed_size for c in chunks if c.uncompressed_size > 40_000)], over
    else:
        assert len(over) > 1
