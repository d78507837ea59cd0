"""The MCAP reader against outlier stamps and corrupt chunks, and ``piezo-ff recover``.

Each test was written against the defect first (the reader allocated from the stamp span and crashed with
``Unable to allocate … TiB``; it stopped at the first corrupt chunk; a killed recorder's file was refused by the
``mcap`` and ``rosbags`` readers).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.cli import main as cli_main
from piezo_ff_ros.core.recording import blocks as B
from piezo_ff_ros.core.recording import load_run
from piezo_ff_ros.core.recording.mcap_io import McapRecorder, block_qos_profile, read_run, scan_mcap
from piezo_ff_ros.core.recording.recover import recover_mcap

FS = 20000
DT_NS = 50_000
T0 = 1_763_800_000_123_450_000
N = 200
ROLES = ("reference", "voltage", "displacement")


def _signals(n_samples: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    ref = rng.standard_normal((n_samples, 2)) * 1e-6
    return {"reference": ref, "voltage": rng.uniform(-150, 150, (n_samples, 2)),
            "displacement": ref + 1e-8 * rng.standard_normal((n_samples, 2))}


def _write(path: Path, sig: dict, *, stamp_of=None, chunk_size: int = 16 * 1024, metadata: bool = True,
           close: bool = True, marker: bool = True) -> Path:
    """A recording of the contract; ``stamp_of(role, k0)`` overrides a block's stamp (None = on the grid)."""
    n = len(sig["reference"])
    rec = McapRecorder(path, chunk_size=chunk_size, flush_interval=None)
    if metadata:
        rec.set_metadata({"sample_rate": FS, "t0_ns": T0, "axes": ["x", "y"], "block_size": N})
    for role in ROLES:
        rec.register_topic(f"/{role}", B.BLOCK_TYPE, [block_qos_profile()])
    rec.register_topic("/experiment", "std_msgs/msg/String")
    if marker:
        rec.write("/experiment", B.serialize_message({"data": json.dumps({"name": "run", "k0": 0})},
                                                     "std_msgs/msg/String"), T0)
    for k0 in range(0, n, N):
        for role in ROLES:
            stamp = B.stamp_for_index(k0, T0, DT_NS)
            if stamp_of is not None and stamp_of(role, k0) is not None:
                stamp = stamp_of(role, k0)
            rec.write(f"/{role}", B.serialize_block(sig[role][k0:k0 + N], stamp), T0 + k0 * DT_NS + 30_000)
    if close:
        rec.close()
    else:
        rec.flush()  # as after SIGKILL: chunks on disk, no summary, no footer
    return path


# ---------------------------------------------------------------------------------------------------------------
# item 1: one outlier timestamp

@pytest.mark.parametrize("outlier", [T0 + 3 * 10**17, T0 - 10**18, 0, (2**31 - 1) * 10**9])
def test_one_outlier_stamp_is_reported_not_allocated(tmp_path, outlier):
    sig = _signals(20 * N)
    path = _write(tmp_path / "outlier.mcap", sig, stamp_of=lambda r, k0: outlier if (r, k0) == ("voltage", 7 * N) else None)
    run = read_run(path)  # used to size the arrays from the stamp span: "Unable to allocate 495 TiB"
    assert len(run) == 20 * N
    info = run.meta["blocks"]["voltage"]
    assert info["outliers"] == 1 and info["outlier_stamps_ns"] == [outlier]
    assert info["gaps"] == [(7 * N, 8 * N)] and info["missing_blocks"] == 1
    assert np.isnan(run.u[7 * N:8 * N]).all()
    assert np.array_equal(run.u[:7 * N], sig["voltage"][:7 * N])
    assert np.array_equal(run.y, sig["displacement"])
    assert any("outside the recording's span" in w for w in run.meta["warnings"])
    # the same through load_run (shared with diagnose and identify) and the CLI
    assert len(load_run(path)) == 20 * N
    assert cli_main(["analyze", str(path), "--json", str(tmp_path / "a.json")]) == 0


def test_outlier_without_metadata_and_in_every_topic(tmp_path):
    sig = _signals(12 * N)
    path = _write(tmp_path / "o.mcap", sig, metadata=False,
                  stamp_of=lambda r, k0: T0 + 10**17 if k0 == 11 * N else None)
    run = read_run(path)
    assert len(run) == 11 * N and run.sample_rate == pytest.approx(FS)
    assert all(run.meta["blocks"][r]["outliers"] == 1 for r in ROLES)


