"""Unit conversions, in one place (and the sample period on the topics' whole-nanosecond grid).

Topics and the core API are SI (metres, volts, seconds — REP 103).  The paper prints its Bouc-Wen matrices in µm/V
and its displacements in µm; µm appear only in YAML files that say so (``units: {length: um}``) and in printed
reports and plots.
"""
from __future__ import annotations

from typing import TypeVar

import numpy as np

__all__ = ["LENGTH_SCALE", "UM", "length_scale", "to_um", "sample_period_ns"]

LENGTH_SCALE = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "nm": 1e-9}

UM = 1e-6  #: one micrometre in metres


def length_scale(unit: str) -> float:
    """Metres per ``unit`` (``'um'`` → 1e-6)."""
    try:
        return LENGTH_SCALE[unit]
    except KeyError:
        raise ValueError(f"unknown length unit {unit!r}; use one of {sorted(LENGTH_SCALE)}") from None


_X = TypeVar("_X", float, np.ndarray)


def to_um(x: _X) -> _X:
    """Metres → micrometres (for reports and plots only).

    Parameters
    ----------
    x : float or ndarray
        Length(s) in metres.

    Returns
    -------
    float or ndarray
        The same length(s) in micrometres.
    """
    return x / UM


def sample_period_ns(sample_rate: float) -> int:
    """Sample period in integer nanoseconds, ``round(1e9 / fs)`` (50 000 at 20 kHz).

    Raises ``ValueError`` when ``fs`` is not positive and finite, or when the period is not a whole number of
    nanoseconds (to within float rounding: stamps would otherwise drift from ``k / fs``).
    """
    fs = float(sample_rate)
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"sample_rate: must be positive and finite, got {sample_rate!r}")
    dt_ns = round(1e9 / fs)
    if dt_ns < 1 or abs(dt_ns - 1e9 / fs) > 1e-6:   # float rounding only: no drift from k/fs
        raise ValueError(f"sample_rate: {fs} Hz has no whole-nanosecond period (1e9/fs = {1e9 / fs!r} ns); "
                         "choose a rate that divides 1e9")
    return int(dt_ns)
