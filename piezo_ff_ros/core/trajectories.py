"""Reference trajectories: pure functions of the sample index, so every block split gives the same samples.

A :class:`Trajectory` maps the integer sample index ``k`` (time ``t = k / fs``) to a row of values, one per axis.
``traj.block(k0, n, fs)`` returns the samples ``k0 … k0+n−1`` as an array ``[n, axes]``; because each sample is
computed from its own index only, ``block(0, 10, fs)`` equals ``block(0, 4, fs)`` stacked on ``block(4, 6, fs)`` to
the last bit.  After its duration (``n_samples(fs)`` samples) a finite trajectory holds its last sample.

Values are in SI units (metres for displacement references, volts when a trajectory drives the voltage directly,
e.g. the paper's 200 V characterisation sines).  :func:`from_dict` / :meth:`Trajectory.to_dict` convert to and from
plain dictionaries (ROS parameters, YAML); a ``unit`` key (``"um"``, ``"nm"`` …) scales the length-like fields of a
spec written by hand.

Generators: :class:`Sine`, :class:`Step`, :class:`Staircase`, :class:`Circle` (paper Fig. 15), :class:`Raster`,
:class:`PRBS`, :class:`Multisine`, :class:`Chirp`, :class:`Hold`, :class:`Spiral`, :class:`Table` (samples from an
array or a file, played sample-exactly at their own rate); :class:`Sequence` concatenates named segments and says
which segment a sample belongs to.  :func:`check_workspace` refuses a trajectory that leaves the workspace.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterable, Mapping

import numpy as np
from numpy.typing import ArrayLike

from .config import ConfigError
from .units import length_scale

__all__ = [
    "Trajectory", "Sine", "Step", "Staircase", "Circle", "Raster", "PRBS", "Multisine", "Chirp", "Hold",
    "Sequence", "Segment", "from_dict", "TRAJECTORY_TYPES", "Spiral", "Table", "check_workspace", "peak",
]

DEFAULT_AXES = ("x", "y")


def _finite(value: Any, name: str, positive: bool = False, nonneg: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(name, f"expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ConfigError(name, f"must be finite, got {value!r}")
    if positive and v <= 0:
        raise ConfigError(name, f"must be > 0, got {v}")
    if nonneg and v < 0:
        raise ConfigError(name, f"must be >= 0, got {v}")
    return v


def _duration(value: Any, name: str = "duration") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(name, f"expected a number or inf, got {value!r}") from None
    if math.isnan(v) or v <= 0:
        raise ConfigError(name, f"must be > 0 (inf allowed for endless), got {value!r}")
    return v


def _axes(value: Iterable[Any]) -> tuple[str, ...]:
    axes = tuple(str(a) for a in value)
    if not axes or len(set(axes)) != len(axes):
        raise ConfigError("axes", f"must be a non-empty list of distinct names, got {value!r}")
    return axes


def _axis_index(axes: tuple[str, ...], axis: Any, name: str = "axis") -> int | None:
    """Index of ``axis`` in ``axes``; ``None``/``"all"`` means every axis."""
    if axis is None or axis == "all":
        return None
    if axis not in axes:
        raise ConfigError(name, f"unknown axis {axis!r}; use one of {list(axes)} or 'all'")
    return axes.index(axis)


def _per_axis(value: Any, axes: tuple[str, ...], name: str) -> tuple[float, ...]:
    """A scalar (same on every axis), a list (one per axis) or a mapping ``{axis: value}`` → tuple per axis."""
    if isinstance(value, Mapping):
        unknown = set(value) - set(axes)
        if unknown:
            raise ConfigError(name, f"unknown axes {sorted(unknown)}; use {list(axes)}")
        return tuple(_finite(value.get(a, 0.0), f"{name}.{a}") for a in axes)
    if np.ndim(value) == 0:
        v = _finite(value, name)
        return tuple(v for _ in axes)
    vals = list(value)
    if len(vals) != len(axes):
        raise ConfigError(name, f"expected {len(axes)} values (one per axis {list(axes)}), got {len(vals)}")
    return tuple(_finite(v, f"{name}[{i}]") for i, v in enumerate(vals))


@dataclass(frozen=True)
class Trajectory:
    """Base class.  Subclasses implement :meth:`_values` (time → ``[n, axes]``) and set ``duration``."""

    axes: tuple[str, ...] = field(default=DEFAULT_AXES, kw_only=True)

    kind = "trajectory"
    #: fields holding lengths (scaled by a spec's ``unit`` key)
    length_fields: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "axes", _axes(self.axes))

    # -- interface -------------------------------------------------------------------------------------------
    @property
    def duration(self) -> float:  # pragma: no cover - overridden
        raise NotImplementedError

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return len(self.axes)

    def n_samples(self, fs: float) -> float | int:
        """Number of samples at rate ``fs`` (``round(duration·fs)``, at least 1), ``math.inf`` if endless."""
        fs = _finite(fs, "fs", positive=True)
        if math.isinf(self.duration):
            return math.inf
        return max(1, int(round(self.duration * fs)))

    def block(self, k0: int, n: int, fs: float) -> np.ndarray:
        """Samples ``k0 … k0+n−1`` at rate ``fs`` as ``[n, axes]`` (held at the last sample after the end)."""
        if n < 0 or k0 < 0:
            raise ValueError(f"block needs k0 >= 0 and n >= 0, got k0={k0}, n={n}")
        k = np.arange(int(k0), int(k0) + int(n), dtype=np.int64)
        return self.at_index(k, fs)

    def at_index(self, k: np.ndarray, fs: float) -> np.ndarray:
        """Values at integer sample indices ``k`` (any order) at rate ``fs``."""
        fs = _finite(fs, "fs", positive=True)
        k = np.asarray(k, dtype=np.int64)
        n_total = self.n_samples(fs)
        if not math.isinf(n_total):
            k = np.minimum(k, n_total - 1)
        out = self._values(k, fs)
        return np.ascontiguousarray(out, dtype=float).reshape(len(k), self.n_axes)

    def sample(self, fs: float) -> tuple[np.ndarray, np.ndarray]:
        """The whole (finite) trajectory: ``(t [N], values [N, axes])``."""
        n = self.n_samples(fs)
        if math.isinf(n):
            raise ValueError(f"{self.kind}: endless trajectory; use block(k0, n, fs)")
        return np.arange(n) / fs, self.block(0, int(n), fs)

    def bound(self) -> tuple[float, ...]:
        """An upper bound of ``|value|`` per axis over the whole trajectory (for workspace checks); ``inf`` when a
        generator does not know one (then :func:`peak` samples it)."""
        return tuple(math.inf for _ in self.axes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary (SI units) that :func:`from_dict` turns back into an equal trajectory."""
        d = {"type": self.kind}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            d[f.name] = _plain(v)
        return d

    # -- helpers for subclasses ------------------------------------------------------------------------------
    def _t(self, k: np.ndarray, fs: float) -> np.ndarray:
        t: np.ndarray = k / fs
        return t

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def _axis_bound(self, peak: float, axis: Any, off_axis: float) -> tuple[float, ...]:
        idx = _axis_index(self.axes, axis)
        return tuple(peak if idx is None or i == idx else (0.0 if idx is not None else off_axis)
                     for i in range(self.n_axes))

    def _on_axis(self, values: np.ndarray, axis: Any, offset: float = 0.0) -> np.ndarray:
        out = np.zeros((len(values), self.n_axes))
        idx = _axis_index(self.axes, axis)
        if idx is None:
            out[:] = (values + offset)[:, None]
        else:
            out[:, idx] = values + offset
        return out