def test_genuine_gap_shorter_than_the_data_is_kept_as_nan(tmp_path):
    sig = _signals(30 * N)
    skip = set(range(10 * N, 20 * N, N))
    # a 10-block pause in every topic: a real gap (the data around it is larger), not an outlier
    path = tmp_path / "gap.mcap"
    rec = McapRecorder(path, chunk_size=16 * 1024)
    rec.set_metadata({"sample_rate": FS, "t0_ns": T0, "axes": ["x", "y"]})
    for role in ROLES:
        rec.register_topic(f"/{role}", B.BLOCK_TYPE)
    for k0 in range(0, 30 * N, N):
        if k0 in skip:
            continue
        for role in ROLES:
            rec.write(f"/{role}", B.serialize_block(sig[role][k0:k0 + N], T0 + k0 * DT_NS), T0)
    rec.close()
    run = read_run(path)
    assert len(run) == 30 * N and run.meta["blocks"]["voltage"]["outliers"] == 0
    assert run.meta["blocks"]["voltage"]["gaps"] == [(10 * N, 20 * N)]


def test_off_grid_stamp_is_reported(tmp_path):
    sig = _signals(6 * N)
    path = _write(tmp_path / "off.mcap", sig, stamp_of=lambda r, k0: T0 + k0 * DT_NS + 7 if (r, k0) == (
        "displacement", 2 * N) else None)
    run = read_run(path)
    assert run.meta["blocks"]["displacement"]["off_grid"] == 1
    assert any("off the 50000 ns sample grid" in w for w in run.meta["warnings"])


# ---------------------------------------------------------------------------------------------------------------
# item 8: corrupt chunks are skipped and reported; a killed recorder's file is recovered

def _chunk_offsets(path: Path) -> list[tuple[int, int]]:
    """(offset, total length) of every top-level Chunk record, parsed independently of the reader under test."""
    import struct

    data = path.read_bytes()
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            out.append((pos, 9 + length))
        if op == 0x0F or pos + 9 + length > len(data):  # DataEnd
            break
        pos += 9 + length
    return out


def test_corrupt_chunk_is_skipped_and_reported(tmp_path):
    sig = _signals(60 * N, seed=3)
    path = _write(tmp_path / "ok.mcap", sig)
    chunks = _chunk_offsets(path)
    assert len(chunks) >= 8
    data = bytearray(path.read_bytes())
    off, length = chunks[3]
    for i in range(off + 60, off + length - 10, 97):  # damage the compressed payload, keep the framing
        data[i] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    run = read_run(bad)
    loss = run.meta["loss"]
    assert loss["chunks_lost"] == 1 and loss["chunks_total"] == len(chunks)
    assert loss["messages_lost"] > 0 and len(loss["lost_time_ranges_ns"]) == 1
    # everything before and after the corrupt chunk is there, sample-exact
    assert len(run) == 60 * N
    y_ok = ~np.isnan(run.y).any(axis=1)
    assert 0.5 * len(run) < y_ok.sum() < len(run)
    assert np.array_equal(run.y[y_ok], sig["displacement"][y_ok])
    assert run.y[-1].tolist() == sig["displacement"][-1].tolist()
    assert any("corrupt or cut-short chunk" in w for w in run.meta["warnings"])


def test_corrupt_chunk_framing_resyncs_on_the_next_chunk(tmp_path):
    sig = _signals(60 * N, seed=5)
    path = _write(tmp_path / "ok.mcap", sig)
    chunks = _chunk_offsets(path)
    data = bytearray(path.read_bytes())
    off, _ = chunks[2]
    data[off + 1:off + 9] = (2**60).to_bytes(8, "little")  # the chunk's length field destroyed
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    run = read_run(bad)
    assert run.meta["loss"]["chunks_lost"] >= 1 and run.meta["loss"]["bytes_skipped"] > 0
    assert run.y[-1].tolist() == sig["displacement"][-1].tolist()


