"""A rig as the commissioning code sees it: a streaming ``process(u [N, axes] V) -> y [N, axes] m`` / ``reset()``
system — the interface ``core.characterisation.run_open_loop`` and ``commissioning.commission_sim`` already
drive — backed by any :class:`~.contract.StreamingBackend` through the :class:`~.driver_core.DriverCore`.

So the same characterisation/identification code runs on the simulator, the clocked simulator or hardware, always
within the configured voltage and slew limits (the driver core's guard), and refuses a device without a sensor.
What the guard changed is counted (``limited_samples``): an identification run whose voltages were clamped or
slew-limited does not describe the requested input, and ``strict=True`` makes that an error.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from .contract import StreamingBackend
from .driver_core import ERROR, DriverCore, DriverSettings

__all__ = ["RigError", "BackendRig"]


class RigError(RuntimeError):
    """The rig cannot do what commissioning needs (no sensor, data lost, limits hit in strict mode, timeout)."""


class BackendRig:
    """``process``/``reset`` over a backend (see the module docstring).

    Parameters
    ----------
    backend : StreamingBackend
        The device (started here).
    settings : DriverSettings
        Limits, safe ramp, write-ahead (as for the driver node).
    block : int
        Samples per block sent to the driver core.
    settle : float
        Seconds at the safe voltage that ``reset`` waits on a device that cannot reset itself (hardware).
    strict : bool
        Raise :class:`RigError` when the limits changed the requested voltages.
    timeout : float
        Seconds allowed beyond the run's own duration (clocked devices).
    """

    def __init__(self, backend: StreamingBackend, settings: DriverSettings, block: int = 200, settle: float = 1.0,
                 strict: bool = False, timeout: float = 10.0, now: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not backend.info.has_sensor:
            raise RigError(f"{backend.info.name} has no sensor: commissioning measures the displacement; "
                           "configure the sensor channels or identify from recordings")
        self.core = DriverCore(settings, backend, now=now)
        self.block, self.settle, self.strict, self.timeout = int(block), float(settle), bool(strict), float(timeout)
        self.now, self.sleep = now, sleep
        self.limited_samples = 0
        self.core.start()

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return self.core.s.n_axes

    def _guard_changed(self) -> int:
        c = self.core.guard.counters
        return c.saturated_samples + c.slew_limited_samples

    def process(self, u: np.ndarray) -> np.ndarray:
        """Apply ``u`` from the current state (contiguous with the previous call); return the measured ``y``."""
        u = np.asarray(u, dtype=float)
        if u.ndim != 2 or u.shape[1] != self.n_axes:
            raise ValueError(f"rig: expected [N, {self.n_axes}] volts, got {u.shape}")
        core, fs = self.core, self.core.s.sample_rate
        before = self._guard_changed()
        lost0 = core.lost_samples()
        checking = True     # loss counts until the last block is in; holds after it are not part of the run
        stamp0 = (core.next_stamp or 0) if core.book.started else 0   # next_stamp is None only before the start
        want = {}
        got = {}
        deadline = self.now() + u.shape[0] / fs + self.timeout
        ahead = core.s.samples(core.s.write_ahead)
        i = 0
        while True:
            if i < u.shape[0] and (not core.info.clocked or core.status().get("write_ahead_samples", 0) < ahead):
                stamp = stamp0 + i * core.period_ns
                blk = u[i:i + self.block]
                want[stamp] = blk.shape[0]
                em = core.on_block(stamp, blk)
                i += blk.shape[0]
            else:
                em = core.tick()
                if core.info.clocked:
                    self.sleep(0.002)
            for lvl, text in em.log:
                if lvl >= ERROR:
                    raise RigError(f"rig: {text}")
            for s, y in em.displacement:
                if s in want:
                    got[s] = y
            if checking:
                lost = core.lost_samples() - lost0
                if lost:
                    raise RigError(f"rig: {lost} sample(s) lost (late/starved/gap): the run does not describe u; "
                                   "raise write_ahead or unload the host")
                checking = i < u.shape[0]
            if self.now() > deadline:
                raise RigError(f"rig: timed out waiting for the sensor ({len(got)} of {len(want)} blocks)")
            if i >= u.shape[0] and len(got) == len(want):
                break
        changed = self._guard_changed() - before
        self.limited_samples += changed
        if changed and self.strict:
            raise RigError(f"rig: {changed} sample(s) clamped or slew-limited by the driver's limits")
        y = np.vstack([got[s] for s in sorted(got)])
        if y.shape[0] != u.shape[0]:
            raise RigError(f"rig: {y.shape[0]} measured samples for {u.shape[0]} applied")
        return y

    def reset(self) -> None:
        """Back to rest: the simulator resets; hardware ramps to the safe voltage and waits ``settle`` seconds."""
        if self.core.reset():
            return
        n = max(1, int(round(self.settle * self.core.s.sample_rate)))
        self.process(np.full((n, self.n_axes), float(self.core.s.limits.safe_voltage)))

    def close(self) -> None:
        """Release the device (the backend puts it at its safe voltage where it can)."""
        self.core.close()
