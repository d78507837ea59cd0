"""A linear mode is not amplitude-dependent dynamics: a base-excited nonlinear mode whose cubic spring and quadratic
damping are within noise of zero on TRAIN is a linear resonance (it explains the same at every amplitude), so it
neither ranks above an accepted linear mode nor is promoted over it by a level shift of the linear fit.

The decision rule is checked on held-out residuals built to the situation seen on clean-room cases (a pole-zero
pair and an additive band-pass mode): both families remove the whole gap, the base-excited fit is better by a
paired z well above the tie threshold but by a negligible energy, and the linear family's resonance refitted on the
small- and large-motion halves of TRAIN "moved" (a significant level shift on runs of two levels).
"""
from __future__ import annotations

import types

import numpy as np
import pytest

from piezo_ff_ros.core.diagnosis import stats
from piezo_ff_ros.core.diagnosis.candidates import FitResult
from piezo_ff_ros.core.diagnosis.decision import _judge, base_excited_is_linear
from piezo_ff_ros.core.diagnosis.scored import Scored

N = 20_000
SHIFT = {"significant": True, "one_level": False, "level_ratio": 3.0}


def _base_excited_fit(cubic, cubic_se, quad=(0.0, 0.0), quad_se=(1e-6, 1e-6)):
    params = {"form": "base_excited", "freq": 170.0, "damping": 0.04, "cubic": list(cubic),
              "quadratic_damping": list(quad), "participation": [1.0, 0.7]}
    stderr = {"form": None, "freq": 0.6, "damping": 0.003, "cubic": list(cubic_se),
              "quadratic_damping": list(quad_se), "participation": [0.5, 50.0]}
    return FitResult("amplitude_dependent_dynamics", params, stderr, [], 44, 1e-8,
                     extra={"level_shift": dict(SHIFT)})


def _mode_fit():
    return FitResult("unmodelled_mode", {"freq": 171.0, "damping": 0.024}, {}, [], 36, 1e-8)


def _scored(fit, r_before, r_after):
    return Scored(fit, float(np.sum(r_before ** 2)), float(np.sum(r_after ** 2)), 0.0, 1.0, 0.1, False, 0.0,
                  {"r_after": r_after})


def _case(ad_fit):
    """Held-out residuals: a resonant gap both families remove; the base-excited fit also removes a tiny part of
    the noise-level rest that the linear one leaves (paired z ≫ 2, energy 0.5 % lower)."""
    rng = np.random.default_rng(3)
    t = np.arange(N) / 5000.0
    gap = 1e-7 * np.sin(2 * np.pi * 171.0 * t)[:, None] * np.array([[0.2, 1.0]])
    noise = 1e-8 * rng.standard_normal((N, 2))
    tiny = 1e-9 * np.sin(2 * np.pi * 37.0 * t)[:, None] * np.ones((1, 2))
    r_before = gap + noise + tiny
    r_mode = noise + tiny
    r_ad = noise + 0.05 * tiny
    held = types.SimpleNamespace(r_before=r_before, cfg=types.SimpleNamespace(dt=1 / 5000.0))
    mode, ad = _scored(_mode_fit(), r_before, r_mode), _scored(ad_fit, r_before, r_ad)
    scored = [ad, mode]
    _judge(scored, None, held, 1e-16, stats.z_critical(3))
    return scored, mode, ad


def test_the_situation_is_the_one_described():
    """Both accepted; the base-excited fit beats the linear one by a paired z above the tie threshold."""
    scored, mode, ad = _case(_base_excited_fit([1.8e-4, -9.7e-5], [1.1e-4, 7.2e-3]))
    assert mode.accepted and ad.accepted
    psd = stats.noise_psd(mode.extra["r_after"])
    assert stats.paired_z(ad.extra["r_after"], mode.extra["r_after"], psd) > 2.0


def test_base_excited_fit_without_a_significant_nonlinearity_does_not_outrank_a_linear_mode():
    """Cubic and quadratic coefficients all within noise of zero: the linear mode ranks first (it was the
    base-excited fit, promoted by the level shift, before)."""
    scored, mode, ad = _case(_base_excited_fit([1.8e-4, -9.7e-5], [1.1e-4, 7.2e-3]))
    assert scored[0] is mode, [s.fit.effect for s in scored]


def test_base_excited_fit_with_a_significant_cubic_spring_keeps_its_place():
    """The same residuals with a cubic spring 30 standard errors from zero: amplitude dependence is shown on TRAIN
    and the level shift stands — the base-excited fit ranks first."""
    scored, mode, ad = _case(_base_excited_fit([3.0e-3, -9.7e-5], [1.0e-4, 7.2e-3]))
    assert scored[0] is ad, [s.fit.effect for s in scored]


@pytest.mark.parametrize("cubic, se, linear", [([1e-4, 0.0], [1e-4, 1e-4], True), ([1e-2, 0.0], [1e-4, 1e-4], False),
                                               ([1e-4, 0.0], [0.0, 1e-4], False)])
def test_linear_form_test(cubic, se, linear):
    """Linear when every nonlinear coefficient is within the Bonferroni two-sided z of zero; missing or zero standard
    errors never call a fit linear."""
    assert base_excited_is_linear(_base_excited_fit(cubic, se)) is linear


def test_a_linear_base_excited_fit_is_not_the_runner_up_of_a_linear_mode_verdict():
    """Beside a linear-mode verdict, a base-excited fit with no nonlinearity told from zero is that mode, not a
    rival: it is neither the runner-up (whose paired z sets the confidence) nor a tie."""
    from piezo_ff_ros.core.diagnosis.decision import _ties
    scored, mode, ad = _case(_base_excited_fit([1.8e-4, -9.7e-5], [1.1e-4, 7.2e-3]))
    j = types.SimpleNamespace(scored=scored, psd=stats.noise_psd(mode.extra["r_after"]), zc=stats.z_critical(3))
    runner, tie_z, ties = _ties(mode, j)
    assert runner is not ad and ad not in ties
