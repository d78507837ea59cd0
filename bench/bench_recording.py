"""Recording benchmark (script, not a test): MCAP write and read throughput, bytes per second of a 20 kHz run.

    PYTHONPATH=. .venv/bin/python bench/bench_recording.py [--seconds 30] [--block 200]

Writes the 3 block topics (reference, voltage, displacement; 2 axes, float64) of a simulated run — a 20 µm, 10 Hz
circle through Dp⁻¹ into the nominal plant (realistic, smooth signals + 1 nm sensor-like noise on y) — with
:class:`McapRecorder` (CDR serialisation included), then reads it back with ``read_run``.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--block", type=int, default=200)
    ap.add_argument("--chunk-kib", type=int, default=512)
    args = ap.parse_args(argv)

    from piezo_ff_ros.core.config import load_config
    from piezo_ff_ros.core.models.plant import Plant
    from piezo_ff_ros.core.recording import blocks as B
    from piezo_ff_ros.core.recording.mcap_io import McapRecorder, block_qos_profile, read_run

    cfg = load_config()
    fs = cfg.sample_rate
    n = int(args.seconds * fs)
    t = np.arange(n) / fs
    ref = 20e-6 * np.column_stack([np.cos(2 * np.pi * 10 * t), np.sin(2 * np.pi * 10 * t)])
    dp = np.asarray(cfg.hysteresis.arrays()["Dp"], float)
    u = ref @ np.linalg.inv(dp).T
    y = Plant(cfg, noise_std=1e-9, seed=1).process(u)
    dt_ns = B.sample_period_ns(fs)
    t0 = time.time_ns() // dt_ns * dt_ns
    blocks = [(k0, B.stamp_for_index(k0, t0, dt_ns)) for k0 in range(0, n, args.block)]

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "bench.mcap")
        raw_bytes = 0
        start = time.perf_counter()
        with McapRecorder(path, chunk_size=args.chunk_kib * 1024,
                          metadata={"sample_rate": fs, "t0_ns": t0, "axes": list(cfg.axes)}) as rec:
            for role in ("reference", "voltage", "displacement"):
                rec.register_topic(f"/{role}", B.BLOCK_TYPE, [block_qos_profile()])
            for k0, stamp in blocks:
                for role, sig in (("reference", ref), ("voltage", u), ("displacement", y)):
                    raw = B.serialize_block(sig[k0:k0 + args.block], stamp)
                    raw_bytes += len(raw)
                    rec.write(f"/{role}", raw, stamp)
        t_write = time.perf_counter() - start
        size = os.path.getsize(path)
        start = time.perf_counter()
        run = read_run(path)
        t_read = time.perf_counter() - start
        assert np.array_equal(run.y, y) and np.array_equal(run.reference, ref) and np.array_equal(run.u, u)

    mb = raw_bytes / 1e6
    print(f"{args.seconds:g} s at {fs:g} Hz, 2 axes, 3 block topics, block {args.block}: "
          f"{len(blocks) * 3} messages, CDR {mb:.2f} MB")
    print(f"file {size / 1e6:.2f} MB = {size / args.seconds / 1e3:.0f} kB/s of run "
          f"(CDR {raw_bytes / args.seconds / 1e3:.0f} kB/s, zstd ratio {raw_bytes / size:.2f})")
    print(f"write (serialise + MCAP + zstd): {t_write:.2f} s = {mb / t_write:.1f} MB/s CDR, "
          f"real-time factor {args.seconds / t_write:.0f}x")
    print(f"read_run (decode + reassemble): {t_read:.2f} s = {mb / t_read:.1f} MB/s CDR, "
          f"real-time factor {args.seconds / t_read:.0f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
