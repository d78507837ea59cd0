"""A fake NI-DAQmx device behind nidaqmx's own ``Task``, ``AnalogMultiChannelWriter`` and ``AnalogMultiChannelReader``.

Only the package's interpreter (the layer that calls the NI-DAQmx C library) is replaced: :class:`FakeInterpreter`
implements :class:`nidaqmx._base_interpreter.BaseInterpreter` for the calls an AO/AI streaming task makes, against a
:class:`FakeDaq` card that keeps a hardware sample clock running in (scalable) real time:

- AO tasks generate from their buffer at the configured rate from ``start``; regeneration is off, so when the buffer
  runs dry the generation stops with error -200290 (the output holds its last value), reported by the next write,
  ``is_task_done``, read of the AI task clocked by it, or ``stop``;
- AI tasks on ``/<dev>/ao/SampleClock`` acquire one sample per AO sample (armed on the AO start trigger): channel i
  reads what AO channel i output ``latency`` samples earlier (a loopback through amplifier and sensor);
  an input buffer that overflows loses its oldest samples and the next read raises -200279;
- a task without sample clock writes on demand (the value goes out at once);
- every value that reaches an AO channel is recorded in :attr:`FakeDaq.wire` with its device time, so that tests can
  assert the largest step the output ever made (:mod:`wire_invariant`).

Errors are raised the way the library interpreter raises them: ``DaqWriteError`` from writes, ``DaqReadError`` from
reads, ``DaqError`` otherwise, with DAQmx's real error codes.  ``FakeDaq.fail`` injects an error into the next call
of a named interpreter method (e.g. ``stop_task``), ``FakeDaq.fail_after`` into its n-th call from now.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from nidaqmx._base_interpreter import BaseInterpreter
from nidaqmx.constants import AcquisitionType, RegenerationMode
from nidaqmx.errors import DaqError, DaqReadError, DaqWriteError

UNDERFLOW = -200290            # generation stopped to prevent the regeneration of old samples
OVERWRITTEN = -200279          # "attempted to read samples that are no longer available"
WRITE_TIMEOUT = -200292        # not enough space in the buffer (timeout 0)
DEVICE_GONE = -201003          # device cannot be accessed

MESSAGES = {
    UNDERFLOW: "The generation has stopped to prevent the regeneration of old samples. Your application was unable "
               "to write samples to the background buffer fast enough to prevent old samples from being regenerated.",
    OVERWRITTEN: "The application is not able to keep up with the hardware acquisition. Attempted to read samples "
                 "that are no longer available.",
    WRITE_TIMEOUT: "Some or all of the samples to write could not be written to the buffer yet.",
    DEVICE_GONE: "Device cannot be accessed. Possible causes: the device is no longer present in the system.",
}


class DeviceClock:
    """Device time [s]: ``time.monotonic`` scaled by ``scale`` (device seconds per wall second), or stepped by hand
    (``manual=True``: :meth:`advance`)."""

    def __init__(self, scale: float = 1.0, manual: bool = False) -> None:
        self.scale, self.manual = float(scale), manual
        self._t0 = time.monotonic()
        self._t = 0.0

    def now(self) -> float:
        return self._t if self.manual else (time.monotonic() - self._t0) * self.scale

    def advance(self, seconds: float) -> None:
        assert self.manual, "advance() is for a manual clock"
        self._t += seconds


@dataclass
class _Task:
    name: str
    ao: list[str] = field(default_factory=list)
    ai: list[str] = field(default_factory=list)
    rate: float | None = None
    mode: Any = None
    source: str = ""
    trigger: str = ""
    regen: int = RegenerationMode.ALLOW_REGENERATION.value
    buf_size: int | None = None
    running: bool = False
    t_start: float = 0.0
    generated: int = 0
    buffer: deque = field(default_factory=deque)      # AO: [channels, n] blocks not generated yet
    buffered: int = 0
    error: int | None = None                          # latched generation/acquisition error
    error_reported: bool = False
    acquired: deque = field(default_factory=deque)    # AI: rows not read yet
    lost: int = 0
    cleared: bool = False

    @property
    def clocked(self) -> bool:
        return self.rate is not None and self.mode == AcquisitionType.CONTINUOUS.value


class FakeDaq:
    """One card (see the module docstring).

    Parameters
    ----------
    latency : int
        AI channel i reads AO channel i this many samples late.
    ai_gain : float
        Loopback gain (sensor volts per AO volt).
    clock : DeviceClock
        The device's time base.
    n_ao : int
        AO channels ``Dev1/ao0…``.
    """

    def __init__(self, latency: int = 3, ai_gain: float = 1.0, clock: DeviceClock | None = None,
                 n_ao: int = 4) -> None:
        self.latency, self.ai_gain = int(latency), float(ai_gain)
        self.clock = clock or DeviceClock()
        self.lock = threading.RLock()
        self.tasks: dict[int, _Task] = {}
        self._next = 1
        self.ao_value = {f"Dev1/ao{i}": 0.0 for i in range(n_ao)}   # what each AO pin holds now
        self._delay_line: dict[str, np.ndarray] = {}                     # the last `latency` AO values per pin
        self._wire: list[tuple[str, np.ndarray, np.ndarray]] = []         # see wire / trace()
        self.fail: dict[str, int] = {}        # interpreter method → error code raised on its next call
        self.fail_after: dict[str, tuple[int, int]] = {}   # method → (on its n-th call from now, error code)
        self.calls: list[str] = []
        self.gone = False

    # -- time --------------------------------------------------------------------------------------------------------
    def advance(self) -> None:
        """Bring every running task up to the device clock."""
        now = self.clock.now()
        for t in list(self.tasks.values()):
            if t.running and t.clocked and t.ao and t.error is None:
                self._generate(t, now)

    def _generate(self, t: _Task, now: float) -> None:
        target = int(np.floor((now - t.t_start) * t.rate + 1e-9)) + 1   # the first sample at the first edge
        n = target - t.generated
        while n > 0:
            if not t.buffer:
                t.error, t.error_reported = UNDERFLOW, False
                return
            b = t.buffer[0]
            take = min(n, b.shape[1])
            k = t.generated + np.arange(take)
            tk = t.t_start + k / t.rate
            for c, ch in enumerate(t.ao):
                self._drive(ch, b[c, :take], tk)
            self._acquire(take, {ch: b[c, :take] for c, ch in enumerate(t.ao)})
            t.generated += take
            t.buffered -= take
            n -= take
            if take == b.shape[1]:
                t.buffer.popleft()
            else:
                t.buffer[0] = b[:, take:]

    def _drive(self, ch: str, v: np.ndarray, tk: np.ndarray) -> None:
        """Values ``v`` reach pin ``ch`` at device times ``tk``."""
        self.ao_value[ch] = float(v[-1])
        self._wire.append((ch, np.asarray(tk, dtype=float), np.array(v, dtype=float)))

    def _acquire(self, n: int, ao: dict[str, np.ndarray]) -> None:
        """AI tasks clocked by the AO sample clock take one sample per edge: AO of ``latency`` edges earlier."""
        tasks = [t for t in self.tasks.values()
                 if t.ai and t.running and t.error is None and t.source.endswith("/ao/SampleClock")]
        cols = []
        for ch in (tasks[0].ai if tasks else []):
            ao_ch = ch.replace("/ai", "/ao")
            new = ao.get(ao_ch, np.full(n, self.ao_value.get(ao_ch, 0.0)))
            past = self._delay_line.get(ao_ch, np.zeros(self.latency))
            line = np.concatenate([past, new])
            cols.append(self.ai_gain * line[:n])
            self._delay_line[ao_ch] = line[-self.latency:] if self.latency else np.zeros(0)
        for t in tasks:
            rows = np.column_stack(cols) if cols else np.zeros((n, 0))
            t.acquired.extend(rows.tolist())
            while t.buf_size is not None and len(t.acquired) > t.buf_size:
                t.acquired.popleft()
                t.lost += 1
                t.error = OVERWRITTEN

    @property
    def wire(self) -> list[tuple[float, str, float]]:
        """``(device time [s], channel, value)`` of every value that reached an AO pin, in order."""
        return [(float(tt), ch, float(vv)) for ch, tk, v in self._wire for tt, vv in zip(tk, v)]

    def trace(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per AO channel: ``(device times, values)`` of everything that reached it, in order."""
        out: dict[str, tuple[list, list]] = {}
        for ch, tk, v in self._wire:
            out.setdefault(ch, ([], []))
            out[ch][0].append(tk)
            out[ch][1].append(v)
        return {ch: (np.concatenate(t), np.concatenate(v)) for ch, (t, v) in out.items()}

    # -- helpers for the interpreter --------------------------------------------------------------------------------
    def task(self, handle: int) -> _Task:
        t = self.tasks.get(handle)
        if t is None or t.cleared:
            raise DaqError("Task specified is invalid or does not exist.", -200088)
        return t


