"""An added hysteretic term with its own loop is hysteresis, not a gain: a Preisach relay plane whose density lies
off the symmetric line (shifted to positive voltages) added at the loop output must be named
``hysteresis_asymmetry``, while a pure per-axis gain error stays ``gain_mismatch``.  The truth is written here from
the physics with its own code, on the nominal chain of the benchmark's independent simulator
(bench/diagnosis/truth.py), not with the package's effect stages."""
from __future__ import annotations

import numpy as np

from bench.diagnosis import truth
from bench.synthetic.in_family import excitation
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose

from test_diagnosis_hys_classes import _chain, _run  # the nominal linear chain and noisy runs, shared


def _relay_plane(v, centre, spread, width, n_grid=14, vmax=160.0):
    """Σ μ(α, β)·γ_αβ(v) of one voltage column: relays switching up at α, down at β ≤ α (state ±1, all down at
    the start), on an n_grid² grid of the half plane; density a Gaussian in the relay's centre (α + β)/2 around
    ``centre`` [V] (``spread`` wide) times a decaying one in its width α − β (``width``), normalised to sum 1."""
    g = np.linspace(-vmax, vmax, n_grid)
    a, b = np.meshgrid(g, g, indexing="ij")
    keep = a >= b
    a, b = a[keep], b[keep]
    mu = np.exp(-0.5 * (((a + b) / 2 - centre) / spread) ** 2) * np.exp(-(a - b) / width)
    mu /= mu.sum()
    out = np.zeros(len(v))
    for ai, bi, mi in zip(a, b, mu):
        event = np.where(v >= ai, 1.0, np.where(v <= bi, -1.0, np.nan))
        event[0] = event[0] if np.isfinite(event[0]) else -1.0
        idx = np.where(np.isfinite(event), np.arange(len(v)), 0)
        np.maximum.accumulate(idx, out=idx)
        out += mi * event[idx]
    return out


def _preisach_term(nom, u, share, centre=60.0, spread=40.0, width=60.0):
    """The relay plane on each voltage, scaled to ``share`` of the nominal hysteresis output's swing, at the loop
    output (before the creep and the dynamics)."""
    term = np.zeros_like(u)
    for i in range(u.shape[1]):
        term[:, i] = nom["Dp"][i, i] * share * 150.0 * _relay_plane(u[:, i], centre, spread, width)
    return _chain(nom, term)


def test_added_asymmetric_preisach_loop_is_asymmetry_not_a_gain():
    fs = 2000.0
    cfg = load_config().with_sample_rate(fs)
    nom = truth.nominal_matrices(cfg)
    runs = []
    for j, kind in enumerate(("train", "test")):
        u = excitation(kind, fs, 10.0, seed=21 + j, amplitude=140.0)
        runs.append(_run(fs, u, truth.simulate(nom, [], u) + _preisach_term(nom, u, 0.06), 90 + j))
    res = diagnose(cfg, runs[0], runs[1], DiagnosisOptions(max_stack=1))
    h = res["heldout"]
    assert res["verdict"] == "hysteresis_asymmetry", \
        [(r["effect"], r["heldout_after_nrmse_percent"]) for r in res["ranking"]]
    assert h["after_nrmse_percent"] < 0.4 * h["before_nrmse_percent"], h


def test_pure_gain_error_stays_a_gain_with_a_preisach_candidate():
    fs = 2000.0
    cfg = load_config().with_sample_rate(fs)
    nom = truth.nominal_matrices(cfg)
    gain = np.array([1.06, 0.96])
    runs = []
    for j, kind in enumerate(("train", "test")):
        u = excitation(kind, fs, 10.0, seed=21 + j, amplitude=140.0)
        runs.append(_run(fs, u, truth.simulate(nom, [], u) * gain, 92 + j))
    res = diagnose(cfg, runs[0], runs[1], DiagnosisOptions(max_stack=1))
    assert res["verdict"] == "gain_mismatch", \
        [(r["effect"], r["heldout_after_nrmse_percent"]) for r in res["ranking"]]
