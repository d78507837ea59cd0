"""Plain JSON values from results holding numpy types (one helper for every command's ``--json``)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["jsonable", "parse_order"]


def jsonable(x: Any) -> Any:
    """``x`` with dict keys as strings, arrays/tuples as lists, numpy scalars as Python ones, non-finite floats as
    None (JSON has no NaN) and any other object as its ``str``."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, (np.integer, int)):
        return int(x)
    if x is None or isinstance(x, str):
        return x
    return str(x)


def parse_order(v: str | int) -> str | int:
    """A model-order option: ``"auto"`` or an integer."""
    return v if v == "auto" else int(v)
