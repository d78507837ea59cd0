"""Fixed cost of one call of the fused chain (cascade + plant, the real H∞ controller): ``Chain.process`` on a
1-sample block (almost all overhead: argument dispatch, set-up) and on a 200-sample block (node-sized), best of 5
runs of 5000 calls each, in µs per call.

    PYTHONPATH=. .venv/bin/python bench/bench_fused_call.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def main() -> int:
    import control

    from piezo_ff_ros.core.chain import Chain
    from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
    from piezo_ff_ros.core.config import load_config
    from piezo_ff_ros.core.models.plant import Plant
    from piezo_ff_ros.core.synthesis.hinf import synthesize_hinf

    cfg = load_config()
    k = control.ss(synthesize_hinf(cfg.dynamics.G_L, cfg.vibration).controller)
    chain = Chain([("cascade", CompensatorCascade(cfg, controller=(k.A, k.B, k.C, k.D))), ("plant", Plant(cfg))])
    rng = np.random.default_rng(0)
    for n in (1, 200):
        block = np.ascontiguousarray(rng.uniform(-1e-6, 1e-6, (n, 2)))
        chain.process(block)
        best = np.inf
        for _ in range(5):
            t0 = time.perf_counter()
            for _ in range(5000):
                chain.process(block)
            best = min(best, (time.perf_counter() - t0) / 5000)
        print(f"{n:4d}-sample block: {best * 1e6:.2f} µs per call ({best / n * 1e9:.1f} ns per sample)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
