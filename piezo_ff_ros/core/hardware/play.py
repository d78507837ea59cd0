"""Play a voltage table on a device and record what it did (no ROS): the engine of ``piezo-ff play``.

A lab commissions a rig whose controller cannot be streamed at 20 kHz by computing the voltages offline
(``piezo-ff feedforward``), playing them once and recording the sensor on the same sample grid.  Two kinds of device:

- a **table player** (a controller with a wave generator and a data recorder, e.g. the PI backend's
  ``PITablePlayer``): anything with ``play(u) -> (applied [N, axes] V, measured [N, axes] m)`` that checks the table
  against the device, ramps in and out at the safe pace and cleans up on error itself — :func:`play_on_table`;
- a **streaming backend** (:class:`~.contract.StreamingBackend`: NI, the simulator): the table is streamed through
  the :class:`~.driver_core.DriverCore` — voltage guard, stamps, faults — preceded by a ramp from the safe voltage to
  the table's first value and followed by a ramp from its last value back to safe, both at the safe ramp's pace
  (:func:`~piezo_ff_ros.core.safety.safe_ramp`); ``voltage_applied`` and ``displacement`` are collected by stamp —
  :func:`play_streaming`.

Either way the result is a :class:`~piezo_ff_ros.core.recording.run.RunData` of the table's samples only (the ramps
are reported in ``meta``), which :func:`write_run` saves as CSV (``t,u_<axis>…,<axis>…``, volts and metres) or
MCAP (the recorder's block topics), both read back by ``piezo-ff analyze``/``identify``/``diagnose``.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from ..recording.run import RunData
from ..safety import SafeRampConfig
from .contract import StreamingBackend
from .driver_core import ERROR, DriverCore, DriverSettings

__all__ = ["PlayError", "TablePlayer", "load_voltage_table", "ramp_between", "play_streaming", "play_on_table",
           "write_run"]


class PlayError(RuntimeError):
    """The play did not complete (device fault, lost samples, timeout); the output was brought to safe where the
    device allowed.  One line."""


class TablePlayer(Protocol):
    """A device that plays a whole table itself, hardware-timed, and records the sensor."""

    def play(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Check ``u [N, axes]`` V against the device, ramp to ``u[0]``, play it hardware-timed, ramp back to safe;
        return ``(applied [N, axes] V, measured [N, axes] m)``; ValueError (one line) if it does not fit."""

    def close(self) -> None:
        """Release the device."""