def _plain(v: Any) -> Any:
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return v


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


@dataclass(frozen=True)
class Table(Trajectory):
    """Samples given as an array (``values`` [N, axes]) or a file (``file``: .npy, or .csv/.txt with one column per
    axis, a header line of axis names optional), at ``sample_rate``.

    Played sample-exactly when the playing rate equals ``sample_rate``; at another rate, linearly interpolated
    between the table's samples (time ``k/fs``).  Held at the last row after the end.  The array travels in the
    spec only when given inline; a file is read once, at construction.
    """

    values: Any = None
    file: str = ""
    sample_rate: float = 20000.0

    kind = "table"
    length_fields = ("values",)

    def __post_init__(self) -> None:
        super().__post_init__()
        fs = _finite(self.sample_rate, "sample_rate", positive=True)
        object.__setattr__(self, "sample_rate", fs)
        if (self.values is None) == (not self.file):
            raise ConfigError("values", "give exactly one of 'values' (an array) or 'file'")
        if self.file:
            arr = _read_table(str(self.file), self.axes)
        else:
            try:
                arr = np.array(self.values, dtype=float)
            except (TypeError, ValueError):
                raise ConfigError("values", "expected a numeric array [N, axes]") from None
        if arr.ndim == 1 and self.n_axes == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[1] != self.n_axes or len(arr) == 0:
            raise ConfigError("file" if self.file else "values",
                              f"expected an array [N >= 1, {self.n_axes}] (axes {list(self.axes)}), got shape {arr.shape}")
        bad = np.argwhere(~np.isfinite(arr))
        if len(bad):
            raise ConfigError("file" if self.file else "values", f"row {int(bad[0][0])}: not a finite number")
        arr.setflags(write=False)
        self._table: np.ndarray    # not a dataclass field: the array read from values/file, set once here
        object.__setattr__(self, "_table", arr)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Table) and self.axes == other.axes and self.sample_rate == other.sample_rate
                and np.array_equal(self._table, other._table))

    def __hash__(self) -> int:
        return hash(("table", self.axes, self.sample_rate, self._table.shape))

    @property
    def duration(self) -> float:
        return len(self._table) / self.sample_rate

    def n_samples(self, fs: float) -> float | int:
        fs = _finite(fs, "fs", positive=True)
        if fs == self.sample_rate:
            return len(self._table)
        return super().n_samples(fs)

    def bound(self) -> tuple[float, ...]:
        return tuple(float(v) for v in np.abs(self._table).max(axis=0))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        if fs == self.sample_rate:
            held: np.ndarray = self._table[np.minimum(k, len(self._table) - 1)]
            return held
        pos = k * (self.sample_rate / fs)
        i0 = np.minimum(np.floor(pos).astype(np.int64), len(self._table) - 1)
        i1 = np.minimum(i0 + 1, len(self._table) - 1)
        a = (pos - i0)[:, None]
        out: np.ndarray = (1 - a) * self._table[i0] + a * self._table[i1]
        return out

    def to_dict(self) -> dict[str, Any]:
        d = {"type": self.kind, "axes": list(self.axes), "sample_rate": self.sample_rate}
        if self.file:
            d["file"] = self.file
        else:
            d["values"] = self._table.tolist()
        return d


