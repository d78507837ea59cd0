"""Trajectory specs (plain dictionaries: ROS parameters, YAML) to trajectories: :func:`from_dict`."""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

from ..config import ConfigError
from ..units import length_scale
from .base import Trajectory
from .excitation import Chirp, Multisine, PRBS
from .per_axis import PerAxis, Ramp
from .sequence import TrajectorySequence
from .shapes import Circle, Hold, Raster, Sine, Spiral, Staircase, Step
from .tables import Table

__all__ = ["TRAJECTORY_TYPES", "from_dict"]


TRAJECTORY_TYPES = {cls.kind: cls for cls in (Hold, Sine, Step, Staircase, Circle, Raster, PRBS, Multisine, Chirp,
                                              Spiral, Table, Ramp)}


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
            return TrajectorySequence(segs, axes=d.get("axes"))
        except ConfigError as exc:
            raise ConfigError(f"{prefix}.{exc.field}", exc.reason) from None
    if kind == "per_axis":
        unknown = set(d) - {"parts", "axes"}
        if unknown:
            raise ConfigError(f"{prefix}.{sorted(unknown)[0]}", "unknown key for a per_axis trajectory (parts, axes)")
        parts = d.get("parts")
        if not isinstance(parts, (list, tuple)):
            raise ConfigError(f"{prefix}.parts", "expected a list of trajectories, each with its own axes")
        try:
            return PerAxis([from_dict(q, prefix=f"{prefix}.parts[{i}]") if isinstance(q, Mapping) else q
                            for i, q in enumerate(parts)], axes=d.get("axes"))
        except ConfigError as exc:
            raise ConfigError(f"{prefix}.{exc.field}", exc.reason) from None
    if kind not in TRAJECTORY_TYPES:
        raise ConfigError(f"{prefix}.type", f"unknown trajectory type {kind!r}; use one of "
                                            f"{sorted(TRAJECTORY_TYPES) + ['per_axis', 'sequence']}")
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