def load_voltage_table(path: str | Path, axes: Sequence[str]) -> tuple[np.ndarray, float | None]:
    """Voltages ``[N, axes]`` [V] and the file's sample rate (None when it does not say) from a ``.csv`` (columns
    ``u_<axis>`` — ``piezo-ff feedforward``'s — with an optional ``t``, or a bare numeric ``[N, axes]``), ``.npy``
    or ``.mat`` (``u``, optional ``t``/``sample_rate``).  ValueError (one line, naming the file) otherwise."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: no such file")
    suffix = p.suffix.lower()
    fs: float | None = None
    t: np.ndarray | None = None
    if suffix == ".csv":
        first = p.read_text(errors="replace").split("\n", 1)[0]
        names = [c.strip() for c in first.split(",")]
        has_header = any(c and not _is_number(c) for c in names)
        try:
            data = np.loadtxt(p, delimiter=",", skiprows=1 if has_header else 0, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"{p}: not a numeric CSV ({str(exc).splitlines()[0]})") from None
        if has_header:
            want = [f"u_{a}" for a in axes]
            missing = [w for w in want if w not in names]
            if missing:
                raise ValueError(f"{p}: no column {missing[0]!r} (columns: {names}); expected u_<axis> per axis")
            u = data[:, [names.index(w) for w in want]]
            if "t" in names:
                t = data[:, names.index("t")]
        else:
            u = data
    elif suffix == ".npy":
        u = np.load(p, allow_pickle=False)
    elif suffix == ".mat":
        import scipy.io

        m = scipy.io.loadmat(str(p))
        if "u" not in m:
            raise ValueError(f"{p}: no variable 'u' (volts [N, axes])")
        u = m["u"]
        if "sample_rate" in m:
            fs = float(np.asarray(m["sample_rate"]).ravel()[0])
        elif "t" in m:
            t = np.asarray(m["t"], dtype=float).ravel()
    else:
        raise ValueError(f"{p}: unknown format {suffix!r} (expected .csv, .npy or .mat)")
    u = np.asarray(u, dtype=float)
    if u.ndim == 1 and len(axes) == 1:
        u = u[:, None]
    if u.ndim != 2 or u.shape[1] != len(axes) or u.shape[0] < 1:
        raise ValueError(f"{p}: expected [N, {len(axes)}] volts for axes {list(axes)}, got shape {u.shape}")
    bad = ~np.isfinite(u)
    if bad.any():
        raise ValueError(f"{p}: {int(bad.sum())} NaN/Inf value(s), first at row {int(np.argwhere(bad)[0][0])}")
    if t is not None and t.size > 1:
        dt = np.diff(t)
        if np.any(dt <= 0) or np.ptp(dt) > 1e-6 * float(np.mean(dt)):
            raise ValueError(f"{p}: column t is not uniformly sampled")
        fs = 1.0 / float(np.mean(dt))
    return u, fs


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def ramp_between(u_from: np.ndarray, u_to: np.ndarray, fs: float, ramp: SafeRampConfig,
                 operating_slew: float = math.inf) -> np.ndarray:
    """Samples from ``u_from`` (exclusive) to ``u_to`` (the last row) along a straight line at the safe ramp's pace:
    at least ``ramp.duration``, no axis faster than ``min(ramp.slew, operating_slew)``; empty if already there."""
    a, b = np.asarray(u_from, dtype=float), np.asarray(u_to, dtype=float)
    dist = float(np.max(np.abs(b - a))) if a.size else 0.0
    if dist == 0.0:
        return np.zeros((0, a.size))
    step = min(float(ramp.slew), float(operating_slew)) / float(fs)
    n = max(int(math.ceil(ramp.duration * fs - 1e-9)), int(math.ceil(dist / step - 1e-9)), 1)
    out: np.ndarray = a[None, :] + (b - a)[None, :] * (np.arange(1, n + 1) / n)[:, None]
    out[-1] = b
    return out


def play_on_table(player: TablePlayer, u: np.ndarray, fs: float, axes: Sequence[str], meta: dict[str, Any]
                  ) -> RunData:
    """Play ``u`` on a table player; the run on the table's grid."""
    applied, y = player.play(u)
    t = np.arange(u.shape[0]) / fs
    return RunData(t, np.asarray(applied, dtype=float), np.asarray(y, dtype=float), tuple(axes),
                   meta={**meta, "mode": "table"})


