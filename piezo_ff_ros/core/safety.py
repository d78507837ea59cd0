"""Driver-side voltage safety, pure (no ROS): whatever the driver is sent, what reaches the amplifier is bounded.

:class:`VoltageGuard` is a streaming stage over the *applied* voltage:

- a block that is not a finite ``[N, axes]`` array with ``1 ≤ N ≤ max_block`` is **rejected** (nothing of it is
  applied; the caller holds the last applied voltage) and counted;
- every sample is clamped to ``±limits.voltage`` (counted as saturated) and then moved towards its target by at
  most ``limits.slew / fs`` volts per sample (counted as slew-limited) — so the applied voltage is continuous and
  bounded even when the input jumps;
- :meth:`ramp_to_safe` produces the samples that bring the applied voltage to ``limits.safe_voltage`` along a
  straight line whose duration and slew come from a :class:`SafeRampConfig`, independent of the (fast) operating
  slew limit: at least ``duration`` seconds, never faster than ``slew`` V/s (nor than the operating limit), all axes
  arriving together (used on stale input and device faults).

:func:`limit_block` / :func:`slew_limit` run the one limiter of the package
(:func:`~piezo_ff_ros.core.kernels.limits.limit_step`: clamp first, then at most ``step`` volts per sample), the
same rule as the compensators' kernels and the amplifier slew-limit effect.

:func:`tightened_limits` is the driver's limit policy: the configuration describes the amplifier, the driver's own
values may tighten its voltage and slew limits, never widen them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from .kernels.limits import limit_run
from .config import LimitsConfig

__all__ = ["tightened_limits", "at_limit", "MIN_RAMP_DURATION", "MAX_RAMP_DURATION", "MAX_RAMP_SLEW", "VoltageGuard", "GuardCounters", "BlockRejected", "SafeRampConfig", "safe_ramp", "slew_limit", "limit_block"]


def tightened_limits(config: LimitsConfig, voltage: float, slew: float, stale_timeout: float,
                     safe_voltage: float) -> LimitsConfig:
    """The limits a driver enforces: ``config``'s (the amplifier's) with the driver's own values.

    Parameters
    ----------
    config : LimitsConfig
        The configuration's limits: the amplifier's range (its ``workspace`` is kept).
    voltage, slew : float
        The driver's ±V and V/s; at most the configuration's (a driver may tighten them, never widen them).
    stale_timeout : float
        No block for this long ramps to the safe state [s], in [1 ms, 1 h].
    safe_voltage : float
        The safe state [V], within ``±voltage``.

    Returns
    -------
    LimitsConfig
        Validated.

    Raises
    ------
    ConfigError
        Naming the field (``limits.voltage``, …): a value that is not plausible, widens the configuration's or is out
        of range.
    """
    from .config import ConfigError

    limits = replace(config, voltage=voltage, slew=slew, stale_timeout=stale_timeout,
                     safe_voltage=safe_voltage).validate()
    for name in ("voltage", "slew"):
        if getattr(limits, name) > getattr(config, name):
            raise ConfigError(f"limits.{name}", f"{getattr(limits, name)!r} exceeds the config's "
                                                f"{getattr(config, name)!r} (the amplifier's range: change the config "
                                                "file to raise it)")
    if not (math.isfinite(limits.stale_timeout) and 1e-3 <= limits.stale_timeout <= 3600.0):
        raise ConfigError("limits.stale_timeout", f"must be in [0.001, 3600] s, got {limits.stale_timeout!r}")
    return limits


class BlockRejected(ValueError):
    """The block cannot be applied at all (wrong shape, NaN/Inf, oversized); the message says why."""


@dataclass
class GuardCounters:
    """What the guard did since construction/reset (reported on ``/diagnostics``)."""

    blocks_applied: int = 0
    samples_applied: int = 0
    saturated_samples: int = 0      #: samples sent at or beyond ±voltage on an axis (clamped here or by the sender)
    slew_limited_samples: int = 0   #: samples where at least one axis was held back by the slew limit
    rejected_blocks: int = 0        #: NaN/Inf, wrong shape, oversized
    safe_ramps: int = 0             #: ramps to the safe state (stale input)

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain mapping."""
        return dict(self.__dict__)


#: the documented bounds of the safe ramp (docs/nodes.md): at least 50 ms, at most 1e4 V/s (200 V in ≥ 20 ms)
MIN_RAMP_DURATION = 0.05
MAX_RAMP_DURATION = 60.0
MAX_RAMP_SLEW = 1.0e4


@dataclass(frozen=True)
class SafeRampConfig:
    """How the driver brings the output to the safe voltage (stale input, device fault).

    The ramp is a straight line that takes at least ``duration`` seconds and moves no axis faster than ``slew`` V/s;
    e.g. the defaults take 50 ms for any distance up to 500 V (≤ 0.2 V per sample at 20 kHz from 200 V).
    """

    duration: float = 0.05   #: minimum ramp duration [s]
    slew: float = 1.0e4      #: maximum ramp slew [V/s] (applied together with the operating limit)

    def validate(self, prefix: str = "safe_ramp") -> "SafeRampConfig":
        """Check the fields against the documented bounds (docs/nodes.md: ``duration`` in
        [:data:`MIN_RAMP_DURATION`, 60] s, ``slew`` in (0, :data:`MAX_RAMP_SLEW`] V/s): a "ramp" of one sample is
        a step.  ``ConfigError`` naming ``prefix.<field>``; returns self."""
        from .config import ConfigError

        d, v = self.duration, self.slew
        if isinstance(d, bool) or not (isinstance(d, (int, float)) and math.isfinite(d)
                                       and MIN_RAMP_DURATION <= d <= MAX_RAMP_DURATION):
            raise ConfigError(f"{prefix}.duration", f"must be a number of seconds in [{MIN_RAMP_DURATION:g}, "
                                                    f"{MAX_RAMP_DURATION:g}], got {d!r}")
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and 0 < v <= MAX_RAMP_SLEW):
            raise ConfigError(f"{prefix}.slew", f"must be a number of V/s in (0, {MAX_RAMP_SLEW:g}], got {v!r}")
        return self


