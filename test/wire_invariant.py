"""The driver's safety invariant, checked on what reached a device's output (the "wire"), for any backend.

Between any two values that reach an output, the voltage changes by no more than the allowed step per elapsed sample
period: ``|v[i] − v[i−1]| ≤ step · credit(t[i] − t[i−1])`` where ``credit`` is 1 for a device whose output changes at
once whatever time passed (a DAC: holding earns nothing, a change is a step) and ``elapsed / period`` for a
set-and-hold device whose set-points are paced in time (a staircase), capped by ``max_change`` (e.g. 1 V per
set-point).  ``step`` is ``limits.slew / fs`` while running and ``min(safe_ramp.slew, limits.slew) / fs`` on the
paths that end at the safe voltage (stop, fault, device error, close).

A backend's wire-level stand-in gives its trace as ``(t [s], value [V at the amplifier])`` per channel; the
NI-DAQmx fake (``nidaqmx_fake.FakeDaq.wire``) is one, a GCS emulator's set-point log can be another
(:func:`from_events`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np


@dataclass(frozen=True)
class Violation:
    """One change on the wire larger than allowed."""

    channel: str
    t: float           #: device time of the second value [s]
    v_from: float
    v_to: float
    allowed: float

    def __str__(self) -> str:
        return (f"{self.channel}: {self.v_from:+.4f} V → {self.v_to:+.4f} V at t={self.t:.6f} s "
                f"(step {abs(self.v_to - self.v_from):.4f} V > allowed {self.allowed:.4f} V)")


def from_events(events: Iterable[tuple[float, str, float]], scale: dict[str, tuple[float, float]] | None = None,
                ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per-channel ``(t, v)`` arrays from ``(t, channel, value)`` events, in order; ``scale[channel] = (gain,
    offset)`` turns device volts into amplifier volts (``gain·value + offset``)."""
    per: dict[str, list[tuple[float, float]]] = {}
    for t, ch, v in events:
        per.setdefault(ch, []).append((t, v))
    out = {}
    for ch, tv in per.items():
        a = np.asarray(tv, dtype=float)
        g, o = (scale or {}).get(ch, (1.0, 0.0))
        out[ch] = (a[:, 0], g * a[:, 1] + o)
    return out


def violations(trace: dict[str, tuple[np.ndarray, np.ndarray]], period: float, step: float, *,
               holds_earn_credit: bool = False, max_change: float | None = None,
               t_from: float = -np.inf, t_to: float = np.inf) -> list[Violation]:
    """Every change between consecutive values of a channel (both in ``[t_from, t_to]``) larger than allowed
    (see the module docstring)."""
    out = []
    for ch, (t, v) in trace.items():
        sel = (t >= t_from) & (t <= t_to)
        t, v = t[sel], v[sel]
        if t.size < 2:
            continue
        dv = np.abs(np.diff(v))
        if holds_earn_credit:
            credit = np.maximum(1.0, np.floor(np.diff(t) / period + 1e-6))
            allowed = step * credit
            if max_change is not None:
                allowed = np.minimum(allowed, max_change)
        else:
            allowed = np.full(dv.shape, step if max_change is None else min(step, max_change))
        bad = np.flatnonzero(dv > allowed * (1 + 1e-9) + 1e-12)
        out += [Violation(ch, float(t[i + 1]), float(v[i]), float(v[i + 1]), float(allowed[i])) for i in bad]
    return out


def largest_step(trace: dict[str, tuple[np.ndarray, np.ndarray]], t_from: float = -np.inf,
                 t_to: float = np.inf) -> float:
    """The largest change between consecutive values of any channel within ``[t_from, t_to]`` [V]."""
    worst = 0.0
    for t, v in trace.values():
        sel = (t >= t_from) & (t <= t_to)
        if np.count_nonzero(sel) > 1:
            worst = max(worst, float(np.max(np.abs(np.diff(v[sel])))))
    return worst


def assert_safe(trace: dict[str, tuple[np.ndarray, np.ndarray]], period: float, step: float, **kw: object) -> None:
    """Fail with the first few :class:`Violation` s, if any."""
    bad = violations(trace, period, step, **kw)   # type: ignore[arg-type]
    assert not bad, f"{len(bad)} step(s) larger than allowed on the wire, e.g.\n" + "\n".join(map(str, bad[:5]))
