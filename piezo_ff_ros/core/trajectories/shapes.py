"""Scan shapes and simple references: :class:`Hold`, :class:`Sine`, :class:`Step`, :class:`Staircase`,
:class:`Circle` (paper Fig. 15), :class:`Raster`, :class:`Spiral`."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import ConfigError
from .base import Trajectory, _axis_index, _duration, _finite, _per_axis

__all__ = ["Hold", "Sine", "Step", "Staircase", "Circle", "Raster", "Spiral"]


@dataclass(frozen=True)
class Hold(Trajectory):
    """Constant ``value`` per axis (scalar, list or ``{axis: value}``) for ``duration`` seconds."""

    value: Any = 0.0
    duration: float = 1.0

    kind = "hold"
    length_fields = ("value",)

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "value", _per_axis(self.value, self.axes, "value"))
        object.__setattr__(self, "duration", _duration(self.duration))

    def bound(self) -> tuple[float, ...]:
        return tuple(abs(v) for v in self.value)

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        return np.broadcast_to(np.array(self.value), (len(k), self.n_axes))


@dataclass(frozen=True)
class Sine(Trajectory):
    """``offset + amplitude·sin(2π·frequency·t + phase)`` on ``axis`` (``'all'``: every axis), zero elsewhere."""

    amplitude: float = 1e-6
    frequency: float = 1.0
    axis: Any = "x"
    offset: float = 0.0
    phase: float = 0.0
    duration: float = math.inf

    kind = "sine"
    length_fields = ("amplitude", "offset")

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("amplitude", "offset", "phase"):
            object.__setattr__(self, name, _finite(getattr(self, name), name))
        object.__setattr__(self, "frequency", _finite(self.frequency, "frequency", positive=True))
        object.__setattr__(self, "duration", _duration(self.duration))
        _axis_index(self.axes, self.axis)

    def bound(self) -> tuple[float, ...]:
        return self._axis_bound(abs(self.offset) + abs(self.amplitude), self.axis, abs(self.offset))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        t = self._t(k, fs)
        return self._on_axis(self.amplitude * np.sin(2 * np.pi * self.frequency * t + self.phase), self.axis,
                             self.offset)


@dataclass(frozen=True)
class Step(Trajectory):
    """0 before ``t_step``, ``amplitude`` (per axis) from ``t_step`` on, for ``t_step + hold`` seconds in all."""

    amplitude: Any = (1e-6, 0.0)
    t_step: float = 0.0
    hold: float = 1.0

    kind = "step"
    length_fields = ("amplitude",)

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "amplitude", _per_axis(self.amplitude, self.axes, "amplitude"))
        object.__setattr__(self, "t_step", _finite(self.t_step, "t_step", nonneg=True))
        object.__setattr__(self, "hold", _duration(self.hold, "hold"))

    @property
    def duration(self) -> float:
        return self.t_step + self.hold

    def step_index(self, fs: float) -> int:
        """First sample index at the step level."""
        return int(math.ceil(self.t_step * fs - 1e-9))

    def bound(self) -> tuple[float, ...]:
        return tuple(abs(v) for v in self.amplitude)

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        on = (k >= self.step_index(fs)).astype(float)
        out: np.ndarray = on[:, None] * np.array(self.amplitude)[None, :]
        return out


@dataclass(frozen=True)
class Staircase(Trajectory):
    """Piecewise-constant ``levels`` (each a scalar on ``axis``, or a row per axis), each held ``dwell`` seconds."""

    levels: Any = (0.0, 5e-6, 10e-6)
    dwell: float = 1.0
    axis: Any = "x"

    kind = "staircase"
    length_fields = ("levels",)

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "dwell", _finite(self.dwell, "dwell", positive=True))
        idx = _axis_index(self.axes, self.axis)
        rows = []
        if len(self.levels) == 0:
            raise ConfigError("levels", "needs at least one level")
        for i, lev in enumerate(self.levels):
            if np.ndim(lev) == 0:
                v = _finite(lev, f"levels[{i}]")
                row = [0.0] * self.n_axes
                if idx is None:
                    row = [v] * self.n_axes
                else:
                    row[idx] = v
                rows.append(tuple(row))
            else:
                rows.append(_per_axis(lev, self.axes, f"levels[{i}]"))
        object.__setattr__(self, "levels", tuple(rows))

    @property
    def duration(self) -> float:
        return self.dwell * len(self.levels)

    def bound(self) -> tuple[float, ...]:
        return tuple(float(v) for v in np.abs(np.array(self.levels)).max(axis=0))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        per_level = self.dwell * fs
        i = np.minimum(np.floor(k / per_level + 1e-9).astype(np.int64), len(self.levels) - 1)
        return np.array(self.levels)[i]


@dataclass(frozen=True)
class Circle(Trajectory):
    """Circle (paper Fig. 15): ``x = cx + r·sin(2πft + φ)``, ``y = cy + r·sin(2πft + φ + π/2)``.

    Two sines shifted by a quarter period, as in the paper; ``revolutions`` sets the duration (``inf`` endless).
    """

    radius: float = 20e-6
    frequency: float = 1.0
    centre: Any = (0.0, 0.0)
    phase: float = 0.0
    revolutions: float = 1.0

    kind = "circle"
    length_fields = ("radius", "centre")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_axes != 2:
            raise ConfigError("axes", f"a circle needs exactly 2 axes, got {list(self.axes)}")
        object.__setattr__(self, "radius", _finite(self.radius, "radius", nonneg=True))
        object.__setattr__(self, "frequency", _finite(self.frequency, "frequency", positive=True))
        object.__setattr__(self, "centre", _per_axis(self.centre, self.axes, "centre"))
        object.__setattr__(self, "phase", _finite(self.phase, "phase"))
        object.__setattr__(self, "revolutions", _duration(self.revolutions, "revolutions"))

    @property
    def duration(self) -> float:
        return self.revolutions / self.frequency

    def bound(self) -> tuple[float, ...]:
        return tuple(abs(c) + self.radius for c in self.centre)

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        theta = 2 * np.pi * self.frequency * self._t(k, fs) + self.phase
        return np.column_stack([self.centre[0] + self.radius * np.sin(theta),
                                self.centre[1] + self.radius * np.cos(theta)])


def _triangle_antiderivative(phi: np.ndarray) -> np.ndarray:
    """Periodic antiderivative of the zero-mean triangle (−1 at phase 0, +1 at phase ½), period 1."""
    p = phi - np.floor(phi)
    out: np.ndarray = np.where(p <= 0.5, -p + 2 * p * p, 3 * (p - 0.5) - 2 * (p * p - 0.25))
    return out


@dataclass(frozen=True)
class Raster(Trajectory):
    """Raster scan: the fast axis sweeps ``width`` back and forth, the slow axis ramps over ``height``.

    Each line (one trace plus one retrace, period ``1/line_rate``) is a triangle whose corners are rounded with
    constant acceleration over a fraction ``turnaround`` of the line period (the triangle averaged over that
    window), rescaled so the sweep still spans exactly ``width``.  The slow axis ramps linearly from
    ``centre − height/2`` to ``centre + height/2`` during the ``lines`` lines.  Starts at the corner
    (−width/2, −height/2) + centre.
    """

    width: float = 20e-6
    lines: int = 16
    line_rate: float = 10.0
    height: float | None = None
    centre: Any = (0.0, 0.0)
    turnaround: float = 0.1
    fast_axis: str = "x"

    kind = "raster"
    length_fields = ("width", "height", "centre")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_axes != 2:
            raise ConfigError("axes", f"a raster scan needs exactly 2 axes, got {list(self.axes)}")
        object.__setattr__(self, "width", _finite(self.width, "width", nonneg=True))
        h = self.width if self.height is None else _finite(self.height, "height", nonneg=True)
        object.__setattr__(self, "height", h)
        try:
            lines = int(self.lines)
        except (TypeError, ValueError):
            raise ConfigError("lines", f"expected an integer, got {self.lines!r}") from None
        if lines < 1 or lines != self.lines:
            raise ConfigError("lines", f"must be a positive integer, got {self.lines!r}")
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "line_rate", _finite(self.line_rate, "line_rate", positive=True))
        object.__setattr__(self, "centre", _per_axis(self.centre, self.axes, "centre"))
        w = _finite(self.turnaround, "turnaround")
        if not 0 < w < 1:
            raise ConfigError("turnaround", f"must be in (0, 1) (fraction of a line period), got {w}")
        object.__setattr__(self, "turnaround", w)
        _axis_index(self.axes, self.fast_axis, "fast_axis")

    @property
    def duration(self) -> float:
        return self.lines / self.line_rate

    def bound(self) -> tuple[float, ...]:
        fi = self.axes.index(self.fast_axis)
        half = [0.0, 0.0]
        height = self.width if self.height is None else self.height   # set in __post_init__, never None after
        half[fi], half[1 - fi] = 0.5 * self.width, 0.5 * height
        return tuple(abs(c) + h for c, h in zip(self.centre, half))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        t = self._t(k, fs)
        phi = t * self.line_rate
        w = self.turnaround
        smooth = (_triangle_antiderivative(phi + w / 2) - _triangle_antiderivative(phi - w / 2)) / w
        fast = 0.5 * self.width * smooth / (1 - w)
        height = self.width if self.height is None else self.height   # set in __post_init__, never None after
        slow = height * (np.clip(t / self.duration, 0.0, 1.0) - 0.5)
        fi = self.axes.index(self.fast_axis)
        out = np.empty((len(k), 2))
        out[:, fi] = self.centre[fi] + fast
        out[:, 1 - fi] = self.centre[1 - fi] + slow
        return out


@dataclass(frozen=True)
class Spiral(Trajectory):
    """Archimedean spiral from the centre out: radius ``radius·t/T`` over ``revolutions`` turns at ``frequency``.

    ``x = cx + ρ(t)·sin(2πft)``, ``y = cy + ρ(t)·cos(2πft)``, ``ρ(t) = radius·min(t/T, 1)``, T = revolutions/f.
    """

    radius: float = 20e-6
    frequency: float = 10.0
    revolutions: float = 5.0
    centre: Any = (0.0, 0.0)

    kind = "spiral"
    length_fields = ("radius", "centre")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_axes != 2:
            raise ConfigError("axes", f"a spiral needs exactly 2 axes, got {list(self.axes)}")
        object.__setattr__(self, "radius", _finite(self.radius, "radius", nonneg=True))
        object.__setattr__(self, "frequency", _finite(self.frequency, "frequency", positive=True))
        rev = _finite(self.revolutions, "revolutions", positive=True)
        object.__setattr__(self, "revolutions", rev)
        object.__setattr__(self, "centre", _per_axis(self.centre, self.axes, "centre"))

    @property
    def duration(self) -> float:
        return self.revolutions / self.frequency

    def bound(self) -> tuple[float, ...]:
        return tuple(abs(c) + self.radius for c in self.centre)

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        t = self._t(k, fs)
        rho = self.radius * np.clip(t / self.duration, 0.0, 1.0)
        theta = 2 * np.pi * self.frequency * t
        return np.column_stack([self.centre[0] + rho * np.sin(theta), self.centre[1] + rho * np.cos(theta)])
