"""``pi_gcs`` backend: a PI digital piezo controller (E-727, E-712, …) driving a tube in open loop, through PI's
``pipython`` (optional extra: ``pip install piezo_ff_ros[pipython]``).  Written against the GCS 2.0 command
reference; exercised here only against a GCS 2.0 emulator served on a loopback TCP port (test/gcs_emulator.py),
never on a controller.

**Connection** — pipython's own pure-Python interfaces by default, nothing from PI to install: ``PISocket``
(``interface: tcpip``) and ``PISerial`` (``interface: serial`` or ``usb``: RS-232 and the controllers' USB serial
ports, e.g. ``/dev/ttyUSB0``; needs ``pyserial``), wrapped in ``GCSDevice(gateway=…)``.  PI's shared library
(``libpi_pi_gcs2``) only with ``use_dll: true``.  At connect the controller's identity (``*IDN?``), axes (``SAI?``),
voltage range per piezo channel (``VMI?``/``VMA?``) and, for table mode, wave-table (``WMS?``) and data-recorder
(``SPA?`` 0x16000200 / 0x16000300, as pipython's ``getmaxnumvalues``) capacities are read; what exceeds them is
refused with one line before anything moves.

Two modes:

- **set-point mode** (the driver backend, ``backend:=pi_gcs``) — open loop (``SVO`` 0); the controller applies a set
  point (``SVA``) at once and holds it, so every voltage move is played **in time** as a staircase of set points no
  more than ``setpoint_step`` (1 V) apart, one at most every ``1/setpoint_rate`` s otherwise, each sent no earlier
  than its sample's instant after the previous one (a late host stretches the staircase, it never compresses it):
  between two set points the voltage changes by no more than the driver's slew limit allows for the time elapsed.
  ``start`` reads the voltage the output holds (``VOL?``) and ramps from there to the safe voltage; ``close`` ramps to
  safe, then closes the connection.  A controller error (e.g. 302, voltage out of limits) is a named fault
  (:class:`GCSFault`, code and text, kind ``limit`` or ``controller``) carrying the last accepted set point
  (``held``): the rest of the block holds it, and the driver core's fault path ramps to safe from there (through
  the same paced staircase); the link stays usable.  A lost link is a :class:`Disconnect`.
  No sensor stream (use table mode to record); ``clocked`` is False, ``holds_setpoints`` True.
- **table mode** (:class:`PITablePlayer`) — the paper's setting for a controller that cannot be streamed at 20 kHz:
  a voltage table (``piezo-ff feedforward``) is checked against the controller's range, the slew limit and the
  wave/record capacities, the output is ramped from what it holds to the table's first value, the table uploaded
  (``WAV … PNT``), connected (``WSL``), played once (``WGC`` 1, ``WTR`` servo rate / sample rate, ``WGO``) while the
  data recorder (``DRC``, ``RTR``) records the sensor; the player waits on the generator **running** (``#9``, as
  pipython's ``waitonwavegen``), reads the recorder back (``DRR?``), stops the generator and ramps to safe — after
  playing and on every error.
"""
from __future__ import annotations

import math
import select
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..core.hardware.contract import ContractError, ControllerFault, DeviceFault, DeviceInfo, Disconnect, \
    StreamingBackend, WriteCursorClock
from ..core.safety import SafeRampConfig, safe_ramp
from .base import BackendError, BackendSpec, Param, float_range, int_range, one_of

if TYPE_CHECKING:
    from ..core.config import LimitsConfig, PiezoConfig

#: GCS error codes that mean "the controller refused a value" (a limit), reported as kind ``limit``
LIMIT_CODES = frozenset({302, 18, 7})


class GCSFault(ControllerFault):
    """A GCS error reported by the controller (``code`` > 0, ``text`` from pipython's table): a named fault.

    ``kind`` (of the contract's ``FAULT_KINDS``) is ``limit`` for a refused value (302 voltage out of limits, 7
    position out of limits, 18 invalid value) and ``controller`` otherwise; ``held`` is the last set point the
    controller accepted (what its output holds).
    """

    def __init__(self, code: int, text: str, where: str, k: int | None = None, held: np.ndarray | None = None) -> None:
        self.text, self.where = str(text), str(where)
        self.kind = "limit" if int(code) in LIMIT_CODES else "controller"
        super().__init__(f"pi_gcs: controller error {int(code)} ({self.text}) on {where}", k, code=int(code),
                         held=held)


