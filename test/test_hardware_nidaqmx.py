"""The nidaqmx backend and the driver core through nidaqmx 1.7's own ``Task``, ``AnalogMultiChannelWriter`` and
``AnalogMultiChannelReader``, with only the package's interpreter replaced by a fake card (``nidaqmx_fake``): a
hardware sample clock (stepped by hand here, real time where said), regeneration off, DAQmx's error codes, AI = AO a
few samples late.  Every value that reaches an AO pin is on the fake's wire record: the tests assert its largest
step.  No NI hardware or driver here (see docs/hardware.md)."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

nidaqmx = pytest.importorskip("nidaqmx")

from nidaqmx.constants import AcquisitionType, RegenerationMode  # noqa: E402

from nidaqmx_fake import DeviceClock, FakeDaq, install  # noqa: E402
from wire_invariant import assert_safe, largest_step  # noqa: E402

from piezo_ff_ros.backends import get_spec  # noqa: E402
from piezo_ff_ros.backends.nidaqmx_backend import NidaqmxBackend  # noqa: E402
from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.hardware import DriverCore, DriverSettings, Underrun  # noqa: E402

GAIN, OFFSET = [25.0, 25.0], [0.0, 2.0]
SCALE = {"Dev1/ao0": (GAIN[0], OFFSET[0]), "Dev1/ao1": (GAIN[1], OFFSET[1])}
FS = 20000.0
RAMP_STEP = 1.0e4 / FS       # the default safe ramp: 1e4 V/s


@pytest.fixture()
def daq(monkeypatch):
    """A card with a hand-stepped clock behind every nidaqmx.Task of the test."""
    return install(monkeypatch, FakeDaq(latency=3, clock=DeviceClock(manual=True)))


def params(**kw):
    p = {"ai_channels": "Dev1/ai0,Dev1/ai1", "amp_gain": GAIN, "amp_offset": OFFSET, "sensor_gain": [1.0, 1.0],
         "fifo_depth": 8000, "latency_samples": 3, **kw}
    return get_spec("nidaqmx").validate(p)


def make_core(dev, write_ahead=0.05, **kw):
    cfg = load_config()
    be = NidaqmxBackend(cfg, params(**kw), now=dev.clock.now, sleep=dev.clock.advance)
    core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits, write_ahead=write_ahead,
                                     low_water=0.01), be, now=dev.clock.now, sleep=dev.clock.advance)
    return be, core


def trace(dev):
    return {ch: (t, SCALE[ch][0] * v + SCALE[ch][1]) for ch, (t, v) in dev.trace().items()}


class Stream:
    """Sends blocks of 200 samples on the stamp grid, one per 10 ms of device time, ticking in between."""

    def __init__(self, core, dev):
        self.core, self.dev, self.k, self.applied, self.measured, self.log = core, dev, 0, [], [], []

    def take(self, em):
        self.applied += em.applied
        self.measured += em.displacement
        self.log += em.log

    def send(self, u):
        self.take(self.core.on_block(self.k * 50_000, u))
        self.k += u.shape[0]
        self.dev.clock.advance(u.shape[0] / FS)
        self.take(self.core.tick())

    def idle(self, seconds, step=0.005):
        for _ in range(int(round(seconds / step))):
            self.dev.clock.advance(step)
            self.take(self.core.tick())


def ramp_to(v_from, v_to, n):
    return np.column_stack([np.linspace(v_from, v_to, n), np.linspace(-v_from, -v_to, n)])


def test_tasks_configured_as_documented_and_stream_aligned(daq):
    be, core = make_core(daq)
    core.start()
    ao, ai = [t for t in daq.tasks.values() if t.ao][0], [t for t in daq.tasks.values() if t.ai][0]
    assert ao.ao == ["Dev1/ao0", "Dev1/ao1"] and ai.ai == ["Dev1/ai0", "Dev1/ai1"]
    assert ao.rate == FS and ao.mode == AcquisitionType.CONTINUOUS.value and ao.buf_size == 8000
    assert ao.regen == RegenerationMode.DONT_ALLOW_REGENERATION.value
    assert ai.source == "/Dev1/ao/SampleClock" and ai.trigger == "/Dev1/ao/StartTrigger"
    assert ao.running and ai.running
    assert ao.buffered == 1000      # the write-ahead of safe voltage, written before the clock started
    s = Stream(core, daq)
    u = ramp_to(0.0, 50.0, 4000)
    for i in range(20):
        s.send(u[i * 200:(i + 1) * 200])
    s.idle(0.1)
    a = np.vstack([b for _, b in s.applied])
    np.testing.assert_array_equal(a[:4000], u)
    assert [st for st, _ in s.applied][:3] == [0, 200 * 50_000, 400 * 50_000]
    # the loopback (AI = AO three samples late) tagged with latency_samples=3: each displacement sample on the stamp
    # of the voltage it answers, through the amplifier's gain/offset
    y = np.vstack([b for st, b in s.measured if st >= 0])
    n = min(y.shape[0], 4000)
    np.testing.assert_allclose(y[:n], (u[:n] - OFFSET) / GAIN, rtol=0, atol=1e-12)
    assert core.status()["underrun_faults"] == 0 and core.status()["overrun_faults"] == 0
    assert_safe(trace(daq), 1 / FS, RAMP_STEP)


def test_first_block_does_not_underflow_in_a_fresh_process(tmp_path):
    """A new process (compiled kernels not loaded yet): the kernel the first block runs (the guard's limiter) is
    compiled before the AO task's clock starts (loading it takes 0.3-0.5 s, longer than a write-ahead), and the first
    block right after start, on a real-time clock with the write-ahead at 0.2 s, does not underflow."""
    here = Path(__file__).resolve().parent
    script = textwrap.dedent(f"""
        import sys, time
        sys.path[:0] = [{str(here)!r}, {str(here.parent)!r}]
        import numpy as np
        from nidaqmx_fake import DeviceClock, FakeDaq, FakeInterpreter
        import nidaqmx.utils
        from piezo_ff_ros.core.kernels.limits import limit_run
        dev = FakeDaq(latency=3, clock=DeviceClock())
        compiled_at_start = []

        class Interp(FakeInterpreter):
            def start_task(self, task):
                compiled_at_start.append(len(limit_run.signatures))
                return super().start_task(task)

        nidaqmx.utils._select_interpreter = lambda grpc_options=None, interpreter=None: Interp(dev)
        from piezo_ff_ros.backends import get_spec
        from piezo_ff_ros.backends.nidaqmx_backend import NidaqmxBackend
        from piezo_ff_ros.core.config import load_config
        from piezo_ff_ros.core.hardware import DriverCore, DriverSettings
        cfg = load_config()
        p = get_spec("nidaqmx").validate({{"amp_gain": [25.0, 25.0]}})
        core = DriverCore(DriverSettings(sample_rate=cfg.sample_rate, n_axes=2, limits=cfg.limits,
                                         write_ahead=0.2, low_water=0.05), NidaqmxBackend(cfg, p))
        core.start()
        core.on_block(0, np.full((200, 2), 1.0))
        t_end = time.monotonic() + 0.3
        while time.monotonic() < t_end:
            core.tick()
            time.sleep(0.002)
        print("compiled at start", compiled_at_start)
        print("underruns", core.status()["underrun_faults"])
        core.close()
    """)
    env = {**os.environ, "PYTHONPATH": str(here.parent)}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "compiled at start [1]" in out.stdout, out.stdout
    assert "underruns 0" in out.stdout, out.stdout + out.stderr[-2000:]


@pytest.mark.parametrize("call, code", [
    ("write_analog_f64", -200290),    # underflow reported by a write
    ("read_analog_f64", -200279),     # AI samples overwritten, reported by a read
    ("is_task_done", -200290),        # underflow reported by the poll
    ("get_read_attribute_uint32", -200279),
])
def test_underflow_and_overrun_from_any_call_take_the_fault_path(daq, call, code):
    be, core = make_core(daq)
    core.start()
    s = Stream(core, daq)
    u = ramp_to(0.0, 40.0, 4000)
    for i in range(10):
        s.send(u[i * 200:(i + 1) * 200])
    daq.fail[call] = code
    for i in range(10, 12):
        s.send(u[i * 200:(i + 1) * 200])       # the error surfaces here: no exception out of the core
    s.idle(0.4)
    st = core.status()
    kind = "underrun" if code == -200290 else "overrun"
    assert st[f"{kind}_faults"] == 1, st
    assert core.state == "safe" and np.all(core.guard.u_last == 0.0)
    assert any(f"device {kind}" in t for _, t in s.log), s.log
    tr = trace(daq)
    assert_safe(tr, 1 / FS, RAMP_STEP)
    assert all(abs(v[-1]) < 1e-12 for _, v in tr.values())    # at the safe voltage, still generating
    core.close()
    assert all(t.cleared for t in daq.tasks.values())


def test_a_failing_restart_start_is_a_fault_not_a_crash(daq):
    be, core = make_core(daq)
    core.start()
    s = Stream(core, daq)
    u = ramp_to(0.0, 40.0, 4000)
    for i in range(5):
        s.send(u[i * 200:(i + 1) * 200])
    daq.clock.advance(0.1)                     # the host stalls: the buffer runs dry (-200290)
    daq.fail["start_task"] = -200290            # and the restart's start reports it again
    s.idle(0.5)
    assert core.state in ("safe", "fault")
    assert core.status()["underrun_faults"] >= 1
    core.close()
    assert all(t.cleared for t in daq.tasks.values())
    assert_safe(trace(daq), 1 / FS, RAMP_STEP)


def test_restart_after_an_underrun_prefills_and_keeps_the_stamps_true(daq):
    """The restarted task gets the write-ahead before its clock starts (no second underflow), the time the output
    was held is counted (later stamps true to when their samples are generated) and AI samples of the stopped
    task are delivered, not dropped."""
    be, core = make_core(daq)
    core.start()
    s = Stream(core, daq)
    n = 16000
    u = np.column_stack([10.0 + 0.001 * np.arange(n), np.full(n, -5.0)])   # unique values: found on the wire
    for i in range(20):
        s.send(u[i * 200:(i + 1) * 200])
    daq.clock.advance(0.15)        # host stall longer than the write-ahead: -200290, the output holds
    s.k += 3000                    # the sender stalled too: its next block is for now
    for i in range(35, 80):
        s.send(u[i * 200:(i + 1) * 200])
    s.idle(0.2)
    st = core.status()
    assert st["underrun_faults"] == 1, (st, s.log)      # one underflow; the restart itself did not underflow
    # stamps: every streamed sample reported applied was generated at (its stamp + one constant offset)
    ch0 = [(t, v) for t, ch, v in daq.wire if ch == "Dev1/ao0"]
    seen = Counter(v for _, v in ch0)
    when = {v: t for t, v in ch0 if seen[v] == 1}     # held values repeat: they say nothing about time
    offsets = []
    for stamp, blk in s.applied:
        for j, val in enumerate(blk[:, 0]):
            if blk[j, 1] == -5.0:      # a streamed sample (holds and ramps differ on axis 1)
                t = when.get((val - OFFSET[0]) / GAIN[0])
                if t is not None:
                    offsets.append(t - (stamp + j * 50_000) * 1e-9)
    offsets = np.array(offsets)
    assert offsets.size > 4000
    assert np.ptp(offsets) <= 1.5 / FS, (offsets.min(), offsets.max())
    # what the AI of the stopped task had acquired was delivered (or counted as an overrun)
    assert st["overrun_faults"] == 0
    ks = sorted(stamp for stamp, _ in s.measured)
    assert ks and ks[0] <= 0 + 200 * 50_000


def test_close_ramps_to_safe_while_generating_then_stops(daq):
    """SIGINT at 100 V: the output comes down by the safe ramp, in time, never 100 V → 0 in one sample."""
    be, core = make_core(daq)
    core.start()
    s = Stream(core, daq)
    u = np.vstack([ramp_to(0.0, 100.0, 4000), ramp_to(100.0, 100.0, 2000)])
    for i in range(30):
        s.send(u[i * 200:(i + 1) * 200])
    t_close = daq.clock.now()
    core.close()
    tr = trace(daq)
    assert largest_step(tr, t_from=t_close - 0.01) <= RAMP_STEP * (1 + 1e-9)
    assert_safe(tr, 1 / FS, RAMP_STEP)
    assert all(abs(v[-1]) < 1e-12 for _, v in tr.values())
    assert all(t.cleared and not t.running for t in daq.tasks.values())


def test_backend_close_alone_after_an_underflow_ramps_from_the_held_voltage(daq):
    """The crash path: the AO task died (underflow) at 100 V and the backend is closed without the driver core."""
    be, core = make_core(daq)
    core.start()
    s = Stream(core, daq)
    u = ramp_to(0.0, 100.0, 4000)
    for i in range(20):
        s.send(u[i * 200:(i + 1) * 200])
    daq.clock.advance(0.5)                      # the buffer runs dry: the output holds 100 V
    with pytest.raises(Underrun):
        be.poll()
    be.close()
    tr = trace(daq)
    assert_safe(tr, 1 / FS, RAMP_STEP)
    assert all(abs(v[-1]) < 1e-12 for _, v in tr.values())
    assert all(t.cleared for t in daq.tasks.values())


def test_ai_task_closed_when_stopping_the_ao_task_raises(daq):
    be, core = make_core(daq)
    core.start()
    s = Stream(core, daq)
    s.send(np.zeros((200, 2)))
    daq.fail["stop_task"] = -200290
    core.close()
    assert all(t.cleared for t in daq.tasks.values()), {t.name: t.cleared for t in daq.tasks.values()}


@pytest.mark.parametrize("kw, msg", [
    (dict(ao_channels="Dev1/ao0"), "ao_channels: 1 channel"),
    (dict(amp_gain=[1.0, 1.0]), "ao_range"),
    (dict(amp_gain=[0.0, 20.0]), "amp_gain"),
    (dict(sensor_gain=[1.0, 2.0, 3.0]), "sensor_gain"),
])
def test_bad_wiring_parameters_refused(kw, msg):
    from piezo_ff_ros.backends import BackendError

    with pytest.raises(BackendError, match=msg):
        NidaqmxBackend(load_config(), params(**kw))


def test_without_the_ni_library_start_fails_with_one_line():
    """The real package here has no NI-DAQmx driver: starting must be a clear BackendError, not a traceback."""
    be = NidaqmxBackend(load_config(), params())
    from piezo_ff_ros.backends import BackendError

    with pytest.raises(BackendError, match="nidaqmx: cannot start on Dev1"):
        be.start(np.zeros(2), prefill=10)


def _stall_and_resume(daq, core, fail=None):
    s = Stream(core, daq)
    u = np.column_stack([np.linspace(1.0, 9.0, 4000), np.full(4000, -3.0)])
    for i in range(10):
        s.send(u[i * 200:(i + 1) * 200])
    daq.clock.advance(0.12)                    # host stall: the buffer runs dry, the AI keeps what it acquired
    if fail:
        daq.fail.update(fail)
    s.idle(0.3)
    return s, u


def test_ai_samples_acquired_before_an_underflow_are_delivered_after_the_restart(daq):
    be, core = make_core(daq)
    core.start()
    s, u = _stall_and_resume(daq, core)
    assert core.status()["underrun_faults"] == 1 and core.status()["overrun_faults"] == 0
    # every streamed sample's answer (AI = AO three samples late, tagged back by latency_samples=3) came back, but
    # for the last three: the clock stopped before their answers were sampled
    got = {st + j * 50_000: row for st, blk in s.measured for j, row in enumerate(blk)}
    for k in range(2000 - 3):
        np.testing.assert_allclose(got[k * 50_000], (u[k] - OFFSET) / GAIN, rtol=0, atol=1e-12)


def test_ai_samples_that_cannot_be_read_at_a_restart_count_as_an_overrun(daq):
    be, core = make_core(daq)
    core.start()
    s, _ = _stall_and_resume(daq, core, fail={"get_read_attribute_uint32": -200279})
    st = core.status()
    assert st["underrun_faults"] == 1 and st["overrun_faults"] == 1, (st, s.log)
    assert any("AI samples" in t and "lost" in t for _, t in s.log), s.log


def test_an_ai_buffer_that_overflows_is_an_overrun_fault_and_a_ramp(daq):
    """The card overwrites unread AI samples (-200279 on the next read): an overrun through the fault path."""
    be, core = make_core(daq, input_buffer=150)
    core.start()
    s = Stream(core, daq)
    s.send(ramp_to(0.0, 5.0, 200))
    daq.clock.advance(0.01)                    # 200 samples acquired, 150 kept: the oldest are overwritten
    s.take(core.tick())
    s.idle(0.2)
    st = core.status()
    assert st["overrun_faults"] == 1 and st["underrun_faults"] == 0, st
    assert any("AI samples lost (-200279)" in t for _, t in s.log)
    assert core.state == "safe"
    assert_safe(trace(daq), 1 / FS, RAMP_STEP)
    # both tasks restarted (DAQmx reports the overrun until then): the sensor answers again, on the right stamps
    assert be.restarts == 1
    late = [(st, b) for st, b in s.measured if st > s.k * 50_000 + 2000 * 50_000]
    rest = (np.zeros(2) - OFFSET) / GAIN                          # the output rests at 0 V: what the AI reads back
    assert late and all(np.allclose(b, rest, rtol=0, atol=1e-12) for _, b in late)


def test_backend_close_alone_while_generating_at_100_v_ramps_then_stops(daq):
    """A crash path that skips the driver core: the backend closed while its task still generates at 100 V."""
    be, core = make_core(daq)
    core.start()
    s = Stream(core, daq)
    u = np.vstack([ramp_to(0.0, 100.0, 4000), ramp_to(100.0, 100.0, 1000)])
    for i in range(25):
        s.send(u[i * 200:(i + 1) * 200])
    be.close()
    tr = trace(daq)
    assert_safe(tr, 1 / FS, RAMP_STEP)
    assert all(abs(v[-1]) < 1e-12 for _, v in tr.values())
    assert all(t.cleared for t in daq.tasks.values())
