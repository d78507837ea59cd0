"""``pi_gcs`` backend: a PI digital piezo controller (E-727, E-712, …) driving a tube in open loop, through PI's
``pipython`` (optional extra: ``pip install piezo_ff_ros[pipython]``).  Written against the GCS 2.0 command
reference; exercised here only against a command-level GCS emulator (test/gcs_emulator.py), never on a controller.

Two modes:

- **table mode** (:class:`PITablePlayer`) — the paper's setting for a controller that cannot be streamed at 20 kHz:
  the voltages for a known trajectory are computed offline (``piezo-ff feedforward``), uploaded to the wave tables
  (``WAV … PNT``, chunks of ``chunk`` points), connected to the wave generators (``WSL``), played once (``WGC`` 1
  cycle, ``WTR`` table rate = servo rate / sample rate, ``WGO`` start), while the data recorder (``DRC`` sources and
  options, ``RTR`` the same rate) records the sensor position; then read back (``DRR?``) as
  ``[N, axes]`` metres;
- **set-point mode** (the driver backend, ``backend:=pi_gcs``) — slow moves: open loop (``SVO`` 0), every block
  sets the axes' open-loop voltage (``SVA``) to the block's last sample; the controller holds it, so what is applied
  is a staircase at the block rate and ``voltage_applied`` reports exactly that staircase.  No sensor stream (use
  table mode to record); not hardware-timed (``clocked`` is False): keep the driver's slew limit low.
"""
from __future__ import annotations

import time

from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..core.hardware.contract import ContractError, DeviceInfo, Disconnect, StreamingBackend, WriteCursorClock
from .base import BackendError, BackendSpec, Param, float_range, int_range, one_of

if TYPE_CHECKING:
    from ..core.config import PiezoConfig


def _axes(text: str) -> list[str]:
    return [a.strip() for a in str(text).split(",") if a.strip()]


def connect(p: dict[str, Any], gateway: Any = None) -> Any:
    """A connected ``pipython.GCSDevice`` (``gateway``: a pipython gateway, e.g. the emulator)."""
    try:
        from pipython import GCSDevice  # noqa: PLC0415 - optional extra
    except ImportError as exc:
        raise BackendError(f"pi_gcs: the pipython package is not installed ({exc}); "
                           "pip install 'piezo_ff_ros[pipython]'") from None
    try:
        if gateway is not None:
            dev = GCSDevice(gateway=gateway)
        else:
            dev = GCSDevice()
            if p["interface"] == "tcpip":
                dev.ConnectTCPIP(ipaddress=p["address"], ipport=p["port"])
            elif p["interface"] == "usb":
                dev.ConnectUSB(serialnum=p["address"])
            else:
                dev.ConnectRS232(comport=p["address"], baudrate=p["baudrate"])
        idn = dev.qIDN().strip()
    except Exception as exc:  # noqa: BLE001 - vendor errors: one line naming the backend
        raise BackendError(f"pi_gcs: cannot connect ({p['interface']} {p['address']}): "
                           f"{str(exc).splitlines()[0] if str(exc) else exc!r}") from None
    return dev, idn


class PISetpointBackend(WriteCursorClock, StreamingBackend):
    """Set-point mode behind the streaming contract (see the module docstring)."""

    def __init__(self, cfg: PiezoConfig, p: dict[str, Any], gateway: Any = None) -> None:
        self.p = p
        self.axes = _axes(p["axes"])
        if len(self.axes) != cfg.n_axes:
            raise BackendError(f"pi_gcs.axes: {len(self.axes)} controller axes for {cfg.n_axes} axes "
                               f"{list(cfg.axes)}")
        self.cfg = cfg
        self.gateway = gateway
        self.dev: Any = None    # the pipython GCSDevice once started
        self.idn = ""
        self.info = DeviceInfo(name="pi_gcs", sample_rate_hz=float(cfg.sample_rate), n_axes=cfg.n_axes,
                               fifo_depth=1 << 30, has_sensor=False, clocked=False)
        self._k = 0
        self._applied: list = []
        self._last = np.zeros(cfg.n_axes)

    def _call(self, fn: Callable[..., Any], *args: Any) -> Any:
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - a controller error or a lost link stops the output
            raise Disconnect(f"pi_gcs: {str(exc).splitlines()[0] if str(exc) else exc!r}") from None

    def start(self, safe_voltage: np.ndarray, prefill: int = 0) -> int:
        self.dev, self.idn = connect(self.p, self.gateway)
        self._last = np.asarray(safe_voltage, dtype=float).copy()
        self._call(self.dev.SVO, self.axes, [False] * len(self.axes))
        self._call(self.dev.SVA, self.axes, self._last.tolist())
        if prefill:
            self.write(self._k, np.tile(self._last, (int(prefill), 1)))
        return self._k

    def write(self, k0: int, block: np.ndarray) -> None:
        if self.dev is None:
            raise ContractError("pi_gcs: not started")
        if k0 != self._k:
            raise ContractError(f"pi_gcs: write at {k0}, expected {self._k}")
        u = np.asarray(block, dtype=float)
        if not u.shape[0]:
            return
        last = u[-1]
        self._call(self.dev.SVA, self.axes, [float(v) for v in last])
        # what the controller does: the previous value until the command lands, then the new one, held
        applied = np.tile(self._last, (u.shape[0], 1))
        applied[-1] = last
        self._applied.append((k0, applied))
        self._last = last.copy()
        self._k += u.shape[0]

    def read(self) -> list[tuple[int, np.ndarray]]:
        return []

    def take_applied(self) -> list[tuple[int, np.ndarray]]:
        out, self._applied = self._applied, []
        return out

    @property
    def latency_samples(self) -> int:
        return 0

    def status(self) -> dict:
        return {"backend": "pi_gcs", "mode": "setpoint", "idn": self.idn, "axes": self.axes}

    def close(self) -> None:
        if self.dev is None:
            return
        try:
            safe = float(self.cfg.limits.safe_voltage)
            self.dev.SVA(self.axes, [safe] * len(self.axes))
            self.dev.CloseConnection()
        except Exception:  # noqa: BLE001 - closing: best effort
            pass
        self.dev = None


