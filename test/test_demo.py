"""`piezo-ff demo` end to end on a short experiment subset (real DDS, separate processes)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
ROOT = Path(__file__).resolve().parents[1]


def test_demo_short_subset(tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "demo", "--out", str(tmp_path), "--quiet",
                        "--only", "hyst_S0_x,step_SL_x,circle20_open", "--creep-duration", "2",
                        "--domain-id", os.environ["ROS_DOMAIN_ID"]],  # the session's isolated domain (conftest)
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:] + "\n--- stdout:\n" + r.stdout[-2000:]
    assert "TABLE I" in r.stdout and "creep runs 2 s" in r.stdout
    assert (tmp_path / "run.mcap").stat().st_size > 0
    result = json.loads((tmp_path / "analysis.json").read_text())
    rp = result["replay"]
    assert [s["name"] for s in rp["segments"]] == ["hyst_S0_x", "step_SL_x", "circle20_open"]
    assert all(s["complete"] for s in rp["segments"])
    for role in ("reference", "voltage", "displacement"):
        assert rp["blocks"][role]["missing_samples"] == 0 and rp["blocks"][role]["duplicates"] == 0
    # the graph reproduces the uncompensated hysteresis (paper 19.23 %) and overshoot (paper 45.1 %) of x
    assert 14 < result["before"]["hysteresis_percent"]["x"] < 22
    assert 40 < result["before"]["overshoot_percent"]["x"] < 50
    # uncompensated circle: the open loop misses by tens of percent (hysteresis + creep + cross-coupling)
    assert 15 < result["tracking"]["circle20_open"]["rms_error_percent"] < 45


def test_demo_on_the_clocked_simulator(tmp_path):
    """The demo through the clocked simulator (FIFO, write-ahead, sensor latency, underruns), its device
    clock at 4× real time: every experiment segment complete and the same paper figures as in lockstep (the
    holds the device plays between experiments belong to no segment)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "demo", "--out", str(tmp_path), "--quiet",
                        "--only", "hyst_S0_x,step_SL_x,circle20_open", "--creep-duration", "2", "--clocked", "4",
                        "--domain-id", os.environ["ROS_DOMAIN_ID"]],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:] + "\n--- stdout:\n" + r.stdout[-2000:]
    assert "on the clocked simulator at 4× real time" in r.stdout
    assert "backend sim (clocked)" in (tmp_path / "logs" / "driver.log").read_text()
    result = json.loads((tmp_path / "analysis.json").read_text())
    rp = result["replay"]
    assert [s["name"] for s in rp["segments"]] == ["hyst_S0_x", "step_SL_x", "circle20_open"]
    assert all(s["complete"] for s in rp["segments"]), rp["segments"]
    assert rp["blocks"]["displacement"]["missing_samples"] == 0 and rp["blocks"]["displacement"]["duplicates"] == 0
    assert 14 < result["before"]["hysteresis_percent"]["x"] < 22
    assert 40 < result["before"]["overshoot_percent"]["x"] < 50
    assert 15 < result["tracking"]["circle20_open"]["rms_error_percent"] < 45
