"""The README's "Using it on a rig" block for the environment the setup creates runs as written: bash, the venv's
console scripts and `piezo-ff` helpers (no `ros2` CLI), ending with a recording that `analyze` reads.  Only the
ROS_DOMAIN_ID is replaced by the test session's own (parallel runs must not meet)."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
ROOT = Path(__file__).resolve().parents[1]


def _rig_block() -> str:
    text = (ROOT / "README.md").read_text()
    section = text[text.index("### In the environment the setup creates"):]
    return re.search(r"```bash\n(.*?)```", section, re.S).group(1)


def test_readme_rig_block_runs_as_written(tmp_path):
    block = _rig_block()
    assert "ros2 " not in block and "source .venv/bin/activate" in block
    venv = Path(sys.prefix)
    if not (venv / "bin" / "activate").exists() or not (venv / "share" / "piezo_ff_ros").is_dir():
        pytest.skip("not running from the venv scripts/setup_env.sh creates (pip install .)")
    (tmp_path / ".venv").symlink_to(venv)
    script = block.replace("ROS_DOMAIN_ID=42", f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}")
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT)          # this tree's code behind the venv's console scripts
    # its own session: whatever the block leaves running (bash -e stops at a failed line) is ended by group id
    with open(tmp_path / "out.txt", "w") as out, open(tmp_path / "err.txt", "w") as err:
        p = subprocess.Popen(["bash", "-euo", "pipefail", "-c", script], cwd=tmp_path, env=env, text=True,
                             stdout=out, stderr=err, start_new_session=True)
        try:
            p.wait(timeout=600)
        finally:
            try:
                os.killpg(p.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
            if p.poll() is None:
                p.kill()
                p.wait()
    r = subprocess.CompletedProcess(p.args, p.returncode, (tmp_path / "out.txt").read_text(),
                                    (tmp_path / "err.txt").read_text())
    problems = [ln for ln in r.stderr.splitlines() if "[INFO]" not in ln and "[WARN]" not in ln]
    assert r.returncode == 0, r.stdout[-3000:] + "\n--- stderr (no INFO/WARN):\n" + "\n".join(problems[-40:])
    assert "active" in r.stdout and "holding [1e-05, 0.0]" in r.stdout
    assert "vibration.t_r: " in r.stdout and "config_yaml: " in r.stdout
    assert "tracking error (whole run" in r.stdout and (tmp_path / "run.mcap").stat().st_size > 0
    assert r.stdout.count("point:") == 2                      # two plot_error messages echoed
