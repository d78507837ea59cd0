"""The Bouc-Wen model follows the continuous, rate-independent Bouc-Wen along the voltage path: large voltage steps
per sample agree with a finely integrated reference, the same path sampled at two rates gives the same h, small
steps keep the single explicit step's numbers bit for bit, the result does not depend on the block split, and the
compensator stays the model's exact inverse on large steps."""
from __future__ import annotations

import numpy as np
import pytest

from piezo_ff_ros.core._jit import njit
from piezo_ff_ros.core.compensators.hysteresis import HysteresisCompensator
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.kernels import bouc_wen as kb
from piezo_ff_ros.core.models.bouc_wen import BoucWenModel
from piezo_ff_ros.core.models.plant import Plant


@pytest.fixture(scope="module")
def paper_config():
    return load_config()


def _arrays(cfg):
    a = cfg.arrays()
    return a["Dp"], a["A"], a["B"], a["Gamma"], a["Delta1"], a["Delta2"], a["P"]


@njit
def _rhs(d, h, A, B, G, D1, D2, P):
    """The increment of h for the path element ``d`` (paper Eq. 2, straight from its definition)."""
    dh_ = P @ d
    return A @ d - B @ (np.abs(dh_) * h) - G @ (dh_ * np.abs(h)) - D1 @ (dh_ * h) - D2 @ (np.abs(dh_) * np.abs(h))


def _reference_h(cfg, u, max_sub=0.25):
    """h of the continuous Bouc-Wen, integrated by RK4 along each straight step in sub-steps of ≤ ``max_sub`` volts
    (compiled when numba is there: the test's own loop, ~30 000 sub-steps a staircase, ~2 s in Python)."""
    Dp, A, B, G, D1, D2, P = (np.ascontiguousarray(x, dtype=float) for x in _arrays(cfg))
    return _reference_h_loop(A, B, G, D1, D2, P, np.ascontiguousarray(u, dtype=float), float(max_sub), Dp.shape[0])


