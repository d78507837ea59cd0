"""DriverCore (core/hardware/driver_core.py): the driver without ROS, on the lockstep and clocked simulators.

Invariants checked on every scenario: the applied-voltage stream covers every stamped device sample exactly once, in
order, on the exact grid; it never leaves ±limit nor moves faster than the operating slew limit (or, in a safe ramp,
the ramp's own slew); the displacement answers exactly the applied voltage.
"""
import numpy as np
import pytest

from piezo_ff_ros.core.config import ConfigError, LimitsConfig
from piezo_ff_ros.core.hardware import ClockedSim, DriverCore, DriverSettings, LockstepSim
from piezo_ff_ros.core.hardware.driver_core import ERROR, OK, WARN
from piezo_ff_ros.core.safety import SafeRampConfig

FS = 20000.0
P = 50_000
LIM = LimitsConfig(voltage=200.0, slew=1.0e7, stale_timeout=0.2, safe_voltage=0.0)


class Gain:
    def process(self, u):
        return 1e-7 * np.asarray(u)

    def reset(self):
        pass


class FakeClock:
    def __init__(self):
        self.n = 0

    def __call__(self):
        return self.n / FS

    def advance(self, samples):
        self.n += samples


def lockstep(clock=None, **kw):
    s = DriverSettings(sample_rate=FS, n_axes=2, limits=kw.pop("limits", LIM), **kw)
    core = DriverCore(s, LockstepSim(FS, 2, Gain()), now=clock or FakeClock())
    core.start()
    return core


class Log:
    """Everything a core emitted, with the invariants."""

    def __init__(self):
        self.applied, self.y, self.log = [], [], []

    def add(self, em):
        self.applied += em.applied
        self.y += em.displacement
        self.log += em.log
        return em

    def stream(self):
        stamps = np.concatenate([s + P * np.arange(b.shape[0]) for s, b in self.applied])
        u = np.vstack([b for _, b in self.applied])
        return stamps, u

    def check(self, limit=200.0, slew_step=None):
        stamps, u = self.stream()
        assert np.all(np.diff(stamps) > 0), "applied samples out of order or repeated"
        assert np.all(np.abs(u) <= limit)
        if slew_step is not None:
            assert np.abs(np.diff(u, axis=0)).max() <= slew_step + 1e-9
        if self.y:                                # every measured sample answers the applied sample of its stamp
            ystamps = np.concatenate([s + P * np.arange(b.shape[0]) for s, b in self.y])
            y = np.vstack([b for _, b in self.y])
            assert np.all(np.diff(ystamps) > 0)
            idx = np.searchsorted(stamps, ystamps)
            assert np.all(stamps[idx] == ystamps)
            np.testing.assert_array_equal(y, 1e-7 * u[idx])
        return stamps, u


def test_contiguous_stream_applied_exactly_and_published_once():
    core, L = lockstep(), Log()
    rng = np.random.default_rng(0)
    blocks = [rng.uniform(-50, 50, size=(200, 2)) for _ in range(10)]
    for i, b in enumerate(blocks):
        L.add(core.on_block(i * 200 * P, b))
    stamps, u = L.check(slew_step=500.0)
    np.testing.assert_array_equal(stamps, np.arange(2000) * P)
    np.testing.assert_array_equal(u, np.vstack(blocks))
    assert core.health()[0] == OK


def test_future_stamped_block_does_not_stall_the_stream():
    """One block stamped far in the future costs only itself: the blocks after it are applied, not dropped as late
    (reproduced on the node before the fix)."""
    core, L = lockstep(), Log()
    L.add(core.on_block(0, np.ones((200, 2))))
    L.add(core.on_block(10 ** 12, np.ones((200, 2))))   # ~16 min in the future
    for i in range(1, 20):
        L.add(core.on_block(i * 200 * P, np.full((200, 2), 2.0)))
    stamps, _ = L.check()
    np.testing.assert_array_equal(stamps, np.arange(20 * 200) * P)
    st = core.status()
    assert st["late_blocks"] == 0 and st["out_of_sequence_blocks"] == 1
    level, msg = core.health()
    assert level == WARN and "out-of-sequence" in msg