def _read_table(path: str, axes: tuple[str, ...]) -> np.ndarray:
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise ConfigError("file", f"{path}: no such file")
    try:
        if p.suffix == ".npy":
            arr: np.ndarray = np.load(p, allow_pickle=False).astype(float)
            return arr
        with p.open() as fh:
            first = fh.readline()
        names = [c.strip() for c in first.replace(";", ",").split(",")]
        header = not all(_is_number(c) for c in names if c)
        arr = np.loadtxt(p, delimiter=",", skiprows=1 if header else 0, ndmin=2)
        if header:  # columns by name, not by position
            missing = [a for a in axes if a not in names]
            if missing:
                raise ConfigError("file", f"{path}: no column named {missing[0]!r} (header {names})")
            arr = arr[:, [names.index(a) for a in axes]]
        return arr
    except ConfigError:
        raise
    except (OSError, ValueError) as exc:
        raise ConfigError("file", f"{path}: cannot read a table ({str(exc).splitlines()[0][:120]})") from None


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


# maximal-length LFSR feedback taps (Fibonacci form, bit positions 1-based), orders 5 … 16
_LFSR_TAPS = {5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4), 9: (9, 5), 10: (10, 7), 11: (11, 9),
              12: (12, 11, 10, 4), 13: (13, 12, 11, 8), 14: (14, 13, 12, 2), 15: (15, 14), 16: (16, 15, 13, 4)}


def _m_sequence(order: int) -> np.ndarray:
    """One period (2^order − 1 chips) of the maximal-length sequence, as 0/1."""
    taps = _LFSR_TAPS[order]
    state = [1] * order
    n = 2 ** order - 1
    out = np.empty(n, dtype=np.int8)
    for i in range(n):
        out[i] = state[-1]
        fb = 0
        for tp in taps:
            fb ^= state[tp - 1]
        state = [fb] + state[:-1]
    return out


