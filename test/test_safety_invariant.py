"""The driver's safety invariant, property-tested on every streaming backend through a stand-in of its device.

Whatever happens — random voltage blocks (clamped, slew-limited), gaps, late and out-of-sequence stamps, host
stalls (underruns), idle input (the stale ramp), injected device faults and DAQmx errors from any call, then
``close()`` — between any two values that reach the output the voltage changes by no more than the allowed step per
sample (``wire_invariant``), and after ``close()`` the output rests at the safe voltage (unless the device is gone).

Backends: the lockstep and clocked simulators (their output record is the device's), ``nidaqmx`` through
nidaqmx's own Task/stream classes with the fake card of ``nidaqmx_fake`` (every value on its AO pins), and
``pi_gcs`` through pipython's ``PISocket`` against the GCS emulator on TCP (every set point that reached the
controller's output, with the time it arrived; a set-and-hold device: ``holds_earn_credit=True``, at most 1 V between
set points), with GCS errors and a dropped connection among the faults.  Another backend joins by adding a
``Bench`` factory that returns its wire trace.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wire_invariant import assert_safe

from piezo_ff_ros.core.config import LimitsConfig, load_config
from piezo_ff_ros.core.hardware import ClockedSim, DriverCore, DriverSettings, LockstepSim
from piezo_ff_ros.core.hardware.simulated_device import inject_fault
from piezo_ff_ros.core.safety import SafeRampConfig

FS = 20000.0
PERIOD_NS = 50_000
# the operating slew limit equal to the safe ramp's: every path must then stay within one step per sample
LIM = LimitsConfig(voltage=100.0, slew=1.0e4, stale_timeout=0.2, safe_voltage=0.0)
STEP = 1.0e4 / FS
CFG = replace(load_config(), limits=LIM)


class ManualClock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


@dataclass
class Bench:
    """A backend, the driver core on it, the clock both run on, and how to read the wire and inject faults."""

    core: DriverCore
    clock: ManualClock
    trace: Callable[[], dict[str, tuple[np.ndarray, np.ndarray]]]
    inject: Callable[[str], None]
    faults: list[str]
    holds_earn_credit: bool = False
    max_change: float | None = None     #: largest change between two values on the wire [V] (set-and-hold)
    close: Callable[[], None] = lambda: None   #: releases the stand-in (a server thread)


class _Recorded:
    """Records every output sample of a simulator with its device time (the simulator's output is its wire)."""

    def _output(self, k0: int, u: np.ndarray) -> None:
        self.wire.append((k0, np.array(u, dtype=float)))
        super()._output(k0, u)   # type: ignore[misc]

    def trace(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        if not self.wire:
            return {}
        k = np.concatenate([k0 + np.arange(u.shape[0]) for k0, u in self.wire])
        u = np.vstack([u for _, u in self.wire])
        return {f"axis{a}": (k / FS, u[:, a]) for a in range(u.shape[1])}


class RecordedClocked(_Recorded, ClockedSim):
    def __init__(self, *a: Any, **kw: Any) -> None:
        self.wire: list = []
        super().__init__(*a, **kw)


class RecordedLockstep(_Recorded, LockstepSim):
    def __init__(self, *a: Any, **kw: Any) -> None:
        self.wire: list = []
        super().__init__(*a, **kw)


WRITE_AHEAD = {"value": 0.05}      # drawn per example (see the test)


def _settings() -> DriverSettings:
    wa = WRITE_AHEAD["value"]
    return DriverSettings(sample_rate=FS, n_axes=2, limits=LIM, ramp=SafeRampConfig(), write_ahead=wa,
                          low_water=wa / 5)


def bench_sim(mode: str, monkeypatch: Any) -> Bench:
    clock = ManualClock()
    if mode == "lockstep":
        be: Any = RecordedLockstep(FS, 2, None)
    else:
        be = RecordedClocked(FS, 2, None, fifo_depth=4000, now=clock.now)
    core = DriverCore(_settings(), be, now=clock.now, sleep=clock.advance)
    return Bench(core, clock, be.trace, lambda kind: inject_fault(be, kind),
                 ["underrun", "overrun", "limit", "disconnect"])


NI_ERRORS = {"write underflow": ("write_analog_f64", -200290), "read overrun": ("read_analog_f64", -200279),
             "poll underflow": ("is_task_done", -200290), "clock underflow": ("get_write_attribute_uint64", -200290),
             "restart start": ("start_task", -200290), "space underflow": ("get_write_attribute_uint32", -200290),
             "device gone": ("is_task_done", -201003)}


def bench_nidaqmx(monkeypatch: Any, fifo_depth: int = 4000) -> Bench:
    pytest.importorskip("nidaqmx")
    from nidaqmx_fake import DeviceClock, FakeDaq, install

    from piezo_ff_ros.backends import get_spec
    from piezo_ff_ros.backends.nidaqmx_backend import NidaqmxBackend

    dev = install(monkeypatch, FakeDaq(latency=2, clock=DeviceClock(manual=True)))
    clock = ManualClock()
    clock.now = dev.clock.now          # type: ignore[method-assign]
    clock.advance = dev.clock.advance  # type: ignore[method-assign]
    p = get_spec("nidaqmx").validate({"ai_channels": "Dev1/ai0,Dev1/ai1", "amp_gain": [25.0, 25.0],
                                      "fifo_depth": fifo_depth, "latency_samples": 2})
    be = NidaqmxBackend(CFG, p, now=clock.now, sleep=clock.advance)
    core = DriverCore(_settings(), be, now=clock.now, sleep=clock.advance)

    def trace() -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return {ch: (t, 25.0 * v) for ch, (t, v) in dev.trace().items()}

    def inject(kind: str) -> None:
        call, code = NI_ERRORS[kind]
        dev.fail[call] = code

    return Bench(core, clock, trace, inject, list(NI_ERRORS))


#: fault name → (command, GCS error code) the emulator fails next; "disconnect": the connection is dropped
PI_FAULTS = {"gcs 302 voltage out of limits": ("SVA", 302), "gcs 5 servo on": ("SVA", 5), "disconnect": None}


def bench_pi_gcs(monkeypatch: Any) -> Bench:
    """pi_gcs set-point mode through pipython's PISocket against the GCS emulator on a loopback TCP port.  Host,
    staircase and emulator share the manual clock: the emulator stamps each set point with the host's time (the host
    waits for every answer), so the wire's timing is exact and the run takes no wall time beyond the round trips."""
    pytest.importorskip("pipython")
    from gcs_emulator import GCSEmulator, GCSServer

    from piezo_ff_ros.backends import get_spec
    from piezo_ff_ros.backends.pi_gcs import PISetpointBackend
    from wire_invariant import from_events

    clock = ManualClock()
    emu = GCSEmulator(clock=clock.now)
    srv = GCSServer(emu, lifetime=120.0)
    p = get_spec("pi_gcs").validate({"address": "127.0.0.1", "port": srv.port, "timeout_ms": 2000})
    be = PISetpointBackend(CFG, p, now=clock.now, sleep=clock.advance)
    core = DriverCore(_settings(), be, now=clock.now, sleep=clock.advance)

    def trace() -> dict[str, tuple[np.ndarray, np.ndarray]]:
        with emu.lock:
            ev = list(emu.events)
        return from_events((t, f"axis{a}", v[a]) for t, v, _ in ev for a in range(len(v)))

    def inject(kind: str) -> None:
        what = PI_FAULTS[kind]
        if what is None:
            emu.drop_after(0)
        else:
            emu.inject_error(*what)

    return Bench(core, clock, trace, inject, list(PI_FAULTS), holds_earn_credit=True,
                 max_change=float(p["setpoint_step"]), close=srv.close)


BENCHES: dict[str, Callable[[Any], Bench]] = {
    "sim-lockstep": lambda mp: bench_sim("lockstep", mp),
    "sim-clocked": lambda mp: bench_sim("clocked", mp),
    "nidaqmx": bench_nidaqmx,
    # a buffer barely larger than the write-ahead: a restart must fit the held value, the samples not yet generated
    # and the new block into it
    "nidaqmx-small-buffer": lambda mp: bench_nidaqmx(mp, fifo_depth=1500),
    "pi_gcs": bench_pi_gcs,
}
#: examples per bench (default 100): a PI example costs a few hundred TCP round trips on a loaded 2-core host
MAX_EXAMPLES = {"pi_gcs": 20}

# one scenario: a list of actions
_block = st.tuples(st.just("block"), st.integers(1, 1500), st.floats(-150.0, 150.0), st.floats(-150.0, 150.0),
                   st.sampled_from(["next", "next", "next", "gap", "late", "jump"]))
_wait = st.tuples(st.just("wait"), st.floats(0.0, 0.4))          # the host runs, no input (stale ramp)
_stall = st.tuples(st.just("stall"), st.floats(0.0, 0.3))        # the host does not run (underrun)
_fault = st.tuples(st.just("fault"), st.integers(0, 6))
SCENARIO = st.lists(st.one_of(_block, _block, _wait, _stall, _fault), min_size=1, max_size=20)


def play(b: Bench, actions: list[tuple]) -> dict[str, bool]:
    core, clock = b.core, b.clock
    core.start()
    stamp = 0
    saw_disconnect = False

    def run_for(seconds: float) -> None:
        for _ in range(int(seconds / 0.005)):
            clock.advance(0.005)
            core.tick()

    for act in actions:
        if act[0] == "block":
            _, n, a, z, where = act
            nxt = core.next_stamp if core.next_stamp is not None else stamp
            s = {"next": nxt, "gap": nxt + 300 * PERIOD_NS, "late": nxt - 300 * PERIOD_NS,
                 "jump": nxt + 10**10}[where]
            core.on_block(s, np.column_stack([np.linspace(a, z, n), np.linspace(z, a, n)]))
            run_for(n / FS)
        elif act[0] == "wait":
            run_for(act[1])
        elif act[0] == "stall":
            clock.advance(act[1])
        else:
            kind = b.faults[act[1] % len(b.faults)]
            saw_disconnect |= kind in ("disconnect", "device gone")
            b.inject(kind)
            run_for(0.01)
    core.close()
    return {"gone": saw_disconnect or core.state == "fault"}


@pytest.mark.parametrize("backend", list(BENCHES))
def test_the_output_never_steps_more_than_allowed(backend, monkeypatch):
    @settings(max_examples=MAX_EXAMPLES.get(backend, 100), deadline=None, suppress_health_check=list(HealthCheck))
    @given(actions=SCENARIO, write_ahead=st.sampled_from([0.02, 0.05, 0.15]))
    def check(actions, write_ahead):
        WRITE_AHEAD["value"] = write_ahead
        with monkeypatch.context() as mp:
            b = BENCHES[backend](mp)
            try:
                out = play(b, actions)
                tr = b.trace()
            finally:
                b.close()
            assert_safe(tr, 1 / FS, STEP, holds_earn_credit=b.holds_earn_credit, max_change=b.max_change)
            if not out["gone"] and tr:
                assert all(abs(v[-1]) < 1e-9 for _, v in tr.values()), {k: v[-1] for k, (_, v) in tr.items()}

    check()


#: a controller error in the middle of a moving stream, a second kind of GCS error, then a dropped connection
PI_SCENARIO = [("block", 1500, 100.0, -100.0, "next"), ("fault", 0), ("block", 1000, 50.0, 50.0, "next"),
               ("wait", 0.3), ("block", 800, -60.0, 60.0, "next"), ("fault", 1), ("block", 500, 10.0, 10.0, "next"),
               ("fault", 2), ("block", 500, 10.0, 10.0, "next")]


def test_pi_gcs_controller_errors_mid_stream_keep_the_invariant_on_the_wire(monkeypatch):
    """One fixed scenario of the property above on the PI bench (random examples may not hit it): a GCS error
    refuses a set point while the stream moves fast; the driver's ramp must start from the value the controller
    still holds, paced, not from what the driver had committed."""
    b = bench_pi_gcs(monkeypatch)
    try:
        play(b, PI_SCENARIO)
        tr = b.trace()
    finally:
        b.close()
    assert b.core.faults["limit"] == 1 and b.core.faults["controller"] == 1 and b.core.faults["disconnect"] == 1
    assert min(len(t) for t, _ in tr.values()) > 100
    assert_safe(tr, 1 / FS, STEP, holds_earn_credit=True, max_change=b.max_change)