class TableError(BackendError):
    """Table mode failed (after the generator was stopped and the output ramped to safe); ``code`` is the GCS error
    code when the controller reported one."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


def _axes(text: str) -> list[str]:
    return [a.strip() for a in str(text).split(",") if a.strip()]


def _first_line(exc: BaseException) -> str:
    s = str(exc)
    return s.splitlines()[0] if s else type(exc).__name__


def _gcs_error(exc: BaseException) -> tuple[int, str] | None:
    """``(code, text)`` of a pipython GCSError, else None."""
    val = getattr(exc, "val", None)
    if isinstance(val, int):
        text = getattr(exc, "msg", "") or str(exc)
        # pipython appends the code to the text ("Voltage out of limits 302"): keep the words
        text = str(text).split(":")[0].strip()
        if text.endswith(str(val)):
            text = text[: -len(str(val))].strip()
        return val, text
    return None


# -- connection ----------------------------------------------------------------------------------------------------
def _gateway_classes() -> tuple[type, type | None]:
    """pipython's ``PISocket`` / ``PISerial`` with a read that waits on the port (``select``/a short sleep) instead of
    returning at once: pipython's ``GCSMessages._read`` polls ``read()`` in a loop until its timeout, which would
    otherwise spin a CPU core for as long as a query stays unanswered.  A connection the controller closed is
    reported as such (``ConnectionError``) instead of looking like silence."""
    from pipython.pidevice.interfaces.pigateway import PI_CONTROLLER_CODEPAGE  # noqa: PLC0415 - optional extra
    from pipython.pidevice.interfaces.pisocket import PISocket  # noqa: PLC0415

    class WaitingSocket(PISocket):
        # pipython keeps the connection callbacks in a class attribute shared by every gateway: a device closed
        # earlier would be called back on this connection.  A class of its own per connection isolates them.
        _connection_status_changed_callbacks: list = []

        def read(self) -> str:
            r, _, _ = select.select([self._socket], [], [], 0.005)
            if not r:
                return ""
            data = self._socket.recv(65536)
            if not data:
                self._connected = False
                raise ConnectionError("the controller closed the TCP connection")
            return data.decode(encoding=PI_CONTROLLER_CODEPAGE, errors="ignore")

        def flush(self) -> None:
            while select.select([self._socket], [], [], 0)[0]:
                if not self._socket.recv(65536):
                    break

        def close(self) -> None:
            if self._socket is not None and self._connected:
                super().close()
            self._connected = False

    try:
        from pipython.pidevice.interfaces.piserial import PISerial  # noqa: PLC0415 - needs pyserial
    except ImportError:
        return WaitingSocket, None

    class WaitingSerial(PISerial):
        _connection_status_changed_callbacks: list = []

        def read(self) -> str:
            if not self._ser.in_waiting:
                time.sleep(0.002)
            return super().read()

    return WaitingSocket, WaitingSerial


@dataclass(frozen=True)
class ControllerInfo:
    """What the controller said about itself at connect."""

    idn: str
    axes: tuple[str, ...]            #: configured axes (``SAI?``)
    vmin: tuple[float, ...]          #: per configured axis, its piezo channel's lower voltage limit (``VMI?``) [V]
    vmax: tuple[float, ...]          #: per configured axis, ``VMA?`` [V]


class GCSLink:
    """A connected controller: the pipython ``GCSDevice``, its gateway and :class:`ControllerInfo`.

    Parameters
    ----------
    p : dict
        The backend's validated parameters.
    """

    def __init__(self, p: dict[str, Any]) -> None:
        self.p = p
        self.axes = _axes(p["axes"])
        self.channels = [int(c) for c in _axes(p["piezo_channels"])] if str(p["piezo_channels"]).strip() else \
            list(range(1, len(self.axes) + 1))
        if len(self.channels) != len(self.axes):
            raise BackendError(f"pi_gcs.piezo_channels: {len(self.channels)} channels for {len(self.axes)} axes")
        where = f"{p['interface']} {p['address']}" + (f":{p['port']}" if p["interface"] == "tcpip" else "")
        try:
            from pipython import GCSDevice  # noqa: PLC0415 - optional extra
        except ImportError as exc:
            raise BackendError(f"pi_gcs: the pipython package is not installed ({exc}); "
                               "pip install 'piezo_ff_ros[pipython]'") from None
        self.gateway: Any = None
        try:
            if p["use_dll"]:
                self.dev = self._connect_dll(GCSDevice, where)
            else:
                sock_cls, serial_cls = _gateway_classes()
                if p["interface"] == "tcpip":
                    self.gateway = sock_cls(host=p["address"], port=p["port"])
                else:
                    if serial_cls is None:
                        raise BackendError(f"pi_gcs.interface: {p['interface']} needs pyserial (pip install "
                                           "pyserial)")
                    self.gateway = serial_cls(port=p["address"], baudrate=p["baudrate"])
                self.gateway.settimeout(int(p["timeout_ms"]))
                self.dev = GCSDevice(gateway=self.gateway)
            self.info = self._query()
        except BackendError:
            self.close()
            raise
        except Exception as exc:  # noqa: BLE001 - vendor/OS errors: one line naming the backend and where
            self.close()
            raise BackendError(f"pi_gcs: cannot connect ({where}): {_first_line(exc)}") from None

    def _connect_dll(self, gcs_device: Callable[..., Any], where: str) -> Any:
        p = self.p
        try:
            dev = gcs_device()
            if p["interface"] == "tcpip":
                dev.ConnectTCPIP(ipaddress=p["address"], ipport=p["port"])
            elif p["interface"] == "usb":
                dev.ConnectUSB(serialnum=p["address"])
            else:
                dev.ConnectRS232(comport=p["address"], baudrate=p["baudrate"])
        except Exception as exc:  # noqa: BLE001 - pipython loads the library lazily, at the first Connect…
            if _gcs_error(exc) is not None:
                raise
            raise BackendError(f"pi_gcs.use_dll: PI's GCS shared library is not usable here ({_first_line(exc)}); "
                               "set use_dll: false to use pipython's own TCP/serial code") from None
        return dev

    def _query(self) -> ControllerInfo:
        d = self.dev
        idn = d.qIDN().strip()
        present = [str(a) for a in d.qSAI()]
        missing = [a for a in self.axes if a not in present]
        if missing:
            raise BackendError(f"pi_gcs.axes: axis {missing[0]!r} is not on the controller ({idn}); it has "
                               f"{present} (SAI?)")
        try:
            vmin = d.qVMI(self.channels)
            vmax = d.qVMA(self.channels)
        except Exception as exc:  # noqa: BLE001 - without the range nothing can be checked: refuse
            raise BackendError(f"pi_gcs: {idn} did not give the voltage range of piezo channels {self.channels} "
                               f"(VMI?/VMA?: {_first_line(exc)}); check pi_gcs.piezo_channels") from None
        return ControllerInfo(idn=idn, axes=tuple(present),
                              vmin=tuple(float(vmin[c]) for c in self.channels),
                              vmax=tuple(float(vmax[c]) for c in self.channels))

    def held_voltage(self) -> np.ndarray:
        """The voltage the piezo channels hold now (``VOL?``) [V per axis]."""
        v = self.dev.qVOL(self.channels)
        return np.array([float(v[c]) for c in self.channels])

    def check_limits(self, limits: LimitsConfig) -> None:
        """Refuse (one line) a driver voltage range the controller would reject with error 302."""
        for a, lo, hi in zip(self.axes, self.info.vmin, self.info.vmax):
            if not (lo <= limits.safe_voltage <= hi):
                raise BackendError(f"limits.safe_voltage: {limits.safe_voltage:g} V is outside axis {a}'s range "
                                   f"[{lo:g}, {hi:g}] V on {self.info.idn} (VMI?/VMA?)")
            if -limits.voltage < lo or limits.voltage > hi:
                raise BackendError(f"limits.voltage: ±{limits.voltage:g} V exceeds axis {a}'s range [{lo:g}, {hi:g}] "
                                   f"V on the controller (VMI?/VMA?); set limits.voltage ≤ {min(-lo, hi):g}")

    def close(self) -> None:
        """Close the connection (the socket or port too); idempotent."""
        gw, self.gateway = self.gateway, None
        dev = getattr(self, "dev", None)
        self.dev = None
        try:
            if dev is not None and gw is not None:
                type(gw).unregister_connection_status_changed_callback(dev.connection_status_changed)
            if gw is not None:
                gw.close()
            elif dev is not None:
                dev.CloseConnection()
        except Exception:  # noqa: BLE001 - closing: nothing more to do
            pass


def connect(p: dict[str, Any]) -> GCSLink:
    """A connected :class:`GCSLink` (BackendError, one line, otherwise)."""
    return GCSLink(p)


# -- the paced staircase -------------------------------------------------------------------------------------------
class Staircase:
    """Plays voltage samples on a set-and-hold controller as a paced staircase of ``SVA`` set points.

    The schedule: a set point where the next sample would be more than ``step_max`` volts from the previous set
    point, at the end of each block, and otherwise every ``decimation`` samples; a single sample step larger than
    ``step_max`` is split into equal set points spread over its sample period.  Pacing, on the wall clock, with the
    block's samples anchored at their real-time instants:

    - a set point goes out no earlier than its sample's instant, and no earlier than the previous set point's
      acknowledgement plus the samples between them — so that on the wire two set points are never closer in time
      than their samples are (the voltage moves no faster than the stream it plays);
    - when the host is late (a long sleep, a loaded machine), the staircase catches up by skipping scheduled set
      points, never by hurrying: it sends the latest scheduled value whose instant has come, provided it is within
      ``step_max`` of the previous set point and no further ahead of it than the time elapsed since.  A block thus
      lasts its real time on the wire; only a lag the rules do not let it absorb is kept (:attr:`late_s`).

    Parameters
    ----------
    send : callable
        ``send(values)``: one set point for all axes (raises on a controller error).
    fs : float
        Sample rate [Hz].
    step_max : float
        Largest voltage difference between consecutive set points [V].
    decimation : int
        Samples between set points when the voltage moves slowly.
    start : array
        The voltage the output holds now.
    """

    def __init__(self, send: Callable[[np.ndarray], None], fs: float, step_max: float, decimation: int,
                 start: np.ndarray, sleep: Callable[[float], None] = time.sleep,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.send, self.fs, self.step_max, self.decimation = send, float(fs), float(step_max), max(1, int(decimation))
        self.sent = np.asarray(start, dtype=float).copy()   #: last value accepted by the controller
        self.anchor: float | None = None                     #: wall time of the next block's first sample
        self.t_done = -math.inf                              #: when the last set point was acknowledged
        self.pos_sent = -math.inf                            #: its position [samples] relative to ``anchor``
        self.setpoints = 0
        self.skipped = 0                                      #: scheduled set points skipped to stay in real time
        self.rows_done = 0
        self.late_s = 0.0                                     #: lag kept at the end of blocks [s]
        self._sleep, self._clock = sleep, clock

    def schedule(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(positions [samples, block-relative; sample j at j + 1], values [m, axes])`` of the planned set
        points (vectorised over the samples between two set points)."""
        pos: list[float] = []
        val: list[np.ndarray] = []
        prev = self.sent
        n = u.shape[0]
        j0 = 0
        while j0 < n:
            seg = u[j0:j0 + self.decimation]
            dev = np.max(np.abs(seg - prev), axis=1) if u.shape[1] else np.zeros(seg.shape[0])
            over = np.flatnonzero(dev > self.step_max)
            if over.size and over[0] == 0:
                # one sample moves more than step_max: equal set points spread over its sample period
                nsub = int(math.ceil(float(dev[0]) / self.step_max - 1e-12))
                for q in range(1, nsub + 1):
                    pos.append(j0 + q / nsub)
                    # the last one is the sample itself (prev + (u - prev)·1 may differ from it in the last bit)
                    val.append(u[j0].copy() if q == nsub else prev + (u[j0] - prev) * (q / nsub))
                prev = u[j0]
                j0 += 1
                continue
            # the last sample still within step_max of the previous set point, at most `decimation` ahead
            j = j0 + int(over[0]) - 1 if over.size else min(j0 + self.decimation, n) - 1
            if np.any(u[j] != prev):
                pos.append(j + 1.0)
                val.append(u[j])
                prev = u[j]
            j0 = j + 1
        return np.array(pos, dtype=float), np.array(val, dtype=float).reshape(len(val), u.shape[1])

    def play(self, u: np.ndarray, applied: np.ndarray | None = None) -> np.ndarray:
        """Play ``u [N, axes]`` in time; return what the output held at each sample ``[N, axes]``.

        On an exception from ``send`` the rows of ``applied`` (if given) up to the failing set point are filled
        (:attr:`rows_done` of them); the exception propagates with :attr:`sent` the last accepted value.
        """
        u = np.asarray(u, dtype=float)
        n = u.shape[0]
        out = np.empty_like(u) if applied is None else applied
        dt = 1.0 / self.fs
        now = self._clock()
        if self.anchor is None or self.anchor < now:
            self.pos_sent -= ((now - self.anchor) / dt) if self.anchor is not None else 0.0
            self.anchor = now                                # the output held meanwhile: the block starts now
        anchor = self.anchor
        if self.setpoints == 0 and math.isinf(self.t_done):
            self.t_done, self.pos_sent = now, 0.0           # the held voltage counts as acknowledged now
        pos, val = self.schedule(u)
        sent_pos: list[float] = []
        sent_vals: list[np.ndarray] = [self.sent.copy()]
        self.rows_done = 0
        i, m = 0, len(pos)
        try:
            while i < m:
                earliest = max(anchor + pos[i] * dt, self.t_done + (pos[i] - self.pos_sent) * dt)
                now = self._clock()
                if earliest > now:
                    self._sleep(earliest - now)
                    now = self._clock()
                # catch up: the latest scheduled value whose instant has come, within step_max of the last set
                # point and no further ahead of it than the time since its acknowledgement
                reach = min((now - anchor) / dt, self.pos_sent + (now - self.t_done) / dt)
                k = i
                while k + 1 < m and pos[k + 1] <= reach and \
                        float(np.max(np.abs(val[k + 1] - self.sent))) <= self.step_max + 1e-12:
                    k += 1
                self.skipped += k - i
                self.rows_done = min(n, int(math.ceil(pos[k])) - 1)
                self.send(val[k])
                self.t_done = self._clock()
                self.sent = val[k].copy()
                self.pos_sent = pos[k]
                sent_pos.append(pos[k])
                sent_vals.append(self.sent.copy())
                self.setpoints += 1
                i = k + 1
            self.rows_done = n
        finally:
            # sample j holds the last set point at a position ≤ j + 1 (sample j's own is at j + 1)
            rows = np.arange(1, self.rows_done + 1, dtype=float)
            out[:self.rows_done] = np.asarray(sent_vals)[np.searchsorted(np.asarray(sent_pos), rows, side="right")]
        end = anchor + n * dt
        now = self._clock()
        if end > now:
            self._sleep(end - now)                           # the block lasts its time on the wire too
        elif now - end > 0:
            self.late_s += now - end
        self.anchor = end
        self.pos_sent -= n
        return out