@dataclass(frozen=True)
class PRBS(Trajectory):
    """Pseudo-random binary sequence: ``offset ± amplitude``, one chip per ``1/clock_rate`` seconds.

    A maximal-length LFSR sequence of ``order`` (period 2^order − 1 chips, flat spectrum up to ≈ clock_rate/2.3);
    ``seed`` picks the starting chip.  On ``axis='all'`` each axis uses the same sequence shifted by
    period/n_axes chips (mutually uncorrelated inputs for MIMO identification).
    """

    amplitude: float = 1e-6
    clock_rate: float = 1000.0
    seed: int = 0
    axis: Any = "x"
    offset: float = 0.0
    order: int = 11
    duration: float = math.inf

    kind = "prbs"
    length_fields = ("amplitude", "offset")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "amplitude", _finite(self.amplitude, "amplitude"))
        object.__setattr__(self, "offset", _finite(self.offset, "offset"))
        object.__setattr__(self, "clock_rate", _finite(self.clock_rate, "clock_rate", positive=True))
        if int(self.order) not in _LFSR_TAPS or int(self.order) != self.order:
            raise ConfigError("order", f"must be an integer in {min(_LFSR_TAPS)}…{max(_LFSR_TAPS)}, got {self.order!r}")
        object.__setattr__(self, "order", int(self.order))
        try:
            object.__setattr__(self, "seed", int(self.seed))
        except (TypeError, ValueError):
            raise ConfigError("seed", f"expected an integer, got {self.seed!r}") from None
        object.__setattr__(self, "duration", _duration(self.duration))
        _axis_index(self.axes, self.axis)
        self._chips: np.ndarray   # not a dataclass field: the ±1 chip sequence, set once here
        object.__setattr__(self, "_chips", 2.0 * _m_sequence(self.order) - 1.0)

    @property
    def period(self) -> float:
        """Sequence period [s]."""
        return float((2 ** self.order - 1) / self.clock_rate)

    def bound(self) -> tuple[float, ...]:
        return self._axis_bound(abs(self.offset) + abs(self.amplitude), self.axis, abs(self.offset))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        chips = self._chips
        n = len(chips)
        chip_index = np.floor(k * (self.clock_rate / fs) + 1e-9).astype(np.int64) + self.seed
        idx = _axis_index(self.axes, self.axis)
        if idx is not None:
            return self._on_axis(self.amplitude * chips[chip_index % n], self.axis, self.offset)
        cols = [chips[(chip_index + j * (n // self.n_axes)) % n] for j in range(self.n_axes)]
        return self.offset + self.amplitude * np.column_stack(cols)


@dataclass(frozen=True)
class Multisine(Trajectory):
    """Sum of ``n_tones`` sines between ``f_min`` and ``f_max`` (linearly spaced), RMS value ``amplitude``.

    Phases: ``'schroeder'`` (φ_i = −π·i(i−1)/n, low crest factor) or ``'random'`` (uniform, from ``seed``).
    Each tone has amplitude ``amplitude·√(2/n)`` so the long-run RMS is exactly ``amplitude``.
    """

    amplitude: float = 1e-6
    f_min: float = 1.0
    f_max: float = 100.0
    n_tones: int = 20
    phases: str = "schroeder"
    seed: int = 0
    axis: Any = "x"
    offset: float = 0.0
    duration: float = math.inf

    kind = "multisine"
    length_fields = ("amplitude", "offset")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "amplitude", _finite(self.amplitude, "amplitude", nonneg=True))
        object.__setattr__(self, "offset", _finite(self.offset, "offset"))
        f0 = _finite(self.f_min, "f_min", positive=True)
        f1 = _finite(self.f_max, "f_max", positive=True)
        if f1 < f0:
            raise ConfigError("f_max", f"must be >= f_min ({f0}), got {f1}")
        object.__setattr__(self, "f_min", f0)
        object.__setattr__(self, "f_max", f1)
        if int(self.n_tones) != self.n_tones or int(self.n_tones) < 1:
            raise ConfigError("n_tones", f"must be a positive integer, got {self.n_tones!r}")
        object.__setattr__(self, "n_tones", int(self.n_tones))
        if self.phases not in ("schroeder", "random"):
            raise ConfigError("phases", f"must be 'schroeder' or 'random', got {self.phases!r}")
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "duration", _duration(self.duration))
        _axis_index(self.axes, self.axis)

    @property
    def frequencies(self) -> np.ndarray:
        return np.linspace(self.f_min, self.f_max, self.n_tones)

    @property
    def tone_phases(self) -> np.ndarray:
        n = self.n_tones
        if self.phases == "schroeder":
            i = np.arange(1, n + 1)
            return -np.pi * i * (i - 1) / n
        return np.random.default_rng(self.seed).uniform(0, 2 * np.pi, n)

    def bound(self) -> tuple[float, ...]:
        peak = abs(self.offset) + self.amplitude * math.sqrt(2.0 / self.n_tones) * self.n_tones
        return self._axis_bound(peak, self.axis, abs(self.offset))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        t = self._t(k, fs)
        a = self.amplitude * math.sqrt(2.0 / self.n_tones)
        v = np.zeros(len(t))
        for f, p in zip(self.frequencies, self.tone_phases):
            v += np.sin(2 * np.pi * f * t + p)
        return self._on_axis(a * v, self.axis, self.offset)


@dataclass(frozen=True)
class Chirp(Trajectory):
    """Swept sine ``offset + amplitude·sin(phase(t))`` from ``f0`` to ``f1`` over ``duration`` seconds.

    ``method``: ``'linear'`` (instantaneous frequency f0 + (f1−f0)·t/T) or ``'logarithmic'`` (geometric sweep).
    """

    amplitude: float = 1e-6
    f0: float = 1.0
    f1: float = 1000.0
    duration: float = 10.0
    method: str = "linear"
    axis: Any = "x"
    offset: float = 0.0

    kind = "chirp"
    length_fields = ("amplitude", "offset")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "amplitude", _finite(self.amplitude, "amplitude"))
        object.__setattr__(self, "offset", _finite(self.offset, "offset"))
        object.__setattr__(self, "f0", _finite(self.f0, "f0", positive=True))
        object.__setattr__(self, "f1", _finite(self.f1, "f1", positive=True))
        d = _duration(self.duration)
        if math.isinf(d):
            raise ConfigError("duration", "a chirp needs a finite duration")
        object.__setattr__(self, "duration", d)
        if self.method not in ("linear", "logarithmic"):
            raise ConfigError("method", f"must be 'linear' or 'logarithmic', got {self.method!r}")
        _axis_index(self.axes, self.axis)

    def instantaneous_frequency(self, t: ArrayLike) -> np.ndarray:
        """The sweep's frequency [Hz] at times ``t`` [s]."""
        t = np.asarray(t, float)
        if self.method == "linear":
            return self.f0 + (self.f1 - self.f0) * t / self.duration
        return self.f0 * (self.f1 / self.f0) ** (t / self.duration)

    def bound(self) -> tuple[float, ...]:
        return self._axis_bound(abs(self.offset) + abs(self.amplitude), self.axis, abs(self.offset))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        t = self._t(k, fs)
        T = self.duration
        if self.method == "linear":
            phase = 2 * np.pi * (self.f0 * t + 0.5 * (self.f1 - self.f0) * t * t / T)
        elif self.f1 == self.f0:
            phase = 2 * np.pi * self.f0 * t
        else:
            r = self.f1 / self.f0
            phase = 2 * np.pi * self.f0 * T / math.log(r) * (r ** (t / T) - 1.0)
        return self._on_axis(self.amplitude * np.sin(phase), self.axis, self.offset)


@dataclass(frozen=True)
class Segment:
    """A named part of a :class:`Sequence`: samples ``[start, stop)`` at a given rate."""

    index: int
    name: str
    trajectory: Trajectory
    meta: dict[str, Any]
    start: int
    stop: float | int


class Sequence(Trajectory):
    """Named segments played one after the other: ``Sequence([(name, trajectory, meta), ...])``.

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
            if isinstance(traj, Mapping):
                traj = from_dict(traj, prefix=f"segments[{i}].trajectory")
            if not isinstance(traj, Trajectory):
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
        return isinstance(other, Sequence) and self.axes == other.axes and self.segments_ == other.segments_

    def __hash__(self) -> int:
        return hash(("sequence", self.axes, tuple(n for n, _, _ in self.segments_)))

    def __repr__(self) -> str:
        return f"Sequence({[n for n, _, _ in self.segments_]})"

    @property
    def names(self) -> list[str]:
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


TRAJECTORY_TYPES = {cls.kind: cls for cls in (Hold, Sine, Step, Staircase, Circle, Raster, PRBS, Multisine, Chirp,
                                              Spiral, Table)}


def _scale_lengths(value: Any, s: float) -> Any:
    if value is None:
        return None
    if isinstance(value, Mapping):
        return {k: _scale_lengths(v, s) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_scale_lengths(v, s) for v in value]
    return float(value) * s


def from_dict(spec: Mapping[str, Any], prefix: str = "trajectory") -> Trajectory:
    """Build a trajectory from ``{"type": <kind>, <field>: value, ...}`` (as produced by ``to_dict``).

    ``unit`` (optional, e.g. ``"um"``) scales the length-like fields (amplitude, offset, radius, width …) of a
    hand-written spec to metres; ``"inf"`` is accepted for durations.  Errors are :class:`ConfigError` naming
    the field as ``<prefix>.<field>``.
    """
    if not isinstance(spec, Mapping):
        raise ConfigError(prefix, f"expected a mapping with a 'type' key, got {type(spec).__name__}")
    d = dict(spec)
    kind = d.pop("type", None)
    if kind == "sequence":
        unknown = set(d) - {"segments", "axes"}
        if unknown:
            raise ConfigError(f"{prefix}.{sorted(unknown)[0]}", "unknown key for a sequence")
        try:
            segs = list(d.get("segments") or [])
        except TypeError:
            raise ConfigError(f"{prefix}.segments", "expected a list of segments") from None
        try:
            return Sequence(segs, axes=d.get("axes"))
        except ConfigError as exc:
            raise ConfigError(f"{prefix}.{exc.field}", exc.reason) from None
    if kind not in TRAJECTORY_TYPES:
        raise ConfigError(f"{prefix}.type", f"unknown trajectory type {kind!r}; use one of "
                                            f"{sorted(TRAJECTORY_TYPES) + ['sequence']}")
    cls = TRAJECTORY_TYPES[kind]
    unit = d.pop("unit", None)
    if unit is not None:
        try:
            s = length_scale(unit)
        except ValueError as exc:
            raise ConfigError(f"{prefix}.unit", str(exc)) from None
        for f in cls.length_fields:
            if f in d:
                d[f] = _scale_lengths(d[f], s)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise ConfigError(f"{prefix}.{sorted(unknown)[0]}", f"unknown field for a {kind} trajectory; "
                                                             f"known: {sorted(names)}")
    for key in ("duration", "hold", "revolutions"):
        if d.get(key) in ("inf", "Infinity", ".inf"):
            d[key] = math.inf
    if "axes" in d:
        d["axes"] = tuple(d["axes"])
    try:
        return cls(**d)
    except ConfigError as exc:
        raise ConfigError(f"{prefix}.{exc.field}", exc.reason) from None
    except TypeError as exc:
        raise ConfigError(prefix, str(exc)) from None


def peak(traj: Trajectory, fs: float = 20000.0, max_samples: int = 4_000_000) -> tuple[float, ...]:
    """``max |value|`` per axis: sampled exactly at ``fs`` when finite and at most ``max_samples`` long, else
    :meth:`Trajectory.bound` (an upper bound)."""
    n = traj.n_samples(fs)
    if math.isinf(n) or n > max_samples:
        return traj.bound()   # may be inf for a generator without a bound: then it cannot be checked
    out = np.zeros(traj.n_axes)
    for k0 in range(0, int(n), 200_000):
        out = np.maximum(out, np.abs(traj.block(k0, min(200_000, int(n) - k0), fs)).max(axis=0))
    return tuple(float(v) for v in out)


def _in_volts(meta: Mapping[str, Any]) -> bool:
    return meta.get("input") == "voltage" or meta.get("stage") in ("hysteresis", "plant")


def check_workspace(traj: Trajectory, workspace_m: float, voltage_limit: float | None = None,
                    prefix: str = "trajectory", fs: float = 20000.0) -> None:
    """Refuse a trajectory that leaves ``±workspace_m`` on any axis (ConfigError naming the field).

    Segments of a :class:`Sequence` whose meta says ``input: voltage`` (paper experiments on S0) or ``stage:
    hysteresis|plant`` (the commissioning's characterisation of S0, played through a bypassed compensator) are in
    volts and checked against ``±voltage_limit`` instead (skipped when it is None).
    ``workspace_m <= 0`` disables the check.
    """
    if workspace_m <= 0:
        return
    if isinstance(traj, Sequence):
        for i, (name, t, meta) in enumerate(traj.segments_):
            limit = workspace_m
            if _in_volts(meta):
                if voltage_limit is None:
                    continue
                limit = voltage_limit
            check_workspace(t, limit, None,
                            prefix=f"{prefix}.segments[{i}].trajectory", fs=fs)
        return
    field_name = traj.length_fields[0] if traj.length_fields else "value"
    if all(b <= workspace_m for b in traj.bound()):
        return
    for axis, b in zip(traj.axes, peak(traj, fs)):
        if math.isfinite(b) and b > workspace_m * (1 + 1e-12):
            raise ConfigError(f"{prefix}.{field_name}",
                              f"reaches {b:.6g} on axis {axis}, outside the workspace ±{workspace_m:g} "
                              f"(SI units: metres; e.g. radius: 2.0e-5 or unit: um)")
