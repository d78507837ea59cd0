"""The exact Bouc-Wen path increment: a large voltage step agrees with a very finely sub-stepped integration (sign
changes of h included), h is a continuous function of the step across the one-step/exact boundary, the generic and
two-axis kernels give the same numbers, and the compensator inverts the model on large 20 kHz steps to rounding."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from piezo_ff_ros.core._jit import njit
from piezo_ff_ros.core.compensators.hysteresis import HysteresisCompensator
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.kernels import bouc_wen as kb
from piezo_ff_ros.core.models.bouc_wen import BoucWenModel


@pytest.fixture(scope="module")
def paper():
    return load_config().hysteresis


def _generalized(cfg):
    return dataclasses.replace(cfg, Delta1=((0.0012, 0.0001), (0.0, -0.0008)),
                               Delta2=((-0.0005, 0.0), (0.0001, 0.0007))).validate()


def _rk4_path(a, h, du, m):
    """h after the straight step ``du`` by ``m`` classical RK4 sub-steps of the increment's ODE (compiled when numba
    is there: the test's own loop, 20 000-40 000 sub-steps a case, cost ~2 s a case in Python)."""
    P, A, B, G, D1, D2 = (np.ascontiguousarray(a[k], dtype=float) for k in ("P", "A", "B", "Gamma", "Delta1", "Delta2"))
    return _rk4_loop(P, A, B, G, D1, D2, np.array(h, float), np.asarray(du, float), int(m))


