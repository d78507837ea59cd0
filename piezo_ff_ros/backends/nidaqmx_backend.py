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
- the device clock is ``out_stream.total_samp_per_chan_generated``; the FIFO space ``out_stream.space_avail``;
- errors: output underflow / regeneration stop (-200290, -200621, -200016, -200018) → :class:`Underrun` (the task
  is restarted at the safe voltage on the next write; the held interval is not sample-exact), samples no longer
  available (-200279) → :class:`Overrun`, device not accessible (-201003, -50405) → :class:`Disconnect`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.hardware.contract import (ContractError, DeviceInfo, Disconnect, Overrun, StreamingBackend,
                                       Underrun)
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

    def __init__(self, cfg: PiezoConfig, p: dict[str, Any], nidaqmx: Any = None) -> None:
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
        self._ao_task: Any = None   # nidaqmx objects once started
        self._ai_task: Any = None
        self._writer: Any = None
        self._reader: Any = None
        self._widx = 0
        self._pending_applied: list[tuple[int, np.ndarray]] = []
        self._applied_upto = 0
        self._read_idx = 0
        self._last = np.zeros(n)
        self._restart = False

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
        code = getattr(exc, "error_code", None)
        if code in UNDERRUN_CODES:
            self._restart = True
            return Underrun(f"nidaqmx: output underflow ({code}): the AO task stopped", k=self._widx)
        if code in OVERRUN_CODES:
            return Overrun(f"nidaqmx: AI samples lost ({code})", k=self._read_idx)
        if code in DISCONNECT_CODES:
            return Disconnect(f"nidaqmx: device not accessible ({code})")
        return Disconnect(f"nidaqmx: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__} ({code})")

    def _to_ao(self, u: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(((u - self.offset) / self.gain).T)   # [channels, samples]

    def _make_tasks(self, safe: np.ndarray, prefill: int) -> None:
        nd, c = self.nd, self.nd.constants
        fs, p = float(self.cfg.sample_rate), self.p
        ao = nd.Task(f"piezo_ff_ao_{p['device']}")
        for ch in self.ao:
            ao.ao_channels.add_ao_voltage_chan(ch, min_val=-p["ao_range"], max_val=p["ao_range"])
        ao.timing.cfg_samp_clk_timing(fs, sample_mode=c.AcquisitionType.CONTINUOUS, samps_per_chan=p["fifo_depth"])
        ao.out_stream.regen_mode = c.RegenerationMode.DONT_ALLOW_REGENERATION
        ao.out_stream.output_buf_size = p["fifo_depth"]
        self._ao_task = ao
        self._writer = nd.stream_writers.AnalogMultiChannelWriter(ao.out_stream, auto_start=False)
        if self.ai:
            ai = nd.Task(f"piezo_ff_ai_{p['device']}")
            for ch in self.ai:
                ai.ai_channels.add_ai_voltage_chan(ch, min_val=-p["ai_range"], max_val=p["ai_range"])
            ai.timing.cfg_samp_clk_timing(fs, source=f"/{p['device']}/ao/SampleClock",
                                          sample_mode=c.AcquisitionType.CONTINUOUS,
                                          samps_per_chan=p["input_buffer"])
            ai.triggers.start_trigger.cfg_dig_edge_start_trig(f"/{p['device']}/ao/StartTrigger")
            self._ai_task = ai
            self._read_idx = 0
            self._reader = nd.stream_readers.AnalogMultiChannelReader(ai.in_stream)
        block = np.tile(safe, (max(int(prefill), 2), 1))
        self._writer.write_many_sample(self._to_ao(block), timeout=0)
        self._pending_applied.append((self._widx, block))
        self._widx += block.shape[0]
        if self._ai_task is not None:
            self._ai_task.start()          # armed: waits for the AO start trigger and clock
        ao.start()

    # -- contract ----------------------------------------------------------------------------------------------
    def start(self, safe_voltage: np.ndarray, prefill: int = 0) -> int:
        self._last = np.asarray(safe_voltage, dtype=float).copy()
        try:
            self._make_tasks(self._last, prefill)
        except Exception as exc:  # noqa: BLE001 - vendor errors: one line naming the backend
            self.close()
            raise BackendError(f"nidaqmx: cannot start on {self.p['device']}: "
                               f"{str(exc).splitlines()[0] if str(exc) else exc!r}") from None
        return self._widx

    def clock(self) -> int:
        if self._ao_task is None:
            return 0
        try:
            return self._base + int(self._ao_task.out_stream.total_samp_per_chan_generated)
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None

    _base = 0   # device index of the current AO task's first sample (after a restart)

    @property
    def write_index(self) -> int:
        return self._widx

    def write_space(self) -> int:
        if self._restart:
            return self.info.fifo_depth
        try:
            return int(self._ao_task.out_stream.space_avail)
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None

    def write(self, k0: int, block: np.ndarray) -> None:
        if k0 != self._widx:
            raise ContractError(f"nidaqmx: write at {k0}, expected {self._widx}")
        u = np.asarray(block, dtype=float)
        if self._restart:  # after an underflow the task stopped: restart it, continuing the sample count
            self._restart = False
            self._base = self._widx
            self._applied_upto = self._widx
            self.close_tasks()
            self._make_tasks(self._last, 2)
        try:
            self._writer.write_many_sample(self._to_ao(u), timeout=0)
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None
        self._pending_applied.append((self._widx, u))
        self._widx += u.shape[0]
        if u.shape[0]:
            self._last = u[-1].copy()

    def poll(self) -> None:
        if self._ao_task is None:
            return
        try:
            self._ao_task.is_task_done()   # raises the task's pending error (underflow, device gone)
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None

    def take_applied(self) -> list[tuple[int, np.ndarray]]:
        """What was written, released once the clock has passed it (exact while the task runs)."""
        clk = self.clock() if not self._restart else self._widx
        out = []
        while self._pending_applied and self._pending_applied[0][0] < clk:
            k0, u = self._pending_applied[0]
            take = min(u.shape[0], clk - k0)
            out.append((k0, u[:take]))
            if take == u.shape[0]:
                self._pending_applied.pop(0)
            else:
                self._pending_applied[0] = (k0 + take, u[take:])
        return out

    def read(self) -> list[tuple[int, np.ndarray]]:
        if self._reader is None:
            return []
        try:
            avail = int(self._ai_task.in_stream.avail_samp_per_chan)
            if avail <= 0:
                return []
            buf = np.zeros((len(self.ai), avail))
            got = int(self._reader.read_many_sample(buf, number_of_samples_per_channel=avail, timeout=0))
        except Exception as exc:  # noqa: BLE001
            raise self._fault(exc) from None
        y = buf[:, :got].T * self.s_gain + self.s_offset
        k0 = self._base + self._read_idx      # AI sample i of this task ↔ AO sample i (same clock and trigger)
        self._read_idx += got
        return [(k0, y)] if got else []

    @property
    def latency_samples(self) -> int:
        return int(self.p["latency_samples"])

    def status(self) -> dict:
        return {"backend": "nidaqmx", "device": self.p["device"], "ao": self.ao, "ai": self.ai,
                "written": self._widx}

    def close_tasks(self) -> None:
        for t in (self._ao_task, self._ai_task):
            if t is None:
                continue
            try:
                t.stop()
            finally:
                t.close()
        self._ao_task = self._ai_task = self._writer = self._reader = None

    def close(self) -> None:
        """Stop, then write the safe voltage once (on-demand) so that the amplifier input rests there."""
        try:
            self.close_tasks()
        except Exception:  # noqa: BLE001 - closing: best effort
            pass
        try:
            with self.nd.Task("piezo_ff_safe") as t:
                for ch in self.ao:
                    t.ao_channels.add_ao_voltage_chan(ch, min_val=-self.p["ao_range"], max_val=self.p["ao_range"])
                safe = np.full(self.cfg.n_axes, float(self.cfg.limits.safe_voltage))
                t.write(((safe - self.offset) / self.gain).tolist(), auto_start=True)
        except Exception:  # noqa: BLE001
            pass


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
        "fifo_depth": Param(8000, "AO buffer [samples]", int_range(64, 10_000_000)),
        "input_buffer": Param(100000, "AI buffer [samples]", int_range(64, 100_000_000)),
        "latency_samples": Param(1, "AO→AI latency [samples] (measure it with rig-check)", int_range(0, 100000)),
    },
    create=create,
)