@njit
def _reference_h_loop(A, B, G, D1, D2, P, u, max_sub, n):
    h = np.zeros(n)
    hs = np.empty((len(u), n))
    hs[0] = h
    for t in range(1, len(u)):
        du = u[t] - u[t - 1]
        m = max(1, int(np.ceil(np.max(np.abs(du)) / max_sub)))
        d = du / m
        for _ in range(m):
            k1 = _rhs(d, h, A, B, G, D1, D2, P)
            k2 = _rhs(d, h + 0.5 * k1, A, B, G, D1, D2, P)
            k3 = _rhs(d, h + 0.5 * k2, A, B, G, D1, D2, P)
            k4 = _rhs(d, h + k3, A, B, G, D1, D2, P)
            h = h + (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        hs[t] = h
    return hs


def _single_step_h(cfg, u):
    """h of one explicit step per sample, in the kernel's order of operations (the model's form before it
    integrated along the path); scalar loops, compiled when numba is there (40 000 samples a case, ~1 s in Python;
    numba keeps IEEE order: no fast-math, no fused multiply-add)."""
    Dp, A, B, G, D1, D2, P = (np.ascontiguousarray(x, dtype=float) for x in _arrays(cfg))
    return _single_step_loop(A, B, G, D1, D2, P, np.ascontiguousarray(u, dtype=float))


@njit
def _single_step_loop(A, B, G, D1, D2, P, u):
    n, k = A.shape
    h = np.zeros(n)
    hs = np.empty((len(u), n))
    hs[0] = h
    du = np.empty(k)
    duh = np.empty(n)
    dh = np.empty(n)
    for t in range(1, len(u)):
        for j in range(k):
            du[j] = u[t, j] - u[t - 1, j]
        for i in range(n):
            acc = 0.0
            for j in range(k):
                acc += P[i, j] * du[j]
            duh[i] = acc
        for i in range(n):
            acc = 0.0
            for j in range(k):
                acc += A[i, j] * du[j]
            for j in range(n):
                ah = abs(h[j])
                phi = B[i, j] * h[j] + D2[i, j] * ah
                psi = G[i, j] * ah + D1[i, j] * h[j]
                acc -= abs(duh[j]) * phi + duh[j] * psi
            dh[i] = acc
        for i in range(n):
            h[i] = h[i] + dh[i]
        hs[t] = h
    return hs


def _staircase(seed, n_steps=40, hold=5, peak=150.0):
    """Random voltage levels held a few samples: raw DAC steps of up to 2·peak volts in one sample."""
    rng = np.random.default_rng(seed)
    lv = rng.uniform(-peak, peak, (n_steps, 2)) * (rng.random((n_steps, 2)) < 0.8)
    return np.ascontiguousarray(np.vstack([np.zeros((1, 2)), np.repeat(lv, hold, axis=0)]))


def _h_of(cfg, u):
    return BoucWenModel(cfg).process_with_taps(u)[1]["h"]


@pytest.mark.parametrize("which", ["paper", "generalized"])
def test_large_voltage_steps_follow_the_continuous_bouc_wen(paper_config, which):
    """Raw steps of up to 300 V in one sample give the h of the finely integrated continuous model (one explicit
    step per sample was tens of per cent off)."""
    cfg = paper_config.hysteresis
    if which == "generalized":
        cfg = _generalized(cfg)
    u = _staircase(1)
    ref = _reference_h(cfg, u)
    h = _h_of(cfg, u)
    scale = np.max(np.abs(ref))
    assert np.max(np.abs(h - ref)) < 1e-3 * scale


def _generalized(cfg):
    import dataclasses
    return dataclasses.replace(cfg, Delta1=((0.0012, 0.0001), (0.0, -0.0008)),
                               Delta2=((-0.0005, 0.0), (0.0001, 0.0007))).validate()


def test_three_axis_model_follows_the_continuous_bouc_wen():
    """The generic (any size) kernel integrates along the path too (the 3-axis tube, steps on every electrode)."""
    cfg = load_config("config/xyz_tube.yaml").hysteresis
    rng = np.random.default_rng(7)
    u = np.vstack([np.zeros((1, 3)), np.repeat(rng.uniform(-150, 150, (30, 3)), 4, axis=0)])
    ref = _reference_h(cfg, u)
    h = _h_of(cfg, np.ascontiguousarray(u))
    assert np.max(np.abs(h - ref)) < 1e-3 * np.max(np.abs(ref))


def test_same_path_at_two_sample_rates_gives_the_same_h(paper_config):
    """Bouc-Wen is rate independent: a 150 V triangle sampled at 100 Hz (6 V per sample) and at 20 kHz gives the
    same h at the common instants."""
    cfg = paper_config.hysteresis

    def path(fs):
        t = np.arange(int(2.0 * fs) + 1) / fs
        tri = 150.0 * (2 / np.pi) * np.arcsin(np.sin(2 * np.pi * 1.0 * t))
        return np.ascontiguousarray(np.column_stack([tri, -0.6 * tri]))
    slow, fast = path(100.0), path(20000.0)
    h_slow = _h_of(cfg, slow)
    h_fast = _h_of(cfg, fast)[::200]
    assert np.allclose(slow, path(20000.0)[::200])
    assert np.max(np.abs(h_slow - h_fast)) < 1e-3 * np.max(np.abs(h_fast))


def test_small_steps_keep_the_single_step_numbers_bit_for_bit(paper_config):
    """Steps with κ ≤ KAPPA_MAX (a 0.1 Hz, 150 V sine and a 1 Hz circle at 20 kHz) give exactly the numbers of one
    explicit step per sample."""
    cfg = paper_config.hysteresis
    t = np.arange(40000) / 20000.0
    u = np.ascontiguousarray(np.column_stack([150 * np.sin(2 * np.pi * 0.1 * t),
                                              10 * np.cos(2 * np.pi * 1.0 * t) - 10]))
    sigma = float(np.max((np.abs(cfg.arrays()["B"]) + np.abs(cfg.arrays()["Gamma"])).sum(axis=1)))
    assert sigma * np.max(np.abs(np.diff(u, axis=0))) <= kb.KAPPA_MAX   # one step everywhere
    assert np.array_equal(_h_of(cfg, u), _single_step_h(cfg, u))
    cfg3 = load_config("config/xyz_tube.yaml").hysteresis
    u3 = np.ascontiguousarray(np.column_stack([u, 0.5 * u[:, 0]]))
    assert np.array_equal(_h_of(cfg3, u3), _single_step_h(cfg3, u3))


@pytest.mark.parametrize("splits", [(1,), (7, 50), (3, 4, 5, 100, 150)])
def test_large_steps_are_block_size_invariant(paper_config, splits):
    """The plant (fused kernel) and the model alone give the same numbers whatever the block split, sub-steps
    included."""
    u = _staircase(2)
    whole = Plant(paper_config).process(u)
    plant = Plant(paper_config)
    parts = [plant.process(b) for b in np.split(u, splits)]
    assert np.array_equal(np.vstack(parts), whole)
    model = BoucWenModel(paper_config.hysteresis)
    ref = BoucWenModel(paper_config.hysteresis).process(u)
    assert np.array_equal(np.vstack([model.process(b) for b in np.split(u, splits)]), ref)


@pytest.mark.parametrize("which", ["paper", "generalized"])
def test_compensator_inverts_the_model_on_large_steps(paper_config, which):
    """Steps asking for ~150 V in one sample: the compensator's voltage gives back Y_H through the model (to
    rounding), and the two share h bit for bit."""
    cfg = paper_config.hysteresis if which == "paper" else _generalized(paper_config.hysteresis)
    rng = np.random.default_rng(3)
    yh = np.ascontiguousarray(np.repeat(rng.uniform(-25e-6, 25e-6, (40, 2)), 5, axis=0))
    comp = HysteresisCompensator(cfg)
    u = comp.process(yh)
    assert np.max(np.abs(np.diff(u, axis=0))) > 100.0     # large steps, integrated in many sub-steps
    model = BoucWenModel(cfg)
    y = model.process(u)
    assert np.max(np.abs(y - yh)) < 1e-17
    assert comp.fallbacks == 0
    assert np.array_equal(model.bw_state.h, comp.h)
