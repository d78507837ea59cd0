"""Stream bookkeeping of the driver (pure): topic stamps ↔ device sample indices, gaps, late and out-of-sequence
blocks.

The topic contract stamps every sample on an exact grid (``stamp = t0 + k·dt_ns``); the device counts its own
samples.  A :class:`StreamBook` keeps the map between the two as *segments* ``(device index, stamp)`` — one per
stream start or confirmed jump — and classifies each incoming block against the device's write cursor ``w`` (the
next device sample not yet committed):

- the block starts at ``w``: ``apply``;
- it starts up to ``max_gap`` samples after ``w``: ``gap`` (the missing samples are held and counted as lost);
- it starts before ``w``: the samples before ``w`` are past (``late``: dropped if nothing is left, else trimmed);
- it starts more than ``max_gap`` away (either way): a *jump candidate* — held back, and applied (with the map
  re-based so that it starts at ``w``) only when the next block continues it; if the next block continues the old
  stream instead, the candidate is dropped as out of sequence.  One stray future-stamped block therefore costs
  that block only, while a sender that really restarted its stream is followed after one block.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Any

__all__ = ["StreamBook", "StreamCounters", "Decision"]


@dataclass
class StreamCounters:
    """What happened to the incoming stream (cumulative since start/reset)."""

    blocks_in: int = 0
    gaps: int = 0                    #: gap events (a block started after the expected sample)
    gap_samples: int = 0             #: samples never received (held at the last voltage)
    lost_blocks: int = 0             #: estimated blocks lost in gaps (gap samples / block size, rounded up)
    late_blocks: int = 0             #: blocks entirely in the past (dropped)
    late_samples: int = 0            #: samples dropped because their instants were past (whole or trimmed blocks)
    out_of_sequence_blocks: int = 0  #: jump candidates that the next block did not confirm (dropped)
    rebases: int = 0                 #: confirmed jumps (the stamp ↔ device map re-based)

    def as_dict(self) -> dict[str, int]:
        """The counters by name (a copy)."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class Decision:
    """What to do with one incoming block."""

    kind: str                  #: apply | gap | late | trim | pending | confirm | first
    fill: int = 0              #: hold samples to write before the block (gap)
    skip: int = 0              #: leading samples of the block to drop (trim)
    replay: tuple[Any, ...] = field(default=())  #: (stamp, n, payload) of a confirmed candidate to apply first


class StreamBook:
    """See the module docstring.  ``period_ns``: the grid step; ``max_gap``: largest gap filled (samples)."""

    def __init__(self, period_ns: int, max_gap: int):
        if period_ns <= 0 or max_gap < 0:
            raise ValueError("period_ns must be > 0 and max_gap ≥ 0")
        self.period_ns = int(period_ns)
        self.max_gap = int(max_gap)
        self.reset()

    def reset(self) -> None:
        """Forget the stream: no segment, counters at zero, no jump candidate."""
        self._seg_d: list[int] = []
        self._seg_stamp: list[int] = []
        self.counters = StreamCounters()
        self.candidate: tuple[int, int, Any] | None = None   # (stamp, n, payload) held back
        self.last_block_n = 0

    @property
    def started(self) -> bool:
        """True once the first block has anchored the stamp ↔ device-index map."""
        return bool(self._seg_d)

    def rebase(self, d: int, stamp: int) -> None:
        """From device index ``d`` on, ``d`` carries ``stamp``."""
        if self._seg_d and d <= self._seg_d[-1]:  # a segment that never got a sample: replace it
            while self._seg_d and d <= self._seg_d[-1]:
                self._seg_d.pop()
                self._seg_stamp.pop()
        self._seg_d.append(int(d))
        self._seg_stamp.append(int(stamp))

    def stamp_of(self, d: int) -> int | None:
        """Stamp of device sample ``d`` (None before the stream started)."""
        i = bisect.bisect_right(self._seg_d, d) - 1
        if i < 0:
            return None
        return self._seg_stamp[i] + (d - self._seg_d[i]) * self.period_ns

    def device_index(self, stamp: int) -> int | None:
        """Device index of ``stamp`` in the latest segment (None before the stream started)."""
        if not self._seg_d:
            return None
        return self._seg_d[-1] + (int(stamp) - self._seg_stamp[-1]) // self.period_ns

    def split(self, d0: int, n: int) -> list[tuple[int, int, int]]:
        """``[(offset, count, stamp)]`` covering device samples ``d0 … d0+n-1`` that have stamps, one per segment."""
        out = []
        i = bisect.bisect_right(self._seg_d, d0) - 1
        k = 0
        if i < 0:  # samples before the first segment have no stamp
            if not self._seg_d or self._seg_d[0] >= d0 + n:
                return []
            k = self._seg_d[0] - d0
            i = 0
        while k < n:
            d = d0 + k
            end = self._seg_d[i + 1] if i + 1 < len(self._seg_d) else d0 + n
            cnt = min(end, d0 + n) - d
            if cnt > 0:
                out.append((k, cnt, self._seg_stamp[i] + (d - self._seg_d[i]) * self.period_ns))
                k += cnt
            i += 1
            if i >= len(self._seg_d):
                break
        return out

    def classify(self, stamp: int, n: int, w: int, payload: Any = None) -> Decision:
        """Classify a block of ``n`` samples stamped ``stamp`` against the write cursor ``w`` (see the module doc)."""
        c = self.counters
        c.blocks_in += 1
        if not self._seg_d:
            self.rebase(w, stamp)
            self.last_block_n = n
            return Decision("first")
        expected = self.stamp_of(w)
        if expected is None:
            raise ValueError(f"device index {w} lies before the first segment of the stream (starts at {self._seg_d[0]})")
        off = stamp - expected
        if off % self.period_ns:
            raise ValueError(f"stamp {stamp} is not on the sample grid of the stream (period {self.period_ns} ns)")
        g = off // self.period_ns
        cand = self.candidate
        if cand is not None:
            self.candidate = None
            if stamp == cand[0] + cand[1] * self.period_ns:  # the candidate is continued: follow the jump
                c.rebases += 1
                self.rebase(w, cand[0])
                self.last_block_n = n
                return Decision("confirm", replay=cand)
            c.out_of_sequence_blocks += 1
            c.late_samples += cand[1]
        if g > self.max_gap or g + n < -self.max_gap:
            self.candidate = (stamp, n, payload)
            return Decision("pending")
        self.last_block_n = n
        if g == 0:
            return Decision("apply")
        if g > 0:
            c.gaps += 1
            c.gap_samples += g
            c.lost_blocks += -(-g // max(n, 1))
            return Decision("gap", fill=g)
        if g + n <= 0:
            c.late_blocks += 1
            c.late_samples += n
            return Decision("late")
        c.late_samples += -g
        return Decision("trim", skip=-g)

    def drop_candidate(self) -> bool:
        """Forget a held-back jump candidate (stale input); True if there was one."""
        if self.candidate is None:
            return False
        self.counters.out_of_sequence_blocks += 1
        self.counters.late_samples += self.candidate[1]
        self.candidate = None
        return True
