"""read_run's memory on long recordings (found by bench/soak.py: reading a 30 min, 1 GB recording peaked at 8.2 GB).

The raw CDR messages of a block topic are released once decoded, and each topic's decoded blocks once placed in its
array, so that the peak stays within a small multiple of the arrays returned (it was 3.7× before).
"""
import tracemalloc

import numpy as np

from piezo_ff_ros.core.recording import blocks as B
from piezo_ff_ros.core.recording.mcap_io import McapRecorder, block_qos_profile, read_run

FS = 20000.0


def test_read_run_peak_memory_is_a_small_multiple_of_the_arrays(tmp_path):
    path = tmp_path / "long.mcap"
    n, blk = int(10 * FS), 200
    dt_ns = B.sample_period_ns(FS)
    t0 = 1_700_000_000 * 10**9
    rng = np.random.default_rng(0)
    sig = {r: rng.standard_normal((n, 2)) for r in ("reference", "voltage", "displacement")}
    with McapRecorder(path, metadata={"sample_rate": FS, "t0_ns": t0, "axes": ["x", "y"]}) as rec:
        for role in sig:
            rec.register_topic(f"/{role}", B.BLOCK_TYPE, [block_qos_profile()])
        for k0 in range(0, n, blk):
            stamp = B.stamp_for_index(k0, t0, dt_ns)
            for role, x in sig.items():
                rec.write(f"/{role}", B.serialize_block(x[k0:k0 + blk], stamp), stamp)
    del sig
    read_run(path)                      # imports and caches outside the measurement
    tracemalloc.start()
    try:
        run = read_run(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    out = run.u.nbytes + run.y.nbytes + run.reference.nbytes
    assert len(run) == n and run.meta["topics"]["/voltage"]["count"] == n // blk
    assert peak <= 2.5 * out, f"read_run peaked at {peak / out:.2f}× the arrays it returned"
