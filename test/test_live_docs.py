"""The documented commands work: the trajectory quoting of docs/nodes.md through a real shell,
the installed params file under the share directory, and the topic table's owners."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def docs(name: str = "nodes.md") -> str:
    path = ROOT / "docs" / name
    if not path.is_file():
        pytest.skip(f"{path} not in this tree")
    return path.read_text()


def test_documented_trajectory_quoting_starts_the_node(tmp_path):
    pytest.importorskip("rclpy")
    m = re.search(r'-p "trajectory:=\'(\{[^\']*\})\'"', docs())
    assert m, "docs/nodes.md lost its trajectory quoting example"
    cmd = f'exec "{sys.executable}" -m piezo_ff_ros.nodes.trajectory --ros-args {m.group(0)}'
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    log = tmp_path / "trajectory.log"
    with open(log, "wb") as out:
        p = subprocess.Popen(["bash", "-c", cmd], env=env, stdout=out, stderr=subprocess.STDOUT, cwd=tmp_path)
        deadline = time.monotonic() + 60
        while "trajectory ready" not in log.read_text() and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        p.send_signal(signal.SIGINT)
        p.wait(15)
    text = log.read_text()
    assert "trajectory ready: Circle" in text, text


def test_docs_name_the_installed_params_path_and_the_compensator_as_reference_point_reader():
    text = docs()
    assert "share/piezo_ff_ros/config/compensator.params.yaml" in text and "AMENT_PREFIX_PATH" in text
    topics = docs("topics.md")
    row = next(line for line in topics.splitlines() if line.startswith("| `reference_point`"))
    assert "you → compensator" in row
    setup = (ROOT / "setup.py").read_text()
    assert '("share/" + package_name + "/config", glob("config/*.yaml"))' in setup   # where the docs say it is
