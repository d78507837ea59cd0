"""``python -m piezo_ff_ros.ros.launcher``: the whole graph from one command, recorded from its first sample."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
ROOT = Path(__file__).resolve().parents[1]


def test_launcher_records_a_finite_trajectory_from_its_first_sample_and_stops_when_it_has_played(tmp_path):
    """The trajectory starts once the recorder and every block writer have matched (a writer sends nothing to a
    reader it has not matched: the first blocks were lost for the recorder on a loaded machine), and a finite
    trajectory ends the run — the recording holds every sample of it on every block topic."""
    from piezo_ff_ros.core.recording.mcap_io import read_run

    spec = {"type": "sine", "amplitude": 2e-6, "frequency": 5.0, "axis": "x", "duration": 0.5}
    env = dict(os.environ)   # the session's own domain (conftest): nothing of ours outlives the test
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros.ros.launcher", "--out", str(tmp_path), "--mode",
                        "lockstep", "--duration", "120", "--trajectory", json.dumps(spec)],
                       env=env, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-3000:] + "\n--- stdout:\n" + r.stdout[-2000:]
    assert "trajectory finished" in r.stdout
    run = read_run(tmp_path / "run.mcap")
    n = int(0.5 * 20000)
    assert run.u.shape[0] == n and run.reference is not None
    for arr in (run.u, run.y, run.reference):
        assert not np.isnan(arr).any()
    assert np.isclose(np.max(run.reference[:, 0]), 2e-6, rtol=1e-3) and np.all(run.reference[:, 1] == 0.0)
    # the plotter's decimated topics are recorded too (Foxglove plots them from run.mcap)
    from mcap.reader import make_reader

    with open(tmp_path / "run.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    for topic in ("/plot_reference", "/plot_voltage", "/plot_displacement", "/plot_error"):
        assert counts.get(topic, 0) > 0, counts
    # the managed driver was started unconfigured and stepped by the launcher (configure, then activate)
    log = (tmp_path / "logs" / "driver.log").read_text()
    assert log.index("driver ready: unconfigured") < log.index("driver configured") < log.index("active:")
