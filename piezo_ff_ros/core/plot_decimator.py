"""Decimation of stamped sample blocks to a plot rate, on one grid shared by every stream.

Blocks ``[N, axes]`` stamped with their first sample's time (ns) at the sample rate are thinned to one sample every
``every = round(sample_rate / rate)`` samples.  Which samples are kept depends only on each sample's index on the
stamp grid (``round(stamp / period) + i``), never on how the stream was cut into blocks, so the reference, voltage
and displacement streams keep the *same* instants and a tracking error can be formed sample by sample: the plot
node (:mod:`piezo_ff_ros.nodes.plotter`) publishes what :class:`PlotDecimator` answers.  Pure logic, no ROS.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .units import sample_period_ns

__all__ = ["PlotDecimator", "StampDecimator", "STREAMS"]

#: the streams a plot shows; ``error`` (reference − displacement) is formed from two of them
STREAMS = ("reference", "voltage", "displacement")


@dataclass
class StampDecimator:
    """Keeps the samples of a stamped block stream whose grid index is a multiple of ``every``.

    Parameters
    ----------
    period_ns : int
        Sample period [ns].
    every : int
        Keep one sample in ``every``.
    """

    period_ns: int
    every: int

    def __post_init__(self) -> None:
        if int(self.period_ns) <= 0 or int(self.every) < 1:
            raise ValueError(f"period_ns must be > 0 and every >= 1, got {self.period_ns}, {self.every}")

    def pick(self, stamp_ns: int, block: ArrayLike) -> list[tuple[int, int, np.ndarray]]:
        """``[(grid index, stamp ns, sample)]`` of the kept samples of one block (oldest first)."""
        b = np.asarray(block, dtype=float)
        if b.ndim != 2:
            raise ValueError(f"a block is [N, axes], got shape {b.shape}")
        k0 = (int(stamp_ns) + self.period_ns // 2) // self.period_ns   # integer: exact for wall-clock stamps
        first = -(-k0 // self.every) * self.every - k0          # offset of the first kept sample in the block
        return [(k0 + i, int(stamp_ns) + i * self.period_ns, b[i].copy()) for i in range(first, b.shape[0], self.every)]


@dataclass
class PlotDecimator:
    """Reference, voltage and displacement decimated on one grid, and the tracking error where both the reference
    and the displacement of an instant have arrived.

    Parameters
    ----------
    sample_rate : float
        Samples per second of the block streams [Hz].
    rate : float
        Plot samples per second [Hz] (at most ``sample_rate``; the kept instants are ``round(sample_rate/rate)``
        samples apart).
    pending : int
        Instants waiting for their partner stream (reference or displacement) that are kept at most; older ones
        are dropped (a stream that stopped must not grow memory).
    """

    sample_rate: float
    rate: float
    pending: int = 4096
    _pick: StampDecimator = field(init=False)
    _waiting: dict[str, OrderedDict[int, np.ndarray]] = field(init=False)

    def __post_init__(self) -> None:
        for name in ("sample_rate", "rate"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name}: expected a finite number > 0, got {v!r}")
        if self.rate > self.sample_rate:
            raise ValueError(f"rate: at most the sample rate {self.sample_rate:g} Hz, got {self.rate!r}")
        self._pick = StampDecimator(sample_period_ns(self.sample_rate), max(1, int(round(self.sample_rate /
                                                                                         self.rate))))
        self._waiting = {"reference": OrderedDict(), "displacement": OrderedDict()}

    @property
    def every(self) -> int:
        """Samples between two plotted instants."""
        return self._pick.every

    def feed(self, stream: str, stamp_ns: int, block: ArrayLike) -> list[tuple[str, int, np.ndarray]]:
        """One block of ``stream`` (one of :data:`STREAMS`) → ``[(topic, stamp ns, sample)]`` to publish, where
        topic is the stream's name or ``error`` (reference − displacement at the same instant)."""
        if stream not in STREAMS:
            raise ValueError(f"stream: one of {STREAMS}, got {stream!r}")
        out: list[tuple[str, int, np.ndarray]] = []
        for k, stamp, x in self._pick.pick(stamp_ns, block):
            out.append((stream, stamp, x))
            if stream in self._waiting:
                other = "displacement" if stream == "reference" else "reference"
                partner = self._waiting[other].pop(k, None)
                if partner is None:
                    mine = self._waiting[stream]
                    mine[k] = x
                    while len(mine) > self.pending:
                        mine.popitem(last=False)
                else:
                    ref, disp = (x, partner) if stream == "reference" else (partner, x)
                    out.append(("error", stamp, ref - disp))
        return out
