"""In-family diagnosis data: truth plants built by the diagnoser's own effect library (nominal + one hidden effect
+ white sensor noise) driven by two different excitations, for ``bench/bench_diagnosis.py`` and the tests.

This is NOT an independent benchmark (the truths are the candidates' own parameterisations): it measures in-family
fitting.  It lives under ``bench/`` so that no installed code depends on it; the independent, withheld-effect
benchmark is ``bench/diagnosis/``.

TRAIN: a slow sine with a growing amplitude, a staircase of held steps, and a band-limited random multisine.
TEST: triangles at two rates, a logarithmic chirp and steps at other levels; the axes are driven differently.
"""
from __future__ import annotations

import numpy as np

from piezo_ff_ros.core.config import PiezoConfig
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording.run import RunData

__all__ = ["excitation", "truth_cases", "make_runs", "NOISE_STD"]

NOISE_STD = 100e-9  #: sensor noise of the benchmark [m]


def _multisine(t, f_lo, f_hi, rms, rng, n_lines=40):
    f = np.geomspace(f_lo, f_hi, n_lines)
    ph = rng.uniform(0, 2 * np.pi, n_lines)
    x = np.sin(2 * np.pi * f[None, :] * t[:, None] + ph[None, :]).sum(axis=1)
    return x * rms / max(x.std(), 1e-12)


def excitation(kind: str, fs: float, duration: float, seed: int = 0, amplitude: float = 150.0) -> np.ndarray:
    """Voltages [N, 2] for ``kind`` 'train' or 'test' (see module docstring)."""
    rng = np.random.default_rng(seed)
    N = int(round(duration * fs))
    t = np.arange(N) / fs
    u = np.zeros((N, 2))
    T = duration
    for ax in range(2):
        if kind == "train":
            f0 = (1.0, 1.7)[ax]
            env = np.clip(t / (0.4 * T), 0.25, 1.0)
            s = amplitude * env * np.sin(2 * np.pi * f0 * t + ax)
            stairs = np.zeros(N)
            levels = rng.permutation(np.linspace(-0.8, 0.8, 7)) * amplitude
            seg = (t >= 0.45 * T) & (t < 0.75 * T)
            idx = np.flatnonzero(seg)
            for k, lev in enumerate(levels):
                a = idx[0] + k * len(idx) // len(levels)
                b = idx[0] + (k + 1) * len(idx) // len(levels)
                stairs[a:b] = lev
            s[seg] = stairs[seg]
            late = t >= 0.75 * T
            s[late] = 0.5 * amplitude * np.sin(2 * np.pi * 5 * t[late]) + _multisine(t[late], 2, 400, 0.12 * amplitude,
                                                                                      rng)
            s += _multisine(t, 0.5, 400, 0.03 * amplitude, rng)
        elif kind == "test":
            f1, f2 = (2.0, 15.0) if ax == 0 else (3.0, 11.0)
            tri = lambda f: 2 * np.abs(2 * ((t * f) % 1.0) - 1) - 1  # noqa: E731
            s = amplitude * 0.95 * tri(f1)
            mid = (t >= 0.3 * T) & (t < 0.5 * T)
            s[mid] = 0.6 * amplitude * tri(f2)[mid]
            ch = (t >= 0.5 * T) & (t < 0.7 * T)
            tc = t[ch] - t[ch][0]
            dur = 0.2 * T
            k = np.log(300.0 / 1.0) / dur
            s[ch] = 0.35 * amplitude * np.sin(2 * np.pi * 1.0 * (np.exp(k * tc) - 1) / k)
            late = t >= 0.7 * T
            idx = np.flatnonzero(late)
            levels = rng.permutation(np.array([-0.9, -0.5, 0.0, 0.3, 0.7, 1.0]) * amplitude * (0.9 if ax else 1.0))
            for j, lev in enumerate(levels):
                a = idx[0] + j * len(idx) // len(levels)
                b = idx[0] + (j + 1) * len(idx) // len(levels)
                s[a:b] = lev
            s += _multisine(t, 1.0, 400, 0.02 * amplitude, rng)
        else:
            raise ValueError(f"excitation kind must be 'train' or 'test', got {kind!r}")
        u[:, ax] = s
    return u


def truth_cases() -> list[dict]:
    """Every effect at a clear and a subtle magnitude, plus null cases: ``{'name', 'effect', 'params', 'level'}``."""
    E = [
        ("hysteresis_asymmetry", {"Delta1": [0.004, 0.003], "Delta2": [0.0, 0.0]},
         {"Delta1": [0.0015, 0.0012], "Delta2": [0.0, 0.0]}),
        ("hysteresis_rate_dependence", {"alpha": 0.5}, {"alpha": 0.15}),
        ("creep_nonlinearity", {"gamma": [0.01, 0.012], "beta": 1.0}, {"gamma": [0.004, 0.004], "beta": 0.5}),
        ("thermal_drift", {"amplitudes": [0.6e-6, -0.4e-6], "time_constant": 8.0},
         {"amplitudes": [0.2e-6, -0.12e-6], "time_constant": 8.0}),
        ("input_delay", {"delay": 1.0e-3}, {"delay": 0.3e-3}),
        ("amplifier_slew_limit", {"rate": 1.5e4}, {"rate": 6e4}),
        ("amplifier_saturation", {"limit": 110.0}, {"limit": 135.0}),
        ("amplifier_bandwidth", {"cutoff": 150.0}, {"cutoff": 600.0}),
        ("unmodelled_mode", {"freq": 300.0, "damping": 0.03, "gains": [1.0, 0.6]},
         {"freq": 300.0, "damping": 0.03, "gains": [0.3, 0.2]}),
        ("gain_mismatch", {"gains": [1.05, 0.97]}, {"gains": [1.015, 0.99]}),
    ]
    cases = []
    for name, clear, subtle in E:
        cases.append({"name": f"{name}/clear", "effect": name, "params": clear, "level": "clear"})
        cases.append({"name": f"{name}/subtle", "effect": name, "params": subtle, "level": "subtle"})
    for k in range(4):
        cases.append({"name": f"null/{k}", "effect": "none", "params": {}, "level": "null", "seed": k})
    return cases


def make_runs(cfg: PiezoConfig, case: dict, duration: float = 20.0, seed: int = 0,
              noise_std: float = NOISE_STD) -> tuple[RunData, RunData]:
    """TRAIN and TEST runs of the truth plant of ``case`` (different excitations and noise seeds)."""
    fs = cfg.sample_rate
    effects = [] if case["effect"] == "none" else [(case["effect"], case["params"])]
    seed = seed + 100 * int(case.get("seed", 0))
    runs = []
    for j, kind in enumerate(("train", "test")):
        u = excitation(kind, fs, duration, seed=seed + j)
        plant = build_plant(cfg, effects, noise_std=noise_std, seed=seed + 10 + j)
        y = plant.process(u)
        t = np.arange(len(u)) / fs
        runs.append(RunData(t=t, u=u, y=y, axes=tuple(cfg.axes), meta={"source": f"synthetic:{case['name']}:{kind}"}))
    return runs[0], runs[1]