def test_lost_blocks_are_flagged_with_counts():
    """A burst that loses 92 % of the blocks leaves /diagnostics at WARN or worse, with the lost counts."""
    core, L = lockstep(), Log()
    core.health()
    k = 0
    for i in range(300):
        if i % 12 == 0:      # only 1 block in 12 arrives
            L.add(core.on_block(k * P, np.ones((100, 2))))
        k += 100
    stamps, _ = L.check()
    np.testing.assert_array_equal(stamps, np.arange(stamps.size) * P)   # the gaps were held, not skipped
    st = core.status()
    assert st["gap_samples"] == 24 * 11 * 100 and st["lost_blocks"] == 24 * 11
    level, msg = core.health()
    assert level == ERROR and "samples lost" in msg and "264 lost" in msg
    assert core.health()[0] == WARN      # later periods without loss: still flagged


@pytest.mark.parametrize("u_from", [[200.0, -200.0], [148.0, 120.0], [-78.6, 0.0]])
def test_safe_ramp_worst_step_is_bounded_by_its_own_slew_and_duration(u_from):
    """The ramp to safe moves by steps its own slew and duration bound (it was a single 78.6 V → 0 V step because it
    used the 1e7 V/s operating limit)."""
    clock = FakeClock()
    ramp = SafeRampConfig(duration=0.05, slew=1.0e4)
    core, L = lockstep(clock, ramp=ramp), Log()
    L.add(core.on_block(0, np.tile(u_from, (400, 1))))
    clock.advance(int(0.25 * FS))                  # > stale_timeout
    L.add(core.tick())
    assert core.state == "safe"
    stamps, u = L.check()
    r = u[400:]
    np.testing.assert_array_equal(stamps[400:], (400 + np.arange(r.shape[0])) * P)
    steps = np.abs(np.diff(np.vstack([u_from, r]), axis=0))
    assert steps.max() <= ramp.slew / FS + 1e-12                 # ≤ 0.5 V per sample
    assert r.shape[0] >= ramp.duration * FS                      # ≥ 50 ms
    np.testing.assert_array_equal(r[-1], [0.0, 0.0])
    assert max(np.max(np.abs(u_from)) / (ramp.duration * FS), 0) >= steps.max() - 1e-12 or \
        r.shape[0] > ramp.duration * FS


def test_rejected_block_holds_and_resume_after_safe_is_announced():
    clock = FakeClock()
    core, L = lockstep(clock), Log()
    L.add(core.on_block(0, np.full((100, 2), 10.0)))
    bad = np.full((100, 2), 5.0)
    bad[3, 0] = np.nan
    L.add(core.on_block(100 * P, bad))
    L.add(core.on_block(200 * P, None, n=100, reject="fields ['y', 'x'], expected axes ['x', 'y']"))
    stamps, u = L.check()
    assert np.all(u[100:] == 10.0) and stamps.size == 300
    assert core.status()["rejected_blocks"] == 2
    clock.advance(10000)
    L.add(core.tick())
    assert core.state == "safe"
    late = L.add(core.on_block(0, np.full((100, 2), 1.0)))          # a late block does not resume
    assert not any("resumed" in t for _, t in late.log) and core.state == "safe"
    em = L.add(core.on_block(core.next_stamp, np.full((100, 2), 1.0)))
    assert any("resumed" in t for _, t in em.log) and core.status()["resumes"] == 1
    L.check()


def test_settings_validated_with_the_field_named():
    for kw, field in ((dict(max_block=0), "max_block"), (dict(max_gap=-1.0), "max_gap"),
                      (dict(write_ahead=0.0), "write_ahead"), (dict(low_water=0.6), "low_water"),
                      (dict(ramp=SafeRampConfig(duration=float("nan"))), "safe_ramp.duration"),
                      (dict(limits=LimitsConfig(voltage=-1.0)), "limits.voltage")):
        with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
            DriverSettings(sample_rate=FS, n_axes=2, limits=kw.pop("limits", LIM), **kw).validate()


