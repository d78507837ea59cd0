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
:class:`PRBS`, :class:`Multisine`, :class:`Chirp`, :class:`Hold`, :class:`Spiral`, :class:`Ramp`, :class:`Table`
(samples from an array or a file, played sample-exactly at their own rate); :class:`PerAxis` puts trajectories of
some axes side by side on a stage of N axes (:func:`helix`: a circle over a z ramp); :class:`TrajectorySequence`
concatenates named segments and says which segment a sample belongs to.  :func:`check_trajectory_peaks` refuses a
trajectory whose peak leaves ``±workspace_m`` on an axis.

Layout: :mod:`.base` (the :class:`Trajectory` base), :mod:`.shapes`, :mod:`.tables`, :mod:`.excitation`,
:mod:`.per_axis`, :mod:`.sequence`, :mod:`.spec` (:func:`from_dict`), :mod:`.workspace`
(:func:`check_trajectory_peaks`, :func:`peak`); every public name is re-exported here.
"""
from __future__ import annotations

from .base import Trajectory
from .excitation import PRBS, Chirp, Multisine
from .per_axis import PerAxis, Ramp, helix
from .sequence import Segment, TrajectorySequence
from .shapes import Circle, Hold, Raster, Sine, Spiral, Staircase, Step
from .spec import TRAJECTORY_TYPES, from_dict
from .tables import Table
from .workspace import check_trajectory_peaks, peak

__all__ = [
    "Trajectory", "Sine", "Step", "Staircase", "Circle", "Raster", "PRBS", "Multisine", "Chirp", "Hold",
    "TrajectorySequence", "Segment", "from_dict", "TRAJECTORY_TYPES", "Spiral", "Table", "check_trajectory_peaks",
    "peak",
    "PerAxis", "Ramp", "helix",
]
