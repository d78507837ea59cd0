"""Driver-side voltage safety, pure (no ROS): whatever the driver is sent, what reaches the amplifier is bounded.

:class:`VoltageGuard` is a streaming stage over the *applied* voltage:

- a block that is not a finite ``[N, axes]`` array with ``1 ≤ N ≤ max_block`` is **rejected** (nothing of it is
  applied; the caller holds the last applied voltage) and counted;
- every sample is clamped to ``±limits.voltage`` (counted as saturated) and then moved towards its target by at
  most ``limits.slew / fs`` volts per sample (counted as slew-limited) — so the applied voltage is continuous and
  bounded even when the input jumps;
- :meth:`ramp_to_safe` produces the samples that bring the applied voltage to ``limits.safe_voltage`` at the slew
  limit (used on stale input).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._jit import njit
from .config import LimitsConfig

__all__ = ["VoltageGuard", "GuardCounters", "BlockRejected"]


class BlockRejected(ValueError):
    """The block cannot be applied at all (wrong shape, NaN/Inf, oversized); the message says why."""


@dataclass
class GuardCounters:
    """What the guard did since construction/reset (reported on ``/diagnostics``)."""

    blocks_applied: int = 0
    samples_applied: int = 0
    saturated_samples: int = 0      #: samples where at least one axis was clamped to ±voltage
    slew_limited_samples: int = 0   #: samples where at least one axis was held back by the slew limit
    rejected_blocks: int = 0        #: NaN/Inf, wrong shape, oversized
    safe_ramps: int = 0             #: ramps to the safe state (stale input)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@njit
def _slew_run(target, u_prev, step, out):  # pragma: no cover - compiled
    """Per-sample rate limiter; returns the number of samples where an axis was limited."""
    n_lim = 0
    for k in range(target.shape[0]):
        limited = False
        for a in range(target.shape[1]):
            d = target[k, a] - u_prev[a]
            if d > step:
                d = step
                limited = True
            elif d < -step:
                d = -step
                limited = True
            u_prev[a] = u_prev[a] + d
            out[k, a] = u_prev[a]
        if limited:
            n_lim += 1
    return n_lim


class VoltageGuard:
    """Clamp, slew-limit and validate voltage blocks before they reach the amplifier.

    Parameters
    ----------
    limits : LimitsConfig
        Voltage bound [V], slew limit [V/s], safe voltage [V] (stale timeout is the caller's business).
    n_axes : int
        Number of axes (columns of a block).
    sample_rate : float
        Samples per second: the slew limit per sample is ``limits.slew / sample_rate``.
    max_block : int
        Largest accepted block (samples); anything larger is rejected as oversized.
    """

    def __init__(self, limits: LimitsConfig, n_axes: int, sample_rate: float, max_block: int = 20000):
        self.limits = limits.validate()
        self.n_axes = int(n_axes)
        self.sample_rate = float(sample_rate)
        self.max_block = int(max_block)
        self.step = limits.slew / self.sample_rate
        self.u_last = np.full(self.n_axes, float(limits.safe_voltage))
        self.counters = GuardCounters()

    def reset(self) -> None:
        """Back to the safe voltage (the amplifier's state after power-up), counters zeroed."""
        self.u_last[:] = self.limits.safe_voltage
        self.counters = GuardCounters()

    def check(self, block) -> np.ndarray:
        """Return the block as a float ``[N, axes]`` array or raise :class:`BlockRejected` (counted)."""
        try:
            u = np.asarray(block, dtype=float)
        except (TypeError, ValueError) as exc:
            self.counters.rejected_blocks += 1
            raise BlockRejected(f"not numeric ({exc})") from None
        reason = None
        if u.ndim != 2 or u.shape[1] != self.n_axes:
            reason = f"wrong shape {u.shape}, expected [N, {self.n_axes}]"
        elif u.shape[0] < 1:
            reason = "empty block"
        elif u.shape[0] > self.max_block:
            reason = f"oversized block: {u.shape[0]} samples > max_block {self.max_block}"
        elif not np.all(np.isfinite(u)):
            bad = int(np.count_nonzero(~np.isfinite(u)))
            reason = f"{bad} NaN/Inf value(s)"
        if reason is not None:
            self.counters.rejected_blocks += 1
            raise BlockRejected(reason)
        return u

    def apply(self, block) -> np.ndarray:
        """Validated, clamped and slew-limited copy of ``block`` (what may be applied); updates the state."""
        u = self.check(block)
        V = self.limits.voltage
        clamped = np.clip(u, -V, V)
        self.counters.saturated_samples += int(np.count_nonzero(np.any(clamped != u, axis=1)))
        out = np.empty_like(clamped)
        self.counters.slew_limited_samples += int(_slew_run(clamped, self.u_last, self.step, out))
        self.counters.blocks_applied += 1
        self.counters.samples_applied += out.shape[0]
        return out

    def hold(self, n: int) -> np.ndarray:
        """``n`` samples holding the last applied voltage (the safe hold after a rejected block)."""
        return np.tile(self.u_last, (int(n), 1))

    @property
    def at_safe(self) -> bool:
        return bool(np.all(self.u_last == self.limits.safe_voltage))

    def ramp_to_safe(self, max_samples: int | None = None) -> np.ndarray:
        """Samples bringing the applied voltage to the safe voltage at the slew limit (empty if already there).

        The ramp ends exactly on the safe voltage; ``max_samples`` bounds one call (call again for the rest).
        """
        dist = np.max(np.abs(self.u_last - self.limits.safe_voltage))
        n = int(np.ceil(dist / self.step - 1e-12)) if dist > 0 else 0
        if max_samples is not None:
            n = min(n, int(max_samples))
        if n == 0:
            return np.zeros((0, self.n_axes))
        target = np.full((n, self.n_axes), float(self.limits.safe_voltage))
        out = np.empty_like(target)
        _slew_run(target, self.u_last, self.step, out)
        self.counters.samples_applied += n
        if self.at_safe:
            self.counters.safe_ramps += 1
        return out
