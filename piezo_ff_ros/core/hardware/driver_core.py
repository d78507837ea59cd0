"""The driver without ROS: voltage blocks in, what the device actually applied (and measured) out.

:class:`DriverCore` owns the :class:`~piezo_ff_ros.core.safety.VoltageGuard` (limits, slew, rejection), the
:class:`~.stream.StreamBook` (stamps ↔ device samples, gaps, late blocks), the idle/active/safe/fault state and a
:class:`~.contract.StreamingBackend`.  The driver node only converts messages and publishes what it returns.

- ``on_block(stamp, block)`` — a voltage block from the topic (or ``reject=`` a reason: the block's samples are
  then held at the last voltage, as long as its size is plausible);
- ``tick()`` — called periodically: polls the device (faults → safe ramp), keeps a clocked device's FIFO fed
  (safe voltage while idle/safe, the last voltage while a late stream is awaited — counted as starved samples —,
  close to the clock once a stream has started),
  ramps to safe after ``stale_timeout`` without input (not counting the time the caller itself stood still: the
  blocks sent meanwhile wait in its reader; on a clocked device once the blocks' own samples have played out too:
  the ramp starts where they end either way), and collects what was applied/measured;
- ``set_stream_paced(on)`` — a lockstep trajectory paces the stream: on a device whose time follows the samples
  written (the lockstep simulator) the wall-clock stale watchdog is suspended meanwhile, since no device time passes
  between blocks — a host stall then loses nothing; ignored by every other device;
- ``close()`` — the safe ramp written while the device still runs, waited for on a clocked device, then the
  backend closed (SIGINT and crash paths end the same way: no step on the output);
- device faults from any backend call (poll, write, clock, read) go through one fault path: counted, logged, the
  safe ramp while a stream runs; a disconnect stops writing;
- each call returns a :class:`DriverOutput`: ``applied`` and ``displacement`` blocks ``(stamp_ns, [N, axes])`` on the
  topic grid (every applied sample exactly once, in order, holds and ramps included), and log lines.
"""
from __future__ import annotations

import json
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..config import ConfigError, LimitsConfig
from ..recording.blocks import BlockFormatError, check_stamp, sample_period_ns
from ..safety import BlockRejected, SafeRampConfig, VoltageGuard, limit_block
from ..status import ERROR, OK, WARN
from .contract import FAULT_KINDS, DeviceFault, Disconnect, StreamingBackend
from .stream import StreamBook

__all__ = ["DriverSettings", "DriverCore", "DriverOutput", "OK", "WARN", "ERROR", "lockstep_pacing"]


def lockstep_pacing(state_json: str) -> tuple[bool, str]:
    """Whether a trajectory's ``~/state`` message (JSON) says that a lockstep run is playing, and why.

    Parameters
    ----------
    state_json : str
        The ``data`` of the trajectory node's latched ``~/state`` (``{"state": ..., "mode": ...}``).

    Returns
    -------
    (bool, str)
        True while ``state`` is ``playing`` in ``mode`` ``lockstep``; a short reason for the driver's log.  A message
        that is not such a JSON object is not pacing.
    """
    try:
        st = json.loads(state_json)
    except (TypeError, ValueError):
        return False, "unreadable trajectory state"
    if not isinstance(st, dict):
        return False, "unreadable trajectory state"
    on = st.get("state") == "playing" and st.get("mode") == "lockstep"
    return on, f"trajectory {st.get('state')!s} ({st.get('mode', 'unknown mode')!s})"


