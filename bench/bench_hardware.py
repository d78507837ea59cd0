"""Benchmark of the hardware layer (a script, not a test).

1. lockstep throughput: blocks through DriverCore + LockstepSim (the paper's plant) vs the bare guard + plant the
   old driver ran — what the contract layer costs per sample;
2. clocked write-ahead sweep: ``rig-check``'s paced stream on the clocked simulator for each (block size,
   write-ahead) pair for ``--seconds`` s: device underruns, starved samples, smallest FIFO margin.

    PYTHONPATH=. .venv/bin/python bench/bench_hardware.py [--seconds 10] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.hardware import DriverCore, DriverSettings, LockstepSim  # noqa: E402
from piezo_ff_ros.core.models.plant import Plant  # noqa: E402
from piezo_ff_ros.core.safety import SafeRampConfig, VoltageGuard  # noqa: E402


def lockstep_throughput(cfg, block: int, seconds: float = 20.0) -> dict:
    fs = cfg.sample_rate
    n = int(seconds * fs) // block * block
    k = np.arange(n)
    u = 50 * np.column_stack([np.sin(2 * np.pi * 5 * k / fs), np.cos(2 * np.pi * 5 * k / fs)])

    def bare():
        plant, guard = Plant(cfg), VoltageGuard(cfg.limits, 2, fs)
        plant.process(np.zeros((1, 2)))
        plant.reset()
        t = time.perf_counter()
        for i in range(0, n, block):
            plant.process(guard.apply(u[i:i + block]))
        return time.perf_counter() - t

    def core():
        plant = Plant(cfg)
        plant.process(np.zeros((1, 2)))
        plant.reset()
        c = DriverCore(DriverSettings(sample_rate=fs, n_axes=2, limits=cfg.limits), LockstepSim(fs, 2, plant),
                       now=lambda: 0.0)
        c.start()
        t = time.perf_counter()
        for i in range(0, n, block):
            c.on_block(i * c.period_ns, u[i:i + block])
        return time.perf_counter() - t

    tb = min(bare() for _ in range(3))
    tc = min(core() for _ in range(3))
    return {"block": block, "samples": n, "bare_s": tb, "core_s": tc, "core_rtf": seconds / tc,
            "bare_rtf": seconds / tb, "overhead_us_per_block": 1e6 * (tc - tb) / (n / block)}


def clocked_sweep(cfg, seconds: float) -> list:
    from piezo_ff_ros.cli.rig_check import rig_check

    out = []
    for block, wa in ((200, 0.02), (200, 0.05), (2000, 0.2)):
        rep = rig_check(cfg, "sim", {}, duration=seconds, block_size=block, write_ahead=wa,
                        test_voltage=20.0, ramp=SafeRampConfig(), say=lambda m: None)
        w = rep["checks"].get("write_ahead", {})
        out.append({"block": block, "write_ahead_s": wa, "ok": rep["ok"], "underruns": rep["underruns"],
                    "starved_samples": w.get("starved_samples"), "late_samples": w.get("late_samples"),
                    "min_margin_samples": w.get("min_margin_samples"), "sample_rate_hz": rep["sample_rate_hz"],
                    "safe_ramp_max_step_v": rep["safe_ramp_max_step_v"]})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds per clocked run")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    cfg = load_config()
    res = {"lockstep": [lockstep_throughput(cfg, b) for b in (200, 2000)], "clocked": clocked_sweep(cfg, a.seconds)}
    for r in res["lockstep"]:
        print(f"lockstep block {r['block']:5d}: DriverCore {r['core_rtf']:7.1f}× real time, bare guard+plant "
              f"{r['bare_rtf']:7.1f}×, contract overhead {r['overhead_us_per_block']:.0f} µs/block")
    for r in res["clocked"]:
        print(f"clocked block {r['block']:5d}, write-ahead {r['write_ahead_s'] * 1e3:4.0f} ms: underruns "
              f"{r['underruns']}, starved {r['starved_samples']}, late {r['late_samples']}, min margin "
              f"{r['min_margin_samples']} samples, clock {r['sample_rate_hz']:.1f} Hz, ok {r['ok']}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
