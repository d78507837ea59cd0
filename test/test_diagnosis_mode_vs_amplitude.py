"""A linear mode is not amplitude-dependent dynamics: amplitude dependence is evidenced by what a linear resonance
cannot explain, so when the accepted linear mode already leaves the held-out residual at the white-noise floor, the
amplitude-dependent fit that contains it is neither promoted over it by a level shift of the linear fit on two
halves of TRAIN nor ranked above it for a gain on the noise-level rest.  When the linear mode leaves part of the gap
above the floor, the level shift still names amplitude dependence; the base-excited mode alone (not containing the
linear family) is ranked by its held-out fit.

The decision rule is checked on held-out residuals built to the situation seen on clean-room cases (a pole-zero
pair and an additive band-pass mode): both families remove the whole gap, the base-excited fit is better by a
paired z well above the tie threshold but by a negligible energy, and the linear family's resonance refitted on the
small- and large-motion halves of TRAIN "moved" (a significant level shift on runs of two levels).
"""
from __future__ import annotations

import types

import numpy as np

from piezo_ff_ros.core.diagnosis import stats
from piezo_ff_ros.core.diagnosis.candidates import FitResult
from piezo_ff_ros.core.diagnosis.decision import _judge
from piezo_ff_ros.core.diagnosis.scored import Scored

N = 20_000
SHIFT = {"significant": True, "one_level": False, "level_ratio": 3.0}


def _base_excited_fit(cubic, cubic_se, quad=(0.0, 0.0), quad_se=(1e-6, 1e-6)):
    params = {"form": "base_excited", "freq": 170.0, "damping": 0.04, "cubic": list(cubic),
              "quadratic_damping": list(quad), "participation": [1.0, 0.7]}
    stderr = {"form": None, "freq": 0.6, "damping": 0.003, "cubic": list(cubic_se),
              "quadratic_damping": list(quad_se), "participation": [0.5, 50.0]}
    # on the linear resonances found: the fit contains the linear mode family
    effects = [("unmodelled_mode", {}), ("amplitude_dependent_dynamics", params)]
    return FitResult("amplitude_dependent_dynamics", params, stderr, effects, 44, 1e-8,
                     extra={"level_shift": dict(SHIFT)})


def _mode_fit():
    return FitResult("unmodelled_mode", {"freq": 171.0, "damping": 0.024}, {}, [], 36, 1e-8)


def _scored(fit, r_before, r_after):
    return Scored(fit, float(np.sum(r_before ** 2)), float(np.sum(r_after ** 2)), 0.0, 1.0, 0.1, False, 0.0,
                  {"r_after": r_after})