class PITablePlayer:
    """Table mode: upload ``u [N, axes]`` V to the wave tables, play once hardware-timed, read the recorded sensor.

    Parameters are the backend's (``axes``, ``wave_generators``, ``wave_tables``, ``record_tables``,
    ``record_option``, ``servo_rate``, ``chunk``); ``dev`` is a connected pipython ``GCSDevice``.
    """

    def __init__(self, dev: Any, p: dict[str, Any], sample_rate: float, voltage_limit: float) -> None:
        self.dev, self.p = dev, p
        self.axes = _axes(p["axes"])
        self.gens = [int(x) for x in _axes(p["wave_generators"])]
        self.tables = [int(x) for x in _axes(p["wave_tables"])]
        self.rec = [int(x) for x in _axes(p["record_tables"])]
        for name, v in (("wave_generators", self.gens), ("wave_tables", self.tables), ("record_tables", self.rec)):
            if len(v) != len(self.axes):
                raise BackendError(f"pi_gcs.{name}: {len(v)} entries for {len(self.axes)} axes")
        ratio = p["servo_rate"] / sample_rate
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise BackendError(f"pi_gcs.servo_rate: {p['servo_rate']:g} Hz / {sample_rate:g} Hz = {ratio:g}: the "
                               "wave table rate must be a whole number of servo cycles; choose the sample rate")
        self.table_rate = int(round(ratio))
        self.fs = float(sample_rate)
        self.voltage_limit = float(voltage_limit)

    def upload(self, u: np.ndarray) -> None:
        u = np.asarray(u, dtype=float)
        if u.ndim != 2 or u.shape[1] != len(self.axes):
            raise ValueError(f"table: expected [N, {len(self.axes)}] volts, got {u.shape}")
        if not np.all(np.isfinite(u)) or np.abs(u).max() > self.voltage_limit:
            raise ValueError(f"table: values must be finite and within ±{self.voltage_limit} V")
        n = int(self.p["chunk"])
        for a, table in enumerate(self.tables):
            for i in range(0, u.shape[0], n):
                part = u[i:i + n, a]
                self.dev.WAV_PNT(table, i + 1, part.size, "X" if i == 0 else "&", [float(v) for v in part])
        self.n = u.shape[0]

    def play(self, timeout: float = 60.0) -> np.ndarray:
        """Play the uploaded tables once, open loop, recording; return the recorded positions ``[N, axes]``."""
        d, ax = self.dev, self.axes
        d.SVO(ax, [False] * len(ax))
        d.WSL(self.gens, self.tables)
        d.WGC(self.gens, [1] * len(self.gens))
        d.WTR(self.gens, [self.table_rate] * len(self.gens), [0] * len(self.gens))
        d.DRC(self.rec, ax, [int(self.p["record_option"])] * len(ax))
        d.RTR(self.table_rate)
        d.WGO(self.gens, [1] * len(self.gens))
        deadline = time.monotonic() + timeout + self.n / self.fs
        while any(d.qWGO(self.gens).values()):
            if time.monotonic() > deadline:
                d.WGO(self.gens, [0] * len(self.gens))
                raise TimeoutError("pi_gcs: the wave generators did not finish")
            time.sleep(0.01)
        d.qDRR(self.rec, 1, self.n)
        while d.bufstate is not True:
            if time.monotonic() > deadline:
                raise TimeoutError("pi_gcs: the data recorder read-back did not finish")
            time.sleep(0.01)
        data = np.array(d.bufdata, dtype=float).T
        return data * float(self.p["position_scale"])


def create(cfg: PiezoConfig, p: dict[str, Any]) -> PISetpointBackend:
    """The backend for the driver node (``BackendSpec.create``)."""
    return PISetpointBackend(cfg, p)


SPEC = BackendSpec(
    name="pi_gcs",
    description="PI digital controller over GCS (pipython): set-point mode in the driver; table mode for trajectories",
    parameters={
        "interface": Param("tcpip", "tcpip | usb | rs232", one_of("tcpip", "usb", "rs232")),
        "address": Param("192.168.0.10", "IP address, USB serial number or COM port"),
        "port": Param(50000, "TCP port", int_range(1, 65535)),
        "baudrate": Param(115200, "RS-232 baud rate", int_range(1200, 1_000_000)),
        "axes": Param("1,2", "controller axis IDs, one per axis in axis order"),
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
