"""The discretised Preisach plane of the asymmetric hysteresis candidate: relays that switch at their thresholds and
remember the last one crossed, the same output whatever the block split, a loop (not a memoryless function), and a
clear error for thresholds out of order."""
from __future__ import annotations

import numpy as np
import pytest

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.models.effects import RelayPlaneTerm, build_plant


def _ramp_up_down(n=200, top=100.0):
    up = np.linspace(-top, top, n)
    return np.r_[up, up[::-1]]


def test_a_relay_switches_up_at_alpha_down_at_beta_and_remembers():
    term = RelayPlaneTerm([1.0], alpha=[30.0], beta=[-10.0], gains=[[1.0]])
    v = np.array([-50.0, 0.0, 29.0, 30.0, 0.0, -9.0, -10.0, 0.0])[:, None]
    states = term.terms(v)[:, 0, 0]
    # starts down (below the centre 10 V), up at 30 V, stays up until -10 V, then stays down
    assert states.tolist() == [-1, -1, -1, 1, 1, 1, -1, -1]


def test_same_output_whatever_the_block_split():
    rng = np.random.default_rng(1)
    u = np.cumsum(rng.standard_normal((3000, 2)), axis=0) * 3.0
    args = ([2e-7, 3e-7], [40.0, 10.0, 70.0], [-20.0, 0.0, 50.0], rng.standard_normal((3, 2)))
    whole = RelayPlaneTerm(*args).process(u)
    split = RelayPlaneTerm(*args)
    parts = np.concatenate([split.process(u[a:b]) for a, b in ((0, 1), (1, 777), (777, 3000))])
    assert np.array_equal(whole, parts)


def test_a_weighted_relay_plane_has_loop_area():
    """Up and down the same voltages, the output differs between the branches: the term is hysteretic."""
    term = RelayPlaneTerm([1.0], alpha=[20.0, 60.0], beta=[0.0, 30.0], gains=[[1.0], [0.5]])
    v = _ramp_up_down()
    y = term.process(v[:, None])[:, 0]
    up, down = y[:200], y[200:][::-1]
    area = float(np.sum(down - up) * (v[1] - v[0]))
    # between a relay's thresholds the branches differ by twice its weight (state +1 on the way down, -1 up)
    assert area > 0 and np.max(np.abs(down - up)) == pytest.approx(2.0)


def test_thresholds_out_of_order_are_refused():
    with pytest.raises(ValueError, match="relay_alpha/relay_beta"):
        RelayPlaneTerm([1.0, 1.0], alpha=[10.0], beta=[20.0], gains=[[1.0, 1.0]])
    with pytest.raises(ValueError, match="relay_gains"):
        RelayPlaneTerm([1.0, 1.0], alpha=[10.0], beta=[0.0], gains=[[1.0]])


def test_build_plant_adds_the_relay_plane_at_the_loop_output():
    cfg = load_config().with_sample_rate(1000.0)
    u = np.c_[_ramp_up_down(), 0.5 * _ramp_up_down()]
    nominal = build_plant(cfg).process(u)
    p = {"Delta1": [0.0, 0.0], "Delta2": [0.0, 0.0], "relay_alpha": [40.0], "relay_beta": [20.0],
         "relay_gains": [[3.0, 0.0]]}
    y = build_plant(cfg, [("hysteresis_asymmetry", p)]).process(u)
    unweighted = build_plant(cfg, [("hysteresis_asymmetry", dict(p, relay_gains=[[0.0, 0.0]]))]).process(u)
    assert np.allclose(unweighted, nominal, rtol=0, atol=1e-15)
    # the x relay moves x's hysteresis output by Dp_xx·3 V·(±1): its change dominates on x (y sees the coupling)
    dx, dy = np.max(np.abs(y - nominal), axis=0)
    assert dx > 1e-7 and dx > 3 * dy
