"""The diagnose speed bench reports the diagnosis' own CPU and peak memory: not the largest of all its children's
(the record writer peaks far above a short diagnosis), and with the record written outside the bench process (on
Linux a child starts from its parent's high-water mark at exec).

The bench runs here as it is run by hand: in a Python process of its own.  Run inside this pytest process — which
has grown past a gigabyte by the time a full suite reaches it — the CLI child would start from pytest's high-water
mark, and its reported peak would be pytest's, not the diagnosis' (a full run in a fresh clone: 1145 MB)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BALLAST_MB = 700

#: the bench with a record writer far larger than the diagnosis of a short record, and busy for a while
_DRIVER = f"""
import subprocess, sys
from bench import bench_diagnose_speed
real = bench_diagnose_speed._make_record_in_child

def fat_writer(path, minutes, fs):
    subprocess.run([sys.executable, "-c", "import numpy as np; a = np.ones({BALLAST_MB * 131_072}); "
                    "[float((a * 1.0001).sum()) for _ in range(8)]"], check=True)
    return real(path, minutes, fs)

bench_diagnose_speed._make_record_in_child = fat_writer
sys.exit(bench_diagnose_speed.main(["--minutes", "0.05", "--json", sys.argv[1]]))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ru_maxrss semantics of Linux")
def test_peak_and_cpu_are_the_diagnosis_own(tmp_path):
    out = tmp_path / "timings.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", _DRIVER, str(out)], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    res = json.loads(out.read_text())
    assert res["samples"] == 60_000 and res["verdict"]
    assert 0 < res["system_seconds"] <= res["cpu_seconds"]
    assert 0 < res["peak_rss_mb"] < BALLAST_MB, f"reported {res['peak_rss_mb']:.0f} MB: the writer's peak"
