"""Unit conversions, in one place.

Topics and the core API are SI (metres, volts, seconds — REP 103).  The paper prints its Bouc-Wen matrices in µm/V
and its displacements in µm; µm appear only in YAML files that say so (``units: {length: um}``) and in printed
reports and plots.
"""
from __future__ import annotations

from typing import TypeVar

import numpy as np

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
