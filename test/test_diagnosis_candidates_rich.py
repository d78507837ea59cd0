"""The richer candidate forms: asymmetric rails, a relaxing hysteretic state, play-operator loop-width
terms and a cubic (instantaneous) stiffness of the modes.

Each one: the streaming stage is block-invariant; fitted on a training run of a plant that has it (the project's
own generator, the candidate's own parameterisation), it recovers its parameters; fitted on a null run (nominal
plant + noise) the extra part does not fire.
"""
from __future__ import annotations

import numpy as np
import pytest

from bench.synthetic.in_family import excitation
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.diagnosis.candidates import FitContext, fit_candidate
from piezo_ff_ros.core.diagnosis.fit_modes import _fit_level_filters
from piezo_ff_ros.core.diagnosis.replay import Windows, simulate
from piezo_ff_ros.core.models import effects as fx
from piezo_ff_ros.core.recording.run import RunData

FS = 5000.0
DUR = 8.0
NOISE = 30e-9


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


def _run(cfg, effects, kind="train", seed=0, amplitude=150.0, noise=NOISE):
    u = excitation(kind, FS, DUR, seed=seed, amplitude=amplitude)
    y = fx.build_plant(cfg, effects, noise_std=noise, seed=seed + 10).process(u)
    return RunData(np.arange(len(u)) / FS, u, y, ("x", "y"))


def _fit(cfg, name, run):
    ctx = FitContext(cfg, [], run.u, run.y, simulate(cfg, run.u, []), Windows.whole(len(run)))
    return fit_candidate(name, ctx)


def _null_verdict(cfg, name, amplitude=150.0):
    train, test = _run(cfg, [], "train", 3, amplitude), _run(cfg, [], "test", 4, amplitude)
    return diagnose(cfg, train, test, DiagnosisOptions(candidates=(name,)))["verdict"]


@pytest.mark.parametrize("effect", [
    ("amplifier_saturation", {"limit": 120.0, "lower_limit": 95.0}),
    ("hysteresis_rate_dependence", {"alpha": 0.1, "relaxation": 1.5e-3}),
    ("hysteresis_asymmetry", {"Delta1": [0.0, 0.0], "Delta2": [0.0, 0.0], "play_radii": [0.3e-6, 1e-6],
                              "play_gains": [[0.05, 0.02], [0.03, 0.04]]}),
    ("amplitude_dependent_dynamics", {"freq": [700.0], "damping": [0.05], "gains": [[[0.0, 0.0], [0.0, 0.0]]],
                                      "level_gains": [[0.0, 0.0]], "cubic_gains": [[0.02, -0.01]]}),
])
def test_stage_is_block_invariant_and_changes_the_output(cfg, effect):
    u = excitation("test", FS, 2.0, seed=1, amplitude=150.0)
    p = fx.build_plant(cfg, [effect])
    y = p.process(u)
    p.reset()
    y2 = np.vstack([p.process(u[:777]), p.process(u[777:778]), p.process(u[778:])])
    assert np.max(np.abs(y - y2)) <= 1e-12 * np.max(np.abs(y))  # the nominal chain's own rounding only
    assert np.max(np.abs(y - fx.build_plant(cfg, []).process(u))) > 1e-9


def test_bad_parameters_are_named(cfg):
    with pytest.raises(ValueError, match="lower_limit"):
        fx.build_plant(cfg, [("amplifier_saturation", {"limit": 100.0, "lower_limit": -1.0})])
    with pytest.raises(ValueError, match="relaxation"):
        fx.build_plant(cfg, [("hysteresis_rate_dependence", {"alpha": 0.0, "relaxation": float("nan")})])
    with pytest.raises(ValueError, match="play_radii"):
        fx.build_plant(cfg, [("hysteresis_asymmetry", {"Delta1": 0.0, "play_radii": [-1e-6], "play_gains": [0.1]})])


def test_asymmetric_rails_are_recovered(cfg):
    fit = _fit(cfg, "amplifier_saturation", _run(cfg, [("amplifier_saturation",
                                                        {"limit": 120.0, "lower_limit": 95.0})]))
    assert fit.params.get("lower_limit") is not None, fit.params
    assert fit.params["limit"] == pytest.approx(120.0, abs=2.0)
    assert fit.params["lower_limit"] == pytest.approx(95.0, abs=2.0)


