"""The compiled kernels (core/kernels/): every two-axis specialisation gives its generic source's numbers, on the
paper's parameters and on random ones, and the one voltage limiter is shared exactly by its three users."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezo_ff_ros.core.compensators.creep import CreepCompensator
from piezo_ff_ros.core.compensators.hysteresis import HysteresisCompensator
from piezo_ff_ros.core.config import BoucWenConfig, LimitsConfig, load_config
from piezo_ff_ros.core.kernels import bouc_wen as kb
from piezo_ff_ros.core.kernels import modal as km
from piezo_ff_ros.core.kernels.limits import limit_run
from piezo_ff_ros.core.lti import DiscreteModalSS, LTIFilter
from piezo_ff_ros.core.models.bouc_wen import BoucWenModel, BoucWenState
from piezo_ff_ros.core.models.effects import AmplifierSlewLimit
from piezo_ff_ros.core.safety import VoltageGuard, at_limit

FS = 20000.0


@pytest.fixture(scope="module")
def paper_config():
    return load_config()


def _signal(n, seed=0, scale=1.0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    x = np.column_stack([np.sin(2 * np.pi * 3 * t) + 0.3 * np.sin(2 * np.pi * 170 * t),
                         np.cos(2 * np.pi * 5 * t + 0.4)]) + 0.05 * rng.standard_normal((n, 2))
    return np.ascontiguousarray(scale * x)


def _random_bw(seed: int, generalized: bool = True) -> BoucWenConfig:
    """Random but well-posed 2×2 Bouc-Wen parameters (µm/V-like scales, loops of a few per cent)."""
    rng = np.random.default_rng(seed)

    def m(diag, off):
        return tuple(tuple(float(v) for v in row) for row in np.diag(diag) + off * (rng.random((2, 2)) - 0.5)
                     * (1 - np.eye(2)))
    Dp = m(rng.uniform(1e-7, 2e-7, 2), 2e-8)
    A = m(rng.uniform(1e-8, 4e-8, 2), 4e-9)
    B = m(rng.uniform(2e-3, 1e-2, 2), 1e-3)
    G = m(rng.uniform(-2e-3, 3e-3, 2), 5e-4)
    kw = {}
    if generalized:
        kw = dict(Delta1=m(rng.uniform(-2e-3, 2e-3, 2), 5e-4), Delta2=m(rng.uniform(-1e-3, 1e-3, 2), 5e-4))
    return BoucWenConfig(Dp=Dp, A=A, B=B, Gamma=G, **kw).validate()


# ---------------------------------------------------------------------------------------------------- Bouc-Wen

def _model_generic(cfg, u):
    st = BoucWenState(2, 2)
    y, hs = np.empty_like(u), np.empty_like(u)
    kb.bw_model_run(kb.params_of(cfg.arrays()), st.h, st.u_prev, st.started, u, y, hs)
    return y, hs, st


def _check_model(cfg, u, split):
    model = BoucWenModel(cfg)
    assert model.two_axis
    a, b = model.process_with_taps(u[:split]), model.process_with_taps(u[split:])
    y, hs, st = _model_generic(cfg, u)
    assert np.array_equal(np.vstack([a[0], b[0]]), y)
    assert np.array_equal(np.vstack([a[1]["h"], b[1]["h"]]), hs)
    assert np.array_equal(model.bw_state.h, st.h) and np.array_equal(model.bw_state.u_prev, st.u_prev)
    assert np.max(np.abs(hs)) > 0


@pytest.mark.parametrize("generalized", [False, True])
def test_two_axis_bouc_wen_model_is_the_generic_kernel_paper(paper_config, generalized):
    cfg = _random_bw(0) if generalized else paper_config.hysteresis
    _check_model(cfg, _signal(4000, seed=3, scale=150.0), 1500)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), split=st.integers(0, 600), generalized=st.booleans())
def test_two_axis_bouc_wen_model_is_the_generic_kernel_random(seed, split, generalized):
    _check_model(_random_bw(seed, generalized), _signal(600, seed=seed % 97, scale=150.0), split)


def _check_comp(cfg, yh, split, loop, limit, slew):
    comp = HysteresisCompensator(cfg, loop, voltage_limit=limit, slew_per_sample=slew)
    assert comp.two_axis
    fast = np.vstack([comp.process(yh[:split]), comp.process(yh[split:])])
    ref = HysteresisCompensator(cfg, loop, voltage_limit=limit, slew_per_sample=slew)
    u = np.empty_like(yh)
    counters = np.zeros(kb.N_COUNTERS, np.int64)
    kb.bw_comp_run(ref.params, ref._Dp_pinv, ref.comp_state(), ref.options, yh, u, counters)
    assert np.array_equal(fast, u)
    assert np.array_equal(comp.bw_state.h, ref.bw_state.h) and np.array_equal(comp._signs, ref._signs)
    assert (comp.fallbacks, comp.saturated) == (counters[kb.FALLBACKS], counters[kb.SATURATED])
    return comp, fast


@pytest.mark.parametrize("generalized,loop,limit,slew", [(False, "exact", None, None), (True, "exact", None, None),
                                                         (False, "delayed", None, None), (False, "exact", 60.0, None),
                                                         (False, "exact", None, 0.05), (True, "exact", 60.0, 0.05)])
def test_two_axis_hysteresis_compensator_is_the_generic_kernel_paper(paper_config, generalized, loop, limit, slew):
    cfg = _random_bw(1) if generalized else paper_config.hysteresis
    comp, fast = _check_comp(cfg, _signal(4000, seed=4, scale=15e-6), 777, loop, limit, slew)
    if limit is not None or slew is not None:
        assert comp.saturated > 0
    if slew is not None:
        assert np.max(np.abs(np.diff(fast, axis=0))) <= slew * (1 + 1e-12)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), split=st.integers(0, 500), loop=st.sampled_from(["exact", "delayed"]),
       limit=st.sampled_from([None, 40.0, 120.0]), slew=st.sampled_from([None, 0.02, 0.5]))
def test_two_axis_hysteresis_compensator_is_the_generic_kernel_random(seed, split, loop, limit, slew):
    _check_comp(_random_bw(seed), _signal(500, seed=seed % 89, scale=15e-6), split, loop, limit, slew)


def test_compensator_limited_like_the_driver_keeps_the_plants_state(paper_config):
    """Clamped and slew-limited exactly as the driver's guard does, the compensator's h stays the plant's h."""
    limits = LimitsConfig(voltage=150.0, slew=2.0e5)
    comp = HysteresisCompensator(paper_config.hysteresis, voltage_limit=limits.voltage,
                                 slew_per_sample=limits.slew / FS)
    yh = np.zeros((4000, 2))
    yh[100:, 0] = 30e-6                                   # a step asking ~190 V at once
    yh[2000:, 1] = -20e-6
    u = comp.process(yh)
    guard = VoltageGuard(limits, 2, FS)
    guard.u_last[:] = u[0]
    applied = guard.apply(u)
    assert np.array_equal(applied, u)                     # the driver has nothing left to clip
    # ... and still counts the samples the compensator held at the limit (the stage was saturated all the same)
    assert guard.counters.saturated_samples == at_limit(u, limits.voltage) > 0
    h = BoucWenModel(paper_config.hysteresis).process_with_taps(applied)[1]["h"]
    assert np.array_equal(h[-1], comp.h)                  # the same voltage steps: the same h, bit for bit


