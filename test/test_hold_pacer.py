"""The held-point pacing of the compensator (core/hold_pacer.py), without ROS: the clock is an argument."""
import math

import numpy as np
import pytest

from piezo_ff_ros.core.hold_pacer import HoldPacer

FS = 20000.0


def _play(pacer, times):
    return [pacer.tick(t) for t in times]


@pytest.mark.parametrize("block,tick_s,jitter_s", [(200, 0.005, 0.0), (200, 0.005, 0.004), (200, 0.001, 0.0),
                                                    (200, 0.0093, 0.003), (200, 0.05, 0.02), (1, 0.001, 0.0005),
                                                    (20000, 0.05, 0.0)])
def test_average_rate_is_the_sample_rate_whatever_the_timer(block, tick_s, jitter_s):
    """Over 2 s of ticks (any period below the lateness bound, random lateness, blocks from 1 sample to 1 s) the
    blocks played are exactly the blocks due."""
    rng = np.random.default_rng(0)
    p = HoldPacer(FS, block, 0.2)
    p.set_point([1e-6, 2e-6])
    base = np.arange(0.0, 2.0, tick_s)
    t = np.maximum.accumulate(base + rng.uniform(0, jitter_s, len(base))) + 10.0
    blocks = sum(_play(p, t))
    due = math.floor((t[-1] - t[0]) * FS / block + 1e-9) + 1
    assert blocks == due
    assert p.restarts == 0


def test_nothing_held_or_stream_active_plays_nothing_then_the_hold_starts_after_the_quiet_time():
    p = HoldPacer(FS, 200, 0.2)
    assert sum(_play(p, np.arange(0, 1, 0.005))) == 0          # nothing held
    p.set_point([0.0, 1e-6])
    p.note_block(1.0)
    quiet = _play(p, 1.0 + np.arange(0, 0.2, 0.005))              # within hold_timeout of the last block
    assert sum(quiet) == 0
    assert p.tick(1.2001) == 1                                       # quiet for hold_timeout: the first block now
    assert p.tick(1.2051) == 0 and p.tick(1.2102) == 1               # then one per 10 ms
    p.note_block(1.3)                                             # the stream is back: the hold stops
    assert p.tick(1.31) == 0
    np.testing.assert_array_equal(p.block(), np.tile([0.0, 1e-6], (200, 1)))


def test_quiet_time_is_at_least_two_block_periods():
    p = HoldPacer(FS, 2000, 0.0)                                  # 0.1 s blocks, no timeout asked
    p.set_point([0.0, 0.0])
    p.note_block(0.0)
    assert p.quiet_needed == pytest.approx(0.2)
    assert p.tick(0.19) == 0 and p.tick(0.2) == 1


def test_a_stall_restarts_the_schedule_instead_of_a_burst():
    p = HoldPacer(FS, 200, 0.2)
    p.set_point([0.0, 0.0])
    assert p.tick(10.0) == 1
    assert p.tick(10.03) == 3                                     # a late tick within the bound catches up
    assert p.tick(11.0) == 1 and p.restarts == 1                  # 1 s stalled: one block, schedule from here
    assert p.tick(11.01) == 1


def test_block_size_change_and_clear():
    p = HoldPacer(FS, 200, 0.2)
    p.set_point([1e-6, 0.0])
    assert p.tick(5.0) == 1
    p.set_block_size(400)
    assert p.block().shape == (400, 2) and p.tick(5.001) == 1 and p.tick(5.01) == 0 and p.tick(5.0215) == 1
    p.clear()
    assert p.tick(6.0) == 0
    with pytest.raises(ValueError, match="no held point"):
        p.block()


@pytest.mark.parametrize("kwargs,field", [({"sample_rate": 0}, "sample_rate"), ({"block_size": 2.5}, "block_size"),
                                          ({"hold_timeout": -1}, "hold_timeout"), ({"max_late_s": 0}, "max_late_s"),
                                          ({"sample_rate": float("nan")}, "sample_rate")])
def test_bad_settings_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=rf"^{field}"):
        HoldPacer(**{"sample_rate": FS, **kwargs})


def test_bad_point_refused():
    p = HoldPacer(FS)
    with pytest.raises(ValueError, match="^reference_point"):
        p.set_point([float("nan"), 0.0])
