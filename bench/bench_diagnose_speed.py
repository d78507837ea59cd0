"""Time ``piezo-ff diagnose`` on a 10-minute 20 kHz record through the CLI (target <= 20 s).

One record (12 M samples) of the paper's nominal plant with a hidden 0.5 ms input delay and 100 nm white noise
(the excitation of ``bench/bench_diagnosis.py``: growing loops / steps / multisine, then triangles / chirp / steps)
is written as a MATLAB ``.mat`` file (``t``, ``u``, ``y``; loading a 12 M-row CSV would time the CSV parser) and
diagnosed as a user would, ``python -m piezo_ff_ros diagnose --data rec.mat --json out.json`` (split 50/50, the
held-out half replayed after its history).  Printed: wall-clock, the child's CPU time (user + system, all
threads: the figure that does not depend on what else runs on the machine), the CLI's own phase timings, the
verdict and the fitted delay.  ``--profile OUT.prof`` also runs the diagnosis in-process under cProfile.

    PYTHONPATH=. .venv/bin/python bench/bench_diagnose_speed.py [--minutes 10] [--fs 20000] [--profile out.prof]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.synthetic.in_family import NOISE_STD, excitation  # noqa: E402
from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.models.effects import build_plant  # noqa: E402


def make_record(path: Path, minutes: float, fs: float, delay: float = 0.5e-3) -> int:
    """Write the record to ``path`` (.mat); returns its number of samples."""
    import scipy.io

    cfg = load_config().with_sample_rate(fs)
    half = minutes * 60.0 / 2
    u = np.concatenate([excitation("train", fs, half, seed=7), excitation("test", fs, half, seed=8)])
    plant = build_plant(cfg, [("input_delay", {"delay": delay})], noise_std=NOISE_STD, seed=5)
    y = np.concatenate([plant.process(u[i:i + 2_000_000]) for i in range(0, len(u), 2_000_000)])
    scipy.io.savemat(str(path), {"t": np.arange(len(u)) / fs, "u": u, "y": y})
    return len(u)


def _make_record_in_child(path: Path, minutes: float, fs: float) -> int:
    """:func:`make_record` in a separate process (this one stays small); returns the number of samples."""
    code = ("import sys; from pathlib import Path; from bench.bench_diagnose_speed import make_record; "
            f"print(make_record(Path({str(path)!r}), {minutes!r}, {fs!r}))")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=str(ROOT), capture_output=True, text=True,
                         check=True)
    return int(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="record length [min] (default 10)")
    ap.add_argument("--fs", type=float, default=20000.0, help="sample rate [Hz] (default 20000)")
    ap.add_argument("--profile", metavar="OUT.prof", help="also profile the diagnosis in-process (cProfile)")
    ap.add_argument("--json", metavar="OUT", help="write the timings")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as td:
        rec = Path(td) / "rec.mat"
        t0 = time.perf_counter()
        # written by a child process: on Linux a child's peak resident set (ru_maxrss) starts from its parent's
        # high-water mark at exec, so a bench that held the 12 M-sample record itself reported that (4125 MB up to
        # session 9) as the diagnosis' peak
        n = _make_record_in_child(rec, a.minutes, a.fs)
        print(f"record: {n} samples ({a.minutes:g} min at {a.fs:g} Hz) written in {time.perf_counter() - t0:.1f} s")
        out = Path(td) / "out.json"
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        t1 = time.perf_counter()
        # this child's own resource usage (os.wait4), not the sum over children (the record writer is one)
        with open(Path(td) / "stdout", "w") as fo, open(Path(td) / "stderr", "w+") as fe:
            proc = subprocess.Popen([sys.executable, "-m", "piezo_ff_ros", "diagnose", "--data", str(rec),
                                     "--json", str(out)], env=env, stdout=fo, stderr=fe)
            _, status, ru = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            fe.seek(0)
            stderr = fe.read()
        wall = time.perf_counter() - t1
        cpu = ru.ru_utime + ru.ru_stime
        system = ru.ru_stime
        peak_mb = ru.ru_maxrss / 1024          # its peak resident set (kB on Linux)
        if proc.returncode != 0:
            print(stderr[-2000:])
            return 1
        res = json.loads(out.read_text())
        delay = next(r for r in res["ranking"] if r["effect"] == "input_delay")["params"]["delay"]["value"]
        load = os.getloadavg()[0]
        print(f"piezo-ff diagnose --data: {wall:.1f} s wall-clock, {cpu:.1f} s CPU (user+sys, all threads), "
              f"diagnosis itself {res['seconds']:.1f} s; load average {load:.1f}; verdict {res['verdict']} "
              f"({res['confidence']}), delay {delay * 1e3:.4f} ms (truth 0.5 ms); target <= 20 s")
        print(f"  of which system time {system:.1f} s; peak resident memory {peak_mb:.0f} MB")
        summary = {"samples": n, "wall_seconds": wall, "cpu_seconds": cpu, "system_seconds": system,
                   "peak_rss_mb": peak_mb, "diagnose_seconds": res["seconds"],
                   "load_average": load, "verdict": res["verdict"], "delay_s": delay}
        if a.profile:
            import cProfile

            from piezo_ff_ros.core.diagnosis import diagnose
            from piezo_ff_ros.core.recording import load_run

            run = load_run(rec)
            cfg = load_config().with_sample_rate(a.fs)
            train, test = run.split(0.5)
            cProfile.runctx("diagnose(cfg, train, test, test_history=train)", globals(),
                            {"diagnose": diagnose, "cfg": cfg, "train": train, "test": test}, a.profile)
            print(f"profile written to {a.profile}")
    if a.json:
        Path(a.json).write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
