"""An amplifier that slews at different rates up and down: ``amplifier_slew_limit`` with ``rate_down`` given.

A piezo driver's slew rate is its output current limit over the load capacitance (dV/dt = I_max/C); the current it
can source (charging the stack, the voltage rising) and sink (discharging it, the voltage falling) often differ —
a class-AB output stage whose two halves differ, a bleeder resistor doing the discharge.  Two rates, one per
direction of motion; equal rates are the symmetric :class:`~.voltage.AmplifierSlewLimit`.
"""
from __future__ import annotations

import math

import numpy as np

from ..._jit import njit
from .common import _block

__all__ = ["AsymmetricSlewLimit"]


@njit
def _asym_slew_run(u: np.ndarray, prev: np.ndarray, started: np.ndarray, up: float, down: float,
                   out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Per column: move towards ``u[k]`` by at most ``up`` volts (rising) or ``down`` volts (falling) per sample;
    the first sample of a run that has not started is passed as it is (there is no previous value)."""
    N, n = u.shape
    for k in range(N):
        for j in range(n):
            if not started[0]:
                v = u[k, j]
            else:
                d = u[k, j] - prev[j]
                if d > up:
                    v = prev[j] + up
                elif d < -down:
                    v = prev[j] - down
                else:
                    v = u[k, j]          # reachable: the target itself, exactly
            prev[j] = v
            out[k, j] = v
        started[0] = True


class AsymmetricSlewLimit:
    """Amplifier slew-rate limits that differ by direction: the voltage rises by at most ``rate·dt`` and falls by at
    most ``rate_down·dt`` per sample [V/s]."""

    def __init__(self, rate: float, rate_down: float, dt: float, n_axes: int = 2):
        for v, what in ((rate, "rate"), (rate_down, "rate_down")):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"amplifier_slew_limit.{what}: must be > 0 V/s, got {v!r}")
        self.rate, self.rate_down, self.dt, self.n = float(rate), float(rate_down), float(dt), n_axes
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._prev = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = np.ascontiguousarray(_block(u, self.n), dtype=float)
        out = np.empty_like(u)
        if len(u):
            _asym_slew_run(u, self._prev, self._started, self.rate * self.dt, self.rate_down * self.dt, out)
        return out
