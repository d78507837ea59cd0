"""A creep whose strength grows with the level and relaxes with one retardation time (a Kelvin–Voigt element fed by
y·|y|, the voltage-dependent creep of the literature) is named ``creep_nonlinearity`` and its held-out gap closed,
although TRAIN holds no level long enough to show its whole relaxation.

The truth is written here from the benchmark's nominal pieces (``bench.diagnosis.truth``): the nominal Bouc-Wen
along the voltage path, the nominal linear creep, then the extra creep ``c·KV_τ(y_H·|y_H|/y_ref)`` added BEFORE the
nominal dynamics (as a creep of the stack is), then the dynamics; white sensor noise.  TRAIN is a multisine, steps
and triangles of a few seconds; TEST adds a slow ramp and a long hold."""
from __future__ import annotations

import math

import numpy as np
from scipy import signal

from bench.diagnosis import truth
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.diagnosis.candidates import FitContext, fit_candidate
from piezo_ff_ros.core.diagnosis.replay import Windows, simulate
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording.run import RunData

FS = 1000.0
DUR = 8.0
NOISE = 2e-9
CANDS = ("creep_nonlinearity", "thermal_drift", "gain_mismatch", "hysteresis_rate_dependence")


def _excitation(kind: str, seed: int, amplitude: float = 110.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    N = int(DUR * FS)
    t = np.arange(N) / FS
    u = np.zeros((N, 2))
    q = N // 3
    for ax in range(2):
        if kind == "train":
            f = np.geomspace(0.3, 100.0, 20)
            s = (f ** -0.5 * np.sin(2 * np.pi * f * t[:q, None] + rng.uniform(0, 2 * np.pi, f.size))).sum(axis=1)
            u[:q, ax] = amplitude * s / np.max(np.abs(s))
            levels = rng.uniform(-1, 1, 8) * amplitude
            u[q:2 * q, ax] = np.repeat(levels, -(-q // 8))[:q]
            u[2 * q:, ax] = amplitude * 0.8 * (2 / np.pi) * np.arcsin(np.sin(2 * np.pi * (1.5 + ax) * t[2 * q:]))
        else:
            lvl = amplitude * (0.9 if ax == 0 else -0.7)
            ramp = np.clip(t / (0.1 * DUR), 0, 1)
            u[:, ax] = lvl * ramp
            u[int(0.6 * N):, ax] = -0.5 * lvl
    out = np.empty_like(u)
    x = np.zeros(2)
    for k in range(N):            # a trajectory generator's slew bound: 1 V per sample
        x = x + np.clip(u[k] - x, -1.0, 1.0)
        out[k] = x
    return out


def _truth(nom, u, c, tau, yref):
    n = nom["n"]
    z = np.zeros(n)
    zz = np.zeros((n, n))
    yh = truth._bouc_wen(nom["Dp"], nom["A"], nom["B"], nom["Gamma"], zz, zz, np.ascontiguousarray(u), z, z, 1.0,
                         0.0, 1.0, 1.0, 0.0, nom["dt"], 0.0)
    yl = yh @ nom["K"].T + truth.lti_mimo(nom["Cr"], nom["dt"], yh)
    a = math.exp(-nom["dt"] / tau)
    yl = yl + c * signal.lfilter([1 - a], [1, -a], yh * np.abs(yh) / yref, axis=0)
    return truth.lti_mimo(nom["G_L"], nom["dt"], yl)


def _runs(cfg, c=0.1, tau=1.3, yref=20e-6):
    nom = truth.nominal_matrices(cfg)
    out = []
    for j, kind in enumerate(("train", "test")):
        u = _excitation(kind, 21 + j)
        y = _truth(nom, u, c, tau, yref) + NOISE * np.random.default_rng(80 + j).standard_normal(u.shape)
        out.append(RunData(np.arange(len(u)) / FS, u, y, ("x", "y")))
    return out


def test_level_dependent_creep_with_one_retardation_time_is_named_and_closed():
    cfg = load_config().with_sample_rate(FS)
    train, test = _runs(cfg)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=CANDS, max_stack=1))
    ranking = [(r["effect"], round(r["heldout_after_nrmse_percent"], 3), r["n_params"]) for r in res["ranking"]]
    assert res["verdict"] == "creep_nonlinearity", ranking
    h = res["heldout"]
    assert h["after_nrmse_percent"] < 0.25 * h["before_nrmse_percent"], (h, ranking)


def test_the_fitted_retardation_time_is_the_truths():
    cfg = load_config().with_sample_rate(FS)
    train, _ = _runs(cfg, tau=1.3)
    ctx = FitContext(cfg, [], train.u, train.y, simulate(cfg, train.u), Windows.whole(len(train)))
    fit = fit_candidate("creep_nonlinearity", ctx)
    assert "retardation" in fit.params, (fit.note, fit.params)
    assert 0.9 < fit.params["retardation"] < 1.8, fit.params


def test_the_kelvin_voigt_creep_stage_is_block_split_invariant():
    cfg = load_config().with_sample_rate(FS)
    y = np.cumsum(np.random.default_rng(3).standard_normal((3000, 2)), axis=0) * 1e-7
    eff = [("creep_nonlinearity", {"retardation": 0.2, "kv_gains": [0.01, -0.02], "kv_level_gains": [0.05, 0.03]})]
    stage = build_plant(cfg, eff).post[0]
    whole = stage.process(y)
    stage.reset()
    parts = np.vstack([stage.process(y[i:i + 777]) for i in range(0, len(y), 777)])
    assert np.array_equal(whole, parts)
    a = math.exp(-cfg.dt / 0.2)
    lp = lambda x: signal.lfilter([1 - a], [1, -a], x, axis=0)  # noqa: E731
    want = y + np.array([0.01, -0.02]) * lp(y) + np.array([0.05, 0.03]) * lp(y * np.abs(y) / 10e-6)
    assert np.allclose(whole, want, rtol=1e-12, atol=1e-18)