def _gap_noise_rest(seed, rest):
    """Held-out residuals at 5 kHz: a 171 Hz resonant gap, white noise (1e-8 m) and a 37 Hz rest of amplitude
    ``rest`` [m].  Returns (gap, noise, rest, held) with ``held.r_before`` their sum."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / 5000.0
    gap = 1e-7 * np.sin(2 * np.pi * 171.0 * t)[:, None] * np.array([[0.2, 1.0]])
    noise = 1e-8 * rng.standard_normal((N, 2))
    rest_part = rest * np.sin(2 * np.pi * 37.0 * t)[:, None] * np.ones((1, 2))
    held = types.SimpleNamespace(r_before=gap + noise + rest_part, cfg=types.SimpleNamespace(dt=1 / 5000.0))
    return gap, noise, rest_part, held


def _case(ad_fit, left=0.0):
    """Held-out residuals: a resonant gap both families remove (the linear mode leaves ``left`` of it, the
    amplitude-dependent fit the same); the base-excited fit also removes a tiny part of the noise-level rest that the
    linear one leaves (paired z ≫ 2, energy < 1 % lower)."""
    gap, noise, tiny, held = _gap_noise_rest(seed=3, rest=1e-9)
    r_before = held.r_before
    r_mode = noise + tiny + left * gap
    r_ad = noise + 0.05 * tiny + left * gap
    mode, ad = _scored(_mode_fit(), r_before, r_mode), _scored(ad_fit, r_before, r_ad)
    scored = [ad, mode]
    _judge(scored, None, held, 1e-16, stats.z_critical(3))
    return scored, mode, ad


LINEAR_LIKE = ([1.8e-4, -9.7e-5], [1.1e-4, 7.2e-3])


def test_the_situation_is_the_one_described():
    """Both accepted; the base-excited fit beats the linear one by a paired z above the tie threshold."""
    scored, mode, ad = _case(_base_excited_fit(*LINEAR_LIKE))
    assert mode.accepted and ad.accepted
    psd = stats.noise_psd(mode.extra["r_after"])
    assert stats.paired_z(ad.extra["r_after"], mode.extra["r_after"], psd) > 2.0


def test_a_linear_mode_at_the_floor_is_not_outranked_by_a_level_shift():
    """The linear mode takes the whole gap above the floor: it ranks first (the level shift promoted the
    amplitude-dependent fit before)."""
    scored, mode, ad = _case(_base_excited_fit(*LINEAR_LIKE))
    assert scored[0] is mode, [s.fit.effect for s in scored]


def test_a_level_shift_still_names_amplitude_dependence_where_the_linear_mode_leaves_a_gap():
    """The linear mode and the amplitude-dependent fit both leave a third of the gap (far above the floor): the
    level shift on two motion levels names amplitude dependence."""
    scored, mode, ad = _case(_base_excited_fit(*LINEAR_LIKE), left=0.6)
    assert mode.extra["excess_shrink"] < 0.9
    assert scored[0] is ad, [s.fit.effect for s in scored]


def test_a_level_shift_on_one_motion_level_promotes_nothing():
    """The same with runs of one motion level: the linear mode stays first."""
    fit = _base_excited_fit(*LINEAR_LIKE)
    fit.extra["level_shift"]["one_level"] = True
    scored, mode, ad = _case(fit, left=0.6)
    assert scored[0] is mode, [s.fit.effect for s in scored]


def _judged_against_a_noise_level_rest(fit):
    """The linear mode and ``fit`` judged on a gap both take, over the noise and a small rest: the linear mode leaves
    the rest, ``fit`` 30 % of it.  Returns (ranking, mode, fit's scored)."""
    _, noise, rest, held = _gap_noise_rest(seed=4, rest=4e-9)
    mode, ad = _scored(_mode_fit(), held.r_before, noise + rest), _scored(fit, held.r_before, noise + 0.3 * rest)
    scored = [ad, mode]
    _judge(scored, None, held, 1e-16, stats.z_critical(3))
    return scored, mode, ad


def test_a_richer_fit_better_only_on_the_noise_level_rest_does_not_outrank_the_linear_mode():
    """No level shift; the amplitude-dependent fit beats the linear mode by a paired z ≫ 2 and 9 % of the held-out
    residual energy, but both leave the residual at the floor (the extra part takes < 1 % of the gap above it): the
    linear mode ranks first (the nesting rule ranked the richer fit first before)."""
    fit = _base_excited_fit(*LINEAR_LIKE)
    fit.extra["level_shift"] = None
    scored, mode, ad = _judged_against_a_noise_level_rest(fit)
    assert ad.sse_after < 0.95 * mode.sse_after
    assert ad.extra["excess_shrink"] - mode.extra["excess_shrink"] < 0.05
    assert scored[0] is mode, [s.fit.effect for s in scored]


def test_the_base_excited_mode_alone_is_a_rival_not_an_extension_of_the_linear_family():
    """The same residuals with the base-excited mode fitted alone (8 parameters, no linear resonances under it): it
    is a smaller model beside the linear family, not an extension of it, and its better held-out fit ranks it first."""
    fit = _base_excited_fit(*LINEAR_LIKE)
    fit.extra["level_shift"] = None
    fit.effects[:] = [("amplitude_dependent_dynamics", fit.params)]
    fit.n_params = 8
    scored, mode, ad = _judged_against_a_noise_level_rest(fit)
    assert scored[0] is ad, [s.fit.effect for s in scored]
