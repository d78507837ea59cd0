"""Recorded samples as a trajectory: :class:`Table` (an array or a .npy/.csv/.txt file, played sample-exactly at its
own rate)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import ConfigError
from .base import Trajectory, _finite

__all__ = ["Table"]


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
