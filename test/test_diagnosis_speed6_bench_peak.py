"""The diagnose speed bench reports the diagnosis' own CPU and peak memory: not the largest of all its children's
(the record writer peaks far above a short diagnosis), and with the record written outside the bench process (on
Linux a child starts from its parent's high-water mark at exec)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from bench import bench_diagnose_speed

BALLAST_MB = 700


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ru_maxrss semantics of Linux")
def test_peak_and_cpu_are_the_diagnosis_own(tmp_path, monkeypatch):
    real = bench_diagnose_speed._make_record_in_child

    def fat_writer(path, minutes, fs):
        # a record writer far larger than the diagnosis of a short record, and busy for a while
        subprocess.run([sys.executable, "-c", f"import numpy as np; a = np.ones({BALLAST_MB * 131_072}); "
                        "[float((a * 1.0001).sum()) for _ in range(8)]"], check=True)
        return real(path, minutes, fs)

    monkeypatch.setattr(bench_diagnose_speed, "_make_record_in_child", fat_writer)
    out = tmp_path / "timings.json"
    assert bench_diagnose_speed.main(["--minutes", "0.05", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["samples"] == 60_000 and res["verdict"]
    assert 0 < res["system_seconds"] <= res["cpu_seconds"]
    assert 0 < res["peak_rss_mb"] < BALLAST_MB, f"reported {res['peak_rss_mb']:.0f} MB: the writer's peak"