# -- clocked ------------------------------------------------------------------------------------------------------
def clocked(**kw):
    clock = FakeClock()
    sim = ClockedSim(FS, 2, Gain(), fifo_depth=4000, latency_samples=5, now=clock)
    s = DriverSettings(sample_rate=FS, n_axes=2, limits=LIM, write_ahead=0.05, low_water=0.01, **kw)
    core = DriverCore(s, sim, now=clock)
    return core, sim, clock


def test_clocked_stream_paced_by_the_device_no_loss_and_latency_mapped_back_to_stamps():
    core, sim, clock = clocked()
    L = Log()
    L.add(core.start())
    t0 = 123_456 * P
    u = np.column_stack([np.linspace(0, 50, 6000), np.linspace(0, -50, 6000)])
    for i in range(30):                    # one 200-sample block per 200 samples of device time
        L.add(core.on_block(t0 + i * 200 * P, u[i * 200:(i + 1) * 200]))
        for _ in range(4):
            clock.advance(50)
            L.add(core.tick())
    for _ in range(7):                     # the stream ended; the FIFO still holds ~1000 samples
        clock.advance(100)
        L.add(core.tick())
    stamps, a = L.check()
    assert stamps[0] == t0                 # nothing published before the stream's first sample
    np.testing.assert_array_equal(stamps[:5600], t0 + np.arange(5600) * P)
    np.testing.assert_array_equal(a[:5600], u[:5600])
    # one applied block and one displacement block per voltage block, with its stamp, whatever the device's chunks
    assert [s for s, _ in L.applied[:28]] == [t0 + i * 200 * P for i in range(28)]
    assert [s for s, _ in L.y[:27]] == [t0 + i * 200 * P for i in range(27)]
    assert all(b.shape[0] == 200 for _, b in L.y[:27])
    st = core.status()
    assert st["starved_samples"] == 0 and st["underrun_faults"] == 0 and st["gap_samples"] == 0
    assert st["latency_samples"] == 5


def test_clocked_late_stream_is_held_counted_and_trimmed_then_stale_ramp():
    core, sim, clock = clocked()
    L = Log()
    L.add(core.start())
    L.add(core.on_block(0, np.full((200, 2), 20.0)))
    for _ in range(80):                    # 400 ms of device time without a block (a stalled compensator)
        clock.advance(100)
        L.add(core.tick())
    st = core.status()
    assert st["starved_samples"] > 0 and core.state == "safe"
    assert st["underrun_faults"] == 0      # the driver kept the FIFO fed: the device never ran dry
    stamps, u = L.check()
    i_ramp = np.flatnonzero(u[:, 0] < 20.0)[0]
    assert np.all(u[200:i_ramp] == 20.0)   # held until the stale timeout, then ramped
    assert u[-1, 0] == 0.0
    level, msg = core.health()
    assert level in (WARN, ERROR) and "starved" in msg


def test_clocked_device_faults_become_safe_ramp_and_diagnostics():
    core, sim, clock = clocked()
    L = Log()
    L.add(core.start())
    L.add(core.on_block(0, np.full((200, 2), 100.0)))
    clock.advance(10)
    sim.inject("underrun")
    em = L.add(core.tick())
    assert core.state == "safe" and core.status()["underrun_faults"] == 1
    assert any(lvl == ERROR and "underrun" in t for lvl, t in em.log)
    sim.inject("disconnect")
    L.add(core.tick())
    assert core.state == "fault" and core.health()[0] == ERROR
    assert core.on_block(10 ** 6, np.ones((10, 2))).log[0][0] == ERROR


