"""Trajectories defined per axis: :class:`PerAxis` puts trajectories of some axes side by side on a stage of N axes
(a z ramp under an x-y raster, a helix = an x-y circle over a z ramp, the paper's circle on an XYZ stage), and
:class:`Ramp`, a linear move per axis."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import ConfigError
from .base import Trajectory, _finite, _plain

__all__ = ["PerAxis", "Ramp", "helix"]


@dataclass(frozen=True)
class Ramp(Trajectory):
    """Linear move from ``start`` to ``end`` (per axis) over ``duration`` seconds (the last sample reaches ``end``)."""

    start: Any = 0.0
    end: Any = 0.0
    duration: float = 1e-3

    kind = "ramp"
    length_fields = ("start", "end")

    def __post_init__(self) -> None:
        super().__post_init__()
        n = self.n_axes
        object.__setattr__(self, "start", tuple(np.broadcast_to(np.asarray(self.start, float), (n,)).tolist()))
        object.__setattr__(self, "end", tuple(np.broadcast_to(np.asarray(self.end, float), (n,)).tolist()))
        if not all(math.isfinite(v) for v in self.start + self.end):
            raise ConfigError("end", "start and end must be finite")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ConfigError("duration", f"must be a positive finite number, got {self.duration!r}")

    def bound(self) -> tuple[float, ...]:
        return tuple(max(abs(a), abs(b)) for a, b in zip(self.start, self.end))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        n = self.n_samples(fs)
        frac = np.clip((np.asarray(k, float) + 1.0) / n, 0.0, 1.0)[:, None]  # last sample reaches `end`
        a, b = np.array(self.start), np.array(self.end)
        out: np.ndarray = a[None, :] + frac * (b - a)[None, :]
        return out


class PerAxis(Trajectory):
    """Trajectories of disjoint groups of axes played side by side on ``axes``: ``PerAxis([circle_xy, ramp_z],
    axes=("x", "y", "z"))``.

    Each part is a trajectory on its own axes (a subset of ``axes``), evaluated at the same sample index and holding
    its last sample after its own end; an axis no part names stays at ``rest`` (0).  The duration is the longest
    part's.  As every trajectory, a pure function of the sample index (any block split gives the same samples).
    """

    kind = "per_axis"
    parts: tuple[Trajectory, ...]

    def __init__(self, parts: Any, axes: Any = None) -> None:
        built: list[Trajectory] = []
        for i, p in enumerate(parts):
            if not isinstance(p, Trajectory):   # specs (dicts) are built by spec.from_dict, not here
                raise ConfigError(f"parts[{i}]", f"expected a trajectory, got {type(p).__name__}")
            built.append(p)
        if not built:
            raise ConfigError("parts", "needs at least one trajectory")
        named = [a for p in built for a in p.axes]
        if len(set(named)) != len(named):
            raise ConfigError("parts", f"an axis is driven by two parts: {named}")
        object.__setattr__(self, "axes", tuple(axes) if axes is not None else tuple(named))
        super().__post_init__()
        unknown = [a for a in named if a not in self.axes]
        if unknown:
            raise ConfigError("parts", f"axes {unknown} are not among the trajectory's axes {list(self.axes)}")
        object.__setattr__(self, "parts", tuple(built))

    def __setattr__(self, name: str, value: Any) -> None:  # immutable like the dataclass trajectories
        raise AttributeError(f"cannot assign to field {name!r}")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PerAxis) and self.axes == other.axes and self.parts == other.parts

    def __hash__(self) -> int:
        return hash((self.axes, self.parts))

    def __repr__(self) -> str:
        return f"PerAxis(parts={list(self.parts)!r}, axes={self.axes!r})"

    @property
    def duration(self) -> float:
        return float(max(p.duration for p in self.parts))

    def bound(self) -> tuple[float, ...]:
        out = dict.fromkeys(self.axes, 0.0)
        for p in self.parts:
            out.update(zip(p.axes, p.bound()))
        return tuple(out[a] for a in self.axes)

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        out = np.zeros((len(k), self.n_axes))
        for p in self.parts:
            out[:, [self.axes.index(a) for a in p.axes]] = p.at_index(k, fs)
        return out

    def to_dict(self) -> dict[str, Any]:
        """``{"type": "per_axis", "axes": [...], "parts": [part.to_dict(), ...]}`` (SI units)."""
        return {"type": self.kind, "axes": _plain(self.axes), "parts": [p.to_dict() for p in self.parts]}


def helix(radius: float, frequency: float, revolutions: float, rise: float, axes: tuple[str, str, str] = ("x", "y", "z"),
          centre: tuple[float, float] = (0.0, 0.0)) -> PerAxis:
    """A helix: the paper's circle (radius, frequency, revolutions) on the first two ``axes`` over a ramp of ``rise``
    metres on the third, both lasting ``revolutions / frequency`` seconds."""
    from .shapes import Circle

    radius = _finite(radius, "radius", nonneg=True)
    frequency = _finite(frequency, "frequency", positive=True)
    c = Circle(radius=radius, frequency=frequency, revolutions=revolutions, centre=centre, axes=axes[:2])
    r = Ramp(start=0.0, end=_finite(rise, "rise"), duration=c.duration, axes=axes[2:])
    return PerAxis([c, r], axes=axes)
