"""A recorded run in memory, whatever file it came from.

Uniformly sampled, SI units: ``t`` [s] shape [N], ``u`` [V] shape [N, axes], ``y`` [m] shape [N, axes], optional
``reference`` [m] shape [N, axes], plus free-form ``meta`` (source file, config, experiment segments, gaps …).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["RunData", "load_run"]


@dataclass
class RunData:
    """One recorded (or simulated) run, sample-aligned, SI units.

    Attributes
    ----------
    t : array [N]
        Time [s].
    u : array [N, axes]
        Voltage [V].
    y : array [N, axes]
        Displacement [m].
    axes : tuple of str
        Column names.
    reference : array [N, axes] or None
        The reference [m] (volts for voltage-driven runs), when recorded.
    meta : dict
        Where the run came from and what happened to it (see :func:`~.mcap_reader.read_run`).
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    axes: tuple[str, ...] = ("x", "y")
    reference: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        """Sample period [s] (NaN for fewer than two samples)."""
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else float("nan")

    @property
    def sample_rate(self) -> float:
        """Sample rate [Hz]."""
        return 1.0 / self.dt

    def __len__(self) -> int:
        return len(self.t)

    def slice(self, start: int, stop: int) -> "RunData":
        """Rows ``start:stop`` (meta copied).

        Parameters
        ----------
        start, stop : int
            Row range.

        Returns
        -------
        RunData
        """
        ref = None if self.reference is None else self.reference[start:stop]
        return RunData(self.t[start:stop], self.u[start:stop], self.y[start:stop], self.axes, ref, dict(self.meta))

    def split(self, fraction: float = 0.5) -> tuple["RunData", "RunData"]:
        """The first ``fraction`` of the rows and the rest.

        Parameters
        ----------
        fraction : float
            Share of the first part.

        Returns
        -------
        tuple of RunData
        """
        k = int(len(self) * fraction)
        return self.slice(0, k), self.slice(k, len(self))


def load_run(path: str | Path, **kwargs: Any) -> RunData:
    """Load a run from ``.mcap`` (our topic contract), ``.csv`` (``t,u_x,u_y,x,y``) or ``.mat`` (``t``, ``u``, ``y``).

    Raises ``ValueError`` with a message that says what is wrong and where for malformed files.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    suffix = p.suffix.lower()
    if suffix == ".mcap" or p.is_dir():
        from .mcap_io import read_run

        return read_run(p, **kwargs)
    if suffix == ".csv":
        from .importers import load_csv

        return load_csv(p, **kwargs)
    if suffix == ".mat":
        from .importers import load_mat

        return load_mat(p, **kwargs)
    raise ValueError(f"{p}: unknown format {suffix!r} (expected .mcap, .csv or .mat)")
