"""Pacing of a held set-point: when to play it, how many blocks, on a monotonic clock.

The compensator plays a held ``reference_point`` as blocks of ``block_size`` samples at the sample rate, but only
while no ``reference`` block arrived for ``max(hold_timeout, 2 · block period)``.  The node calls :meth:`HoldPacer.tick`
from an executor timer (any period, any jitter); the pacer counts the samples due since the hold started and
answers with the number of whole blocks to play now, so the average rate is the sample rate whatever the timer's
period or lateness.  A tick up to ``max_late_s`` behind the schedule (the process was stalled: a loaded host, a
collection) plays the blocks due at once, so that the stream stays on the wall clock and the driver's queue keeps its
write-ahead; a tick later than that does not replay the backlog in a burst (the driver has run past those instants by
then): the schedule restarts from that tick.  Pure logic, no ROS: the clock is an argument.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["HoldPacer", "HOLD_BLOCK_SIZE"]

#: samples per block of a held point by default (50 ms at 20 kHz).  Each block costs a fixed overhead in every node
#: it passes (publish, take, executor wake-ups: the compensator, the driver, its voltage_applied/displacement and
#: every reader): with 200-sample blocks (100 blocks/s) a driver on a loaded 2-core host (two CPU-bound loaders,
#: load average 11-19) fell behind its input by 1 s within a second of holding (late blocks); 1000-sample blocks
#: use about a third of the CPU and kept up.  The hold's latency is the driver's write-ahead, not this.
HOLD_BLOCK_SIZE = 1000


def _check_number(value: object, name: str, integer: bool = False, allow_zero: bool = False) -> float:
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value) and (
        value > 0 or (allow_zero and value == 0)) and (not integer or int(value) == value)
    if not ok:
        raise ValueError(f"{name}: expected a finite {'integer' if integer else 'number'} "
                         f"{'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return float(value)  # type: ignore[arg-type]  # reason: checked to be an int or float just above


def _positive(value: object, name: str, allow_zero: bool = False) -> float:
    return _check_number(value, name, allow_zero=allow_zero)


def _positive_int(value: object, name: str) -> int:
    return int(_check_number(value, name, integer=True))


@dataclass
class HoldPacer:
    """Decides when a held point is played (see the module docstring).

    Parameters
    ----------
    sample_rate : float
        Samples per second [Hz].
    block_size : int
        Samples per played block.
    hold_timeout : float
        The held point plays once no reference block came for this long [s] (at least two block periods).
    max_late_s : float
        Lateness [s] beyond which the backlog is dropped and the schedule restarts (at least one block period).
        Default 0.5 s, the driver's default write-ahead: a shorter stall is caught up.  Otherwise each stall would
        shorten the driver's margin for good (with 0.1 s, three stalls of 0.15 s would take 0.45 s of its 0.5 s
        write-ahead, and the next blocks would come late).
    """

    sample_rate: float
    block_size: int = HOLD_BLOCK_SIZE
    hold_timeout: float = 0.2
    max_late_s: float = 0.5
    point: np.ndarray | None = field(default=None, init=False)
    _last_block: float = field(default=-math.inf, init=False)
    _start: float | None = field(default=None, init=False)
    _played: int = field(default=0, init=False)
    restarts: int = field(default=0, init=False)   #: schedules restarted after a stall (backlog dropped)

    def __post_init__(self) -> None:
        self.sample_rate = _positive(self.sample_rate, "sample_rate")
        self.block_size = _positive_int(self.block_size, "block_size")
        self.hold_timeout = _positive(self.hold_timeout, "hold_timeout", allow_zero=True)
        self.max_late_s = _positive(self.max_late_s, "max_late_s")

    @property
    def block_period(self) -> float:
        """Seconds per block."""
        return self.block_size / self.sample_rate

    @property
    def quiet_needed(self) -> float:
        """How long the reference stream must have been silent before the held point plays [s]."""
        return max(self.hold_timeout, 2.0 * self.block_period)

    def set_block_size(self, n: int) -> None:
        """A new block size, from the next block on (the schedule restarts)."""
        self.block_size = _positive_int(n, "block_size")
        self._start = None

    def set_point(self, point: ArrayLike) -> None:
        """Hold ``point`` (one value per axis, finite) from now on."""
        p = np.array(point, float).ravel()
        if p.size == 0 or not np.all(np.isfinite(p)):
            raise ValueError("reference_point: expected finite values, got " + repr(point))
        self.point = p

    def clear(self) -> None:
        """Forget the held point (e.g. on a reset)."""
        self.point = None
        self._start = None

    def note_block(self, now: float) -> None:
        """A reference block arrived at ``now`` [s]: the held point waits for the stream to go quiet again."""
        self._last_block = now
        self._start = None

    def tick(self, now: float) -> int:
        """Blocks of the held point to play at ``now`` [s] (0 when nothing is held or the stream is not quiet)."""
        if self.point is None or now - self._last_block < self.quiet_needed:
            self._start = None
            return 0
        if self._start is None:          # the hold starts: its first block is due now
            self._start, self._played = now, 0
        due = int(math.floor((now - self._start) * self.sample_rate / self.block_size + 1e-9)) + 1 - self._played
        if (due - 1) * self.block_period > max(self.max_late_s, self.block_period):   # stalled: no burst, restart
            self.restarts += 1
            self._start, self._played, due = now, 0, 1
        due = max(due, 0)
        self._played += due
        return due

    def block(self) -> np.ndarray:
        """One block of the held point ``[block_size, axes]``."""
        if self.point is None:
            raise ValueError("no held point")
        return np.tile(self.point, (self.block_size, 1))
