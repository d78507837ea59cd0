"""Named segments played one after the other (:class:`TrajectorySequence`), and which segment a sample belongs to."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numpy as np
from numpy.typing import ArrayLike

from ..config import ConfigError
from .base import Trajectory, _axes, _finite, _plain

__all__ = ["Segment", "TrajectorySequence"]


@dataclass(frozen=True)
class Segment:
    """A named part of a :class:`TrajectorySequence`: samples ``[start, stop)`` at a given rate."""

    index: int
    name: str
    trajectory: Trajectory
    meta: dict[str, Any]
    start: int
    stop: float | int


class TrajectorySequence(Trajectory):
    """Named segments played one after the other: ``TrajectorySequence([(name, trajectory, meta), ...])``.

    Segment ``i`` occupies samples ``[start_i, start_i + n_samples_i(fs))``; inside it the segment's own
    trajectory is evaluated at its local index ``k − start_i`` (each segment starts at its own t = 0).  Only the
    last segment may be endless.  ``meta`` is free-form (e.g. which compensator stages an experiment uses).
    """

    kind = "sequence"
    segments_: tuple[tuple[str, Trajectory, dict[str, Any]], ...]   #: (name, trajectory, meta) per segment

    def __init__(self, segments: Iterable[Any], axes: Iterable[str] | None = None) -> None:
        segs = []
        names = set()
        for i, seg in enumerate(segments):
            if isinstance(seg, Mapping):
                name, traj, meta = seg.get("name"), seg.get("trajectory"), seg.get("meta", {})
            else:
                seg = tuple(seg)
                if len(seg) not in (2, 3):
                    raise ConfigError(f"segments[{i}]", "expected (name, trajectory[, meta])")
                name, traj, meta = seg[0], seg[1], (seg[2] if len(seg) == 3 else {})
            if not isinstance(traj, Trajectory):   # a spec (mapping) is built by trajectories.from_dict first
                raise ConfigError(f"segments[{i}].trajectory", f"expected a Trajectory, got {type(traj).__name__}")
            name = str(name)
            if name in names:
                raise ConfigError(f"segments[{i}].name", f"duplicate segment name {name!r}")
            names.add(name)
            segs.append((name, traj, dict(meta or {})))
        if not segs:
            raise ConfigError("segments", "a sequence needs at least one segment")
        ax = _axes(axes) if axes is not None else segs[0][1].axes
        for i, (name, traj, _) in enumerate(segs):
            if traj.axes != ax:
                raise ConfigError(f"segments[{i}].trajectory.axes", f"{list(traj.axes)} differ from {list(ax)}")
            if math.isinf(traj.duration) and i != len(segs) - 1:
                raise ConfigError(f"segments[{i}].trajectory.duration", "only the last segment may be endless")
        object.__setattr__(self, "axes", ax)
        object.__setattr__(self, "segments_", tuple(segs))

    def __setattr__(self, name: str, value: Any) -> None:  # keep it immutable like the other trajectories
        raise dataclasses.FrozenInstanceError(f"cannot assign to field {name!r}")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, TrajectorySequence) and self.axes == other.axes and self.segments_ == other.segments_

    def __hash__(self) -> int:
        return hash(("sequence", self.axes, tuple(n for n, _, _ in self.segments_)))

    def __repr__(self) -> str:
        return f"TrajectorySequence({[n for n, _, _ in self.segments_]})"

    @property
    def names(self) -> list[str]:
        """Segment names, in playing order."""
        return [n for n, _, _ in self.segments_]

    @property
    def duration(self) -> float:
        return float(sum(t.duration for _, t, _ in self.segments_))

    def n_samples(self, fs: float) -> float | int:
        fs = _finite(fs, "fs", positive=True)
        total: float | int = 0
        for _, traj, _ in self.segments_:
            n = traj.n_samples(fs)
            if math.isinf(n):
                return math.inf
            total += n
        return total

    def segments(self, fs: float) -> list[Segment]:
        """All segments with their sample ranges at rate ``fs``."""
        out, start = [], 0
        for i, (name, traj, meta) in enumerate(self.segments_):
            n = traj.n_samples(fs)
            out.append(Segment(i, name, traj, meta, start, start + n))
            start = start + int(n) if not math.isinf(n) else start
        return out

    def segment(self, name: str, fs: float) -> Segment:
        """The segment called ``name``, with its sample range at ``fs``.

        Parameters
        ----------
        name : str
            Segment name.
        fs : float
            Sample rate [Hz].

        Returns
        -------
        Segment

        Raises
        ------
        KeyError
            No segment has that name.
        """
        for seg in self.segments(fs):
            if seg.name == name:
                return seg
        raise KeyError(f"no segment named {name!r}; have {self.names}")

    def segment_at(self, k: int, fs: float) -> Segment:
        """The segment sample ``k`` belongs to (the last one for samples after the end)."""
        segs = self.segments(fs)
        for seg in segs:
            if k < seg.stop:
                return seg
        return segs[-1]

    def segment_index(self, k: np.ndarray, fs: float) -> np.ndarray:
        """Segment number of each sample index in ``k`` (vectorised :meth:`segment_at`)."""
        segs = self.segments(fs)
        stops = np.array([s.stop for s in segs[:-1]], dtype=float)
        return np.searchsorted(stops, np.asarray(k), side="right")

    def at_index(self, k: ArrayLike, fs: float) -> np.ndarray:
        fs = _finite(fs, "fs", positive=True)
        k = np.asarray(k, dtype=np.int64)
        segs = self.segments(fs)
        which = self.segment_index(k, fs)
        out = np.empty((len(k), self.n_axes))
        for i, seg in enumerate(segs):
            sel = which == i
            if np.any(sel):
                out[sel] = seg.trajectory.at_index(k[sel] - seg.start, fs)
        return out

    def bound(self) -> tuple[float, ...]:
        return tuple(float(v) for v in np.max([t.bound() for _, t, _ in self.segments_], axis=0))

    def to_dict(self) -> dict[str, Any]:
        return {"type": "sequence", "axes": list(self.axes),
                "segments": [{"name": n, "trajectory": t.to_dict(), "meta": _plain_meta(m)}
                             for n, t, m in self.segments_]}


def _plain_meta(m: Any) -> Any:
    if isinstance(m, Mapping):
        return {str(k): _plain_meta(v) for k, v in m.items()}
    if isinstance(m, (list, tuple)):
        return [_plain_meta(v) for v in m]
    return _plain(m)

