"""Characterisation presets that the node graph's trajectory node can play (only ``trajectories.TRAJECTORY_TYPES``).

:mod:`~piezo_ff_ros.core.characterisation` builds its signals with two local types (``Sum``, ``Ramp``) that the
trajectory node cannot parse from a parameter.  Here the same experiments are expressed with graph types only:

- a ``Ramp`` (slew-limited step edge) becomes a ``Staircase`` with one level per sample — the same samples;
- the two-axis sine ``Sum`` with a quarter period between the axes is a ``Circle`` (the paper's circle is exactly
  that);
- any other ``Sum`` (the plant-validation multisine: 7 lines per axis, different on x and y) has no graph type: it
  is written to ``table_dir`` as a ``.npy`` table and played as a ``Table`` at the run's rate — the same samples,
  bit for bit (the node reads the file once; a 30 s two-axis table at 20 kHz is 9.6 MB and loads in milliseconds,
  where the same samples as a YAML spec took about a minute to parse);
- every run that would start away from 0 V gets a short ramp from rest first (the driver is reset to rest before
  each run; a one-sample jump of hundreds of volts is what the discrete Bouc-Wen form cannot represent).

Pure: no ROS import.
"""
from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from .characterisation import Ramp, Sum
from .trajectories import TRAJECTORY_TYPES, Circle, Sine, Staircase, Table, Trajectory, TrajectorySequence

__all__ = ["FROM_REST_S", "graph_playable", "from_rest", "graph_run_trajectory"]

#: s, the ramp from rest to a run's first sample
FROM_REST_S = 2e-3   # = CharacterisationSettings.step_ramp: an amplifier-like 200 V/ms edge


def _ramp_staircase(start: ArrayLike, end: ArrayLike, n: int, fs: float, axes: tuple[str, ...]) -> Staircase:
    a, b = np.asarray(start, float), np.asarray(end, float)
    levels = [tuple((a + (k + 1) / n * (b - a)).tolist()) for k in range(n)]
    return Staircase(levels=levels, dwell=1.0 / fs, axes=axes)


def _table_file(traj: Trajectory, fs: float, table_dir: Path) -> Table:
    """``traj``'s samples at rate ``fs`` written to ``table_dir`` (``.npy``, named by their hash) as a ``Table``."""
    _, v = traj.sample(fs)
    v = np.ascontiguousarray(v, dtype=float)
    table_dir.mkdir(parents=True, exist_ok=True)
    path = table_dir / f"{traj.kind}_{hashlib.sha256(v.tobytes()).hexdigest()[:16]}.npy"
    if not path.exists():
        np.save(path, v, allow_pickle=False)
    return Table(file=str(path.resolve()), sample_rate=fs, axes=traj.axes)


def graph_playable(traj: Trajectory, fs: float, table_dir: Path | str) -> Trajectory:
    """The same samples at rate ``fs`` as a trajectory the trajectory node can build (``to_dict``/``from_dict``).

    Parameters
    ----------
    traj : Trajectory
        A characterisation preset (``Sum``, ``Ramp``, a ``TrajectorySequence`` of them, or any graph type).
    fs : float
        The rate the graph plays at [Hz].
    table_dir : path
        Where a ``Sum`` with no graph type is written as a ``.npy`` table (played sample-exactly as a ``Table``).

    Returns
    -------
    Trajectory
        A quarter-period two-axis sine ``Sum`` becomes a ``Circle``, a ``Ramp`` a one-level-per-sample
        ``Staircase``, any other ``Sum`` a ``Table`` file; graph types as they are.

    Raises
    ------
    ValueError
        For a type with no graph equivalent.
    """
    if isinstance(traj, TrajectorySequence):
        return TrajectorySequence([(n, graph_playable(t, fs, table_dir), m) for n, t, m in traj.segments_],
                                  axes=traj.axes)
    if isinstance(traj, Ramp):
        return _ramp_staircase(traj.start, traj.end, int(traj.n_samples(fs)), fs, traj.axes)
    if isinstance(traj, Sum):
        parts = traj.parts
        if (len(traj.axes) == 2 and len(parts) == 2 and all(isinstance(p, Sine) for p in parts)
                and [p.axis for p in parts] == list(traj.axes)
                and parts[0].amplitude == parts[1].amplitude and parts[0].frequency == parts[1].frequency
                and parts[0].duration == parts[1].duration and parts[0].offset == parts[1].offset == 0
                and math.isclose(parts[1].phase - parts[0].phase, math.pi / 2)):
            p = parts[0]
            return Circle(radius=p.amplitude, frequency=p.frequency, phase=p.phase,
                          revolutions=p.duration * p.frequency, axes=traj.axes)
        return _table_file(traj, fs, Path(table_dir))
    if traj.kind in TRAJECTORY_TYPES:
        return traj
    raise ValueError(f"graph_playable: trajectory type {traj.kind!r} has no graph equivalent")


def from_rest(name: str, traj: Trajectory, fs: float, ramp: float) -> Trajectory:
    """``traj`` preceded by a ramp from 0 to its first sample when that is not 0."""
    first = traj.block(0, 1, fs)[0]
    if not np.any(first) or ramp <= 0:
        return traj
    n = max(1, int(round(ramp * fs)))
    zero = tuple(0.0 for _ in traj.axes)
    return TrajectorySequence([("from_rest", _ramp_staircase(zero, first, n, fs, traj.axes)), (name, traj)],
                              axes=traj.axes)


def graph_run_trajectory(name: str, traj: Trajectory, fs: float, table_dir: Path | str,
                         ramp: float = FROM_REST_S) -> Trajectory:
    """What the graph rig plays for the characterisation run ``name``: ``traj`` as graph types, from rest.

    The driver is reset to rest before each run: a run that starts elsewhere is reached by a ``ramp`` s ramp,
    which stays part of the run (the hysteresis state it builds is the run's initial state).  The recorded run
    (voltages and displacements) therefore has exactly these samples.

    Parameters
    ----------
    name : str
        The run's name (the segment the recorder names).
    traj : Trajectory
        The planned run.
    fs : float
        The rate the graph plays at [Hz].
    table_dir : path
        Where a signal with no graph type is written as a ``.npy`` table (see :func:`graph_playable`).
    ramp : float
        Seconds of the ramp from rest (0: none).

    Returns
    -------
    Trajectory
    """
    return from_rest(name, graph_playable(traj, fs, table_dir), fs, ramp)