@njit
def _rk4_loop(P, A, B, G, D1, D2, h, du, m):
    d = du / m
    q = P @ d
    for _ in range(m):
        k1 = _rk4_rate(A, B, G, D1, D2, d, q, h)
        k2 = _rk4_rate(A, B, G, D1, D2, d, q, h + 0.5 * k1)
        k3 = _rk4_rate(A, B, G, D1, D2, d, q, h + 0.5 * k2)
        k4 = _rk4_rate(A, B, G, D1, D2, d, q, h + k3)
        h = h + (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
    return h


@njit
def _rk4_rate(A, B, G, D1, D2, d, q, x):
    return A @ d - B @ (np.abs(q) * x) - G @ (q * np.abs(x)) - D1 @ (q * x) - D2 @ (np.abs(q) * np.abs(x))


def _exact(cfg, h, du):
    p = kb.params_of(cfg.arrays())
    he = np.zeros(len(h))
    kb.bw_exact_path(p, kb.bw_sigma(p), np.array(h, float), np.array(du, float), he, kb.path_scratch(len(h)))
    return he


def _path(cfg, h, du):
    """h after the step through the generic kernel's path increment."""
    p = kb.params_of(cfg.arrays())
    n = len(h)
    h = np.array(h, float)
    dh = np.zeros(n)
    kb.bw_path_increment(p, kb.bw_sigma(p), h, np.array(du, float), dh, np.zeros(n), np.zeros(n), np.zeros(n),
                         kb.path_scratch(n))
    return h + dh


CASES = [  # (start h as a fraction of the loop, step [V]): sign changes of h one way, the other, both, none
    ((0.0, 0.0), (300.0, -200.0)),
    ((1.0, -1.0), (-250.0, 250.0)),
    ((-1.0, 0.5), (400.0, 40.0)),
    ((0.3, 0.2), (20.0, 15.0)),
    ((0.0, 0.0), (0.4, -0.3)),
]


@pytest.mark.parametrize("which", ["paper", "generalized"])
@pytest.mark.parametrize("h0,du", CASES)
def test_exact_path_matches_a_finely_sub_stepped_integration(paper, which, h0, du):
    """A step of up to 400 V (h changing sign on the way) ends where 20 000 RK4 sub-steps end, to 1e-10 of the
    loop (the reference's own error where h changes sign, ~1/m²; the explicit sub-steps it replaces were ~1e-4
    off)."""
    cfg = paper if which == "paper" else _generalized(paper)
    a = cfg.arrays()
    scale = 3e-6                                        # h of a 150 V loop on the paper's tube is a few µm
    h = scale * np.array(h0)
    ref = _rk4_path(a, h, np.array(du), 20000)
    got = _exact(cfg, h, du)
    assert np.max(np.abs(got - ref)) < 1e-10 * max(scale, np.max(np.abs(ref)))
    # through the dispatcher: beyond 2·KAPPA_MAX the step is the exact path
    sigma = kb.bw_sigma(kb.params_of(a))
    if sigma * np.max(np.abs(a["P"] @ np.array(du))) >= 2 * kb.KAPPA_MAX:
        assert np.array_equal(_path(cfg, h, du), h + (got - h))


def test_exact_path_sign_change_is_located():
    """A step that drives h through zero: the sign change ends a piece and the remaining path continues from zero
    in the next orthant (a single series across the kink is visibly wrong: checked by the reference)."""
    cfg = _generalized(load_config().hysteresis)
    a = cfg.arrays()
    h = np.array([2e-6, -2e-6])
    du = np.array([-120.0, 120.0])
    ref = _rk4_path(a, h, du, 40000)
    got = _exact(cfg, h, du)
    assert np.sign(got[0]) != np.sign(h[0]) and np.sign(got[1]) != np.sign(h[1])
    assert np.max(np.abs(got - ref)) < 1e-11 * np.max(np.abs(ref))


@pytest.mark.parametrize("which", ["paper", "generalized"])
def test_h_is_continuous_across_the_one_step_boundary(paper, which):
    """Scanning the step size through κ = KAPPA_MAX and 2·KAPPA_MAX: h changes by O(the change of the step), no
    jump (the compensator's Newton inverts this map)."""
    cfg = paper if which == "paper" else _generalized(paper)
    a = cfg.arrays()
    sigma = kb.bw_sigma(kb.params_of(a))
    direction = np.array([1.0, -0.4])
    unit = sigma * np.max(np.abs(a["P"] @ direction))   # κ of a 1 V step in this direction
    h = np.array([1.5e-6, 0.7e-6])
    for x in (1.0, 2.0):
        s0 = x * kb.KAPPA_MAX / unit
        eps = 1e-9 * s0
        below = _path(cfg, h, (s0 - eps) * direction)
        above = _path(cfg, h, (s0 + eps) * direction)
        spread = _path(cfg, h, 1.01 * s0 * direction) - _path(cfg, h, 0.99 * s0 * direction)
        slope = np.max(np.abs(spread)) / (0.02 * s0)
        assert np.max(np.abs(above - below)) < 10 * slope * 2 * eps


def test_two_axis_exact_path_is_the_generic_kernel(paper):
    """The two-axis specialisation gives the generic kernel's numbers bit for bit on large steps (sign changes
    included)."""
    for cfg in (paper, _generalized(paper)):
        c = kb.model_coeff_tuple(kb.coeffs_2x2(kb.params_of(cfg.arrays())))
        sigma = kb.bw_sigma(kb.params_of(cfg.arrays()))
        for h0, du in CASES:
            h = 3e-6 * np.array(h0)
            e0, e1 = kb.bw2_exact_path(c, sigma, h[0], h[1], du[0], du[1])
            assert np.array_equal(np.array([e0, e1]), _exact(cfg, h, du))


@pytest.mark.parametrize("which", ["paper", "generalized"])
def test_compensator_inverts_the_model_across_all_regimes(paper, which):
    """Held references whose steps ask for 0.01 V to ~300 V in one 20 kHz sample (one step, the blend, the exact
    path): compensate then model gives the reference back to 1e-12 of its size, and the two share h."""
    cfg = paper if which == "paper" else _generalized(paper)
    rng = np.random.default_rng(11)
    sizes = np.exp(rng.uniform(np.log(2e-9), np.log(40e-6), 120))     # Y_H steps from ~0.01 V to ~300 V
    levels = np.cumsum(sizes[:, None] * rng.choice([-1.0, 1.0], (120, 2)), axis=0)
    levels = np.clip(levels, -25e-6, 25e-6)
    yh = np.ascontiguousarray(np.repeat(levels, 3, axis=0))
    comp = HysteresisCompensator(cfg)
    u = comp.process(yh)
    steps = np.max(np.abs(np.diff(u, axis=0)), axis=1)
    sigma = kb.bw_sigma(kb.params_of(cfg.arrays()))
    kappa = sigma * np.max(np.abs(np.diff(u, axis=0) @ cfg.arrays()["P"].T), axis=1)
    assert np.any((kappa > kb.KAPPA_MAX) & (kappa < 2 * kb.KAPPA_MAX))  # the blend is exercised
    assert np.max(steps) > 100.0
    model = BoucWenModel(cfg)
    y = model.process(u)
    assert np.max(np.abs(y - yh)) < 1e-12 * np.max(np.abs(yh))
    assert comp.fallbacks == 0
    assert np.array_equal(model.bw_state.h, comp.h)


@pytest.mark.parametrize("alpha", [0.0, 0.4])
def test_two_axis_fast_path_of_the_generic_loop_gives_the_generic_numbers(paper, alpha):
    """The generic (rate) model loop takes the two-axis increment for two axes: its numbers are those of the
    generic increment, seen through a third, uncoupled axis that forces the generic code."""
    from piezo_ff_ros.core.kernels.bouc_wen import BoucWenParams
    rng = np.random.default_rng(5)
    u2 = np.ascontiguousarray(np.cumsum(rng.normal(0.0, 3.0, (3000, 2)), axis=0))
    p2 = kb.params_of(_generalized(paper).arrays())

    def embed(m, corner=0.0):
        out = np.zeros((3, 3))
        out[:2, :2] = m
        out[2, 2] = corner
        return out
    p3 = BoucWenParams(embed(p2.Dp, 1e-7), embed(p2.A), embed(p2.B), embed(p2.G), embed(p2.D1), embed(p2.D2),
                       embed(p2.P))
    u3 = np.ascontiguousarray(np.column_stack([u2, np.zeros(len(u2))]))

    def run(p, u):
        n = u.shape[1]
        y, hs = np.empty_like(u), np.empty_like(u)
        kb.bw_model_rate_run(p, alpha, 50.0, 0.9, 5e-5, np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(1, np.bool_),
                             u, y, hs)
        return hs
    h2, h3 = run(p2, u2), run(p3, u3)
    assert np.array_equal(h2, h3[:, :2]) and not np.any(h3[:, 2])
    assert np.max(np.abs(h2)) > 0