def safe_ramp(u_from: ArrayLike, safe_voltage: float, sample_rate: float, ramp: SafeRampConfig,
              operating_slew: float = math.inf) -> np.ndarray:
    """Samples ``[n, axes]`` from ``u_from`` (exclusive) to ``safe_voltage`` (the last row, exactly).

    ``n = max(ceil(duration·fs), ceil(distance·fs / min(ramp.slew, operating_slew)))``; empty when already safe.
    """
    u0 = np.asarray(u_from, dtype=float)
    dist = float(np.max(np.abs(u0 - safe_voltage))) if u0.size else 0.0
    if dist == 0.0:
        return np.zeros((0, u0.size))
    step = min(float(ramp.slew), float(operating_slew)) / float(sample_rate)
    n = max(int(math.ceil(ramp.duration * sample_rate - 1e-9)), int(math.ceil(dist / step - 1e-9)), 1)
    frac = (np.arange(1, n + 1) / n)[:, None]
    out = u0[None, :] + (safe_voltage - u0)[None, :] * frac
    out[-1] = safe_voltage
    return out


def slew_limit(target: ArrayLike, u_prev: np.ndarray, step: float, out: np.ndarray | None = None,
               limit: float = math.inf) -> tuple[np.ndarray, int]:
    """Rate-limit ``target [N, axes]`` to at most ``step`` volts per sample starting from ``u_prev`` (updated in
    place to the last output sample), after clamping to ``±limit``; return ``(limited, samples where an axis was
    held back by the rate)``.  The rule is :func:`~piezo_ff_ros.core.kernels.limits.limit_step`, shared with the
    compensators and the amplifier effect."""
    out, _, n_slewed = limit_block(target, u_prev, step, limit, out)
    return out, n_slewed


def limit_block(target: ArrayLike, u_prev: np.ndarray, step: float, limit: float = math.inf,
                out: np.ndarray | None = None) -> tuple[np.ndarray, int, int]:
    """Clamp to ``±limit`` then rate-limit to ``step`` per sample from ``u_prev`` (updated in place); return
    ``(limited, samples with an axis clamped, samples with an axis held back by the rate)``."""
    target = np.ascontiguousarray(target, dtype=float)
    out = np.empty_like(target) if out is None else out
    counts = np.zeros(2, np.int64)
    limit_run(target, u_prev, np.ones(1, np.bool_), float(limit), float(step), out, counts)
    return out, int(counts[0]), int(counts[1])


def at_limit(u: ArrayLike, limit: float) -> int:
    """Samples of ``u [N, axes]`` at the voltage limit on at least one axis: ``|u| ≥ limit·(1 − 1e-9)`` (the rule
    of the driver's ``saturated_samples`` and of ``piezo-ff analyze``)."""
    a = np.asarray(u, float)
    return int(np.count_nonzero(np.any(np.abs(a) >= float(limit) * (1 - 1e-9), axis=1)))


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

    def check(self, block: ArrayLike) -> np.ndarray:
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

    def apply(self, block: ArrayLike) -> np.ndarray:
        """Validated, clamped and slew-limited copy of ``block`` (what may be applied); updates the state."""
        u = self.check(block)
        out, _, n_limited = limit_block(u, self.u_last, self.step, self.limits.voltage)
        # sent at or beyond the limit, whoever clamped it (a compensator clamps to exactly ±voltage): the rule
        # of the analyzer on the voltage topic, so that the two agree
        self.counters.saturated_samples += at_limit(u, self.limits.voltage)
        self.counters.slew_limited_samples += n_limited
        self.counters.blocks_applied += 1
        self.counters.samples_applied += out.shape[0]
        return out

    def hold(self, n: int) -> np.ndarray:
        """``n`` samples holding the last applied voltage (the safe hold after a rejected block)."""
        return np.tile(self.u_last, (int(n), 1))

    @property
    def at_safe(self) -> bool:
        """True when the last applied voltage is the safe voltage on every axis."""
        return bool(np.all(self.u_last == self.limits.safe_voltage))

    def ramp_to_safe(self, ramp: SafeRampConfig | None = None) -> np.ndarray:
        """Samples bringing the applied voltage to the safe voltage (see :func:`safe_ramp`; empty if already there).

        The ramp ends exactly on the safe voltage and becomes the applied state; it is counted in ``safe_ramps``.
        """
        ramp = SafeRampConfig() if ramp is None else ramp
        out = safe_ramp(self.u_last, self.limits.safe_voltage, self.sample_rate, ramp, self.limits.slew)
        self.counters.safe_ramps += 1
        if out.shape[0]:
            self.u_last[:] = out[-1]
            self.counters.samples_applied += out.shape[0]
        return out
