"""An amplifier that slews at different rates up and down (a driver whose source and sink currents differ) is named
``amplifier_slew_limit``, with both rates measured; a symmetric slew limit keeps its one-rate form.

The truth is written here: the commanded staircase (each DAC sample held) drives a current-limited amplifier
integrated within each sample (``bench.diagnosis.truth``'s ``current_limit``: dv/dt = S·tanh((u − v)/(S·τ)), S the
rising or the falling rate, the interval mean passed on), then the nominal chain; white sensor noise.  The
excitations move at up to 1 V per sample, so that both rates are reached."""
from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis import truth
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.diagnosis.candidates import FitContext, fit_candidate
from piezo_ff_ros.core.diagnosis.replay import Windows, simulate
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording.run import RunData

FS = 2000.0
DUR = 4.0
NOISE = 5e-9
#: the rivals the asymmetric slew was taken for (a roll-off, a rate-dependent loop) and the delay
CANDS = ("amplifier_slew_limit", "amplifier_bandwidth", "hysteresis_rate_dependence", "input_delay")


def _excitation(seed: int, amplitude: float = 120.0) -> np.ndarray:
    """A random multisine then triangles on each axis, bounded to 1 V per sample (as a trajectory generator does)."""
    rng = np.random.default_rng(seed)
    N = int(DUR * FS)
    t = np.arange(N) / FS
    u = np.zeros((N, 2))
    for ax in range(2):
        f = np.geomspace(0.5, 300.0, 30)
        s = (f ** -0.5 * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 2 * np.pi, f.size))).sum(axis=1)
        s *= amplitude / np.max(np.abs(s))
        half = t >= DUR / 2
        ft = rng.uniform(3.0, 8.0)
        s[half] = amplitude * 0.9 * (2 / np.pi) * np.arcsin(np.sin(2 * np.pi * ft * t[half]))
        u[:, ax] = s
    u[: int(0.05 * FS)] = 0.0
    out = np.empty_like(u)
    x = np.zeros(2)
    for k in range(N):
        x = x + np.clip(u[k] - x, -1.0, 1.0)
        out[k] = x
    return out


def _runs(cfg, rate_up: float, rate_down: float):
    nom = truth.nominal_matrices(cfg)
    lim = {"kind": "current_limit", "rate_up": rate_up, "rate_down": rate_down, "tau": 0.05 / FS}
    out = []
    for j, seed in enumerate((11, 12)):
        u = _excitation(seed)
        y = truth.simulate(nom, [lim], u) + NOISE * np.random.default_rng(60 + j).standard_normal(u.shape)
        out.append(RunData(np.arange(len(u)) / FS, u, y, ("x", "y")))
    return out


def test_slew_rates_that_differ_by_direction_are_named_amplifier_slew_limit():
    cfg = load_config().with_sample_rate(FS)
    up, down = 0.7 * FS, 0.3 * FS          # V/s: 0.7 and 0.3 V per sample against 1 V per sample commanded
    train, test = _runs(cfg, up, down)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=CANDS, max_stack=1))
    ranking = [(r["effect"], round(r["heldout_after_nrmse_percent"], 3), r["n_params"]) for r in res["ranking"]]
    assert res["verdict"] == "amplifier_slew_limit", ranking
    h = res["heldout"]
    assert h["after_nrmse_percent"] < 0.2 * h["before_nrmse_percent"], ranking
    p = next(r for r in res["ranking"] if r["effect"] == "amplifier_slew_limit")["params"]
    rise, fall = p["rate"]["value"], p["rate_down"]["value"]
    assert 0.5 * up < rise < 1.5 * up and 0.5 * down < fall < 1.5 * down, (rise, fall)


def _context(cfg, run):
    y_base = simulate(cfg, run.u, [])
    return FitContext(cfg, [], run.u, run.y, y_base, Windows.whole(len(run)))


def test_a_symmetric_slew_limit_keeps_the_one_rate_form():
    cfg = load_config().with_sample_rate(FS)
    train, _ = _runs(cfg, 0.5 * FS, 0.5 * FS)
    fit = fit_candidate("amplifier_slew_limit", _context(cfg, train))
    assert fit.n_params == 1 and "rate_down" not in fit.params, fit.params
    assert 0.35 * FS < fit.params["rate"] < 0.7 * FS, fit.params


@pytest.mark.parametrize("split", [1, 7, 333])
def test_the_asymmetric_slew_stage_is_block_split_invariant_and_slews_by_direction(split):
    cfg = load_config().with_sample_rate(FS)
    u = _excitation(5)
    eff = [("amplifier_slew_limit", {"rate": 0.8 * FS, "rate_down": 0.2 * FS})]
    stage = build_plant(cfg, eff).pre[0]
    whole = stage.process(u)
    stage.reset()
    parts = np.vstack([stage.process(u[i:i + split]) for i in range(0, len(u), split)])
    assert np.array_equal(whole, parts)
    d = np.diff(whole, axis=0)
    assert d.max() <= 0.8 + 1e-12 and d.min() >= -0.2 - 1e-12
    assert d.max() > 0.79 and d.min() < -0.19          # both limits are reached by this excitation
    assert whole[0].tolist() == u[0].tolist()           # the first sample passes (no previous value)
