"""VoltageGuard (core/safety.py): clamp, slew limit, rejection, safe ramp — pure, no ROS."""
import numpy as np
import pytest

from piezo_ff_ros.core.config import LimitsConfig
from piezo_ff_ros.core.safety import BlockRejected, VoltageGuard

FS = 20000.0


def guard(**kw):
    return VoltageGuard(LimitsConfig(**kw), 2, FS, max_block=1000)


def test_clamps_and_slew_limits_every_sample():
    g = guard(voltage=200.0, slew=2e5)  # 10 V per sample
    u = np.array([[500.0, -500.0]] * 30)
    out = g.apply(u)
    step = np.diff(np.vstack([[0.0, 0.0], out]), axis=0)
    assert np.all(np.abs(step) <= 10.0 + 1e-12)
    assert np.all(np.abs(out) <= 200.0)
    np.testing.assert_allclose(out[:20, 0], np.arange(1, 21) * 10.0)
    np.testing.assert_allclose(out[20:, 0], 200.0)
    np.testing.assert_allclose(out[20:, 1], -200.0)
    assert g.counters.saturated_samples == 30
    assert g.counters.slew_limited_samples == 19  # the 20th step is exactly 10 V


def test_in_range_slow_input_passes_unchanged_and_split_invariant():
    t = np.arange(4000) / FS
    u = np.column_stack([100 * np.sin(2 * np.pi * 5 * t), 50 * np.cos(2 * np.pi * 3 * t) - 50])
    g1, g2 = (VoltageGuard(LimitsConfig(), 2, FS, max_block=4000) for _ in range(2))
    whole = g1.apply(u)
    parts = np.vstack([g2.apply(u[i:i + 137]) for i in range(0, len(u), 137)])
    np.testing.assert_array_equal(whole, parts)
    assert np.allclose(whole[200:], u[200:])  # after the initial slew from 0 V
    assert g1.counters.saturated_samples == 0


@pytest.mark.parametrize("bad, why", [
    (np.array([[1.0, np.nan]]), "NaN"),
    (np.array([[1.0, np.inf]]), "NaN/Inf"),
    (np.zeros((5, 3)), "wrong shape"),
    (np.zeros(5), "wrong shape"),
    (np.zeros((1001, 2)), "oversized"),
    (np.zeros((0, 2)), "empty"),
])
def test_rejects_bad_blocks_and_keeps_state(bad, why):
    g = guard()
    g.apply(np.full((3, 2), 5.0))
    before = g.u_last.copy()
    with pytest.raises(BlockRejected, match=why.split("/")[0]):
        g.apply(bad)
    np.testing.assert_array_equal(g.u_last, before)
    assert g.counters.rejected_blocks == 1
    np.testing.assert_array_equal(g.hold(4), np.tile(before, (4, 1)))


def test_ramp_to_safe_at_slew_limit():
    g = guard(voltage=200.0, slew=2e5, safe_voltage=0.0)
    g.apply(np.tile([[150.0, -37.0]], (40, 1)))
    assert g.u_last.tolist() == [150.0, -37.0]
    r = g.ramp_to_safe()
    assert r.shape == (15, 2)
    steps = np.abs(np.diff(np.vstack([[150.0, -37.0], r]), axis=0))
    assert steps.max() <= 10.0 + 1e-12
    np.testing.assert_array_equal(r[-1], [0.0, 0.0])
    assert g.at_safe and g.counters.safe_ramps == 1
    assert g.ramp_to_safe().shape == (0, 2)
