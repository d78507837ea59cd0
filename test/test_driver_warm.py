"""The driver's kernels are compiled (or loaded from numba's cache) when it is configured, not on the first block:
a first compile takes longer than a clocked device's write-ahead.  Run in a fresh interpreter (nothing warm yet)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = """
import numpy as np
from piezo_ff_ros.core._jit import HAVE_NUMBA
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.hardware import DriverCore, DriverSettings
from piezo_ff_ros.core.hardware.simulated_device import LockstepSim
from piezo_ff_ros.core.kernels.limits import limit_run

cfg = load_config()
core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=cfg.n_axes, limits=cfg.limits),
                  LockstepSim(cfg.sample_rate, cfg.n_axes, None))
print("numba", HAVE_NUMBA)
print("before", len(limit_run.signatures))
core.warm()
print("after", len(limit_run.signatures))
st = core.status()
print("untouched", core.guard.u_last.tolist() == [0.0, 0.0] and st["samples_applied"] == 0 and not core.started)
"""


def test_warm_compiles_the_guard_kernel_and_leaves_the_core_untouched():
    r = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=300,
                       env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr[-2000:]
    out = dict(line.split(" ", 1) for line in r.stdout.strip().splitlines())
    if out["numba"] != "True":
        pytest.skip("numba not installed: nothing to compile")
    assert out["before"] == "0" and int(out["after"]) >= 1, out
    assert out["untouched"] == "True", out
