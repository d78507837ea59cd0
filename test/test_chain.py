"""The Chain (core/chain.py): taps through their own method, state/reset by delegation, and the fused compiled pass
giving the stages' own numbers — outputs, states and counters — whatever the block split."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezo_ff_ros.core.chain import Chain, FusedPass
from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.models import effects as fx
from piezo_ff_ros.core.models.plant import Plant

# a 4th-order 2×2 stand-in for C(s) (real and complex modes, D ≠ 0), no H∞ synthesis needed
_A = np.array([[-300.0, 0, 0, 0], [0, -2000.0, 0, 0], [0, 0, -500.0, 4000.0], [0, 0, -4000.0, -500.0]])
_B = np.array([[300.0, 0.0], [0.0, 2000.0], [100.0, 50.0], [0.0, 80.0]])
_C = np.array([[0.2, 0.0, 0.1, 0.05], [0.0, 0.1, 0.02, 0.1]])
_D = np.array([[0.9, 0.01], [0.02, 0.85]])
CTRL = (_A, _B, _C, _D)


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def _ref(n, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 20000.0
    x = np.column_stack([np.sin(2 * np.pi * 7 * t) + 0.2 * np.sin(2 * np.pi * 900 * t), np.cos(2 * np.pi * 11 * t)])
    return np.ascontiguousarray(15e-6 * (x + 0.05 * rng.standard_normal((n, 2))))


def _split(x, rng):
    cuts = np.sort(rng.integers(0, len(x), size=6))
    return np.split(x, cuts)


def _full(cfg, fuse, **limits):
    c = replace(cfg, limits=replace(cfg.limits, **limits)) if limits else cfg
    return Chain([("cascade", CompensatorCascade(c, controller=CTRL)), ("plant", Plant(c))], fuse=fuse)


def _states(chain):
    return {k: {n: a.copy() for n, a in v.items()} for k, v in chain["cascade"].state().items()} | \
        {f"plant.{k}": dict(v) for k, v in chain["plant"].state().items()}


def test_the_standard_chain_fuses_into_one_pass(cfg):
    plan = _full(cfg, True).plan()
    assert len(plan) == 1 and isinstance(plan[0], FusedPass) and plan[0].slots == [0, 1, 2, 3, 4, 5]
    assert all(not isinstance(s, FusedPass) for s in _full(cfg, False).plan())
    # effects and noise stages are not fusable: the nominal stages between them still are
    p = Plant(cfg, pre=[fx.AmplifierSlewLimit(1e5, cfg.dt)], post=[fx.GainMismatch([1.01, 0.99])], noise_std=1e-9)
    kinds = [type(s).__name__ for s in p.plan()]
    assert kinds == ["AmplifierSlewLimit", "FusedPass", "GainMismatch", "SensorNoise"]


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), voltage=st.sampled_from([None, 60.0]), slew=st.sampled_from([None, 2e4]))
def test_fused_pass_gives_the_stages_numbers_whatever_the_split(cfg, seed, voltage, slew):
    limits = {k: v for k, v in (("voltage", voltage), ("slew", slew)) if v is not None}
    yr = _ref(3000, seed % 1000) * (4.0 if voltage else 1.0)
    rng = np.random.default_rng(seed)
    fused, plain = _full(cfg, True, **limits), _full(cfg, False, **limits)
    y_plain = np.vstack([plain.process(p) for p in _split(yr, rng)])
    y_fused = np.vstack([fused.process(p) for p in _split(yr, rng)])
    assert np.array_equal(y_fused, y_plain)
    sf, sp = _states(fused), _states(plain)
    assert sf.keys() == sp.keys()
    for k in sf:
        for n in sf[k]:
            assert np.array_equal(sf[k][n], sp[k][n]), (k, n)
    hf, hp = fused["cascade"].hysteresis, plain["cascade"].hysteresis
    assert (hf.fallbacks, hf.saturated) == (hp.fallbacks, hp.saturated)
    if voltage or slew:
        assert hf.saturated > 0


def test_taps_through_their_own_method_and_the_same_output(cfg):
    chain = _full(cfg, True)
    yr = _ref(2000, 3)
    y, taps = chain.process_with_taps(yr)
    assert set(taps) == {"cascade", "plant"} and np.array_equal(taps["plant"], y)
    chain.reset()
    assert np.array_equal(chain.process(yr), y)
    casc = CompensatorCascade(cfg, controller=CTRL)
    u, ct = casc.process_with_taps(yr)
    assert list(ct) == ["yl", "yh", "u"] and np.array_equal(ct["u"], u) and np.array_equal(taps["cascade"], u)
    plant = Plant(cfg)
    yp, pt = plant.process_with_taps(u)
    assert set(pt) == {"yh", "yl"} and np.array_equal(yp, y)


def test_state_load_state_and_reset_delegate(cfg):
    yr = _ref(3000, 5)
    a = _full(cfg, True)
    a.process(yr[:1700])
    saved = {"cascade": a["cascade"].state(), "plant": a["plant"].state()}
    rest = a.process(yr[1700:])
    b = _full(cfg, True)
    b.load_state(saved)
    assert np.array_equal(b.process(yr[1700:]), rest)        # a swap at a block boundary, bumpless
    a.reset()
    fresh = _full(cfg, True)
    assert np.array_equal(a.process(yr), fresh.process(yr))  # reset = back to rest, fused states included


def test_chain_errors_name_the_problem(cfg):
    with pytest.raises(ValueError, match="unique"):
        Chain([("a", None), ("a", None)], n_in=2)
    with pytest.raises(ValueError, match=r"shape \[N, 2\]"):
        _full(cfg, True).process(np.zeros((10, 3)))
    with pytest.raises(TypeError, match="no state"):
        Plant(cfg, post=[fx.GainMismatch([1.0, 1.0])]).state()
