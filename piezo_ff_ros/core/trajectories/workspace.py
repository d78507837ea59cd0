"""Peak values of a trajectory, the check of its peaks against a symmetric workspace ``±workspace_m``
(:func:`check_trajectory_peaks`) and the stage's reachable range (:func:`reachable_range`, the compensator's default
``reference_limit``; the compensator checks its ``[min, max]`` per axis box with
:func:`~piezo_ff_ros.core.parameter_book.check_box_parameter`)."""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from ..config import ConfigError
from .base import Trajectory
from .sequence import TrajectorySequence

__all__ = ["check_trajectory_peaks", "peak", "reachable_range", "REACH_MARGIN"]

#: the default reference limit is this many times the stage's static reach at the voltage limit: a reference beyond
#: it cannot be a position of this stage (a unit mistake, a corrupt sample), while every reachable one passes with
#: room for the hysteresis loop and model error
REACH_MARGIN = 2.0


def reachable_range(cfg: Any, margin: float = REACH_MARGIN) -> tuple[float, ...]:
    """The stage's reachable displacement per axis with a margin, flat ``[min_x, max_x, min_y, max_y, …]`` [m].

    The static gain from the voltages to the displacement, ``(K + Cr(0))·Dp`` (creep over the hysteresis' linear
    part), driven anywhere within ``±limits.voltage``: axis ``i`` reaches ``±Σ_j |G0_ij|·V``; the range is that
    widened by ``margin`` around its centre.

    Parameters
    ----------
    cfg : PiezoConfig
        The configuration (hysteresis ``Dp`` [m/V], creep ``K`` and ``Cr``, ``limits.voltage`` [V]).
    margin : float
        Factor on the half-width (≥ 1).

    Returns
    -------
    tuple of float
        ``[min, max]`` per axis [m], finite, ``min < max``.
    """
    dp = np.asarray(cfg.hysteresis.Dp, float)
    g0 = (np.asarray(cfg.creep.K, float) + np.asarray(cfg.creep.Cr.dc_gain(), float)) @ dp
    v = float(cfg.limits.voltage)
    centre = g0 @ np.full(dp.shape[1], float(cfg.limits.safe_voltage))
    half = np.abs(g0) @ np.full(dp.shape[1], v)
    half = np.maximum(half, 1e-12) * float(margin)
    return tuple(float(x) for c, h in zip(centre, half) for x in (c - h, c + h))


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


def check_trajectory_peaks(traj: Trajectory, workspace_m: float, voltage_limit: float | None = None,
                    prefix: str = "trajectory", fs: float = 20000.0) -> None:
    """Refuse a trajectory that leaves ``±workspace_m`` on any axis (ConfigError naming the field).

    Segments of a :class:`TrajectorySequence` whose meta says ``input: voltage`` (paper experiments on S0) or ``stage:
    hysteresis|plant`` (the commissioning's characterisation of S0, played through a bypassed compensator) are in
    volts and checked against ``±voltage_limit`` instead (skipped when it is None).
    ``workspace_m <= 0`` disables the check.
    """
    if workspace_m <= 0:
        return
    if isinstance(traj, TrajectorySequence):
        for i, (name, t, meta) in enumerate(traj.segments_):
            limit = workspace_m
            if _in_volts(meta):
                if voltage_limit is None:
                    continue
                limit = voltage_limit
            check_trajectory_peaks(t, limit, None,
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
