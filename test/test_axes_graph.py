"""The whole chain on stages of one and three axes: `piezo-ff commission` through the ROS 2 node graph (real DDS,
separate processes) → its recording → `piezo-ff analyze`, short durations."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name, axes, only", [
    ("single_stack", ("x",), "hyst_S0_x,hyst_SH_x,step_SL_x,step_T_x"),
    ("xyz_tube", ("x", "y", "z"), "hyst_S0_x,hyst_S0_z,step_SL_z,step_T_x,step_T_z,circle20_T"),
])
def test_commission_graph_recording_analyze(tmp_path, name, axes, only):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    # one period per hysteresis characterisation sine (default two): the loop is identified from it just as well
    # (held-out fit ≈ 99.2–99.9 % on the XYZ tube either way) on half the samples, the Bouc-Wen fit's cost
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--out", str(tmp_path), "--quiet",
                        "--config", str(ROOT / "config" / f"{name}.yaml"), "--creep-duration", "2",
                        "--sine-frequency", "1", "--sine-periods", "1", "--probe-timeout", "1", "--only", only,
                        "--domain-id", os.environ["ROS_DOMAIN_ID"]],
                       env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:] + "\n--- stdout:\n" + r.stdout[-2000:]
    result = json.loads((tmp_path / "commission.json").read_text())
    pairs = {o + i for o in axes for i in axes}
    assert set(result["fit_percent"]["hysteresis"]) == set(axes) and set(result["fit_percent"]["dynamics"]) == pairs
    assert min(result["fit_percent"]["hysteresis"].values()) > 95
    assert min(result["fit_percent"]["dynamics"][a + a] for a in axes) > 90
    from piezo_ff_ros.core.config import load_config

    cfg = load_config(tmp_path / "config.yaml")
    assert cfg.axes == axes and cfg.name == f"{name}_identified" and cfg.vibration.controller is not None
    # the recording: every axis, the held-out voltage record played sample-exactly in bypass
    from piezo_ff_ros.core.characterisation import CharacterisationSettings, plant_validation_trajectory
    from piezo_ff_ros.core.recording.mcap_io import read_run

    run = read_run(tmp_path / "commission.mcap")
    assert run.axes == axes
    seg = next(s for s in run.meta["segments"] if s["name"] == "plant_validation")
    u, ref = run.u[seg["start"]:seg["stop"]], run.reference[seg["start"]:seg["stop"]]
    _, want = plant_validation_trajectory(CharacterisationSettings(), axes).sample(run.sample_rate)
    assert np.array_equal(ref[-want.shape[0]:], want) and np.array_equal(u, ref)
    # analyze reads the same tables from the recording as commission read while verifying
    out = tmp_path / "analysis.json"
    a = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "analyze", str(tmp_path / "commission.mcap"),
                        "--json", str(out)], env=env, capture_output=True, text=True, timeout=300)
    assert a.returncode == 0, a.stderr[-3000:]
    analysis = json.loads(out.read_text())
    assert analysis["before"] == result["before"] and analysis["after"] == result["after"]
    assert set(analysis["before"]["hysteresis_percent"]) == set(axes)
    assert 10 < analysis["before"]["hysteresis_percent"][axes[-1]] < 25
    assert analysis["after"]["overshoot_percent"][axes[-1]] < 5
    if len(axes) == 3:
        cc = analysis["cross_coupling_pairs_percent"]
        assert cc == result["cross_coupling_pairs_percent"]
        assert abs(cc["before"]["xz"]) < 0.05 and abs(cc["after"]["zx"]) < 0.05   # z decoupled
        assert "x←z" in a.stdout and "circle20_T" in analysis["tracking"]
    else:
        assert "one axis: no cross-coupling" in a.stdout


def test_commission_refuses_a_driver_of_other_axes(tmp_path):
    """A running driver loaded with the XYZ tube's config, commissioning started from the paper's 2-axis config:
    refused in one line naming both axis sets, before anything moves (no recording written)."""
    from test_nodes_integration import start_node, stop_node

    driver = start_node("driver", "-p", f"config_file:={ROOT / 'config' / 'xyz_tube.yaml'}", log_dir=tmp_path)
    try:
        env = dict(os.environ)
        env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--out", str(tmp_path / "c"),
                            "--quiet", "--creep-duration", "2", "--probe-timeout", "10",
                            "--domain-id", os.environ["ROS_DOMAIN_ID"]],
                           env=env, capture_output=True, text=True, timeout=300)
    finally:
        assert stop_node(driver) == 0
    assert r.returncode == 2, r.stderr[-2000:]
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in r.stderr
    assert "['x', 'y']" in err[0] and "['x', 'y', 'z']" in err[0], err
    assert not (tmp_path / "c" / "commission.mcap").exists()