# ---------------------------------------------------------------------------------------------------- the limiter

@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), limit=st.floats(1.0, 200.0), step=st.floats(0.01, 50.0))
def test_one_limiter_for_the_guard_the_effect_and_the_compensator(seed, limit, step):
    rng = np.random.default_rng(seed)
    target = np.cumsum(rng.normal(0.0, 20.0, size=(300, 2)), axis=0)
    # the driver's guard (from the first target, clamped: as a started effect would be)
    guard = VoltageGuard(LimitsConfig(voltage=limit, slew=step * FS), 2, FS)
    guard.step = step  # the same step to the bit (step·FS/FS need not round back to step)
    guard.u_last[:] = np.clip(target[0], -limit, limit)
    g = guard.apply(target)
    # the shared kernel, started on the first (clamped) sample
    out, prev, counts = np.empty_like(target), np.zeros(2), np.zeros(2, np.int64)
    limit_run(target, prev, np.zeros(1, np.bool_), limit, step, out, counts)
    assert np.array_equal(g, out)
    assert (guard.counters.saturated_samples, guard.counters.slew_limited_samples) == tuple(counts)
    # the amplifier effect (no clamp) on clamped targets
    eff = AmplifierSlewLimit(step, 1.0, 2).process(np.clip(target, -limit, limit))
    assert np.array_equal(eff, out)
    # a reference loop written from the rule's words
    u, ref = np.clip(target[0], -limit, limit), np.empty_like(target)
    for k in range(len(target)):
        c = np.clip(target[k], -limit, limit)
        u = np.where(np.abs(c - u) <= step, c, u + np.clip(c - u, -step, step))
        ref[k] = u
    assert np.array_equal(ref, out)


