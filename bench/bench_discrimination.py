"""Discriminate, don't guess: ambiguous cases, the proposed experiment, and the verdict it settles.

Each scenario has a truth built here with scipy/numpy (not with the candidates' stages) and TRAIN/TEST runs whose
excitation cannot separate two explanations.  The script diagnoses TRAIN/TEST, checks that the result says the
verdict is ambiguous and proposes an experiment, "plays" the proposed trajectory through the truth (what the
trajectory node + driver would record), and diagnoses again with ``--discriminate`` semantics.

    cd <repo> && PYTHONPATH=. .venv/bin/python bench/bench_discrimination.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import scipy.signal

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose  # noqa: E402
from piezo_ff_ros.core.models.plant import Plant  # noqa: E402
from piezo_ff_ros.core.recording.run import RunData  # noqa: E402
from piezo_ff_ros.core.trajectories import from_dict  # noqa: E402

FS = 5000.0
NOISE = 50e-9


def _rolloff(fc):
    b, a = scipy.signal.bilinear([1.0], [1 / (2 * np.pi * fc), 1.0], fs=FS)

    def pre(u):
        return scipy.signal.lfilter(b, a, u, axis=0, zi=scipy.signal.lfilter_zi(b, a)[:, None] * u[:1])[0]
    return pre


def _delay(seconds):
    def pre(u):  # band-limited (FFT) fractional delay of the voltage, edges padded with the first/last values
        pad = 4096
        x = np.vstack([np.repeat(u[:1], pad, 0), u, np.repeat(u[-1:], pad, 0)])
        f = np.fft.rfftfreq(len(x), 1 / FS)
        X = np.fft.rfft(x, axis=0) * np.exp(-2j * np.pi * f * seconds)[:, None]
        return np.fft.irfft(X, n=len(x), axis=0)[pad:pad + len(u)]
    return pre


SCENARIOS = {
    "rolloff_400Hz_vs_delay": ("amplifier_bandwidth", _rolloff(400.0)),
    "rolloff_250Hz_vs_delay": ("amplifier_bandwidth", _rolloff(250.0)),
    "delay_0.35ms_vs_rolloff": ("input_delay", _delay(0.35e-3)),
}


def main() -> int:
    cfg = load_config().with_sample_rate(FS)
    plant = Plant(cfg)

    def truth(pre, u, seed):
        plant.reset()
        y = plant.process(pre(u))
        return y + NOISE * np.random.default_rng(seed).standard_normal(y.shape)

    def slow(pre, f, seed):
        t = np.arange(int(10 * FS)) / FS
        u = np.c_[120 * np.sin(2 * np.pi * f * t) + 20 * np.sin(2 * np.pi * 3.1 * f * t + seed),
                  100 * np.sin(2 * np.pi * 1.3 * f * t + 1)]
        return RunData(t, u, truth(pre, u, seed), ("x", "y"))

    opts = DiagnosisOptions(candidates=("input_delay", "amplifier_bandwidth", "gain_mismatch", "unmodelled_mode"),
                            max_stack=1)
    ok = 0
    for name, (expected, pre) in SCENARIOS.items():
        train, test = slow(pre, 2.0, 1), slow(pre, 3.0, 2)
        t0 = time.perf_counter()
        res = diagnose(cfg, train, test, opts)
        d = res["discrimination"]
        line = f"{name:26s} before: {res['verdict']} ({res['confidence']})"
        if not d or "experiment" not in d:
            print(line + "  — not flagged as ambiguous")
            ok += res["verdict"] == expected
            continue
        exp = d["experiment"]
        _, u = from_dict(exp["trajectory"]).sample(FS)
        run_c = RunData(np.arange(len(u)) / FS, u, truth(pre, u, 7), ("x", "y"))
        res2 = diagnose(cfg, train, test, opts, discriminate=run_c)
        dec = res2["discrimination"]["decided_on_run"]
        right = res2["verdict"] == expected
        ok += right
        print(f"{line}, ambiguous between {d['ambiguous_between']}; proposed '{exp['design']}' "
              f"{exp['duration_s']:.3g} s (expected difference {exp['expected_rms_difference_um']:.3g} µm, "
              f"z {exp['expected_z']:.3g}) -> after: {res2['verdict']} ({res2['confidence']}, paired z "
              f"{dec['paired_z']:.3g}) {'RIGHT' if right else 'WRONG'}  [{time.perf_counter() - t0:.0f} s]")
    print(f"{ok}/{len(SCENARIOS)} right after discrimination")
    return 0 if ok == len(SCENARIOS) else 1


if __name__ == "__main__":
    sys.exit(main())