def test_clocked_stream_recovers_after_a_host_stall():
    """A 300 ms stall of the host (no tick, no block): the device runs dry (one underrun), the driver ramps to safe;
    the sender then catches up with its backlog (as the trajectory node does in realtime mode): the blocks whose
    instants are past are dropped and counted, and the stream is applied again from the first block that is in
    time — it is not dropped block after block (what a loaded host saw before the driver kept its own holds close
    to the clock)."""
    core, sim, clock = clocked()
    L = Log()
    L.add(core.start())
    i = 0
    for step in range(60):                         # one block per 200 samples of device time, catching up
        if step == 10:
            clock.advance(6000)                   # the stall: 300 ms of device time, nothing from the host
            L.add(core.tick())
        due = step + (30 if step >= 10 else 0)    # blocks the sender owes by now
        while i <= due:
            L.add(core.on_block(i * 200 * P, np.full((200, 2), 30.0 + i)))
            i += 1
        for _ in range(4):
            clock.advance(50)
            L.add(core.tick())
    st = core.status()
    assert st["underrun_faults"] == 1 and st["resumes"] == 1 and core.state == "active"
    assert st["late_blocks"] > 0 and st["late_samples"] >= st["late_blocks"] * 200
    stamps, a = L.check()
    for j in range(60, 80):                        # the last blocks: applied exactly as sent, at their stamps
        k = np.searchsorted(stamps, j * 200 * P)
        assert stamps[k] == j * 200 * P
        np.testing.assert_array_equal(a[k:k + 200], 30.0 + j)


def test_stream_paced_lockstep_sim_does_not_ramp_on_a_host_stall_and_loses_nothing():
    """While a lockstep trajectory paces a lockstep simulator, the simulator's time follows the
    samples written, so a host stall longer than ``stale_timeout`` is no stale input: no ramp, and the blocks in flight
    are applied, none late.  Once the pacing ends (the run finished, failed or its source is gone) the wall-clock
    watchdog is back."""
    clock = FakeClock()
    core, L = lockstep(clock), Log()
    assert core.info.time_follows_samples
    L.add(core.on_block(0, np.full((200, 2), 10.0)))
    L.add(core.set_stream_paced(True, "lockstep trajectory playing"))
    clock.advance(int(5.0 * FS))                    # a 5 s stall ≫ stale_timeout 0.2 s
    L.add(core.tick())
    assert core.state == "active" and core.status()["stream_paced"] is True
    L.add(core.on_block(200 * P, np.full((200, 2), 11.0)))
    stamps, u = L.check()
    np.testing.assert_array_equal(stamps, np.arange(400) * P)
    np.testing.assert_array_equal(u[200:], 11.0)
    assert core.lost_samples() == 0 and core.book.counters.late_blocks == 0
    L.add(core.set_stream_paced(False, "trajectory finished"))
    assert any("wall clock" in m for _, m in L.log)
    clock.advance(int(0.25 * FS))
    L.add(core.tick())
    assert core.state == "safe"                     # the watchdog runs again


def test_stream_pacing_is_ignored_by_devices_whose_time_runs_on_its_own():
    """A clocked device (and a non-clocked real device, whose time is the wall clock) keeps the stale watchdog
    whatever the trajectory says: a stall there does hold a voltage on a real stage."""
    clock = FakeClock()
    s = DriverSettings(sample_rate=FS, n_axes=2, limits=LIM)
    sim = ClockedSim(FS, 2, Gain(), fifo_depth=8000, now=clock)
    core, L = DriverCore(s, sim, now=clock), Log()
    assert not core.info.time_follows_samples
    L.add(core.start())
    em = L.add(core.set_stream_paced(True, "lockstep trajectory playing"))
    assert any("ignored" in m for _, m in em.log) and core.status()["stream_paced"] is False
    L.add(core.on_block(core.next_stamp or 0, np.full((200, 2), 10.0)))
    clock.advance(int(0.5 * FS))   # > stale_timeout, and the block (0.5 s write-ahead) has played out
    L.add(core.tick())
    assert core.state == "safe"
