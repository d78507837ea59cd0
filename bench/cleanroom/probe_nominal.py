"""Probe the agreement of the clean-room nominal plant with the package's nominal replay (RESULTS.md, F1).

Null records (no effect, 2 nm white noise) at 1 kHz: random staircases with raw one-sample DAC steps, and the same
staircases with their edges spread over 3 ms and 10 ms. Each is diagnosed through the public CLI and only
``heldout.before_nrmse_percent`` is read. For comparison it also prints the NRMSE between this plant's Bouc-Wen
(RK4 along the path) and the same equations integrated with ONE explicit Euler step per record sample — a hypothesis
for the disagreement, computed here, not read from the package.

    PYTHONPATH=$PWD .venv/bin/python bench/cleanroom/probe_nominal.py [--keep DIR]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import truth  # noqa: E402


def nrmse(a, b):
    return 100.0 * np.linalg.norm(a - b) / np.linalg.norm(b - b.mean(axis=0))


def euler_bouc_wen(u):
    h = np.zeros(2)
    y = np.empty_like(u)
    for k in range(len(u)):
        y[k] = truth.DP @ u[k] - h
        if k + 1 < len(u):
            du = u[k + 1] - u[k]
            h = h + truth.A_BW @ du - truth.B_BW @ (np.abs(du) * h) - truth.G_BW @ (du * np.abs(h))
    return y


def staircase(seed, fs, smooth_s):
    rng = np.random.default_rng(seed)
    u = truth.exc_steps(rng, fs, 6.0, 150.0)
    if smooth_s:
        k = int(smooth_s * fs)
        w = np.ones(k) / k
        u = np.stack([np.convolve(u[:, a], w)[:len(u)] for a in range(2)], axis=1)
    return np.vstack([np.zeros((50, 2)), u])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--keep")
    a = ap.parse_args()
    root = Path(a.keep or tempfile.mkdtemp(prefix="cleanroom_probe_"))
    fs = 1000.0
    for smooth in (0.0, 0.003, 0.010):
        d = root / f"steps_{int(smooth * 1000)}ms"
        d.mkdir(parents=True, exist_ok=True)
        for name, seed in (("train", 1), ("test", 2)):
            u = staircase(seed, fs, smooth)
            y = truth.simulate(u, fs, truth.Effect())
            y = y + np.random.default_rng(seed).normal(0, 2e-9, y.shape)
            truth.write_csv(d / f"{name}.csv", np.arange(len(u)) / fs, u, y)
        u = staircase(2, fs, smooth)
        exact = truth.bouc_wen(np.ascontiguousarray(u), truth.DP, truth.A_BW, truth.B_BW, truth.G_BW, 0.0,
                               np.ones(len(u)))
        subprocess.run([sys.executable, "-m", "piezo_ff_ros", "diagnose", "--train", str(d / "train.csv"),
                        "--test", str(d / "test.csv"), "--json", str(d / "out.json"), "--quiet"],
                       check=True, capture_output=True)
        before = json.loads((d / "out.json").read_text())["heldout"]["before_nrmse_percent"]
        print(f"edges {smooth * 1000:4.0f} ms: package nominal vs clean-room plant {before:6.2f} % NRMSE; "
              f"one-Euler-step-per-sample Bouc-Wen vs RK4 {nrmse(euler_bouc_wen(u), exact):6.2f} %", flush=True)


if __name__ == "__main__":
    main()