@dataclass(frozen=True)
class DriverSettings:
    """The driver's validated settings (from node parameters or a rig-check)."""

    sample_rate: float
    n_axes: int
    limits: LimitsConfig
    ramp: SafeRampConfig = field(default_factory=SafeRampConfig)
    max_block: int = 20000           #: largest accepted block [samples]
    max_gap: float = 1.0             #: largest gap filled by holding [s]; larger jumps need confirmation
    #: clocked devices: target FIFO margin ahead of the clock [s].  0.5 s held with 0 underruns on the clocked
    #: simulator with two CPU-bound loaders on a 2-core host (rig-check, 60 s, twice; 0.1 and 0.2 s underran
    #: 6 times in 30 s, 0.3 s passed once: docs/hardware.md); references are
    #: known ahead, so a deeper write-ahead costs no tracking, only the delay between a block's arrival and its output
    write_ahead: float = 0.5
    #: clocked devices: below this margin the last voltage is held [s]; the driver's own holds (idle after a ramp,
    #: a late stream) stay within 1–2× this of the clock, so it is also the margin a stalled host has in the safe
    #: state (0.01 s underran on a loaded 2-core host).  Left at its default with a write-ahead ≤ 0.1 s it becomes
    #: write_ahead / 5.
    low_water: float = 0.1

    def __post_init__(self) -> None:
        if self.low_water == 0.1 and isinstance(self.write_ahead, (int, float)) and 0 < self.write_ahead <= 0.1:
            object.__setattr__(self, "low_water", self.write_ahead / 5)

    def validate(self) -> "DriverSettings":
        """Check every field (``ConfigError`` naming the field); returns self."""
        self.limits.validate()
        self.ramp.validate()
        if not (isinstance(self.max_block, int) and 1 <= self.max_block <= 10 * self.sample_rate):
            raise ConfigError("max_block", f"must be an integer in [1, {int(10 * self.sample_rate)}] samples "
                                           f"(10 s), got {self.max_block!r}")
        for name, lo, hi in (("max_gap", 0.0, 3600.0), ("write_ahead", 1e-3, 10.0), ("low_water", 0.0, 10.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise ConfigError(name, f"must be a number of seconds in [{lo:g}, {hi:g}], got {v!r}")
        if self.low_water >= self.write_ahead:
            raise ConfigError("low_water", f"must be below write_ahead ({self.write_ahead} s), got {self.low_water}")
        return self

    def samples(self, seconds: float) -> int:
        """``seconds`` as a whole number of samples at the stream rate."""
        return int(round(seconds * self.sample_rate))


@dataclass
class DriverOutput:
    """What a call produced: blocks to publish and log lines ``(level, text)``."""

    applied: list[tuple[int, np.ndarray]] = field(default_factory=list)
    displacement: list[tuple[int, np.ndarray]] = field(default_factory=list)
    log: list[tuple[int, str]] = field(default_factory=list)

    def extend(self, other: "DriverOutput") -> "DriverOutput":
        """Append ``other``'s blocks and log lines to this one; returns self."""
        self.applied += other.applied
        self.displacement += other.displacement
        self.log += other.log
        return self


class _Rechunker:
    """Re-cuts a device's sample stream at the driver's block boundaries, so that ``voltage_applied`` and
    ``displacement`` come one block per block applied (same stamps as the voltage blocks), whatever chunks the
    device delivers.  A hole in the delivered samples (lost sensor data) flushes what was buffered."""

    def __init__(self) -> None:
        self.cuts: deque[int] = deque()
        self._d0: int | None = None
        self._parts: list[np.ndarray] = []
        self._n = 0

    def cut(self, d: int) -> None:
        if not self.cuts or d > self.cuts[-1]:
            self.cuts.append(d)

    def feed(self, d0: int, arr: np.ndarray) -> list[tuple[int, np.ndarray]]:
        out = []
        if self._d0 is not None and d0 != self._d0 + self._n and self._n:
            out.append((self._d0, np.vstack(self._parts)))
            self._parts, self._n = [], 0
        if not self._n:
            self._d0 = d0
        assert self._d0 is not None   # set whenever samples are buffered
        self._parts.append(arr)
        self._n += arr.shape[0]
        while self.cuts and self.cuts[0] <= self._d0:
            self.cuts.popleft()
        end = self._d0 + self._n
        if self.cuts and self.cuts[0] <= end:
            buf = np.vstack(self._parts) if len(self._parts) > 1 else self._parts[0]
            while self.cuts and self.cuts[0] <= end:
                c = self.cuts.popleft()
                if c > self._d0:
                    out.append((self._d0, buf[:c - self._d0]))
                    buf = buf[c - self._d0:]
                    self._d0 = c
            self._parts, self._n = ([buf], buf.shape[0]) if buf.shape[0] else ([], 0)
        return out

    def clear(self) -> None:
        self.cuts.clear()
        self._d0, self._parts, self._n = None, [], 0


class DriverCore:
    """See the module docstring."""

    def __init__(self, settings: DriverSettings, backend: StreamingBackend,
                 now: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.s = settings.validate()
        self.backend = backend
        self.info = backend.info
        if self.info.n_axes != self.s.n_axes:
            raise ConfigError("backend", f"{self.info.name} has {self.info.n_axes} axes, the config {self.s.n_axes}")
        if abs(self.info.sample_rate_hz - self.s.sample_rate) > 1e-9 * self.s.sample_rate:
            raise ConfigError("backend", f"{self.info.name} runs at {self.info.sample_rate_hz} Hz, "
                                         f"the config at {self.s.sample_rate} Hz")
        self.now = now
        self.sleep = sleep     # how close() waits for the device to play its ramp (injectable with ``now``)
        self.period_ns = sample_period_ns(self.s.sample_rate)
        self.guard = VoltageGuard(self.s.limits, self.s.n_axes, self.s.sample_rate, max_block=self.s.max_block)
        self.book = StreamBook(self.period_ns, self.s.samples(self.s.max_gap))
        self.safe = np.full(self.s.n_axes, float(self.s.limits.safe_voltage))
        self.state = "idle"
        self.faults = dict.fromkeys(FAULT_KINDS, 0)
        self.last_fault = ""                        # the last device fault, as the device named it (diagnostics)
        self.last_fault_code: int | None = None
        self.starved_samples = 0
        self.resumes = 0
        self.last_error = ""
        self.last_block_wall: float | None = None
        self._block_end: int | None = None         # device index after the last block's samples (clocked devices)
        self.stream_paced = False                   # a lockstep source paces a time-follows-samples device
        self._queue: deque[np.ndarray] = deque()   # committed samples not yet in the device FIFO
        self._queued = 0
        self._w = 0                                 # device index after everything committed
        self._chunks = (_Rechunker(), _Rechunker())  # applied, measured
        self._started = False
        self._window = {"samples": 0, "lost": 0}    # since the last health() call
        self._lost_seen = 0

    # -- life cycle ------------------------------------------------------------------------------------------------
    def _prefill(self) -> int:
        return min(self.s.samples(self.s.write_ahead), self.info.fifo_depth) if self.info.clocked else 0

    def _warm_kernels(self) -> None:
        """Load the compiled kernels the first block runs (the guard's limiter) now, before the device's clock
        starts: loading one takes longer than the write-ahead (0.3-0.5 s from numba's disk cache)."""
        limit_block(np.zeros((2, self.s.n_axes)), np.zeros(self.s.n_axes), 1.0, 1.0)

    def start(self) -> DriverOutput:
        """Start the device (its clock runs from here: call it where the periodic ``tick`` starts too)."""
        self._warm_kernels()
        self._w = self.backend.start(self.safe.copy(), self._prefill())
        self._started = True
        em = DriverOutput()
        if self.info.clocked and self.s.samples(self.s.write_ahead) > self.info.fifo_depth:
            em.log.append((WARN, f"write_ahead {self.s.write_ahead} s is more than {self.info.name}'s FIFO "
                                 f"({self.info.fifo_depth} samples): the margin is capped there (raise the "
                                 "backend's fifo_depth or lower write_ahead)"))
        return em.extend(self.tick())

    def reset(self) -> bool:
        """Back to rest if the device can (the simulator); stream and counters start anew."""
        if not self.backend.reset():
            return False
        self.guard.reset()
        self.book.reset()
        self._queue.clear()
        self._queued = 0
        for c in self._chunks:
            c.clear()
        self.state, self.last_block_wall, self.last_error = "idle", None, ""
        self._block_end = None
        self.last_fault, self.last_fault_code = "", None
        self.starved_samples = self.resumes = 0
        self.faults = dict.fromkeys(self.faults, 0)
        self._warm_kernels()
        self._w = self.backend.start(self.safe.copy(), self._prefill())
        return True

    @property
    def next_stamp(self) -> int | None:
        """Stamp of the next sample the stream expects (None before the first block)."""
        self._sync()
        return self.book.stamp_of(self._w) if self.book.started else None

    @property
    def started(self) -> bool:
        """True once the device stream has started."""
        return self._started

    def close(self) -> DriverOutput:
        """Stop: ramp to the safe voltage **while the device still runs** (the safe ramp, in time), wait until it
        has output the ramp (a clocked device; bounded by the ramp's duration + 1 s), then close the backend — also
        when the ramp fails.  Returns what was emitted meanwhile."""
        em = DriverOutput()
        try:
            if self._started and self.state != "fault":
                self._poll(em)
                if self.state != "fault" and not self.guard.at_safe:
                    self._ramp(em, "closing")
                em.extend(self._collect())
                self._sync()          # a restarted device may have moved the write cursor
                end = self._w
                if self.info.clocked:
                    fs = self.s.sample_rate
                    wait = max(0, end - self._clock_or_fault(em)) / fs + 1.0
                    deadline = self.now() + wait
                    for _ in range(int(wait / 0.002) + 1):   # bounded also when now() stands still
                        if self.state == "fault" or self.now() > deadline or self._clock_or_fault(em) >= end:
                            break
                        self.sleep(0.002)
                        em.extend(self.tick())   # keeps feeding: the safe voltage follows the ramp
        except Exception as exc:  # noqa: BLE001 - closing: the backend is closed whatever happened
            self._err(em, f"closing: {type(exc).__name__}: {exc}")
        finally:
            self.backend.close()
        return em

    def set_stream_paced(self, on: bool, why: str = "") -> DriverOutput:
        """Tell the core whether a lockstep source paces the stream (``why``: for the log).

        On a device whose time follows the samples written (``info.time_follows_samples``, the lockstep simulator)
        the wall-clock stale watchdog is suspended while ``on``: between two blocks no device time passes, so
        waiting for a stalled host holds nothing and ramping would take the stamps of the blocks in flight (they
        would then be dropped as late).  Every other device ignores it (its time runs on its own).
        """
        em = DriverOutput()
        on = bool(on)
        if on and not self.info.time_follows_samples:
            if not self.stream_paced:
                em.log.append((OK, f"stream pacing ignored ({why}): {self.info.name} runs in wall-clock time, the "
                                   "stale watchdog stays on"))
            return em
        if on != self.stream_paced:
            self.stream_paced = on
            em.log.append((OK, f"{why}: " + ("the stream paces the simulator's time, stale watchdog suspended" if on
                                             else "stale watchdog back on the wall clock")))
        return em

    # -- input ------------------------------------------------------------------------------------------------------
    def on_block(self, stamp: int, block: Any = None, *, n: int | None = None,
                 reject: str | None = None) -> DriverOutput:
        """A voltage block stamped ``stamp`` (first sample, ns); with ``reject`` (a reason) it is not applied and
        its ``n`` samples hold the last voltage (nothing if ``n`` is out of [1, max_block])."""
        em = DriverOutput()
        if self.state == "fault":
            em.log.append((ERROR, f"block at {stamp} ignored: device fault ({self.last_error})"))
            return em
        try:   # a stamp off the grid cannot be placed (and must never anchor the stream): refused, counted
            check_stamp(stamp, self.period_ns)
        except BlockFormatError as exc:
            self.guard.counters.rejected_blocks += 1
            self._err(em, f"voltage block rejected ({exc}); nothing applied")
            return em
        u: np.ndarray | None = None
        if reject is not None:
            self.guard.counters.rejected_blocks += 1
        else:
            try:
                u = self.guard.check(block)
            except BlockRejected as exc:
                reject, n = str(exc), int(np.shape(block)[0]) if np.ndim(block) >= 1 else 0
        if reject is not None:
            n = int(n or 0)
            if not 1 <= n <= self.s.max_block:
                self._err(em, f"voltage block rejected ({reject}); nothing applied")
                return em
            self._err(em, f"voltage block rejected ({reject}); holding {self.guard.u_last.tolist()} V for {n} "
                          "samples")
            u = None
        else:
            assert u is not None   # the guard accepted the block
            n = u.shape[0]
        self.last_block_wall = self.now()
        if self.info.clocked:
            # the device's clock moved since the last tick: catch up (faults first) so that the block is placed
            # against where the device really is; a first block gets the full write-ahead margin
            self._poll(em)
            if self.state == "fault":
                return em
            self._sync()
            if not self.book.started:
                self._feed(em)
        self._sync()
        if self.state == "safe" and self.book.started:
            # after a safe ramp the stream re-anchors on the next valid block beyond max_gap ahead: a new stream
            # starts right away, without waiting for a second block to confirm the jump (a nearer one is a gap,
            # held as before, so that the stamps of voltage_applied stay contiguous)
            nxt = self.book.stamp_of(self._w)
            if nxt is not None and stamp - nxt > self.book.max_gap * self.period_ns:
                self.book.candidate = None
                self.book.rebase(self._w, int(stamp))
                self.book.counters.rebases += 1
                em.log.append((WARN, f"stream re-anchored on the block at {stamp} after the safe state"))
        try:
            d = self.book.classify(int(stamp), n, self._w, payload=u)
        except ValueError as exc:
            self.guard.counters.rejected_blocks += 1
            self._err(em, f"voltage block dropped: {exc}")
            return em
        if d.kind == "pending":
            off = abs(stamp - (self.book.stamp_of(self._w) or 0)) // self.period_ns
            em.log.append((WARN, f"block at {stamp} is {off} samples off the stream: held back until the next "
                                 "block confirms the jump"))
            return em.extend(self._collect())
        if d.kind == "late":
            self._err(em, f"late block dropped: stamp {stamp} is for samples already applied "
                          f"(next expected {self.book.stamp_of(self._w)})", level=WARN)
            return em.extend(self._collect())
        if d.kind == "confirm":
            em.log.append((WARN, f"stream jumped to stamp {d.replay[0]}: map re-based (a gap in the stamps, no "
                                 "samples lost on the device)"))
            self._commit_block(d.replay[2], d.replay[1])
        if d.kind == "gap":
            self._err(em, f"{d.fill} sample(s) missing before stamp {stamp} (lost blocks?): holding "
                          f"{self.guard.u_last.tolist()} V", level=WARN)
            self._commit(self.guard.hold(d.fill))
        if d.kind == "trim":
            em.log.append((WARN, f"{d.skip} leading sample(s) of the block at {stamp} were past: dropped"))
        if self.state == "safe":
            self.resumes += 1
            em.log.append((WARN, "input resumed after the safe state: the applied voltage restarts from "
                                 f"{self.guard.u_last.tolist()} V (see voltage_applied)"))
        self.state = "active"
        self._commit_block(u, n, skip=d.skip)
        self._block_end = self._w
        em.extend(self._collect())
        if self.info.holds_setpoints and self.state == "active":
            # the write played the block in wall time: the input is stale only ``stale_timeout`` after its end
            self.last_block_wall = self.now()
        return em

    def _commit_block(self, u: np.ndarray | None, n: int, skip: int = 0) -> None:
        if u is None:
            self._commit(self.guard.hold(n - skip))
        else:
            self._commit(self.guard.apply(u[skip:]))

    def _sync(self) -> None:
        """Follow the device's write cursor if it moved on its own (samples it held after an underrun)."""
        head = self.backend.write_index
        if head != self._w - self._queued:
            self._w = head + self._queued

    def _commit(self, u: np.ndarray) -> None:
        if u.shape[0] == 0:
            return
        for c in self._chunks:
            c.cut(self._w)
            c.cut(self._w + u.shape[0])
        self._queue.append(u)
        self._queued += u.shape[0]
        self._w += u.shape[0]
        self._window["samples"] += u.shape[0]

    # -- time ------------------------------------------------------------------------------------------------------
    def tick(self, stalled: float = 0.0) -> DriverOutput:
        """Poll the device, keep the FIFO fed, ramp on stale input; see the module docstring.

        Parameters
        ----------
        stalled : float
            How long the caller itself stood still before this tick [s] (its timer fired that much later than due:
            a garbage collection, a host that did not schedule it).  Blocks sent meanwhile are waiting to be read,
            so that time is not the input's silence: the stale watchdog does not count it (the caller reads them
            next).  A source that really stopped is still found ``stale_timeout`` of running time later.
        """
        em = DriverOutput()
        if self.state == "fault":
            return em
        if stalled > 0 and self.last_block_wall is not None:
            self.last_block_wall = min(self.now(), self.last_block_wall + float(stalled))
        self._poll(em)
        if self.state == "fault":
            return em
        self._sync()
        stale = self.state == "active" and self.last_block_wall is not None and not self.stream_paced and \
            self.now() - self.last_block_wall >= self.s.limits.stale_timeout and not self._blocks_still_play()
        if stale:
            if self.book.drop_candidate():
                em.log.append((WARN, "a held-back out-of-sequence block was never confirmed: dropped"))
            self._ramp(em, f"no voltage block for {self.s.limits.stale_timeout} s (limits.stale_timeout)")
        if self.info.clocked:
            self._feed(em)
        return em.extend(self._collect())

    def _blocks_still_play(self) -> bool:
        """A clocked device still has more than ``low_water`` of the blocks' own samples ahead of its clock.

        The safe ramp is written after what is already committed, so on a clocked device it starts where the last
        block's samples end whenever it is decided; deciding it only when they run out (within ``low_water``)
        leaves the output the same for a source that stopped, and applies the blocks of a source that only paused
        (a loaded host's hiccup shorter than ``write_ahead − low_water``) instead of dropping them as late behind
        the ramp."""
        if not self.info.clocked or self._block_end is None:
            return False
        try:
            clock = self.backend.clock()
        except DeviceFault:   # the feed that follows reports it through the fault path
            return False
        return self._block_end - clock >= self.s.samples(self.s.low_water)

    def _feed(self, em: DriverOutput) -> None:
        """Keep a clocked device's FIFO from running dry.  Before the first block: ``write_ahead`` of the safe
        voltage (the first block then lands that far ahead of the clock: the stream's margin).  Afterwards the
        driver's own holds stay close to the clock (below ``low_water``, up to 2·low_water), so that a stream
        that resumes a little late still finds its sample instants free."""
        try:
            margin = self._w - self.backend.clock()
        except DeviceFault as exc:
            self._fault(em, exc)
            return
        lw = self.s.samples(self.s.low_water)
        if self.book.started:
            if margin >= lw:
                return
            target = min(2 * lw, self.s.samples(self.s.write_ahead))
        else:
            target = self.s.samples(self.s.write_ahead)
        want = target - margin
        if want <= 0:
            return
        if self.state == "active":
            self.starved_samples += want
        self._commit(self.guard.hold(want))

    def _ramp(self, em: DriverOutput, why: str) -> None:
        u_from = self.guard.u_last.tolist()
        r = self.guard.ramp_to_safe(self.s.ramp)
        em.log.append((WARN, f"{why}: ramping from {u_from} V to the safe state {self.s.limits.safe_voltage} V in "
                             f"{r.shape[0]} samples"))
        self._commit(r)
        self.state = "safe"

    def _poll(self, em: DriverOutput) -> None:
        try:
            self.backend.poll()
        except DeviceFault as exc:
            self._fault(em, exc)

    def _clock_or_fault(self, em: DriverOutput) -> int:
        """The device clock; a fault reading it goes through :meth:`_fault` (then the write cursor is returned)."""
        try:
            return self.backend.clock()
        except DeviceFault as exc:
            self._fault(em, exc)
            return self._w

    def _fault(self, em: DriverOutput, exc: DeviceFault) -> None:
        """A device fault from any call: a disconnect stops the output (nothing can be written); anything else
        (underrun, overrun, limit, controller) is counted and, while a stream runs, ramps to the safe voltage — from
        the voltage the output holds when the device says so (``exc.held``: a set-and-hold controller that refused
        a set point holds its last accepted one), also when the fault interrupted the safe ramp itself."""
        self.last_fault = str(exc)
        self.last_fault_code = getattr(exc, "code", None)
        if isinstance(exc, Disconnect):
            self.faults["disconnect"] += 1
            self.state = "fault"
            self._err(em, f"device fault: {exc}; output stopped")
            return
        self.faults[exc.kind] = self.faults.get(exc.kind, 0) + 1
        self._window["lost"] += 1
        held = getattr(exc, "held", None)
        if held is not None and not self._queued and np.shape(held) == self.guard.u_last.shape:
            # the output stopped short of what was committed: the stream goes on from where it really is
            self.guard.u_last[:] = held
            if self.state in ("idle", "safe") and not self.guard.at_safe:
                self.state = "active"        # a ramp to safe (the start's, the safe ramp) was cut short: ramp again
        hint = ""
        if exc.kind == "underrun" and self.info.clocked:
            hint = (f" (the host fell more than the write-ahead behind the device: raise the driver's write_ahead, "
                    f"now {self.s.write_ahead:g} s, and low_water, now {self.s.low_water:g} s, or unload the host)")
        self._err(em, f"device fault ({exc.kind}): {exc}{hint}")
        if self.state == "active":
            self._ramp(em, f"device {exc.kind}")

    def _collect(self) -> DriverOutput:
        """Write what fits into the FIFO; map what the device applied and measured to stamps."""
        em = DriverOutput()
        applied: list[tuple[int, np.ndarray]] = []
        measured: list[tuple[int, np.ndarray]] = []
        for _attempt in range(3):   # a fault queues the safe ramp; the next attempt writes it (a DAQ restarts)
            try:
                had = bool(self._queue)
                self._write_queue()
                if had and self.info.holds_setpoints:
                    # a set-and-hold device reports a refused set point after the write: ramp from it now, not a
                    # tick later
                    self.backend.poll()
                break
            except DeviceFault as exc:
                self._fault(em, exc)
                if self.state == "fault":
                    return em
        for what in ("applied", "measured"):
            try:
                if what == "applied":
                    applied = self.backend.take_applied()
                else:
                    measured = self.backend.read()
            except DeviceFault as exc:
                self._fault(em, exc)
                if self.state == "fault":
                    return em
        for src, dst, chunker in ((applied, em.applied, self._chunks[0]), (measured, em.displacement,
                                                                           self._chunks[1])):
            for d_in, b_in in src:
                for d0, blk in chunker.feed(d_in, b_in):
                    for off, cnt, stamp in self.book.split(d0, blk.shape[0]):
                        dst.append((stamp, blk[off:off + cnt]))
        return em

    def _write_queue(self) -> None:
        """Write the committed samples that fit into the device FIFO."""
        self._sync()
        while self._queue:
            space = self.backend.write_space()
            if space <= 0:
                break
            b = self._queue[0]
            part = b[:space]
            self.backend.write(self.backend.write_index, part)
            self._queued -= part.shape[0]
            if part.shape[0] == b.shape[0]:
                self._queue.popleft()
            else:
                self._queue[0] = b[part.shape[0]:]

    # -- reporting ---------------------------------------------------------------------------------------------------
    def _err(self, em: DriverOutput, text: str, level: int = ERROR) -> None:
        self.last_error = text
        em.log.append((level, text))

    def status(self) -> dict[str, Any]:
        """State, guard and stream counters and the device status, as a flat mapping."""
        st = {"state": self.state, **self.guard.counters.as_dict(), **self.book.counters.as_dict(),
              "starved_samples": self.starved_samples, "resumes": self.resumes, "stream_paced": self.stream_paced,
              **{f"{k}_faults": v for k, v in self.faults.items()},
              "applied_voltage": self.guard.u_last.tolist(),
              "next_stamp_ns": self.book.stamp_of(self._w) if self.book.started else None,
              "latency_samples": self.backend.latency_samples, "last_error": self.last_error,
              "last_fault": self.last_fault, "last_fault_code": self.last_fault_code}
        if self.info.clocked and self.state != "fault":
            try:
                st["write_ahead_samples"] = self._w - self.backend.clock()
            except DeviceFault as exc:   # reported by the next tick's fault path
                st["device.error"] = str(exc)
        try:
            st.update({f"device.{k}": v for k, v in self.backend.status().items()})
        except Exception as exc:  # noqa: BLE001 - a status read must never take the driver down
            st["device.error"] = str(exc)
        return st

    def lost_samples(self) -> int:
        """Samples lost so far: stream gaps, late blocks and device starvation."""
        c = self.book.counters
        return c.gap_samples + c.late_samples + self.starved_samples

    def health(self) -> tuple[int, str]:
        """(level, message) for ``/diagnostics``: ERROR on a device fault or when ≥ 10 % of the samples since the
        last call were lost; WARN when anything was lost, rejected, clamped or faulted since start."""
        st = self.status()
        lost_now = self.lost_samples()
        window_lost = lost_now - self._lost_seen + self._window["lost"]
        window_total = max(self._window["samples"], 1)
        self._lost_seen = lost_now
        self._window = {"samples": 0, "lost": 0}
        c = self.book.counters
        losses = (f"lost: {c.gap_samples} gap + {c.late_samples} late + {self.starved_samples} starved samples, "
                  f"~{c.lost_blocks} lost / {c.late_blocks} late / {c.out_of_sequence_blocks} out-of-sequence blocks")
        faults = sum(self.faults.values())
        if self.state == "fault":
            return ERROR, f"fault: {self.last_error}"
        if window_lost and window_lost >= 0.1 * window_total:
            return ERROR, f"{self.state}; {window_lost} of {window_total} samples lost since the last report; {losses}"
        if lost_now or faults or st["rejected_blocks"] or st["saturated_samples"] or c.out_of_sequence_blocks:
            last = f" (last: {self.last_fault})" if self.last_fault else ""
            return WARN, f"{self.state}; {losses}; {faults} device fault(s){last}; {st['rejected_blocks']} rejected"
        return OK, self.state

    # -- managed (lifecycle) transitions -------------------------------------------------------------------------
    def ramp_to_safe(self, why: str) -> DriverOutput:
        """Commit the safe ramp now (a managed driver's deactivate/shutdown): the output goes from where it is to
        ``limits.safe_voltage`` along ``safe_ramp`` and holds there; later blocks restart from it.  Nothing on a
        device not started (it is at the safe voltage) or in fault (its output is stopped)."""
        em = DriverOutput()
        if not self._started or self.state == "fault":
            return em
        self._poll(em)
        if self.state == "fault":
            return em
        self._sync()
        if self.book.drop_candidate():
            em.log.append((WARN, "a held-back out-of-sequence block was never confirmed: dropped"))
        if np.any(self.guard.u_last != self.safe) or self.state != "safe":
            self._ramp(em, why)
        self._safe_from = self._w
        return em.extend(self._collect())

    def played_out(self) -> bool:
        """True once the device has output every committed sample (a clocked device's clock is past them; a
        lockstep device outputs what it is written)."""
        self._sync()
        end = getattr(self, "_safe_from", self._w)
        if self._w - self._queued < end:
            return False
        return not self.info.clocked or self.backend.clock() >= end

    def warm(self) -> None:
        """Compile (or load from numba's cache) every kernel the first block runs through, on a throw-away guard:
        a clocked device's write-ahead is tens of ms, a first compile takes longer than that."""
        guard = VoltageGuard(self.s.limits, self.s.n_axes, self.s.sample_rate, max_block=self.s.max_block)
        guard.check(np.zeros((2, self.s.n_axes)))
        guard.apply(np.zeros((2, self.s.n_axes)))
        guard.hold(2)
        guard.ramp_to_safe(self.s.ramp)
