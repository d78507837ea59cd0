"""CPU per sample of the hysteresis compensator on references far outside the stage's reach.

A unit mistake (1 m instead of 1 µm) with ``reference_limit`` emptied asks the Bouc-Wen inverse for megavolts; its
cost must not grow with the size of the mistake (docs/nodes.md, "A reference far outside the stage's reach").  For
each amplitude a fresh ``HysteresisCompensator`` (paper's tube, ±200 V, 500 V/sample) takes a 4000-sample block of
that reference (after a short ordinary start; the first amplitude also pays the kernels' compilation, so it is run
twice) and the process CPU per sample is printed.

    PYTHONPATH=. .venv/bin/python bench/bench_compensator_huge_reference.py
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def main() -> int:
    import numpy as np

    from piezo_ff_ros.core.compensators.hysteresis import HysteresisCompensator
    from piezo_ff_ros.core.config import load_config

    cfg = load_config()
    n = 4000
    wobble = 1e-7 * np.sin(np.arange(n) * 0.01)[:, None]
    print(f"load average {os.getloadavg()[0]:.1f}; hysteresis compensator, paper's tube, {n}-sample blocks")
    for amp in (10e-6, 10e-6, 1e-3, 1.0, 1e6, -1e6):
        hc = HysteresisCompensator(cfg.hysteresis, voltage_limit=200.0, slew_per_sample=500.0)
        hc.process(np.tile([10e-6, -5e-6], (10, 1)))
        ref = np.tile([amp, -0.3 * amp], (n, 1)) + wobble
        t = time.process_time()
        u = hc.process(ref)
        cpu = time.process_time() - t
        print(f"  {amp:>8g} m: {cpu / n * 1e6:8.1f} µs CPU per sample; last voltage {np.round(u[-1], 3)} V")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
