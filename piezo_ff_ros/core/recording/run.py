"""A recorded run in memory, whatever file it came from.

Uniformly sampled, SI units: ``t`` [s] shape [N], ``u`` [V] shape [N, axes], ``y`` [m] shape [N, axes], optional
``reference`` [m] shape [N, axes], plus free-form ``meta`` (source file, config, experiment segments, gaps …).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

__all__ = ["RunData", "AXIS_ORDER", "canonical_axes"]

#: axis names put first, in this order, whatever the column order of the file (x, y, z as in REP 103)
AXIS_ORDER = ("x", "y", "z")


def canonical_axes(names: Iterable[str]) -> tuple[str, ...]:
    """Axis names in a fixed order — x, y, z first, then the others as given — so that the column order of a
    file never changes which column is which axis."""
    names = list(names)
    return tuple([a for a in AXIS_ORDER if a in names] + [a for a in names if a not in AXIS_ORDER])


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
        Where the run came from and what happened to it (see :func:`~piezo_ff_ros.core.recording.mcap_reader.read_run`).
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
