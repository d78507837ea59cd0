"""A smooth amplifier compression of any sharpness: the soft-knee (Rapp) law, per rail.

``amplifier_saturation`` with ``sharpness`` given: ``v ← v/(1 + (|v|/L)^p)^(1/p)``, L = ``limit`` for v ≥ 0 and
``lower_limit`` for v < 0.  Rapp's law of a solid-state amplifier's output compression: memoryless, odd when the
rails are equal, a function of the commanded voltage only, close to the identity at small |v| (the compression
grows as (|v|/L)^p) and tending to the rail L; p → ∞ is the hard clip.  One family for hard, soft-knee and
asymmetric rails.
"""
from __future__ import annotations

import math

import numpy as np

from .common import _block

__all__ = ["SoftSaturation"]


class SoftSaturation:
    """Soft-knee amplifier rails (Rapp's law): ``v/(1 + (|v|/L)^p)^(1/p)``, ``L`` = ``limit`` [V] above zero and
    ``lower_limit`` [V] below, sharpness ``p`` (1 … 100; large p is the hard clip).  Memoryless."""

    def __init__(self, limit: float, lower_limit: float, sharpness: float, n_axes: int = 2):
        for v, what in ((limit, "limit"), (lower_limit, "lower_limit")):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"amplifier_saturation.{what}: must be > 0 V, got {v!r}")
        if not (math.isfinite(sharpness) and 0.5 <= sharpness <= 200.0):
            raise ValueError(f"amplifier_saturation.sharpness: must be in [0.5, 200], got {sharpness!r}")
        self.limit, self.lower_limit, self.sharpness, self.n = float(limit), float(lower_limit), float(sharpness), \
            n_axes

    def reset(self) -> None:
        """All states back to rest (none: memoryless)."""
        pass

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``."""
        u = _block(u, self.n)
        L = np.where(u >= 0, self.limit, self.lower_limit)
        p = self.sharpness
        # (1 + x^p)^(1/p) computed as exp(log1p(x^p)/p): x^p overflows for a hard knee far beyond the rail
        x = np.abs(u) / L
        with np.errstate(over="ignore"):
            xp = x ** p
        den = np.where(np.isfinite(xp), np.exp(np.log1p(xp) / p), x)
        res: np.ndarray = u / den
        return res