def test_the_compensator_limits_with_the_same_rule(paper_config):
    """The hysteresis compensator's voltage is what the shared limiter makes of its unlimited voltage steps."""
    comp = HysteresisCompensator(paper_config.hysteresis, voltage_limit=100.0, slew_per_sample=0.3)
    yh = _signal(3000, seed=9, scale=25e-6)
    u = comp.process(yh)
    guard = VoltageGuard(LimitsConfig(voltage=100.0, slew=0.3 * FS), 2, FS)
    guard.u_last[:] = u[0]
    assert np.array_equal(guard.apply(u), u) and comp.saturated > 0


# ---------------------------------------------------------------------------------------------------- modal banks

def _mimo_modal_ss(dt):
    """A 2×2 continuous system with real and complex modes, dense B, C and D ≠ 0 (like an H∞ controller)."""
    rng = np.random.default_rng(5)
    A = np.diag([-30.0, -400.0, -2000.0, -50.0, -50.0])
    A[3, 4], A[4, 3] = 900.0, -900.0
    T = rng.standard_normal((5, 5)) + 3 * np.eye(5)
    A = T @ A @ np.linalg.inv(T)
    return DiscreteModalSS.zoh_from_ss(A, rng.standard_normal((5, 2)), rng.standard_normal((2, 5)),
                                       rng.standard_normal((2, 2)), dt)


@pytest.mark.parametrize("which", ["dynamics", "creep", "mimo_modal"])
def test_two_axis_bank_is_the_generic_kernel(paper_config, which):
    dt = paper_config.dt
    ss = {"dynamics": lambda: DiscreteModalSS.zoh_from_tf_matrix(paper_config.dynamics.G_L, dt),
          "creep": lambda: DiscreteModalSS.zoh_from_tf_matrix(paper_config.creep.Cr, dt),
          "mimo_modal": lambda: _mimo_modal_ss(dt)}[which]()
    assert ss.small_blocks and np.any(ss.sizes == 2) and np.any(ss.sizes == 1)
    u = _signal(3000, seed=2, scale=1e-5)
    filt = LTIFilter(ss)
    assert filt.two_axis
    if which != "mimo_modal":  # SISO-derived: every block reaches exactly one output
        assert set(filt.feeds.tolist()) == {1, 2}
    fast = np.vstack([filt.process(u[:1234]), filt.process(u[1234:])])
    generic = np.empty_like(fast)
    Ablk, offsets = ss.packed()
    x = np.zeros(ss.n_states)
    km.bank_run(Ablk, offsets, ss.sizes, ss.B, ss.C, ss.D, x, u, generic)
    assert np.array_equal(fast, generic) and np.array_equal(filt.x, x)
    assert np.max(np.abs(fast)) > 0


def test_two_axis_creep_compensator_is_the_generic_kernel(paper_config):
    yl = _signal(4000, seed=6, scale=20e-6)
    comp = CreepCompensator(paper_config.creep, paper_config.dt)
    assert comp.two_axis
    fast = np.vstack([comp.process(yl[:2500]), comp.process(yl[2500:])])
    ss = comp.ss
    Ablk, offsets = ss.packed()
    x = np.zeros(ss.n_states)
    ref = np.empty_like(yl)
    km.inverse_affine_run(comp.Kinv, Ablk, offsets, ss.sizes, ss.B, ss.C, x, yl, ref)
    assert np.array_equal(fast, ref) and np.array_equal(comp.x, x)
