"""Replay analysis on synthetic recordings whose numbers are known in advance."""
from __future__ import annotations

import json

import numpy as np
import pytest

from piezo_ff_ros.cli import main as cli_main
from piezo_ff_ros.core.analysis import analyze_run, segment_signals
from piezo_ff_ros.core.recording import blocks as B
from piezo_ff_ros.core.recording.mcap_io import McapRecorder, read_run

FS = 20000
DT_NS = 50_000
T0 = 10**18
N = 250
UM = 1e-6


def _record(path, ref, u, y, markers=(), skip=(), diag_values=None, metadata=None):
    with McapRecorder(path) as rec:
        rec.set_metadata(metadata or {"sample_rate": FS, "t0_ns": T0})
        for role in ("reference", "voltage", "displacement"):
            rec.register_topic(f"/{role}", B.BLOCK_TYPE)
        rec.register_topic("/experiment", "std_msgs/msg/String")
        rec.register_topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        marks = dict(markers)
        for k0 in range(0, len(ref), N):
            stamp = T0 + k0 * DT_NS
            if k0 in marks:
                mark = marks[k0] if isinstance(marks[k0], dict) else {"name": marks[k0]}
                rec.write("/experiment", B.serialize_message(
                    {"data": json.dumps({"k0": k0, "stages": [], **mark})}, "std_msgs/msg/String"), stamp)
            for role, sig in (("reference", ref), ("voltage", u), ("displacement", y)):
                if (role, k0) not in skip:
                    rec.write(f"/{role}", B.serialize_block(sig[k0:k0 + N], stamp), stamp)
        if diag_values:
            d = {"header": {"stamp": B.ns_to_stamp(T0), "frame_id": ""},
                 "status": [{"level": 0, "name": "piezo_driver", "message": "running", "hardware_id": "sim",
                             "values": [{"key": k, "value": str(v)} for k, v in diag_values.items()]}]}
            rec.write("/diagnostics", B.serialize_message(d, "diagnostic_msgs/msg/DiagnosticArray"), T0)
    return path


@pytest.fixture
def known_run(tmp_path):
    """2 s: segment 'A' (1 s) with a constant x error of 0.1 µm and a 0.3 µm sine error on y (whole periods),
    segment 'B' (1 s) with zero error; 7 voltage samples at the 200 V limit."""
    n = 2 * FS
    t = np.arange(n) / FS
    ref = np.column_stack([10 * UM * np.sin(2 * np.pi * 3 * t), 5 * UM * np.cos(2 * np.pi * 2 * t)])
    err = np.zeros_like(ref)
    err[:FS, 0] = 0.1 * UM
    err[:FS, 1] = 0.3 * UM * np.sin(2 * np.pi * 50 * t[:FS])
    u = np.column_stack([100 * np.sin(2 * np.pi * t), np.zeros(n)])
    u[FS + 10:FS + 17, 1] = -200.0
    path = _record(tmp_path / "known.mcap", ref, u, ref + err, markers={0: "A", FS: "B"},
                   diag_values={"saturation_count": 7, "dropped_blocks": 0, "state": "running"})
    return path, ref, u, ref + err


def test_tracking_saturation_and_counts_are_the_known_values(known_run):
    path, ref, u, y = known_run
    result = analyze_run(read_run(path), evaluate=lambda rec: {}).to_json()
    rp = result["replay"]
    seg = {s["name"]: s for s in rp["segments"]}
    a, b = seg["A"]["tracking"], seg["B"]["tracking"]
    assert a["rms"] == pytest.approx([0.1 * UM, 0.3 * UM / np.sqrt(2)], rel=1e-9)
    assert a["max"] == pytest.approx([0.1 * UM, 0.3 * UM], rel=1e-6)
    assert b["rms"] == [0.0, 0.0] and b["max"] == [0.0, 0.0]
    whole = rp["tracking"]
    assert whole["rms"] == pytest.approx([0.1 * UM / np.sqrt(2), 0.3 * UM / 2], rel=1e-9)
    assert rp["saturation"] == {"limit_V": 200.0, "samples": 7, "fraction": 7 / (2 * FS)}
    assert rp["diagnostics"]["counters"] == {"piezo_driver/saturation_count": 7.0,
                                             "piezo_driver/dropped_blocks": 0.0}
    assert rp["samples"] == 2 * FS and rp["duration_s"] == pytest.approx(2.0)
    assert all(blk["missing_samples"] == 0 for blk in rp["blocks"].values())
    json.dumps(result, allow_nan=False)  # JSON-ready