def test_symmetric_rails_stay_one_limit(cfg):
    fit = _fit(cfg, "amplifier_saturation", _run(cfg, [("amplifier_saturation", {"limit": 110.0})]))
    assert fit.params.get("lower_limit") is None, fit.params
    assert fit.params["limit"] == pytest.approx(110.0, abs=2.0)


def test_relaxation_of_the_hysteretic_state_is_recovered(cfg):
    fit = _fit(cfg, "hysteresis_rate_dependence",
               _run(cfg, [("hysteresis_rate_dependence", {"alpha": 0.0, "relaxation": 1.5e-3})]))
    assert fit.params.get("relaxation") == pytest.approx(1.5e-3, rel=0.15), fit.params
    assert abs(fit.params["alpha"]) < 0.1


def test_loop_width_play_terms_are_recovered(cfg):
    """Truth = the candidate's own form with two of its own radii: the fitted play gains at those radii recover the
    truth's, and the fitted correction reproduces most of the truth's loop-width correction."""
    run = _run(cfg, [])
    y_nom = simulate(cfg, run.u, [])
    half = float(np.mean(0.5 * (y_nom.max(axis=0) - y_nom.min(axis=0))))
    radii = [0.15 * half, 0.4 * half]
    truth = ("hysteresis_asymmetry", {"Delta1": [0.0, 0.0], "Delta2": [0.0, 0.0], "play_radii": radii,
                                      "play_gains": [[0.04, 0.02], [0.02, 0.03]]})
    run = _run(cfg, [truth])
    fit = _fit(cfg, "hysteresis_asymmetry", run)
    r_fit = np.asarray(fit.params["play_radii"])
    assert r_fit[1:] == pytest.approx(radii, rel=0.01)  # the candidate's 0.15 and 0.4 shares of the stroke
    g = np.asarray(fit.params["play_gains"])
    assert g[1:] == pytest.approx(np.asarray(truth[1]["play_gains"]), rel=0.25, abs=0.004), g
    d_true = simulate(cfg, run.u, [truth]) - y_nom
    d_fit = simulate(cfg, run.u, fit.effects) - y_nom
    err = np.sqrt(np.mean((d_fit - d_true) ** 2)) / np.sqrt(np.mean(d_true ** 2))
    assert err < 0.5, err  # (the generalized Bouc-Wen terms, fitted first, take a little of it)


def test_cubic_stiffness_of_a_mode_is_recovered(cfg):
    truth = ("amplitude_dependent_dynamics", {"freq": [700.0], "damping": [0.05], "gains": [[[0.0, 0.0], [0.0, 0.0]]],
                                              "level_gains": [[0.0, 0.0]], "cubic_gains": [[0.03, -0.02]]})
    run = _run(cfg, [truth], noise=5e-9)
    ctx = FitContext(cfg, [], run.u, run.y, simulate(cfg, run.u, []), Windows.whole(len(run)))
    ctx.cache["modes"] = [(700.0, 0.05)]  # the resonance the mode search would hand over
    fit = fit_candidate("amplitude_dependent_dynamics", ctx)
    c = np.asarray(fit.params["cubic_gains"])[0]
    assert c[0] == pytest.approx(0.03, rel=0.1) and c[1] == pytest.approx(-0.02, rel=0.1), c


@pytest.mark.parametrize("name,amplitude", [("amplifier_saturation", 150.0), ("hysteresis_rate_dependence", 150.0),
                                            ("hysteresis_asymmetry", 150.0)])
def test_rich_candidates_do_not_fire_on_a_null(cfg, name, amplitude):
    assert _null_verdict(cfg, name, amplitude) == "none"


def test_rich_parts_stay_off_on_a_null_fit(cfg):
    run = _run(cfg, [], seed=5)
    assert _fit(cfg, "amplifier_saturation", run).params.get("lower_limit") is None
    assert _fit(cfg, "hysteresis_rate_dependence", run).params.get("relaxation") is None
    ctx = FitContext(cfg, [], run.u, run.y, simulate(cfg, run.u, []), Windows.whole(len(run)))
    ctx.cache["modes"] = [(700.0, 0.05)]
    # the level-modulated filter family's rich parts (the candidate may name the fewer-parameter base-excited form
    # on a null instead, by BIC on TRAIN)
    c = np.asarray(_fit_level_filters(ctx).params["cubic_gains"])
    assert np.all(np.abs(c) < 2e-3), c