def play_streaming(backend: StreamingBackend, settings: DriverSettings, u: np.ndarray, axes: Sequence[str],
                   meta: dict[str, Any], block: int = 1000, timeout: float = 10.0,
                   log: Callable[[str], None] | None = None) -> RunData:
    """Stream ``u`` (with a ramp in from and out to the safe voltage) through a :class:`DriverCore`; the run on the
    table's grid (applied voltages from ``voltage_applied``, the sensor from ``displacement``).

    Raises :class:`PlayError` if the driver faulted or samples of the table were lost (after the ramp to safe)."""
    fs = settings.sample_rate
    safe = np.full(settings.n_axes, float(settings.limits.safe_voltage))
    r_in = ramp_between(safe, u[0], fs, settings.ramp, settings.limits.slew)
    r_out = ramp_between(u[-1], safe, fs, settings.ramp, settings.limits.slew)
    seq = np.vstack([r_in, u, r_out])
    n_in, n = r_in.shape[0], u.shape[0]
    core = DriverCore(settings, backend)
    period = core.period_ns
    applied = np.full(seq.shape, np.nan)
    measured = np.full(seq.shape, np.nan)
    errors: list[str] = []

    def take(em: Any) -> None:
        for dst, blocks in ((applied, em.applied), (measured, em.displacement)):
            for stamp, b in blocks:
                k = int(round(stamp / period))
                lo, hi = max(k, 0), min(k + b.shape[0], seq.shape[0])
                if hi > lo:
                    dst[lo:hi] = b[lo - k:hi - k]
        for level, text in em.log:
            if level >= ERROR:
                errors.append(text)
            if log is not None:
                log(text)

    clocked = backend.info.clocked
    ahead = settings.samples(settings.write_ahead)
    try:
        take(core.start())
        for i in range(0, seq.shape[0], block):
            if clocked:   # keep about write_ahead queued: the device's clock paces the loop
                while backend.write_index - backend.clock() > ahead and core.state != "fault":
                    time.sleep(min(0.005, ahead / fs / 4))
                    take(core.tick())
            take(core.on_block(i * period, seq[i:i + block]))
            if core.state == "fault" or errors:
                break
        want_sensor = backend.info.has_sensor
        deadline = time.monotonic() + timeout + (seq.shape[0] / fs if clocked else 0.0)
        # wait until the device has output everything, the ramp out included (closing earlier would cut the ramp),
        # and the sensor samples of the table have arrived
        while (np.isnan(applied).any() or (want_sensor and np.isnan(measured[n_in:n_in + n]).any())) \
                and core.state != "fault" and not errors and time.monotonic() < deadline:
            take(core.tick())
            if clocked:
                time.sleep(0.002)
            elif not want_sensor:
                break
    finally:
        core.close()
    if errors:
        raise PlayError(f"play stopped: {errors[0]}")
    lost = int(np.isnan(applied[n_in:n_in + n]).any(axis=1).sum())
    if lost:
        raise PlayError(f"play: {lost} of {n} table samples were not applied (see the driver's log)")
    y = measured[n_in:n_in + n]
    if backend.info.has_sensor and np.isnan(y).any():
        raise PlayError(f"play: {int(np.isnan(y).any(axis=1).sum())} sensor samples missing after {timeout:g} s")
    t = np.arange(n) / fs
    info = {**meta, "mode": "streaming", "ramp_in_samples": int(n_in), "ramp_out_samples": int(r_out.shape[0]),
            "max_step_v": float(np.max(np.abs(np.diff(np.vstack([safe, applied[:n_in + n + r_out.shape[0]]]),
                                                      axis=0))))}
    return RunData(t, applied[n_in:n_in + n].copy(), y.copy(), tuple(axes), meta=info)


def write_run(run: RunData, path: str | Path) -> Path:
    """Save ``run`` as ``.csv`` (``t,u_<axis>…,<axis>…``) or ``.mcap`` (``/voltage`` and ``/displacement`` blocks with
    the recorder's metadata); returns the path."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".csv":
        header = ",".join(["t"] + [f"u_{a}" for a in run.axes] + list(run.axes))
        np.savetxt(p, np.column_stack([run.t, run.u, run.y]), delimiter=",", header=header, comments="",
                   fmt="%.17g")
        return p
    if suffix == ".mcap":
        from ..recording import blocks as B
        from ..recording.mcap_io import McapRecorder

        fs = run.sample_rate if len(run) > 1 else float(run.meta.get("sample_rate", 0.0))
        period = B.sample_period_ns(fs)
        with McapRecorder(p) as rec:
            rec.set_metadata({"sample_rate": fs, "t0_ns": 0, "axes": list(run.axes),
                              "play": {k: v for k, v in run.meta.items() if isinstance(v, (str, int, float, bool))}})
            for role in ("voltage", "displacement"):
                rec.register_topic(f"/{role}", B.BLOCK_TYPE)
            for k0 in range(0, len(run), 1000):
                stamp = k0 * period
                rec.write("/voltage", B.serialize_block(run.u[k0:k0 + 1000], stamp, run.axes), stamp)
                rec.write("/displacement", B.serialize_block(run.y[k0:k0 + 1000], stamp, run.axes), stamp)
        return p
    raise ValueError(f"--out: {p.name}: use .csv or .mcap")
