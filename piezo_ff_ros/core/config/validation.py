"""The error type of every config and the value checks the sections share: matrices, numbers, keys, bounds.

:class:`ConfigError` carries the dotted name of the offending field, and every message starts with it
(``hysteresis.Dp: singular matrix …``).  The helpers turn a YAML value into a checked one or raise that error:
``_matrix`` (shape, finiteness; a scalar or a diagonal given as a list), ``_number``, ``_integer``, ``_section``
(a mapping or nothing), ``_unknown_keys`` (a misspelt key is refused with the closest known one; public as
:func:`dataclass_from_mapping` for sections outside :mod:`.stages`), ``_bounded`` against the plausibility bounds of
a piezo actuator (``MAX_*``: values outside are unit mistakes, not actuators).
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence, TypeVar

import numpy as np

__all__ = ["ConfigError", "Matrix", "dataclass_from_mapping", "MAX_GAIN_M_PER_V", "MAX_HYSTERESIS_RATE",
           "MAX_LIMIT_VOLTAGE", "MAX_LIMIT_SLEW", "MAX_STALE_TIMEOUT", "MIN_SAMPLE_RATE", "MAX_SAMPLE_RATE",
           "VOLTAGE_UNITS"]


#: a matrix as a config holds it: rows of floats (hashable, immutable)
Matrix = tuple[tuple[float, ...], ...]


class ConfigError(ValueError):
    """A configuration value is invalid; ``field`` is its dotted name."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.reason = message


def _matrix(value: Any, name: str, shape: tuple[int, int] | None = None) -> Matrix:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(name, f"not a numeric matrix ({exc})") from None
    if a.ndim == 1 and shape is not None and shape[0] == shape[1] == a.size:
        a = np.diag(a)
    if a.ndim == 0 and shape is not None:
        a = np.full(shape, float(a)) if shape[0] != shape[1] else np.eye(shape[0]) * float(a)
    if a.ndim != 2:
        raise ConfigError(name, f"expected a matrix, got an array of {a.ndim} dimension(s)")
    if shape is not None and a.shape != shape:
        raise ConfigError(name, f"expected shape {shape[0]}x{shape[1]}, got {a.shape[0]}x{a.shape[1]}")
    if not np.all(np.isfinite(a)):
        raise ConfigError(name, "contains NaN or Inf")
    return tuple(tuple(float(v) for v in row) for row in a)


def _arr(m: Matrix) -> np.ndarray:
    return np.array(m, dtype=float)


# Plausibility bounds of a piezoelectric positioner (SI).  Values outside are unit mistakes (µm/V entered as m/V,
# kV, ms …), not actuators: refused with the field's name.
#: |Dp|, |A| entries [m/V]: piezo stacks and tubes give 1e-10…1e-6 m/V; amplified (flexure) stages up to ~2e-5 m/V
MAX_GAIN_M_PER_V = 1e-4
#: |B|, |Gamma|, |Delta1|, |Delta2| entries [1/V]: fitted values are 1e-4…1e-1 1/V (the paper: 0.0073); above this
#: the hysteresis would saturate within a fraction of a volt
MAX_HYSTERESIS_RATE = 10.0
#: |limits.voltage| [V]: piezo amplifiers stay under 1.5 kV
MAX_LIMIT_VOLTAGE = 2000.0
#: limits.slew [V/s]: 1e7 V/s already needs ~50 mA into a few nF
MAX_LIMIT_SLEW = 1e10
#: limits.stale_timeout [s]: longer than this and a dead stream is never noticed
MAX_STALE_TIMEOUT = 60.0
#: sample rates a piezo drive runs at [Hz] (the same range the importers accept for recorded data)
MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 100.0, 10.0e6
#: the only voltage unit of a config file (gains per volt, limits in volts)
VOLTAGE_UNITS = ("V",)


_T = TypeVar("_T")


def _unknown_keys(d: Mapping[Any, Any], allowed: Sequence[Any], prefix: str) -> None:
    """Refuse keys not in ``allowed`` (a misspelling must not be silently ignored), suggesting the closest one."""
    import difflib

    for key in d:
        if key not in allowed:
            name = f"{prefix}.{key}" if prefix else str(key)
            close = difflib.get_close_matches(str(key), [str(a) for a in allowed], n=1, cutoff=0.6)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ConfigError(name, f"unknown key; {hint}(allowed: {', '.join(sorted(map(str, allowed)))})")


def dataclass_from_mapping(cls: type[_T], d: Mapping[str, Any] | None, prefix: str) -> _T:
    """``cls(**d)`` for a config dataclass, refusing unknown keys (named ``prefix.key``, with the closest known one).

    Parameters
    ----------
    cls : type
        A dataclass whose fields are the allowed keys (its ``__post_init__`` validates the values).
    d : mapping or None
        The section as read from YAML or parameters (None: all defaults).
    prefix : str
        The section's name in error messages (``learning``, ``preview`` …).

    Returns
    -------
    An instance of ``cls``.
    """
    import dataclasses

    values = dict(d or {})
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]  # _T is any config dataclass
    _unknown_keys(values, names, prefix)
    return cls(**values)


def _section(d: Mapping[str, Any], key: str, prefix: str = "", required: bool = False) -> dict[str, Any]:
    """``d[key]`` as a dict (``{}`` when absent or null); ``ConfigError`` naming it if it is not a mapping."""
    name = f"{prefix}.{key}" if prefix else key
    v = d.get(key)
    if v is None:
        if required:
            raise ConfigError(name, "missing section")
        return {}
    if not isinstance(v, Mapping):
        raise ConfigError(name, f"expected a mapping of keys to values, got {type(v).__name__} {v!r}"[:200])
    return dict(v)


def _number(value: Any, name: str) -> float:
    """A real number (numeric strings such as YAML's ``1e-3`` included, booleans not)."""
    if isinstance(value, bool) or value is None:
        raise ConfigError(name, f"expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(name, f"expected a number, got {value!r}"[:200]) from None


def _integer(value: Any, name: str) -> int:
    """An integer; a float is accepted only when it is integral (``12.0``), never rounded (``12.5``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(name, f"expected an integer, got {value!r}")
    if isinstance(value, float) and not value.is_integer():
        raise ConfigError(name, f"expected an integer, got {value!r} (not rounded: say what you mean)")
    return int(value)


def _bounded(m: Matrix, name: str, bound: float, unit: str) -> None:
    a = np.abs(_arr(m))
    if a.size and a.max() > bound:
        i, j = np.unravel_index(int(np.argmax(a)), a.shape)
        raise ConfigError(name, f"entry ({i + 1},{j + 1}) = {_arr(m)[i, j]:.6g} {unit} is not plausible for a "
                                f"piezo actuator (|entry| ≤ {bound:g} {unit}); check the units "
                                "(units.length, SI at runtime)")
