"""Plain JSON values from results holding numpy types: the one helper behind every command's ``--json``.

:func:`jsonable` turns any result (dicts, lists, numpy arrays and scalars, and the frozen result dataclasses) into
plain JSON values; :class:`JsonResult` is the base of those dataclasses, whose :meth:`JsonResult.to_json` gives the
dictionary a command prints (its keys are the dataclass's field names: a contract, see the commands' docs).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

__all__ = ["jsonable", "parse_order", "JsonResult"]


def jsonable(x: Any) -> Any:
    """Plain JSON value of ``x``.

    Parameters
    ----------
    x : object
        A result: dicts, lists, tuples, numpy arrays and scalars, :class:`JsonResult` instances (through their
        :meth:`~JsonResult.to_json`), strings, None.

    Returns
    -------
    object
        ``x`` with dict keys as strings, arrays/tuples as lists, numpy scalars as Python ones, non-finite floats as
        None (JSON has no NaN) and any other object as its ``str``.
    """
    if isinstance(x, JsonResult):
        return x.to_json()
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


@dataclasses.dataclass(frozen=True)
class JsonResult:
    """Base of the frozen result dataclasses: one :meth:`to_json` for all of them.

    A field whose ``metadata`` has ``{"json": False}`` stays out of the JSON (arrays, models); a field whose value
    is None and whose ``metadata`` has ``{"omit_none": True}`` is left out too (an optional key of the contract).
    Subclasses whose JSON has more structure override :meth:`to_json` and still return plain JSON values.
    """

    def to_json(self) -> dict[str, Any]:
        """The result as a dictionary of plain JSON values.

        Returns
        -------
        dict
            ``{field name: jsonable(value)}`` in field order.
        """
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if not f.metadata.get("json", True):
                continue
            value = getattr(self, f.name)
            if value is None and f.metadata.get("omit_none", False):
                continue
            out[f.name] = jsonable(value)
        return out


def parse_order(v: str | int) -> str | int:
    """A model-order option.

    Parameters
    ----------
    v : str or int
        ``"auto"`` or an integer (as text or a number).

    Returns
    -------
    str or int
        ``"auto"`` or the integer.
    """
    return v if v == "auto" else int(v)
