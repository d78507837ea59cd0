"""The driver's stale-input watchdog and the driver's own stalls (core/hardware/driver_core.py, no ROS).

A driver process that stood still (a garbage collection, a host that did not schedule it) finds, when it wakes up,
its tick due before the blocks that arrived meanwhile are read: that time is not the input's silence.  A source that
really stopped is still found ``stale_timeout`` of running time later.
"""
import numpy as np

from piezo_ff_ros.core.config import LimitsConfig
from piezo_ff_ros.core.hardware import ClockedSim, DriverCore, DriverSettings

FS = 20000.0
LIM = LimitsConfig(voltage=200.0, slew=1.0e7, stale_timeout=0.2, safe_voltage=0.0)


class Gain:
    def process(self, u):
        return 1e-7 * np.asarray(u)

    def reset(self):
        pass


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _clocked():
    clock = Clock()
    sim = ClockedSim(FS, 2, Gain(), fifo_depth=40000, now=lambda: int(round(clock.t * FS)) / FS)
    core = DriverCore(DriverSettings(sample_rate=FS, n_axes=2, limits=LIM), sim, now=clock)
    core.start()
    return core, clock


def _stream(core, clock, seconds, stamp, value=20.0):
    """Blocks of 200 samples every 10 ms, ticks every 5 ms in between; returns the next stamp."""
    for _ in range(int(round(seconds / 0.01))):
        core.on_block(stamp, np.full((200, 2), value))
        stamp += 200 * core.period_ns
        for _ in range(2):
            clock.t += 0.005
            core.tick()
    return stamp


def test_a_stall_of_the_driver_itself_is_not_stale_input_and_loses_no_block():
    core, clock = _clocked()
    stamp = _stream(core, clock, 0.1, core.next_stamp or 0)
    clock.t += 0.3                      # the driver stood still 0.3 s (> stale_timeout); the source did not
    em = core.tick(stalled=0.3 - LIM.stale_timeout / 2)
    assert core.state == "active", em.log
    for _ in range(30):                 # the 30 blocks that came meanwhile, read after the tick
        em.extend(core.on_block(stamp, np.full((200, 2), 20.0)))
        stamp += 200 * core.period_ns
    _stream(core, clock, 0.1, stamp)
    assert core.state == "active" and not any("no voltage block" in t or "late" in t for _, t in em.log), em.log
    assert core.book.counters.late_blocks == 0


def test_a_source_that_stops_is_still_stale_after_the_timeout_of_running_time():
    core, clock = _clocked()
    _stream(core, clock, 0.1, core.next_stamp or 0)
    clock.t += 0.3
    core.tick(stalled=0.3 - LIM.stale_timeout / 2)      # the driver's own stall: not counted
    assert core.state == "active"
    ticks = 0
    while core.state == "active":       # nothing comes any more: the watchdog runs on the driver's running time
        clock.t += 0.005
        ticks += 1
        em = core.tick()
        assert ticks < 100
    assert any("no voltage block for 0.2 s" in t for _, t in em.log)
    assert 0.005 * ticks <= LIM.stale_timeout     # the stall counted at most half a timeout, the rest ran


def test_a_source_that_pauses_while_its_blocks_still_play_loses_nothing():
    """A clocked device with the default write-ahead (0.5 s): the source pauses 0.3 s (> stale_timeout, < write-ahead
    − low_water) while the driver runs — the blocks already written still play, so no ramp, and the blocks that
    follow are applied, none late."""
    core, clock = _clocked()
    stamp = _stream(core, clock, 0.1, core.next_stamp or 0)
    for _ in range(60):                 # 0.3 s of ticks, no block
        clock.t += 0.005
        em = core.tick()
        assert core.state == "active", em.log
    _stream(core, clock, 0.1, stamp)
    assert core.state == "active" and core.book.counters.late_blocks == 0 and core.starved_samples == 0


def test_a_stopped_source_ramps_where_its_last_block_ends():
    """The source stops: the ramp starts right after the last block's samples (no hold before it), once they have
    played out within low_water, and no earlier than stale_timeout."""
    core, clock = _clocked()
    _stream(core, clock, 0.1, core.next_stamp or 0)
    t_last = clock.t - 0.01
    while core.state == "active":
        clock.t += 0.005
        em = core.tick()
        assert clock.t - t_last < 1.0
    assert clock.t - t_last >= LIM.stale_timeout
    assert core.starved_samples == 0                   # nothing held between the last block and the ramp
    assert any("no voltage block for 0.2 s" in t and "ramping from [20.0, 20.0] V" in t for _, t in em.log), em.log