def _open_with_strict_readers(path: Path) -> tuple[int, int]:
    """Message counts from the ``mcap`` seeking reader (needs summary + footer) and from ``rosbags``."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        n_mcap = sum(1 for _ in reader.iter_messages())
    with AnyReader([path]) as r:
        n_rosbags = sum(1 for _ in r.messages())
    return n_mcap, n_rosbags


def test_recover_killed_recorder_file(tmp_path):
    sig = _signals(30 * N, seed=7)
    killed = _write(tmp_path / "killed.mcap", sig, close=False)
    from mcap.reader import make_reader

    with open(killed, "rb") as f, pytest.raises(Exception):
        list(make_reader(f).iter_messages())  # the defect: strict readers refuse it
    out = tmp_path / "fixed.mcap"
    assert cli_main(["recover", str(killed), "--out", str(out)]) == 0
    n_mcap, n_rosbags = _open_with_strict_readers(out)
    assert n_mcap == n_rosbags == 1 + 3 * 30
    a, b = read_run(killed), read_run(out)
    assert not b.meta["truncated"] and np.array_equal(a.y, b.y) and np.array_equal(a.u, b.u)
    assert b.meta["metadata"]["sample_rate"] == str(FS) or float(b.meta["metadata"]["sample_rate"]) == FS
    assert scan_mcap(out).channel_metadata["/reference"]["topic_type_hash"].startswith("RIHS01_")


def test_recover_truncated_and_corrupted_file(tmp_path):
    sig = _signals(60 * N, seed=8)
    path = _write(tmp_path / "ok.mcap", sig)
    chunks = _chunk_offsets(path)
    data = bytearray(path.read_bytes())
    off, length = chunks[4]
    data[off + length // 2] ^= 0x5A  # one corrupt chunk …
    cut = bytes(data[: chunks[-2][0] + chunks[-2][1] // 2])  # … and cut inside the second last chunk
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(cut)
    report = recover_mcap(bad, tmp_path / "fixed.mcap")
    assert report["chunks_lost"] == 2 and report["truncated"]  # the corrupt one and the one cut short
    assert report["messages_written"] > 0
    n_mcap, n_rosbags = _open_with_strict_readers(tmp_path / "fixed.mcap")
    assert n_mcap == n_rosbags == report["messages_written"]


def test_recover_refuses_to_overwrite_and_garbage(tmp_path, capsys):
    sig = _signals(4 * N)
    path = _write(tmp_path / "r.mcap", sig)
    assert cli_main(["recover", str(path), "--out", str(path)]) == 2
    (tmp_path / "exists.mcap").write_bytes(b"x")
    assert cli_main(["recover", str(path), "--out", str(tmp_path / "exists.mcap")]) == 2
    (tmp_path / "junk.mcap").write_bytes(b"junk" * 100)
    assert cli_main(["recover", str(tmp_path / "junk.mcap")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("\n") == 3
    # default output name next to the input
    assert cli_main(["recover", str(path)]) == 0
    assert (tmp_path / "r.recovered.mcap").is_file()


@pytest.mark.parametrize("marker", [{"name": "a", "k0": "zero"}, {"name": "a", "stamp_ns": 1.5},
                                    {"name": "a", "k0": 0, "k1": [3]}, {"name": "a", "k0": True},
                                    {"name": "a", "k0": 10**30}, {"name": "a", "k0": -5, "n": 10**12}])
def test_malformed_experiment_markers_are_skipped_with_a_warning(tmp_path, marker):
    """Another writer's experiment markers with odd fields (they used to raise ValueError/TypeError from int())."""
    sig = _signals(4 * N)
    path = tmp_path / "m.mcap"
    rec = McapRecorder(path, chunk_size=16 * 1024)
    rec.set_metadata({"sample_rate": FS, "t0_ns": T0, "axes": ["x", "y"]})
    for role in ROLES:
        rec.register_topic(f"/{role}", B.BLOCK_TYPE)
    rec.register_topic("/experiment", "std_msgs/msg/String")
    rec.write("/experiment", B.serialize_message({"data": json.dumps(marker)}, "std_msgs/msg/String"), T0)
    for k0 in range(0, 4 * N, N):
        for role in ROLES:
            rec.write(f"/{role}", B.serialize_block(sig[role][k0:k0 + N], T0 + k0 * DT_NS), T0)
    rec.close()
    run = read_run(path)  # huge indices allocate nothing
    assert len(run) == 4 * N
    bad_type = any(isinstance(marker.get(k), (str, list, bool, float)) for k in ("k0", "stamp_ns", "k1"))
    assert bad_type == any("not integers; skipped" in w for w in run.meta["warnings"])
    assert cli_main(["analyze", str(path), "--json", str(tmp_path / "a.json")]) == 0


@pytest.mark.parametrize("md", [{"axes": "5"}, {"axes": "[1, 2]"}, {"axes": '["x", "x"]'}, {"sample_rate": "nan"},
                                {"sample_rate": "30000"}, {"sample_rate": "-1"}, {"t0_ns": "soon"},
                                {"sample_rate": 10000}, {"sample_rate": "40000"}, {"t0_ns": 1},
                                {"t0_ns": str(T0 + 25_000)}])
def test_malformed_metadata_falls_back_to_the_blocks_with_a_warning(tmp_path, md):
    sig = _signals(6 * N)
    path = tmp_path / "md.mcap"
    rec = McapRecorder(path, chunk_size=16 * 1024)
    rec.set_metadata(md)
    for role in ROLES:
        rec.register_topic(f"/{role}", B.BLOCK_TYPE)
    for k0 in range(0, 6 * N, N):
        for role in ROLES:
            rec.write(f"/{role}", B.serialize_block(sig[role][k0:k0 + N], T0 + k0 * DT_NS), T0)
    rec.close()
    run = read_run(path)
    assert len(run) == 6 * N and run.axes == ("x", "y") and run.sample_rate == pytest.approx(FS)
    assert np.array_equal(run.u, sig["voltage"])
    assert any("metadata" in w for w in run.meta["warnings"])


def test_bad_sample_rate_override_names_it(tmp_path):
    path = _write(tmp_path / "r.mcap", _signals(2 * N))
    with pytest.raises(ValueError, match=r"r.mcap: --sample-rate/sample_rate= sample_rate: 30000"):
        read_run(path, sample_rate=30000)
