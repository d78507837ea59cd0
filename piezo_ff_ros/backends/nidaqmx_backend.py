"""``nidaqmx`` backend: an NI DAQ card drives the amplifier inputs (AO) and, optionally, reads a displacement sensor
(AI), on one sample clock.  Optional extra: ``pip install piezo_ff_ros[nidaqmx]`` (plus NI-DAQmx itself).

Thin by design — buffering, alignment, stale input, faults and the safe ramp live in the contract layer
(``core/hardware``).  What this adapter does, as NI's documentation describes it (not run on hardware here):

- AO task: one voltage channel per axis (``ao_channels``), range ±``ao_range`` V, continuous sample clock at the
  config's rate, **regeneration off** (``RegenerationMode.DONT_ALLOW_REGENERATION``: an empty buffer is an error, never
  a replay of old samples), output buffer ``fifo_depth`` samples, pre-filled with the safe voltage before the task
  starts; blocks written with an ``AnalogMultiChannelWriter`` (``write_many_sample``, timeout 0: never blocks);
- amplifier gain/offset per axis: the piezo voltage is ``gain·V_ao + offset`` — the adapter writes
  ``(U − offset) / gain``;
- AI task (if ``ai_channels`` is set): one channel per axis, its sample clock **is the AO sample clock**
  (``/<dev>/ao/SampleClock``) and it arms on the AO start trigger, so AI sample k is taken on AO sample k's clock edge;
  read with an ``AnalogMultiChannelReader``; ``y = sensor_gain·V_ai + sensor_offset`` [m];
- AI sample i is taken on AO sample i's clock edge; it is tagged with the output index it answers,
  ``i − latency_samples`` (the AO→AI delay of amplifier, sensor and filters: measure it with ``piezo-ff rig-check``,
  which reports the value to set);
- the device clock is ``out_stream.total_samp_per_chan_generated``; the FIFO space ``out_stream.space_avail``;
- errors from any call (write, read, poll, start, the restart): output underflow / regeneration stop (-200290,
  -200621, -200016, -200018) → :class:`Underrun`, samples no longer available (-200279) → :class:`Overrun`, device
  not accessible (-201003, -50405) and anything else → :class:`Disconnect`;
- after an AI overrun (DAQmx reports it until the task restarts; the samples still buffered have no known index)
  both tasks are restarted the same way as after an underflow (the AO task stopped first);
- after an underflow the output holds its last generated value.  The next write restarts the task: the write-ahead
  (that held value), the samples the old task had not generated and the new block are written **before** the clock
  starts; the new task's first sample takes the device index the host clock says it is, so the held samples keep
  their place on the sample grid (reported as applied; later stamps stay true to when their samples are generated)
  and what the stopped AI task had acquired is still delivered (if it cannot be read: an :class:`Overrun`);
- ``close()`` ramps the output to the safe voltage **while the task generates** (a new task if it had stopped),
  waits until the ramp is out, then stops and closes every task, the AI task whatever the AO task does.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..core.hardware.contract import (ContractError, DeviceInfo, Disconnect, Overrun, StreamingBackend,
                                       Underrun)
from ..core.safety import SafeRampConfig, safe_ramp
from .base import BackendError, BackendSpec, Param, float_range, int_range, non_empty

if TYPE_CHECKING:
    from ..core.config import PiezoConfig

UNDERRUN_CODES = {-200290, -200621, -200016, -200018}
OVERRUN_CODES = {-200279}
DISCONNECT_CODES = {-201003, -50405}


def _channels(text: str) -> list[str]:
    return [c.strip() for c in str(text).split(",") if c.strip()]


class NidaqmxBackend(StreamingBackend):
    """See the module docstring.  ``nidaqmx`` is the imported package (injectable for tests)."""

    def __init__(self, cfg: PiezoConfig, p: dict[str, Any], nidaqmx: Any = None,
                 now: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        if nidaqmx is None:
            try:
                import importlib  # noqa: PLC0415 - the optional extra is imported only when used

                nidaqmx = importlib.import_module("nidaqmx")
                for sub in ("stream_readers", "stream_writers"):   # not imported by the package itself
                    importlib.import_module(f"nidaqmx.{sub}")
            except ImportError as exc:
                raise BackendError(f"nidaqmx: the nidaqmx package is not installed ({exc}); "
                                   "pip install 'piezo_ff_ros[nidaqmx]'") from None
        self.nd = nidaqmx
        self.cfg = cfg
        self.p = p
        n = cfg.n_axes
        self.ao = _channels(p["ao_channels"])
        self.ai = _channels(p["ai_channels"])
        for name, chans in (("ao_channels", self.ao), ("ai_channels", self.ai)):
            if chans and len(chans) != n:
                raise BackendError(f"nidaqmx.{name}: {len(chans)} channel(s) for {n} axes {list(cfg.axes)}")
        if not self.ao:
            raise BackendError("nidaqmx.ao_channels: one AO channel per axis is required")
        self.gain = self._per_axis("amp_gain")
        self.offset = self._per_axis("amp_offset")
        self.s_gain = self._per_axis("sensor_gain")
        self.s_offset = self._per_axis("sensor_offset")
        if np.any(self.gain == 0):
            raise BackendError("nidaqmx.amp_gain: must not be 0")
        lim = cfg.limits.voltage
        worst = np.max(np.abs((np.array([lim, -lim])[:, None] - self.offset) / self.gain))
        if worst > p["ao_range"] + 1e-9:
            raise BackendError(f"nidaqmx.ao_range: ±{p['ao_range']} V cannot express ±{lim} V at the amplifier "
                               f"with amp_gain {self.gain.tolist()} (needs ±{worst:.3g} V)")
        self.info = DeviceInfo(name=f"nidaqmx:{p['device']}", sample_rate_hz=float(cfg.sample_rate), n_axes=n,
                               fifo_depth=int(p["fifo_depth"]), has_sensor=bool(self.ai), clocked=True)
        self.now, self.sleep = now, sleep
        self._ao_task: Any = None   # nidaqmx objects once started
        self._ai_task: Any = None
        self._writer: Any = None
        self._reader: Any = None
        self._widx = 0              # next device index to write
        self._base = 0              # device index of the current AO task's first sample (after a restart)
        self._t_start = 0.0         # now() when the current AO task started
        self._prefill = 2           # samples written before a task's clock starts (the driver's write-ahead)
        self._pending_applied: list[tuple[int, np.ndarray]] = []
        self._read_idx = 0          # AI samples read from the current AI task
        self._ai_backlog: list[tuple[int, np.ndarray]] = []
        self._ai_lost = False
        self._ai_overrun = False    # the AI task reported lost samples: restart both tasks
        self._last_released = np.zeros(n)   # the last sample reported applied
        self._last = np.zeros(n)    # the last sample written: what the output holds once the buffer ran dry
        self._dead_at: int | None = None   # device index where the stopped task's output stopped
        self._restart = False       # the AO task stopped (underflow): restart on the next write
        self.restarts = 0
        self.close_errors: list[str] = []

    def _per_axis(self, name: str) -> np.ndarray:
        v = np.array(self.p[name], dtype=float).ravel()
        if v.size == 1:
            v = np.repeat(v, self.cfg.n_axes)
        if v.size != self.cfg.n_axes or not np.all(np.isfinite(v)):
            raise BackendError(f"nidaqmx.{name}: need {self.cfg.n_axes} finite values (one per axis), got "
                               f"{self.p[name]!r}")
        return v

    # -- vendor calls ------------------------------------------------------------------------------------------
    def _fault(self, exc: Exception) -> Exception:
        """The contract's fault for a vendor error (an underflow also marks the task for a restart)."""
        code = getattr(exc, "error_code", None)
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if code in UNDERRUN_CODES:
            self._mark_dead()
            return Underrun(f"nidaqmx: output underflow ({code}): the AO task stopped, the output holds "
                            f"{self._last.tolist()} V", k=self._widx)
        if code in OVERRUN_CODES:
            # DAQmx keeps reporting it until the task restarts, and the samples still buffered no longer have a
            # known index: both tasks are restarted (the AI re-armed on the new AO start trigger) on the next write
            self._ai_overrun = True
            self._mark_dead()
            return Overrun(f"nidaqmx: AI samples lost ({code}): the tasks restart", k=self._base + self._read_idx)
        if code in DISCONNECT_CODES:
            return Disconnect(f"nidaqmx: device not accessible ({code})")
        return Disconnect(f"nidaqmx: {first} ({code})")

    def _mark_dead(self) -> None:
        """The AO task stopped generating: from now on the output holds its last generated value, and the clock is
        counted on the host from the task's start (the held samples keep their place on the sample grid)."""
        self._restart = True

    def _generated_end(self) -> int:
        """Device index after the last sample the AO task generated (everything written if it cannot say)."""
        try:
            return min(self._widx, self._base + int(self._ao_task.out_stream.total_samp_per_chan_generated))
        except Exception:  # noqa: BLE001 - no count (no task, device error): a real underflow generated everything
            return self._widx

    def _stopped_at(self) -> int:
        """Device index where the stopped task's output stopped (asked once, after stopping it; a failed restart
        keeps it)."""
        if self._dead_at is None:
            if self._ao_task is not None:
                try:
                    self._ao_task.stop()     # a task restarted after an overrun still runs: stop it before counting
                except Exception:  # noqa: BLE001 - it had stopped (underflow): its count stands
                    pass
            self._dead_at = self._generated_end()
        return self._dead_at

    def _restart_hold(self, unplayed: int) -> int:
        """Samples of the held value a restarted task starts with: the write-ahead, within the buffer that must
        also take the ``unplayed`` samples the stopped task had not generated."""
        return max(2, min(self._prefill, self.info.fifo_depth - unplayed - 1))

    def _host_clock(self) -> int:
        """The device index the sample clock would be at now, counted on the host since the task started."""
        return self._base + int(round((self.now() - self._t_start) * float(self.cfg.sample_rate)))

    def _to_ao(self, u: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(((u - self.offset) / self.gain).T)   # [channels, samples]

    def _make_tasks(self, prefill_block: np.ndarray) -> None:
        """Create the AO (and AI) task, write ``prefill_block`` before the clock starts, start AI (armed on the AO
        start trigger), then AO."""
        nd, c = self.nd, self.nd.constants
        fs, p = float(self.cfg.sample_rate), self.p
        ao = nd.Task(f"piezo_ff_ao_{p['device']}")
        self._ao_task = ao
        for ch in self.ao:
            ao.ao_channels.add_ao_voltage_chan(ch, min_val=-p["ao_range"], max_val=p["ao_range"])
        ao.timing.cfg_samp_clk_timing(fs, sample_mode=c.AcquisitionType.CONTINUOUS, samps_per_chan=p["fifo_depth"])
        ao.out_stream.regen_mode = c.RegenerationMode.DONT_ALLOW_REGENERATION
        ao.out_stream.output_buf_size = p["fifo_depth"]
        self._writer = nd.stream_writers.AnalogMultiChannelWriter(ao.out_stream, auto_start=False)
        if self.ai:
            ai = nd.Task(f"piezo_ff_ai_{p['device']}")
            self._ai_task = ai
            for ch in self.ai:
                ai.ai_channels.add_ai_voltage_chan(ch, min_val=-p["ai_range"], max_val=p["ai_range"])
            ai.timing.cfg_samp_clk_timing(fs, source=f"/{p['device']}/ao/SampleClock",
                                          sample_mode=c.AcquisitionType.CONTINUOUS,
                                          samps_per_chan=p["input_buffer"])
            ai.triggers.start_trigger.cfg_dig_edge_start_trig(f"/{p['device']}/ao/StartTrigger")
            self._reader = nd.stream_readers.AnalogMultiChannelReader(ai.in_stream)
        self._writer.write_many_sample(self._to_ao(prefill_block), timeout=0)
        if self._ai_task is not None:
            self._ai_task.start()          # armed: waits for the AO start trigger and clock
        self._t_start = self.now()
        ao.start()

    # -- contract ----------------------------------------------------------------------------------------------
    def start(self, safe_voltage: np.ndarray, prefill: int = 0) -> int:
        self._last = np.asarray(safe_voltage, dtype=float).copy()
        self._prefill = max(int(prefill), 2)
        block = np.tile(self._last, (self._prefill, 1))
        self._base = self._widx = self._read_idx = 0
        try:
            self._make_tasks(block)
        except Exception as exc:  # noqa: BLE001 - vendor errors: one line naming the backend
            self.close_tasks()
            raise BackendError(f"nidaqmx: cannot start on {self.p['device']}: "
                               f"{str(exc).splitlines()[0] if str(exc) else exc!r}") from None
        self._pending_applied.append((0, block))
        self._widx = block.shape[0]
        return self._widx

    def clock(self) -> int:
        if self._ao_task is None:
            return self._widx
        if self._restart:
            return self._host_clock()
        try:
            return self._base + int(self._ao_task.out_stream.total_samp_per_chan_generated)
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None

    @property
    def write_index(self) -> int:
        # while the task is stopped the output holds: those samples pass with the clock
        return max(self._widx, self._host_clock()) if self._restart else self._widx

    def write_space(self) -> int:
        if self._restart:   # conservative: fewer samples remain unplayed by the time the task restarts
            end = self._dead_at if self._dead_at is not None else self._generated_end()
            unplayed = self._widx - end
            return max(0, self.info.fifo_depth - self._restart_hold(unplayed) - unplayed)
        try:
            return int(self._ao_task.out_stream.space_avail)
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None

    def write(self, k0: int, block: np.ndarray) -> None:
        u = np.asarray(block, dtype=float)
        if k0 != self.write_index and not (self._restart and k0 >= self._widx):
            raise ContractError(f"nidaqmx: write at {k0}, expected {self.write_index}")
        if self._restart:
            self._restart_with(u)
        else:
            try:
                self._writer.write_many_sample(self._to_ao(u), timeout=0)
            except Exception as exc:  # noqa: BLE001
                raise self._fault(exc) from None
            self._pending_applied.append((self._widx, u))
            self._widx += u.shape[0]
        if u.shape[0]:
            self._last = u[-1].copy()

    def _restart_with(self, u: np.ndarray) -> None:
        """After an underflow: a new task whose buffer holds the write-ahead (the held voltage), any samples the old
        task had buffered but not generated, and ``u`` before its clock starts.  The samples the output held
        meanwhile keep their place on the sample grid (the new task's first sample is the device index the host
        clock says it is) and are reported as applied; what the stopped AI task had acquired is kept for
        :meth:`read`."""
        gen_end = self._stopped_at()
        n_hold = self._restart_hold(self._widx - gen_end)
        held, unplayed = self._split_pending(gen_end)
        if self._ai_overrun:
            self._ai_overrun = False    # what it still holds has no known index: lost (counted by that overrun)
        else:
            self._drain_ai()
        self.close_tasks()
        hold = np.tile(held, (n_hold, 1))
        first = np.vstack([hold, unplayed, u])
        old_base, old_t0 = self._base, self._t_start
        try:
            self._make_tasks(first)
        except Exception as exc:  # noqa: BLE001 - the restart failed: a fault, retried on the next write
            self.close_tasks()
            self._t_start = old_t0        # the host clock still counts from the stopped task's start
            if unplayed.shape[0]:
                self._pending_applied.append((gen_end, unplayed))   # still to be output by the next attempt
            raise self._fault(exc) from None
        # the new task's first sample: where the old task's clock would be at the new start (host-counted)
        base = max(gen_end, old_base + int(round((self._t_start - old_t0) * float(self.cfg.sample_rate))))
        if base > gen_end:
            self._pending_applied.append((gen_end, np.tile(held, (base - gen_end, 1))))
        self._restart, self._dead_at = False, None
        self._base, self._read_idx = base, 0
        self._pending_applied.append((base, first))
        self._widx = base + first.shape[0]
        self.restarts += 1

    def _split_pending(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(value of sample k − 1, samples written from k on)``; the latter leave the pending record."""
        keep, later = [], []
        for k0, u in self._pending_applied:
            if k0 + u.shape[0] <= k:
                keep.append((k0, u))
            elif k0 >= k:
                later.append(u)
            else:
                keep.append((k0, u[:k - k0]))
                later.append(u[k - k0:])
        self._pending_applied = keep
        held = keep[-1][1][-1].copy() if keep else self._last_released.copy()
        unplayed = np.vstack(later) if later else np.zeros((0, self.cfg.n_axes))
        return held, unplayed

    def _drain_ai(self) -> None:
        """Keep what the AI task acquired before it is closed; if that fails, the samples are counted lost."""
        if self._reader is None:
            return
        try:
            got = self._read_available()
        except Exception:  # noqa: BLE001 - the samples are gone: an overrun on the next read
            self._ai_lost = True
            return
        if got is not None:
            self._ai_backlog.append(got)

    def _read_available(self) -> tuple[int, np.ndarray] | None:
        avail = int(self._ai_task.in_stream.avail_samp_per_chan)
        if avail <= 0:
            return None
        buf = np.zeros((len(self.ai), avail))
        got = int(self._reader.read_many_sample(buf, number_of_samples_per_channel=avail, timeout=0))
        if not got:
            return None
        y = buf[:, :got].T * self.s_gain + self.s_offset
        # AI sample i of this task is taken on AO sample i's clock edge; it answers the output latency_samples
        # earlier (amplifier, sensor, filters)
        k0 = self._base + self._read_idx - self.latency_samples
        self._read_idx += got
        return k0, y

    def poll(self) -> None:
        if self._ao_task is None or self._restart:
            return
        try:
            self._ao_task.is_task_done()   # raises the task's pending error (underflow, device gone)
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None

    def take_applied(self) -> list[tuple[int, np.ndarray]]:
        """What was written (and held), released once the clock has passed it."""
        clk = self.clock()
        out = []
        while self._pending_applied and self._pending_applied[0][0] < clk:
            k0, u = self._pending_applied[0]
            take = min(u.shape[0], clk - k0)
            if take > 0:
                out.append((k0, u[:take]))
                self._last_released = u[take - 1].copy()
            if take >= u.shape[0]:
                self._pending_applied.pop(0)
            else:
                self._pending_applied[0] = (k0 + take, u[take:])
        return out

    def read(self) -> list[tuple[int, np.ndarray]]:
        out, self._ai_backlog = self._ai_backlog, []
        if self._ai_lost:
            self._ai_lost = False
            raise Overrun("nidaqmx: AI samples of the stopped task could not be read: lost", k=self._base)
        if self._reader is None or self._restart:
            return out
        try:
            got = self._read_available()
        except Exception as exc:  # noqa: BLE001
            self._ai_backlog = out + self._ai_backlog    # delivered on the next read
            raise self._fault(exc) from None
        return out + ([got] if got is not None else [])

    @property
    def latency_samples(self) -> int:
        return int(self.p["latency_samples"])

    def status(self) -> dict:
        return {"backend": "nidaqmx", "device": self.p["device"], "ao": self.ao, "ai": self.ai,
                "written": self._widx, "restarts": self.restarts}

    def close_tasks(self) -> None:
        """Stop and close every task, each whatever the others do (a stop that raises does not leak a task)."""
        errors = []
        for attr in ("_ao_task", "_ai_task"):
            t = getattr(self, attr)
            setattr(self, attr, None)
            if t is None:
                continue
            try:
                t.stop()
            except Exception as exc:  # noqa: BLE001 - closing continues
                errors.append(exc)
            try:
                t.close()
            except Exception as exc:  # noqa: BLE001
                errors.append(exc)
        self._writer = self._reader = None
        self.close_errors += [str(e).splitlines()[0] if str(e) else type(e).__name__ for e in errors]

    def _wait_generated(self, index: int) -> None:
        """Wait (bounded) until the AO task has generated every sample before device ``index``."""
        fs = float(self.cfg.sample_rate)
        for _ in range(int(((index - self.clock()) / fs + 1.0) / 0.002) + 1):
            if self.clock() >= index:
                return
            self.sleep(0.002)

    def close(self) -> None:
        """Bring the output to the safe voltage by a ramp **while the task generates** (a new task if the old one
        stopped: the output held its last value), wait until it has been output, then stop and close the tasks —
        the AI task whatever the AO task does.  The ramp is the default safe ramp (``SafeRampConfig``) within the
        configured slew limit; the driver core normally ramps first, then this has nothing left to do."""
        safe = np.full(self.cfg.n_axes, float(self.cfg.limits.safe_voltage))
        try:
            if self._ao_task is not None or self._restart:
                ramp = safe_ramp(self._last, float(self.cfg.limits.safe_voltage), float(self.cfg.sample_rate),
                                 SafeRampConfig(), self.cfg.limits.slew)
                tail = np.tile(safe, (max(self._prefill, 2), 1))   # so that the buffer never runs dry meanwhile
                if ramp.shape[0] or self.write_space() >= tail.shape[0]:
                    self.write(self.write_index, np.vstack([ramp, tail]))
                    self._wait_generated(self._widx - tail.shape[0])
                else:    # the buffer is full: its last sample is the safe voltage; stop once it is out
                    self._wait_generated(self._widx)
        except Exception as exc:  # noqa: BLE001 - closing: the tasks are closed whatever happened
            self.close_errors.append(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        finally:
            self.close_tasks()
            self._restart = False


def create(cfg: PiezoConfig, p: dict[str, Any]) -> NidaqmxBackend:
    """The backend for the driver node (``BackendSpec.create``)."""
    return NidaqmxBackend(cfg, p)


SPEC = BackendSpec(
    name="nidaqmx",
    description="NI-DAQmx card: AO to the amplifier inputs, optional AI sensor, one sample clock",
    parameters={
        "device": Param("Dev1", "NI device name (NI MAX)", non_empty),
        "ao_channels": Param("Dev1/ao0,Dev1/ao1", "AO channels, one per axis in axis order", non_empty),
        "ai_channels": Param("", "AI channels of the displacement sensor, one per axis ('' = no sensor)"),
        "ao_range": Param(10.0, "AO range ±V", float_range(0.1, 10.0)),
        "ai_range": Param(10.0, "AI range ±V", float_range(0.1, 10.0)),
        "amp_gain": Param([20.0], "amplifier gain per axis [V/V] (piezo V = gain·V_ao + offset)"),
        "amp_offset": Param([0.0], "amplifier offset per axis [V]"),
        "sensor_gain": Param([1.0e-5], "sensor gain per axis [m/V]"),
        "sensor_offset": Param([0.0], "sensor offset per axis [m]"),
        "fifo_depth": Param(20000, "AO buffer [samples] (≥ the driver's write_ahead)", int_range(64, 10_000_000)),
        "input_buffer": Param(100000, "AI buffer [samples]", int_range(64, 100_000_000)),
        "latency_samples": Param(1, "AO→AI latency [samples] (measure it with rig-check)", int_range(0, 100000)),
    },
    create=create,
)