def test_segments_go_to_the_shared_evaluation_and_its_keys_are_kept(known_run):
    path, ref, u, y = known_run
    seen = {}

    def fake_evaluate(recorded):
        seen.update(recorded)
        return {"before": {"n": len(recorded)}, "after": {}, "hinf": None}

    result = analyze_run(read_run(path), evaluate=fake_evaluate).to_json()
    assert set(result) == {"before", "after", "hinf", "replay"} and result["before"] == {"n": 2}
    t, r, uu, yy = seen["B"]
    assert t[0] == 0.0 and t[-1] == pytest.approx((FS - 1) / FS)
    assert np.array_equal(r, ref[FS:]) and np.array_equal(uu, u[FS:]) and np.array_equal(yy, y[FS:])
    assert np.array_equal(seen["A"][3], y[:FS])


def test_incomplete_segment_is_left_out_with_a_warning(tmp_path):
    n = FS
    ref = np.zeros((n, 2))
    path = _record(tmp_path / "gap.mcap", ref, ref, ref, markers={0: "A", n // 2: "B"},
                   skip={("displacement", 3 * N)})
    run = read_run(path)
    recorded, warnings = segment_signals(run)
    assert list(recorded) == ["B"] and any("'A': incomplete" in w for w in warnings)
    result = analyze_run(run, evaluate=lambda rec: {"seen": sorted(rec)}).to_json()
    assert result["seen"] == ["B"]
    assert result["replay"]["blocks"]["displacement"]["missing_blocks"] == 1
    # tracking over the finite samples only (the gap is excluded, not counted as error)
    assert result["replay"]["tracking"]["samples"] == n - N


def test_run_without_markers_reports_tracking_only(tmp_path):
    n = 4 * N
    ref = np.full((n, 2), 1 * UM)
    path = _record(tmp_path / "user.mcap", ref, np.zeros((n, 2)), ref + 0.5 * UM)
    result = analyze_run(read_run(path), evaluate=lambda rec: pytest.fail("no segments: not evaluated")).to_json()
    assert set(result) == {"replay"} and result["replay"]["segments"] == []
    assert result["replay"]["tracking"]["max"] == pytest.approx([0.5 * UM, 0.5 * UM])


def test_voltage_driven_segments_have_no_tracking_error(tmp_path):
    """The paper's S0 experiments put volts on `reference`: they must not pollute the tracking figures."""
    n = 8 * N
    ref = np.full((n, 2), 1 * UM)
    ref[: n // 2] = 100.0                       # volts: the voltage-driven segment
    y = ref + 0.5 * UM
    y[: n // 2] = 10 * UM
    path = _record(tmp_path / "mixed.mcap", ref, ref, y,
                   markers={0: {"name": "hyst_S0_x", "input": "voltage"}, n // 2: {"name": "step", "input": "displacement"}})
    result = analyze_run(read_run(path), evaluate=lambda rec: {}).to_json()
    segs = {s["name"]: s for s in result["replay"]["segments"]}
    assert segs["hyst_S0_x"]["tracking"] is None and segs["hyst_S0_x"]["input"] == "voltage"
    assert segs["step"]["tracking"]["max"] == pytest.approx([0.5 * UM, 0.5 * UM])
    assert result["replay"]["tracking"]["max"] == pytest.approx([0.5 * UM, 0.5 * UM])
    assert result["replay"]["tracking"]["samples"] == n // 2


def test_cli_analyze_json_plots_and_clean_errors(known_run, tmp_path, capsys):
    path = known_run[0]
    out_json, plots = tmp_path / "out" / "analysis.json", tmp_path / "plots"
    assert cli_main(["analyze", str(path), "--json", str(out_json), "--plots", str(plots)]) == 0
    data = json.loads(out_json.read_text())
    assert data["replay"]["saturation"]["samples"] == 7
    pngs = sorted(p.name for p in plots.glob("*.png"))
    assert pngs == ["00_A.png", "01_B.png"] and all((plots / p).stat().st_size > 10_000 for p in pngs)
    assert "segments:" in capsys.readouterr().out

    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\xff" * 100)
    assert cli_main(["analyze", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "piezo-ff analyze: error:" in err and "bad.mcap" in err and "Traceback" not in err
    assert cli_main(["analyze", str(tmp_path / "missing.mcap")]) == 2
