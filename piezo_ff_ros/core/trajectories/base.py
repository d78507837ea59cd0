"""The :class:`Trajectory` base (a pure function of the sample index) and the field checks every generator uses."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterable, Mapping

import numpy as np

from ..config import ConfigError

__all__ = ["DEFAULT_AXES", "Trajectory"]


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
        """Length [s] of the trajectory (``inf`` for an endless one); after it the last sample is held."""
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
