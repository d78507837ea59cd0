"""`piezo-ff commission` through the ROS 2 graph (real DDS, separate processes), short durations."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
ROOT = Path(__file__).resolve().parents[1]


def test_commission_ros_short(tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--out", str(tmp_path), "--quiet",
                        "--creep-duration", "2", "--sine-frequency", "1", "--probe-timeout", "1",
                        "--only", "hyst_S0_x,hyst_SH_x,step_SL_x,step_T_x",
                        "--domain-id", os.environ["ROS_DOMAIN_ID"]],  # the session's isolated domain (conftest)
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:] + "\n--- stdout:\n" + r.stdout[-2000:]
    assert "TABLE I" in r.stdout
    result = json.loads((tmp_path / "commission.json").read_text())
    assert set(result["fit_percent"]) == {"hysteresis", "creep", "dynamics", "plant"}
    assert result["conditions"]["graph"] == "started sim graph"
    # the main diagonal is identified from the graph's recording, scored on held-out runs
    assert result["fit_percent"]["hysteresis"]["x"] > 95 and result["fit_percent"]["hysteresis"]["y"] > 95
    assert result["fit_percent"]["creep"]["xx"] > 90 and result["fit_percent"]["dynamics"]["xx"] > 90
    # the identified whole plant simulated from the held-out voltage record played through the graph
    assert result["fit_percent"]["plant"]["x"] >= 95 and result["fit_percent"]["plant"]["y"] >= 95
    assert result["timing_s"]["identify_hysteresis_refit"] > 0   # Bouc-Wen refitted once creep is known
    # the record was played in bypass (voltages = trajectory), all 38 s of it, tagged as never fitted on
    from piezo_ff_ros.core.recording.mcap_io import read_run

    run = read_run(tmp_path / "commission.mcap")
    seg = next(s for s in run.meta["segments"] if s["name"] == "plant_validation")
    assert seg["info"]["stage"] == "plant" and seg["info"]["role"] == "validation"
    u, ref = run.u[seg["start"]:seg["stop"]], run.reference[seg["start"]:seg["stop"]]
    assert len(u) == 760080 and np.array_equal(u, ref) and 100 < np.abs(u).max() <= 200
    # played sample-exactly at 20 kHz (a .npy table), no longer a 2 kHz hold of the preset
    from piezo_ff_ros.core.characterisation import CharacterisationSettings, plant_validation_trajectory

    _, want = plant_validation_trajectory(CharacterisationSettings()).sample(run.sample_rate)
    assert np.array_equal(ref[-want.shape[0]:], want)
    # the identified config loads as the compensator node loads it
    from piezo_ff_ros.core.config import load_config

    cfg = load_config(tmp_path / "config.yaml")
    assert cfg.vibration.controller is not None
    # before: the uncompensated graph (paper 19.23 % / 45.1 %); after: the identified cascade pushed live
    assert 14 < result["before"]["hysteresis_percent"]["x"] < 22
    assert 40 < result["before"]["overshoot_percent"]["x"] < 50
    assert result["after"]["hysteresis_percent"]["x"] < 3
    assert result["after"]["overshoot_percent"]["x"] < 5
    assert (tmp_path / "commission.mcap").stat().st_size > 0


def test_commission_refuses_a_running_driver_without_sensor(tmp_path):
    """A driver whose backend measures nothing (here the simulator with ``sim.sensor:=false``) publishes
    no ``displacement``; commissioning against it stops with one line naming the cause, before moving the stage.
    (The driver used to create its displacement publisher whatever the backend: it passed for a sensor.)"""
    from test_nodes_integration import Probe, start_node, stop_node

    driver = start_node("driver", "-p", "sim.sensor:=false", log_dir=tmp_path)
    try:
        # wait until the driver is configured (its /voltage subscription is made after the displacement publisher
        # a sensor would have), so that commissioning's own probe (5 s, its floor for "no /displacement") looks at
        # a configured driver instead of waiting out a longer timeout that covered the driver's start
        probe = Probe("sensorless_probe")
        try:
            probe.spin_until(lambda: probe.node.count_subscribers("/voltage") > 0, 90, "the driver configured")
        finally:
            probe.close()
        env = dict(os.environ)
        env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--out", str(tmp_path / "c"),
                            "--quiet", "--creep-duration", "2", "--probe-timeout", "5",
                            "--domain-id", os.environ["ROS_DOMAIN_ID"]],
                           env=env, capture_output=True, text=True, timeout=300)
    finally:
        assert stop_node(driver) == 0
    assert r.returncode != 0, r.stdout[-2000:]
    assert "Traceback" not in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert "sensor" in last, r.stderr[-2000:]
    assert "the device has no displacement sensor" in (tmp_path / "driver.log").read_text()
