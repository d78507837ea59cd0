"""The simulated positioner behind the streaming backend contract, in two modes.

- :class:`LockstepSim` — time advances only with the samples written (deterministic, as fast as the host goes): a
  write is output at once and its displacement is readable at once (latency 0, never an underrun).
- :class:`ClockedSim` — paced by a clock like a DAQ: the device outputs ``sample_rate_hz`` samples per second of
  ``now()`` from a FIFO of ``fifo_depth`` samples whatever the host does; when the FIFO runs dry it holds the last
  value (a DAC holds) and raises :class:`~.contract.Underrun` on the next :meth:`poll`; sensor samples become
  readable ``latency_samples`` (+ up to ``jitter_samples`` of random delivery delay) after they were output; an
  unread input buffer larger than ``input_buffer`` loses its oldest samples (:class:`~.contract.Overrun`).
  ``time_scale`` > 1 runs the simulated device clock that many times faster than ``now()`` (long simulated runs,
  e.g. the demo's creep experiments, through every clocked timing path in less wall time); 1 = a real DAQ.

``plant`` is any streaming stage ``process(block[N, axes]) -> block`` / ``reset()`` (e.g. ``core.models.plant.Plant``)
or None for a device without sensor.  ``now`` is injectable so that tests drive the clock deterministically.
"""
from __future__ import annotations

import math
import time
from collections import deque
from typing import Any, Callable

import numpy as np

from ..stage import Processor
from .contract import (ContractError, DeviceFault, DeviceInfo, Disconnect, LimitFault, Overrun, StreamingBackend,
                       Underrun, WriteCursorClock)

__all__ = ["LockstepSim", "ClockedSim", "inject_fault"]



_FAULTS: dict[str, type[DeviceFault]] = {"underrun": Underrun, "overrun": Overrun, "disconnect": Disconnect, "limit": LimitFault}


class _SimBase(StreamingBackend):
    def __init__(self, info: DeviceInfo, plant: Processor | None = None):
        self.info = info
        self.plant = plant
        self.started = False
        self._applied: list[tuple[int, np.ndarray]] = []
        self._sensor: deque[tuple[int, np.ndarray]] = deque()
        self._pending: list[DeviceFault] = []
        self._disconnected = False
        self.counters = {"underruns": 0, "underrun_samples": 0, "overruns": 0, "overrun_samples": 0}

    def _check_alive(self) -> None:
        if self._disconnected:
            raise Disconnect(f"{self.info.name}: device disconnected")
        if not self.started:
            raise ContractError(f"{self.info.name}: not started")

    def _output(self, k0: int, u: np.ndarray) -> None:
        """The device outputs ``u`` for samples k0…: record it, run the plant, queue the sensor samples."""
        self._applied.append((k0, u))
        if self.plant is not None:
            self._sensor.append((k0, np.asarray(self.plant.process(u), dtype=float)))

    def inject(self, kind: str) -> None:
        """Test hook: the next :meth:`poll` raises a fault of ``kind`` (``disconnect`` is permanent)."""
        if kind == "disconnect":
            self._disconnected = True
        self._pending.append(_FAULTS[kind](f"{self.info.name}: injected {kind}"))

    def poll(self) -> None:
        if self._pending:
            raise self._pending.pop(0)
        if self._disconnected:
            raise Disconnect(f"{self.info.name}: device disconnected")

    def take_applied(self) -> list[tuple[int, np.ndarray]]:
        out, self._applied = self._applied, []
        return out

    def status(self) -> dict[str, Any]:
        return {"backend": self.info.name, "clock": self.clock() if self.started else 0, **self.counters}


class LockstepSim(WriteCursorClock, _SimBase):
    """The simulator in lockstep: the device clock is the write cursor."""

    def __init__(self, fs: float, n_axes: int, plant: Processor | None = None, name: str = "sim"):
        super().__init__(DeviceInfo(name=name, sample_rate_hz=float(fs), n_axes=int(n_axes), fifo_depth=1 << 30,
                                    has_sensor=plant is not None, clocked=False, time_follows_samples=True), plant)
        self._k = 0

    def start(self, safe_voltage: np.ndarray, prefill: int = 0) -> int:
        self.started = True
        if prefill:
            self.write(self._k, np.tile(np.asarray(safe_voltage, dtype=float), (int(prefill), 1)))
        return self._k

    def write(self, k0: int, block: np.ndarray) -> None:
        self._check_alive()
        if k0 != self._k:
            raise ContractError(f"{self.info.name}: write at {k0}, expected {self._k}")
        u = np.array(block, dtype=float)
        self._output(k0, u)
        self._k += u.shape[0]

    def read(self) -> list[tuple[int, np.ndarray]]:
        out = list(self._sensor)
        self._sensor.clear()
        return out

    @property
    def latency_samples(self) -> int:
        return 0

    def reset(self) -> bool:
        """All states back to rest."""
        if self.plant is not None:
            self.plant.reset()
        self._k = 0
        self._applied, self._pending = [], []
        self._sensor.clear()
        return True


