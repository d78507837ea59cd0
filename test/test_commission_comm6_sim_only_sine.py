"""``piezo-ff commission --sim-only`` characterises the hysteresis with ``--sine-frequency`` and ``--sine-periods``
(they were read by the ROS graph path only), and says in one line which ROS-graph-only options it ignores."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _commission(*args, timeout=600):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--sim-only", *args],
                          env=env, capture_output=True, text=True, timeout=timeout)


def test_sim_only_plays_the_sines_it_is_asked_for_and_warns_about_graph_options(tmp_path):
    """One 1 Hz period per sine at 20 kHz: three fitting runs of 20 000 samples each reach the identification
    (the paper's default, 0.1 Hz × 2 periods, is 1 200 000).  A sensor noise larger than the motion ends the
    command right after the hysteresis identification (refused), which keeps the test short."""
    r = _commission("--out", str(tmp_path / "c"), "--creep-duration", "2", "--noise-nm", "50000",
                    "--sine-frequency", "1", "--sine-periods", "1", "--step-um", "10", "--only", "step_T_x")
    lines = r.stderr.strip().splitlines()
    assert lines[0] == ("piezo-ff commission: warning: ROS graph options ignored with --sim-only: "
                        "--step-um, --only"), r.stderr[-2000:]
    assert any(line.endswith("hysteresis: 3 run(s), 60000 samples, subsampled ×6") for line in lines), \
        r.stderr[-3000:]
    assert r.returncode == 3 and lines[-1].startswith("piezo-ff commission: refused: hysteresis"), r.stderr[-2000:]


def test_sim_only_refuses_a_bad_sine_setting_in_one_line(tmp_path):
    for opt, value in (("--sine-periods", "0"), ("--sine-frequency", "-1")):
        r = _commission("--out", str(tmp_path / "c"), opt, value, timeout=120)
        assert r.returncode == 2, r.stderr[-2000:]
        assert r.stderr.strip().splitlines() == [
            f"piezo-ff commission: error: {opt} must be "
            + ("a positive number, got -1.0" if opt == "--sine-frequency" else ">= 1, got 0")]