def _error(code: int, *, written: int | None = None, read: int | None = None) -> DaqError:
    msg = MESSAGES.get(code, f"error {code}") + f"\nStatus Code: {code}"
    if read is not None:
        return DaqReadError(msg, code, read)
    if written is not None:
        return DaqWriteError(msg, code, written)
    return DaqError(msg, code)


class FakeInterpreter(BaseInterpreter):
    """nidaqmx's interpreter with the C library replaced by :class:`FakeDaq` (see the module docstring)."""

    __slots__ = ("dev", "_last_chan")

    def __init__(self, dev: FakeDaq) -> None:
        self.dev = dev
        self._last_chan = ""

    # every call: the device catches up with its clock, then an injected error, if any
    def _enter(self, name: str) -> None:
        dev = self.dev
        dev.calls.append(name)
        dev.advance()
        if dev.gone:
            raise _error(DEVICE_GONE)
        code = dev.fail.pop(name, None)
        if code is None and name in dev.fail_after:
            left, c = dev.fail_after[name]
            if left <= 1:
                del dev.fail_after[name]
                code = c
            else:
                dev.fail_after[name] = (left - 1, c)
        if code is not None:
            if name.startswith("write"):
                raise _error(code, written=0)
            if name.startswith("read"):
                raise _error(code, read=0)
            raise _error(code)

    # -- task life cycle -------------------------------------------------------------------------------------------
    def create_task(self, session_name):
        with self.dev.lock:
            self._enter("create_task")
            h = self.dev._next
            self.dev._next += 1
            self.dev.tasks[h] = _Task(session_name)
            return h, True

    def clear_task(self, task):
        with self.dev.lock:
            self.dev.calls.append("clear_task")
            t = self.dev.tasks.get(task)
            if t is not None:
                t.running, t.cleared = False, True

    def start_task(self, task):
        with self.dev.lock:
            self._enter("start_task")
            t = self.dev.task(task)
            if t.ao and t.clocked:
                if t.regen == RegenerationMode.DONT_ALLOW_REGENERATION.value and not t.buffered:
                    raise _error(-200462)   # "generation cannot be started because the output buffer is empty"
            t.running, t.error, t.generated, t.lost = True, None, 0, 0
            t.t_start = self.dev.clock.now()
            if t.ao and t.clocked:
                self.dev._generate(t, t.t_start)

    def stop_task(self, task):
        with self.dev.lock:
            self._enter("stop_task")
            t = self.dev.task(task)
            t.running = False
            if t.error is not None and not t.error_reported:   # DAQmx reports a pending error at stop
                code, t.error_reported = t.error, True
                raise _error(code)

    def task_control(self, task, action):
        with self.dev.lock:
            self._enter("task_control")

    def is_task_done(self, task):
        with self.dev.lock:
            self._enter("is_task_done")
            t = self.dev.task(task)
            if t.error is not None:
                t.error_reported = True
                raise _error(t.error)
            return not t.running

    # -- configuration -----------------------------------------------------------------------------------------------
    def create_ao_voltage_chan(self, task, physical_channel, name_to_assign_to_channel, min_val, max_val, units,
                               custom_scale_name):
        with self.dev.lock:
            self._enter("create_ao_voltage_chan")
            if physical_channel not in self.dev.ao_value:
                raise _error(-200170)   # physical channel does not exist
            self.dev.task(task).ao.append(physical_channel)
            self._last_chan = physical_channel

    def create_ai_voltage_chan(self, task, physical_channel, name_to_assign_to_channel, terminal_config, min_val,
                               max_val, units, custom_scale_name):
        with self.dev.lock:
            self._enter("create_ai_voltage_chan")
            self.dev.task(task).ai.append(physical_channel)
            self._last_chan = physical_channel

    def internal_get_last_created_chan(self):
        return self._last_chan

    def cfg_samp_clk_timing(self, task, rate, source, active_edge, sample_mode, samps_per_chan):
        with self.dev.lock:
            self._enter("cfg_samp_clk_timing")
            t = self.dev.task(task)
            t.rate, t.source, t.mode = float(rate), source, sample_mode
            if t.buf_size is None:
                t.buf_size = int(samps_per_chan)

    def cfg_dig_edge_start_trig(self, task, trigger_source, trigger_edge):
        with self.dev.lock:
            self._enter("cfg_dig_edge_start_trig")
            self.dev.task(task).trigger = trigger_source

    def set_write_attribute_int32(self, task, attribute, value):
        with self.dev.lock:
            self._enter("set_write_attribute_int32")
            if attribute == 0x1453:
                self.dev.task(task).regen = int(value)

    def set_buffer_attribute_uint32(self, task, attribute, value):
        with self.dev.lock:
            self._enter("set_buffer_attribute_uint32")
            if attribute in (0x186d, 0x186c):
                self.dev.task(task).buf_size = int(value)

    def get_write_attribute_uint32(self, task, attribute):
        with self.dev.lock:
            self._enter("get_write_attribute_uint32")
            t = self.dev.task(task)
            if attribute == 0x217e:    # number of channels
                return len(t.ao)
            if attribute == 0x1460:    # space available in the buffer
                return (t.buf_size or 0) - t.buffered
            raise NotImplementedError(f"write attribute {attribute:#x}")

    def get_write_attribute_uint64(self, task, attribute):
        with self.dev.lock:
            self._enter("get_write_attribute_uint64")
            if attribute == 0x192b:    # total samples per channel generated
                return self.dev.task(task).generated
            raise NotImplementedError(f"write attribute {attribute:#x}")

    def get_write_attribute_int32(self, task, attribute):
        with self.dev.lock:
            if attribute == 0x1453:
                return self.dev.task(task).regen
            raise NotImplementedError(f"write attribute {attribute:#x}")

    def get_read_attribute_uint32(self, task, attribute):
        with self.dev.lock:
            self._enter("get_read_attribute_uint32")
            t = self.dev.task(task)
            if attribute == 0x1223:    # available samples per channel
                return len(t.acquired)
            if attribute == 0x217b:    # number of channels
                return len(t.ai)
            raise NotImplementedError(f"read attribute {attribute:#x}")

    def get_task_attribute_string(self, task, attribute):
        t = self.dev.task(task)
        if attribute == 0x1273:        # channel names
            return ", ".join(t.ao or t.ai)
        if attribute == 0x1276:
            return t.name
        raise NotImplementedError(f"task attribute {attribute:#x}")

    def get_task_attribute_uint32(self, task, attribute):
        t = self.dev.task(task)
        if attribute == 0x2181:
            return len(t.ao or t.ai)
        raise NotImplementedError(f"task attribute {attribute:#x}")

    def get_chan_attribute_int32(self, task, channel, attribute):
        t = self.dev.task(task)
        if attribute == 0x187f:        # channel type
            from nidaqmx.constants import ChannelType
            return (ChannelType.ANALOG_OUTPUT if t.ao else ChannelType.ANALOG_INPUT).value
        raise NotImplementedError(f"channel attribute {attribute:#x}")

    # -- data ------------------------------------------------------------------------------------------------------
    def write_analog_f64(self, task, num_samps_per_chan, auto_start, timeout, data_layout, write_array):
        with self.dev.lock:
            self._enter("write_analog_f64")
            t = self.dev.task(task)
            data = np.asarray(write_array, dtype=float).reshape(len(t.ao), -1)[:, :num_samps_per_chan]
            if not t.clocked:       # on demand: out at once
                now = self.dev.clock.now()
                for c, ch in enumerate(t.ao):
                    self.dev._drive(ch, data[c, -1:], np.array([now]))
                return num_samps_per_chan
            if t.error is not None:
                t.error_reported = True
                raise _error(t.error, written=0)
            space = (t.buf_size or 0) - t.buffered
            n = min(space, num_samps_per_chan)
            if n:
                t.buffer.append(np.array(data[:, :n]))
                t.buffered += n
            if n < num_samps_per_chan:
                raise _error(WRITE_TIMEOUT, written=n)
            if auto_start and not t.running:
                self.start_task(task)
            return n

    def read_analog_f64(self, task, num_samps_per_chan, timeout, fill_mode, read_array):
        with self.dev.lock:
            self._enter("read_analog_f64")
            t = self.dev.task(task)
            if t.error is not None:
                code, t.error = t.error, None
                raise _error(code, read=0)
            n = min(int(num_samps_per_chan), len(t.acquired))
            for i in range(n):
                read_array[:, i] = t.acquired.popleft()
            return read_array, n

    def hash_task_handle(self, task_handle):
        return hash(task_handle)

    @property
    def driver_version(self):
        return (24, 8, 0)

    def get_extended_error_info(self):
        return ""

    def get_error_string(self, error_code):
        return MESSAGES.get(error_code, "")


def _not_on_the_fake(name: str) -> Callable[..., Any]:
    def call(self, *args, **kwargs):
        raise NotImplementedError(f"FakeInterpreter.{name}: not used by the backend (add it to the fake)")
    call.__name__ = name
    return call


for _name in sorted(BaseInterpreter.__abstractmethods__ - set(vars(FakeInterpreter))):
    setattr(FakeInterpreter, _name, _not_on_the_fake(_name))
FakeInterpreter.__abstractmethods__ = frozenset()


def install(monkeypatch: Any, dev: FakeDaq) -> FakeDaq:
    """Route every ``nidaqmx.Task`` created from now on to ``dev`` (the package's interpreter selection)."""
    import nidaqmx.utils

    monkeypatch.setattr(nidaqmx.utils, "_select_interpreter",
                        lambda grpc_options=None, interpreter=None: FakeInterpreter(dev))
    return dev