class ClockedSim(_SimBase):
    """The simulator paced by ``now()`` like a DAQ (see the module docstring).

    Parameters
    ----------
    fs : float
        Sample clock [Hz].
    n_axes : int
        Output channels.
    plant : streaming stage or None
        The positioner (None: no sensor).
    fifo_depth : int
        Output FIFO [samples]: how far ahead of the clock the host may write.
    latency_samples : int
        Transport latency of the sensor path [samples].
    jitter_samples : int
        Random extra delay of sensor delivery, uniform in ``0…jitter_samples`` per read.
    input_buffer : int
        Unread sensor samples kept; older ones are lost (Overrun). Default: one second of ``now()``.
    now : callable
        Clock source [s] (``time.monotonic``).
    seed : int
        Seed of the jitter.
    time_scale : float
        Device seconds per second of ``now()`` (1 = real time; 10 = the device clock runs 10× faster).
    """

    def __init__(self, fs: float, n_axes: int, plant: Processor | None = None, *, fifo_depth: int = 4000, latency_samples: int = 2,
                 jitter_samples: int = 0, input_buffer: int | None = None, now: Callable[[], float] = time.monotonic,
                 seed: int = 0, name: str = "sim", time_scale: float = 1.0):
        if not (isinstance(time_scale, (int, float)) and math.isfinite(time_scale) and 1e-3 <= time_scale <= 1e3):
            raise ValueError(f"time_scale: must be a number in [0.001, 1000], got {time_scale!r}")
        for field, v, lo in (("fifo_depth", fifo_depth, 1), ("latency_samples", latency_samples, 0),
                             ("jitter_samples", jitter_samples, 0)):
            if not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"{field}: must be an integer ≥ {lo}, got {v!r}")
        super().__init__(DeviceInfo(name=name, sample_rate_hz=float(fs), n_axes=int(n_axes),
                                    fifo_depth=int(fifo_depth), has_sensor=plant is not None, clocked=True), plant)
        self.latency = int(latency_samples)
        self.jitter = int(jitter_samples)
        # default: one second of now() — the host reads on a wall-clock cadence, whatever the device speed
        self.input_buffer = int(input_buffer) if input_buffer is not None else int(fs * max(1.0, time_scale))
        self.now = now
        self._clock_hz = float(fs) * float(time_scale)   # device samples per second of now()
        self._rng = np.random.default_rng(seed)
        self._fifo: deque[np.ndarray] = deque()
        self._fifo_n = 0
        self._t0 = 0.0
        self._played = 0        # next index to output
        self._widx = 0          # next index to write
        self._read_cap = 0      # sensor samples below this index were delivered
        self._last = np.zeros(int(n_axes))
        self._dry = False

    def start(self, safe_voltage: np.ndarray, prefill: int = 0) -> int:
        self._last = np.array(safe_voltage, dtype=float).reshape(self.info.n_axes)
        self.started = True
        if prefill:
            if prefill > self.info.fifo_depth:
                raise ContractError(f"{self.info.name}: prefill {prefill} > FIFO depth {self.info.fifo_depth}")
            self._fifo.append(np.tile(self._last, (int(prefill), 1)))
            self._fifo_n += int(prefill)
            self._widx += int(prefill)
        self._t0 = self.now() - self._played / self._clock_hz
        return self._widx

    def clock(self) -> int:
        if not self.started:
            return 0
        return max(self._played, int(math.floor((self.now() - self._t0) * self._clock_hz + 1e-6)))

    def _advance(self) -> None:
        target = self.clock()
        n = target - self._played
        if n <= 0:
            return
        parts, got = [], 0
        while self._fifo and got < n:
            b = self._fifo[0]
            take = min(b.shape[0], n - got)
            parts.append(b[:take])
            if take == b.shape[0]:
                self._fifo.popleft()
            else:
                self._fifo[0] = b[take:]
            got += take
        self._fifo_n -= got
        if got < n:  # FIFO ran dry: the DAC holds its last value
            hold_from = self._played + got
            last = parts[-1][-1] if parts else self._last
            parts.append(np.tile(last, (n - got, 1)))
            self.counters["underrun_samples"] += n - got
            if not self._dry:  # one fault per running-dry, however long it lasts
                self._dry = True
                self.counters["underruns"] += 1
                self._pending.append(Underrun(f"{self.info.name}: output FIFO ran dry at sample {hold_from}: "
                                              "holding the last value", k=hold_from))
        u = np.vstack(parts)
        self._last = u[-1].copy()
        self._output(self._played, u)
        self._played = target
        self._widx = max(self._widx, self._played)
        unread = sum(b.shape[0] for _, b in self._sensor)
        if unread > self.input_buffer:  # host too slow: the oldest acquired samples are overwritten
            lost = unread - self.input_buffer
            excess = lost
            while excess > 0:
                k0, b = self._sensor[0]
                if b.shape[0] <= excess:
                    self._sensor.popleft()
                    excess -= b.shape[0]
                else:
                    self._sensor[0] = (k0 + excess, b[excess:])
                    excess = 0
            if lost:
                self.counters["overruns"] += 1
                self.counters["overrun_samples"] += lost
                self._read_cap = max(self._read_cap, self._sensor[0][0] if self._sensor else self._played)
                self._pending.append(Overrun(f"{self.info.name}: input buffer overflow, {lost} sensor sample(s) "
                                             "lost", k=self._played))

    def poll(self) -> None:
        if self.started and not self._disconnected:
            self._advance()
        super().poll()

    # write_index / write_space / write do not move the clock (only poll and read do), so that a caller's
    # ``write(write_index, block[:write_space()])`` is consistent; the space is conservative until the next poll.
    @property
    def write_index(self) -> int:
        return self._widx

    def write_space(self) -> int:
        return max(0, self.info.fifo_depth - (self._widx - self._played))

    def write(self, k0: int, block: np.ndarray) -> None:
        self._check_alive()
        u = np.array(block, dtype=float)
        if k0 != self._widx:
            raise ContractError(f"{self.info.name}: write at {k0}, expected {self._widx}")
        if u.shape[0] > self.write_space():
            raise ContractError(f"{self.info.name}: {u.shape[0]} samples > FIFO space {self.write_space()}")
        if u.shape[0]:
            self._dry = False
            self._fifo.append(u)
            self._fifo_n += u.shape[0]
            self._widx += u.shape[0]

    def read(self) -> list[tuple[int, np.ndarray]]:
        if self._disconnected:
            raise Disconnect(f"{self.info.name}: device disconnected")
        if not self.started or self.plant is None:
            return []
        self._advance()
        cap = self._played - self.latency - (int(self._rng.integers(0, self.jitter + 1)) if self.jitter else 0)
        cap = max(self._read_cap, cap)
        out = []
        while self._sensor and self._sensor[0][0] < cap:
            k0, y = self._sensor[0]
            take = min(y.shape[0], cap - k0)
            out.append((k0, y[:take]))
            if take == y.shape[0]:
                self._sensor.popleft()
            else:
                self._sensor[0] = (k0 + take, y[take:])
        self._read_cap = cap
        return out

    @property
    def latency_samples(self) -> int:
        return self.latency

    def reset(self) -> bool:
        """The simulated stage back at rest and the stream stopped: FIFO, sensor queue and sample index cleared;
        the next :meth:`start` restarts the clock from index 0 (as re-arming a DAQ task does)."""
        if self.plant is not None:
            self.plant.reset()
        self._applied, self._pending = [], []
        self._sensor.clear()
        self._fifo.clear()
        self._fifo_n = 0
        self._played = self._widx = self._read_cap = 0
        self._dry = False
        self.started = False
        return not self._disconnected

    def status(self) -> dict[str, Any]:
        st = super().status()
        st.update(write_ahead=self._widx - self._played, fifo_depth=self.info.fifo_depth,
                  latency_samples=self.latency)
        return st


def inject_fault(backend: _SimBase, kind: str) -> None:
    """Ask a simulator to raise a fault of ``kind`` on its next poll (fault-injection tests).

    Parameters
    ----------
    backend : LockstepSim or ClockedSim
        The simulator.
    kind : str
        ``underrun``, ``overrun``, ``disconnect`` (permanent) or ``limit``.
    """
    backend.inject(kind)
