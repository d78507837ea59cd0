"""VoltageGuard (core/safety.py): clamp, slew limit, rejection, safe ramp — pure, no ROS."""
import numpy as np
import pytest

from piezo_ff_ros.core.config import LimitsConfig
from piezo_ff_ros.core.safety import BlockRejected, SafeRampConfig, VoltageGuard, safe_ramp, slew_limit

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


def test_ramp_to_safe_own_duration_and_slew_not_the_operating_limit():
    """The ramp to safe is a straight line of ≥ its own duration and ≤ its own slew (and the operating one); with the
    operating limit of the paper's config (1e7 V/s = 500 V per sample) the old ramp was a single 78.6 V → 0 V step."""
    g = guard(voltage=200.0, slew=1.0e7, safe_voltage=0.0)
    g.apply(np.tile([[150.0, -37.0]], (40, 1)))
    ramp = SafeRampConfig(duration=0.05, slew=1.0e4)
    r = g.ramp_to_safe(ramp)
    assert r.shape == (1000, 2)                       # 50 ms: 150 V at 0.5 V/sample would take only 15 ms
    steps = np.abs(np.diff(np.vstack([[150.0, -37.0], r]), axis=0))
    assert steps.max() <= 150.0 / 1000 + 1e-12
    np.testing.assert_array_equal(r[-1], [0.0, 0.0])
    assert g.at_safe and g.counters.safe_ramps == 1
    assert g.ramp_to_safe(ramp).shape == (0, 2)


@pytest.mark.parametrize("duration, slew, op_slew", [(0.05, 1e4, 1e7), (0.0, 1e4, 1e7), (0.0, 1e7, 2e5),
                                                      (0.2, 1e3, 1e7), (0.001, 5e5, 1e6)])
def test_safe_ramp_worst_step_from_the_worst_state(duration, slew, op_slew):
    """The worst case: both axes at opposite limits; every step ≤ min(ramp slew, operating slew)/fs and the ramp
    lasts ≥ duration, ending exactly on the safe voltage."""
    for u0 in ([200.0, -200.0], [-200.0, 200.0], [200.0, 200.0]):
        r = safe_ramp(np.array(u0), 0.0, FS, SafeRampConfig(duration=duration, slew=slew), op_slew)
        steps = np.abs(np.diff(np.vstack([u0, r]), axis=0))
        assert steps.max() <= min(slew, op_slew) / FS * (1 + 1e-12)
        assert r.shape[0] >= duration * FS - 1e-9
        np.testing.assert_array_equal(r[-1], [0.0, 0.0])
        assert np.all(np.abs(r) <= 200.0)


def test_slew_limit_matches_a_reference_loop_and_passes_reachable_targets_exactly():
    rng = np.random.default_rng(4)
    target = rng.uniform(-100, 100, size=(500, 3))
    step = 7.5
    prev = np.zeros(3)
    out, n = slew_limit(target, prev.copy(), step)
    ref, u, n_ref = np.empty_like(target), np.zeros(3), 0
    for k in range(500):  # the obvious reference: clip the increment
        d = np.clip(target[k] - u, -step, step)
        n_ref += bool(np.any(np.abs(target[k] - u) > step))
        u = np.where(np.abs(target[k] - u) <= step, target[k], u + d)
        ref[k] = u
    np.testing.assert_array_equal(out, ref)
    assert n == n_ref


def test_the_driver_may_tighten_the_amplifiers_limits_never_widen_them():
    """tightened_limits: the config's limits with the driver's values; a wider voltage or slew is refused naming the
    field and the config's value, the stale timeout must be in [1 ms, 1 h], the config's workspace is kept."""
    from piezo_ff_ros.core.config import ConfigError, LimitsConfig
    from piezo_ff_ros.core.safety import tightened_limits

    amp = LimitsConfig(voltage=200.0, slew=2.0e5, stale_timeout=0.2, safe_voltage=0.0, workspace=((-1e-4, 1e-4),))
    got = tightened_limits(amp, voltage=150.0, slew=1.0e5, stale_timeout=1.0, safe_voltage=5.0)
    assert got == LimitsConfig(voltage=150.0, slew=1.0e5, stale_timeout=1.0, safe_voltage=5.0,
                               workspace=((-1e-4, 1e-4),))
    assert tightened_limits(amp, 200.0, 2.0e5, 0.2, 0.0) == amp
    for kw, field, text in [({"voltage": 250.0}, "limits.voltage", "250.0 exceeds the config's 200.0"),
                            ({"slew": 3.0e5}, "limits.slew", "300000.0 exceeds the config's 200000.0"),
                            ({"stale_timeout": 1e-4}, "limits.stale_timeout", "must be in [0.001, 3600] s"),
                            ({"voltage": -1.0}, "limits.voltage", "must be a finite number > 0"),
                            ({"safe_voltage": 300.0}, "limits.safe_voltage", "outside the voltage limit")]:
        args = {"voltage": 200.0, "slew": 2.0e5, "stale_timeout": 0.2, "safe_voltage": 0.0, **kw}
        with pytest.raises(ConfigError) as e:
            tightened_limits(amp, **args)
        assert str(e.value).startswith(f"{field}: ") and text in str(e.value), str(e.value)
