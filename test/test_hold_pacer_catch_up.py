"""A held point stays on the wall clock through the short stalls of a loaded host (core/hold_pacer.py, no ROS).

The driver places the first held block ``write_ahead`` (0.5 s) ahead of its device clock; the pacer then plays the
blocks due.  A stall the driver survives (its queue still holds samples) must not shorten that margin for good: the
pacer plays the blocks due at once.  A stall longer than the write-ahead restarts the schedule (no burst of blocks
for instants the device has already passed).
"""
import math

from piezo_ff_ros.core.hold_pacer import HOLD_BLOCK_SIZE, HoldPacer

FS = 20000.0


def _due(t0, t, block):
    return math.floor((t - t0) * FS / block + 1e-9) + 1


def test_stalls_shorter_than_the_write_ahead_are_caught_up_and_the_stream_stays_on_the_wall_clock():
    p = HoldPacer(FS, HOLD_BLOCK_SIZE, 0.2)
    p.set_point([1e-6, 0.0])
    t0 = 100.0
    played = p.tick(t0)
    t = t0
    for stall in (0.15, 0.3, 0.15, 0.45, 0.15):       # 1.2 s of stalls in all, each shorter than 0.5 s
        for _ in range(10):                          # 10 ticks at the timer's period
            t += 0.025
            played += p.tick(t)
        t += stall
        played += p.tick(t)
    assert p.restarts == 0
    assert played == _due(t0, t, HOLD_BLOCK_SIZE)    # every block due by now: no margin lost


def test_a_stall_longer_than_the_write_ahead_restarts_the_schedule():
    p = HoldPacer(FS, HOLD_BLOCK_SIZE, 0.2)
    p.set_point([0.0, 0.0])
    assert p.tick(10.0) == 1
    assert p.tick(10.8) == 1 and p.restarts == 1