# -- set-point mode ------------------------------------------------------------------------------------------------
class PISetpointBackend(WriteCursorClock, StreamingBackend):
    """Set-point mode behind the streaming contract (see the module docstring)."""

    def __init__(self, cfg: PiezoConfig, p: dict[str, Any], ramp: SafeRampConfig | None = None,
                 now: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        self.p = p
        self._now, self._sleep = now, sleep      # the staircase's pacing clock (injectable for tests)
        self.axes = _axes(p["axes"])
        if len(self.axes) != cfg.n_axes:
            raise BackendError(f"pi_gcs.axes: {len(self.axes)} controller axes for {cfg.n_axes} axes "
                               f"{list(cfg.axes)}")
        self.cfg = cfg
        self.fs = float(cfg.sample_rate)
        self.ramp = ramp or SafeRampConfig(float(p["safe_ramp_duration"]), float(p["safe_ramp_slew"]))
        self.link: GCSLink | None = None
        self.stairs: Staircase | None = None
        self.info = DeviceInfo(name="pi_gcs", sample_rate_hz=self.fs, n_axes=cfg.n_axes,
                               fifo_depth=1 << 30, has_sensor=False, clocked=False, holds_setpoints=True)
        self._k = 0
        self._applied: list = []
        self._pending: DeviceFault | None = None
        self._latched = ""          # why nothing can be written any more (the link is lost)
        self.ramps = 0

    # -- helpers -----------------------------------------------------------------------------------------------------
    def _send(self, values: np.ndarray) -> None:
        assert self.link is not None
        self.link.dev.SVA(self.axes, [float(v) for v in values])

    def _ramp_samples(self, u_from: np.ndarray) -> np.ndarray:
        lim = self.cfg.limits
        return safe_ramp(u_from, lim.safe_voltage, self.fs, self.ramp, lim.slew)

    def _play(self, u: np.ndarray, where: str) -> np.ndarray:
        """Play ``u`` as a staircase; on an error the rest of the block holds the last accepted set point and the
        fault waits for :meth:`poll`: a GCS error is a named :class:`GCSFault` (the driver ramps to safe from
        ``held``), anything else a lost link (latched: nothing more is written)."""
        assert self.stairs is not None
        applied = np.empty_like(u)
        try:
            return self.stairs.play(u, applied)
        except Exception as exc:  # noqa: BLE001 - sorted below: controller error vs lost link
            done = min(u.shape[0], self.stairs.rows_done)
            fault = self._classify(exc, where)
            self._pending = self._pending or fault
            if isinstance(fault, Disconnect):
                self._latched = str(fault)
            applied[done:] = self.stairs.sent
            return applied

    def _classify(self, exc: BaseException, where: str) -> DeviceFault:
        err = _gcs_error(exc)
        if err is not None and err[0] > 0:
            assert self.stairs is not None
            return GCSFault(err[0], err[1], where, self._k, held=self.stairs.sent.copy())
        return Disconnect(f"pi_gcs: link to the controller lost during {where} ({_first_line(exc)}); the output "
                          f"holds its last set point {self.stairs.sent.tolist() if self.stairs else '?'} V", self._k)

    def _safe_ramp_now(self) -> np.ndarray:
        """Ramp from the last accepted set point to the safe voltage, in time; the samples it held."""
        assert self.stairs is not None
        r = self._ramp_samples(self.stairs.sent)
        self.ramps += 1
        if not r.shape[0]:
            return r
        try:
            return self.stairs.play(r)
        except Exception as exc:  # noqa: BLE001 - a second failure: nothing more can be done over this link
            self._latched = f"{self._latched}; the safe ramp failed too ({_first_line(exc)})"
            self._pending = self._pending or Disconnect(self._latched, self._k)
            return np.tile(self.stairs.sent, (r.shape[0], 1))

    # -- contract ----------------------------------------------------------------------------------------------------
    def start(self, safe_voltage: np.ndarray, prefill: int = 0) -> int:
        self.link = connect(self.p)
        try:
            self.link.check_limits(self.cfg.limits)
            self.link.dev.SVO(self.axes, [False] * len(self.axes))
            held = self.link.held_voltage()
        except BackendError:
            self.link.close()
            raise
        except Exception as exc:  # noqa: BLE001 - one line
            self.link.close()
            raise BackendError(f"pi_gcs: start failed on {self.link.info.idn}: {_first_line(exc)}") from None
        self.held_at_start = held.copy()
        self.stairs = Staircase(self._send, self.fs, float(self.p["setpoint_step"]),
                                int(round(self.fs / float(self.p["setpoint_rate"]))), held, sleep=self._sleep,
                                clock=self._now)
        r = safe_ramp(held, float(np.asarray(safe_voltage).flat[0]), self.fs, self.ramp, self.cfg.limits.slew)
        if r.shape[0]:
            self._append(self._k, self._play(r, "the start ramp"))
        if prefill:
            self.write(self._k, np.tile(np.asarray(safe_voltage, dtype=float), (int(prefill), 1)))
        return self._k

    def write(self, k0: int, block: np.ndarray) -> None:
        if self.link is None or self.stairs is None:
            raise ContractError("pi_gcs: not started")
        if k0 != self._k:
            raise ContractError(f"pi_gcs: write at {k0}, expected {self._k}")
        u = np.asarray(block, dtype=float)
        if not u.shape[0]:
            return
        if self._latched:
            raise Disconnect(f"pi_gcs: nothing written: {self._latched}", self._k)
        self._append(k0, self._play(u, f"SVA at sample {k0}"))

    def _append(self, k0: int, applied: np.ndarray) -> None:
        """Report ``applied`` from sample ``k0``."""
        self._applied.append((k0, applied))
        self._k = k0 + applied.shape[0]

    def poll(self) -> None:
        fault, self._pending = self._pending, None
        if fault is not None:
            raise fault

    def read(self) -> list[tuple[int, np.ndarray]]:
        return []

    def take_applied(self) -> list[tuple[int, np.ndarray]]:
        out, self._applied = self._applied, []
        return out

    @property
    def latency_samples(self) -> int:
        return 0

    def status(self) -> dict:
        info = self.link.info if self.link is not None else None
        return {"backend": "pi_gcs", "mode": "setpoint", "idn": info.idn if info else "", "axes": self.axes,
                "setpoints": self.stairs.setpoints if self.stairs else 0,
                "late_s": round(self.stairs.late_s, 6) if self.stairs else 0.0, "latched": self._latched}

    def close(self) -> None:
        """Ramp from the last accepted set point to the safe voltage, in time, then close the connection."""
        if self.link is None:
            return
        try:
            if self.stairs is not None and not isinstance(self._pending, Disconnect) and \
                    not self._latched.startswith("pi_gcs: link"):
                self._safe_ramp_now()
        finally:
            self.link.close()
            self.link = None


# -- table mode ------------------------------------------------------------------------------------------------------
class PITablePlayer:
    """Table mode: play ``u [N, axes]`` V once through the wave generators, hardware-timed, recording the sensor.

    Parameters
    ----------
    cfg : PiezoConfig
        Sample rate, axes and the driver's limits (voltage, slew, safe voltage) the table is checked against.
    p : dict
        The backend's validated parameters.
    ramp : SafeRampConfig, optional
        How the output is brought to the table's first value and back to safe.
    link : GCSLink, optional
        An open connection (default: connect with ``p``).
    """

    def __init__(self, cfg: PiezoConfig, p: dict[str, Any], ramp: SafeRampConfig | None = None,
                 link: GCSLink | None = None) -> None:
        self.cfg, self.p = cfg, p
        self.axes = _axes(p["axes"])
        if len(self.axes) != cfg.n_axes:
            raise BackendError(f"pi_gcs.axes: {len(self.axes)} controller axes for {cfg.n_axes} axes "
                               f"{list(cfg.axes)}")
        self.gens = [int(x) for x in _axes(p["wave_generators"])]
        self.tables = [int(x) for x in _axes(p["wave_tables"])]
        self.rec = [int(x) for x in _axes(p["record_tables"])]
        for name, v in (("wave_generators", self.gens), ("wave_tables", self.tables), ("record_tables", self.rec)):
            if len(v) != len(self.axes):
                raise BackendError(f"pi_gcs.{name}: {len(v)} entries for {len(self.axes)} axes")
        self.fs = float(cfg.sample_rate)
        ratio = p["servo_rate"] / self.fs
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise BackendError(f"pi_gcs.servo_rate: {p['servo_rate']:g} Hz / {self.fs:g} Hz = {ratio:g}: the "
                               "wave table rate must be a whole number of servo cycles; choose the sample rate")
        self.table_rate = int(round(ratio))
        self.ramp = ramp or SafeRampConfig(float(p["safe_ramp_duration"]), float(p["safe_ramp_slew"]))
        self.link = link or connect(p)
        self.setpoint_faults: list[str] = []
        try:
            self.wave_points, self.record_points = self._capacities()
        except BackendError:
            self.link.close()
            raise
        self.info = self.link.info
        self.timeout = 60.0
        safe = float(cfg.limits.safe_voltage)
        for a, lo, hi in zip(self.axes, self.info.vmin, self.info.vmax):
            if not lo <= safe <= hi:
                self.link.close()
                raise BackendError(f"limits.safe_voltage: {safe:g} V is outside axis {a}'s range [{lo:g}, {hi:g}] V "
                                   "on the controller (VMI?/VMA?)")

    def _capacities(self) -> tuple[int, int | None]:
        d = self.link.dev
        try:
            wms = d.qWMS(self.tables)
            wave = min(int(wms[t]) for t in self.tables)
        except Exception as exc:  # noqa: BLE001 - without a capacity nothing can be checked: refuse
            raise BackendError(f"pi_gcs: cannot read the wave table capacity (WMS?): {_first_line(exc)}") from None
        rec = None
        try:
            ntab = int(d.qTNR())
            if max(self.rec) > ntab:
                raise BackendError(f"pi_gcs.record_tables: table {max(self.rec)} but the controller has {ntab} "
                                   "(TNR?)")
            total = self._param(0x16000200)
            chans = self._param(0x16000300) or ntab
            if total:
                rec = int(total) // int(chans)
        except BackendError:
            raise
        except Exception:  # noqa: BLE001 - unknown record capacity: checked by DRR? itself (error 77)
            rec = None
        return wave, rec

    def _param(self, pid: int) -> int | None:
        """A controller parameter (``SPA? 1 <id>``) as pipython's ``getparam``, without its help-text lookup."""
        d = self.link.dev
        ans = d.ReadGCSCommand(f"SPA? 1 0x{pid:08X}")
        err = d.qERR()
        if err or "=" not in ans:
            return None
        try:
            return int(float(ans.split("=")[1].strip()))
        except ValueError:
            return None

    # -- checks ------------------------------------------------------------------------------------------------------
    def check(self, u: np.ndarray) -> np.ndarray:
        """``u`` as ``[N, axes]`` floats, or ValueError (one line) if the controller or the amplifier could not
        follow it: shape, NaN, the controller's range, the driver's voltage and slew limits, the capacities."""
        u = np.asarray(u, dtype=float)
        if u.ndim != 2 or u.shape[1] != len(self.axes) or u.shape[0] < 1:
            raise ValueError(f"table: expected [N, {len(self.axes)}] volts, got shape {u.shape}")
        if not np.all(np.isfinite(u)):
            raise ValueError(f"table: {int(np.count_nonzero(~np.isfinite(u)))} NaN/Inf value(s)")
        n = u.shape[0]
        if n > self.wave_points:
            raise ValueError(f"table: {n} samples exceed the wave table capacity {self.wave_points} (WMS?) on "
                             f"{self.info.idn}; shorten the trajectory or lower the sample rate")
        if self.record_points is not None and n > self.record_points:
            raise ValueError(f"table: {n} samples exceed the data recorder capacity {self.record_points} per table "
                             "(SPA? 0x16000200/0x16000300); shorten the trajectory")
        for a, (name, lo, hi) in enumerate(zip(self.axes, self.info.vmin, self.info.vmax)):
            bad = (u[:, a] < lo) | (u[:, a] > hi)
            if bad.any():
                worst = float(max(lo - u[:, a].min(), u[:, a].max() - hi))
                raise ValueError(f"table: {int(bad.sum())} sample(s) of axis {name} outside the controller's range "
                                 f"[{lo:g}, {hi:g}] V (VMI?/VMA?), by up to {worst:.3g} V")
        lim = self.cfg.limits
        over = np.abs(u) > lim.voltage
        if over.any():
            raise ValueError(f"table: {int(over.any(axis=1).sum())} sample(s) beyond limits.voltage ±{lim.voltage:g} "
                             f"V, by up to {float(np.abs(u).max() - lim.voltage):.3g} V")
        step = lim.slew / self.fs
        du = np.abs(np.diff(u, axis=0))
        fast = du > step * (1 + 1e-9)
        if fast.any():
            raise ValueError(f"table: {int(fast.any(axis=1).sum())} sample step(s) beyond limits.slew "
                             f"{lim.slew:g} V/s ({step:.3g} V per sample), by up to {float(du.max() - step):.3g} V")
        return u

    # -- playing -----------------------------------------------------------------------------------------------------
    def _staircase(self, start: np.ndarray) -> Staircase:
        d, axes = self.link.dev, self.axes
        return Staircase(lambda v: d.SVA(axes, [float(x) for x in v]), self.fs, float(self.p["setpoint_step"]),
                         int(round(self.fs / float(self.p["setpoint_rate"]))), start)

    def _ramp_to(self, target: np.ndarray, start: np.ndarray) -> Staircase:
        """Ramp in time from ``start`` to ``target`` at the safe ramp's pace (set points ≤ setpoint_step apart)."""
        lim = self.cfg.limits
        stairs = self._staircase(start)
        # safe_ramp goes to a scalar: ramp each axis by the same fraction (all axes arrive together)
        dist = float(np.max(np.abs(target - start))) if start.size else 0.0
        if dist > 0:
            step = min(self.ramp.slew, lim.slew) / self.fs
            n = max(int(math.ceil(self.ramp.duration * self.fs - 1e-9)), int(math.ceil(dist / step - 1e-9)), 1)
            frac = (np.arange(1, n + 1) / n)[:, None]
            stairs.play(start[None, :] + (target - start)[None, :] * frac)
        return stairs

    def play(self, u: np.ndarray, timeout: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Play ``u`` once (checked first); return ``(applied [N, axes] V, recorded positions [N, axes] m)``.

        ``timeout``: seconds to wait beyond the table's length (default :attr:`timeout`, 60 s).

        Before: the output is ramped, in time, from the voltage it holds to ``u[0]``.  After — and on every error —
        the generators are stopped and the output ramped to the safe voltage.  Errors are :class:`TableError`
        (one line: the GCS code and text, or the timeout)."""
        u = self.check(u)
        timeout = self.timeout if timeout is None else float(timeout)
        d, ax, n = self.link.dev, self.axes, u.shape[0]
        started = False
        try:
            running = any(d.IsGeneratorRunning(self.gens).values())
        except Exception as exc:  # noqa: BLE001 - nothing was sent yet
            raise TableError(f"pi_gcs: cannot query the wave generators (#9): {_first_line(exc)}") from None
        if running:       # someone else's: not ours to stop or to ramp
            raise TableError("pi_gcs: a wave generator is already running; stop it first (WGO 0)")
        try:
            d.SVO(ax, [False] * len(ax))
            held = self.link.held_voltage()
            self._ramp_to(u[0], held)
            chunk = int(self.p["chunk"])
            for a, table in enumerate(self.tables):
                for i in range(0, n, chunk):
                    part = u[i:i + chunk, a]
                    d.WAV_PNT(table, i + 1, part.size, "X" if i == 0 else "&", [float(v) for v in part])
            d.WSL(self.gens, self.tables)
            d.WGC(self.gens, [1] * len(self.gens))
            d.WTR(self.gens, [self.table_rate] * len(self.gens), [0] * len(self.gens))
            d.DRC(self.rec, ax, [int(self.p["record_option"])] * len(ax))
            d.RTR(self.table_rate)
            started = True
            d.WGO(self.gens, [1] * len(self.gens))
            deadline = time.monotonic() + timeout + n / self.fs
            poll = min(0.1, max(0.005, n / self.fs / 20))
            while any(d.IsGeneratorRunning(self.gens).values()):          # '#9', as pipython's waitonwavegen
                if time.monotonic() > deadline:
                    raise TableError(f"pi_gcs: the wave generators still run {timeout:g} s after the table's end")
                time.sleep(poll)
            d.qDRR(self.rec, 1, n)
            while d.bufstate is not True:          # raises pipython's -7 timeout if the controller stays silent
                if time.monotonic() > deadline:
                    raise TableError("pi_gcs: the data recorder read-back (DRR?) did not finish")
                time.sleep(0.01)
            y = np.array(d.bufdata, dtype=float).T * float(self.p["position_scale"])
            if y.shape != u.shape:
                raise TableError(f"pi_gcs: DRR? returned {y.shape} values for a {u.shape} table")
        except TableError as exc:
            raise TableError(f"{exc}; {self._to_safe(started)}", exc.code) from None
        except (KeyboardInterrupt, SystemExit):    # Ctrl-C / SIGTERM: stop and ramp to safe, then go on stopping
            self._to_safe(started)
            raise
        except Exception as exc:  # noqa: BLE001 - named, after the clean-up
            after = self._to_safe(started)
            err = _gcs_error(exc)
            if err is not None:
                what = "no answer" if err[0] == -7 else f"controller error {err[0]} ({err[1]})"
                raise TableError(f"pi_gcs: table mode stopped: {what}; {after}", code=err[0]) from None
            raise TableError(f"pi_gcs: table mode stopped: {_first_line(exc)}; {after}") from None
        self._to_safe(started)
        if self.setpoint_faults:
            raise TableError(f"pi_gcs: the table played but {self.setpoint_faults[-1]}")
        return u.copy(), y

    def _to_safe(self, started: bool) -> str:
        """Stop the generators (if they were started) and ramp from what the output holds to the safe voltage;
        what happened, for the message."""
        d = self.link.dev
        if d is None:
            return "the connection is closed: the controller holds its last value"
        try:
            if started:
                d.WGO(self.gens, [0] * len(self.gens))
            held = self.link.held_voltage()
            self._ramp_to(np.full(len(self.axes), float(self.cfg.limits.safe_voltage)), held)
        except Exception as exc:  # noqa: BLE001 - reported, the connection is probably gone
            self.setpoint_faults.append(f"the clean-up failed ({_first_line(exc)}): the controller holds its last "
                                        "value")
            return self.setpoint_faults[-1]
        return "generators stopped, output ramped to safe" if started else "output ramped to safe"

    def close(self) -> None:
        """Close the connection (socket included)."""
        self.link.close()


def create(cfg: PiezoConfig, p: dict[str, Any]) -> PISetpointBackend:
    """The backend for the driver node (``BackendSpec.create``)."""
    return PISetpointBackend(cfg, p)


def open_table_player(cfg: PiezoConfig, p: dict[str, Any], ramp: SafeRampConfig | None = None) -> PITablePlayer:
    """The table player for ``piezo-ff play`` (connects)."""
    return PITablePlayer(cfg, p, ramp)


SPEC = BackendSpec(
    name="pi_gcs",
    description="PI digital controller over GCS (pipython): set-point mode in the driver; table mode for trajectories",
    parameters={
        "interface": Param("tcpip", "tcpip (PISocket) | serial, usb, rs232 (PISerial, a serial port such as "
                                    "/dev/ttyUSB0)", one_of("tcpip", "serial", "usb", "rs232")),
        "address": Param("192.168.0.10", "IP address, or serial port (USB serial number with use_dll)"),
        "port": Param(50000, "TCP port", int_range(1, 65535)),
        "baudrate": Param(115200, "serial baud rate", int_range(1200, 1_000_000)),
        "use_dll": Param(False, "true: connect through PI's GCS shared library (must be installed) instead of "
                                "pipython's own interfaces"),
        "timeout_ms": Param(7000, "answer timeout of a query [ms]", int_range(10, 600_000)),
        "axes": Param("1,2", "controller axis IDs, one per axis in axis order"),
        "piezo_channels": Param("", "piezo channel per axis for VOL?/VMA?/VMI? (default 1, 2, …)"),
        "setpoint_step": Param(1.0, "set-point mode: largest step between two set points [V]",
                               float_range(1e-3, 10.0)),
        "setpoint_rate": Param(1000.0, "set-point mode: set points per second while the voltage moves slowly [Hz]",
                               float_range(1.0, 1e5)),
        "safe_ramp_duration": Param(0.05, "the backend's own ramps (start from the held voltage, close, after a "
                                          "controller error, into and out of a table): minimum duration [s]",
                                    float_range(0.0, 60.0)),
        "safe_ramp_slew": Param(1.0e4, "the backend's own ramps: maximum slew [V/s]", float_range(1e-3, 1e7)),
        "wave_generators": Param("1,2", "wave generator IDs (table mode)"),
        "wave_tables": Param("1,2", "wave table IDs (table mode)"),
        "record_tables": Param("1,2", "data recorder table IDs (table mode)"),
        "record_option": Param(2, "DRC record option of the sensor position (see your controller's manual)",
                               int_range(0, 1000)),
        "position_scale": Param(1.0e-6, "recorded position unit [m] (µm on most PI controllers)",
                                float_range(1e-12, 1.0)),
        "servo_rate": Param(50000.0, "controller servo rate [Hz]", float_range(1.0, 1e7)),
        "chunk": Param(64, "wave points per WAV command", int_range(1, 1000)),
    },
    create=create,
)
