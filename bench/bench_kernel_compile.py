"""First-use cost of the kernels specialised to a model's structure (``core/kernels/specialise.py``).

With an empty kernel cache (a fresh temporary ``PIEZO_FF_KERNEL_CACHE``), time the first ``process`` of: the plant
(fused pass), the same plant stage by stage (``process_with_taps``: the stages' own runs), a compensator cascade
with a 4th-order stand-in C(s) (fused), and the whole chain (cascade + plant, fused; its loops already compiled
above).  Then, in a second process on the now warm cache, the same calls again (what every later run pays: loading
compiled code).  Printed in seconds.

    PYTHONPATH=. .venv/bin/python bench/bench_kernel_compile.py
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _first_calls() -> dict[str, float]:
    import numpy as np

    from piezo_ff_ros.core.chain import Chain
    from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
    from piezo_ff_ros.core.config import load_config
    from piezo_ff_ros.core.models.plant import Plant

    cfg = load_config()
    z = np.zeros((1, 2))
    ctrl = (np.array([[-300.0, 0, 0, 0], [0, -2000.0, 0, 0], [0, 0, -500.0, 4000.0], [0, 0, -4000.0, -500.0]]),
            np.array([[300.0, 0.0], [0.0, 2000.0], [100.0, 50.0], [0.0, 80.0]]),
            np.array([[0.2, 0.0, 0.1, 0.05], [0.0, 0.1, 0.02, 0.1]]), np.array([[0.9, 0.01], [0.02, 0.85]]))
    out = {}
    for name, run in (("plant_fused", lambda: Plant(cfg).process(z)),
                      ("plant_stage_by_stage", lambda: Plant(cfg).process_with_taps(z)),
                      ("cascade_fused", lambda: CompensatorCascade(cfg, controller=ctrl).process(z)),
                      ("full_chain_fused", lambda: Chain([("cascade", CompensatorCascade(cfg, controller=ctrl)),
                                                          ("plant", Plant(cfg))]).process(z))):
        t0 = time.perf_counter()
        run()
        out[name] = round(time.perf_counter() - t0, 3)
    return out


def main() -> int:
    if os.environ.get("_PFF_COMPILE_CHILD"):
        print(json.dumps(_first_calls()))
        return 0
    cache = tempfile.mkdtemp(prefix="pff-kernels-")
    env = dict(os.environ, PIEZO_FF_KERNEL_CACHE=cache, _PFF_COMPILE_CHILD="1",
               PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    for label in ("empty kernel cache", "warm kernel cache"):
        res = subprocess.run([sys.executable, __file__], env=env, capture_output=True, text=True, check=True)
        print(f"{label}: " + ", ".join(f"{k} {v:.2f} s" for k, v in json.loads(res.stdout).items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
