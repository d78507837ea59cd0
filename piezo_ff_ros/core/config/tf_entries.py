"""Transfer-function matrix entries of a config: YAML ``{xy: {k, num, den}, …}`` ↔ ``TFMatrix``, checked.

``creep.Cr`` and ``dynamics.G_L`` are n×n matrices of factored transfer functions
(:class:`~piezo_ff_ros.core.transfer.TFMatrix`).  In YAML an entry is named by its output and input axes (``xy``,
``x,y`` or ``x_y``) or given as a nested list; an absent or zero entry is zero.  ``_tf_matrix_from_dict`` parses and
checks the factors (finite, non-zero leading coefficient), ``_tf_matrix_to_dict`` writes the non-zero entries back,
``_check_tf_matrix`` refuses an improper, unstable or (where required) not strictly proper entry, named by its dotted
field (``dynamics.G_L.xy``).  These helpers are private to the config package (:mod:`.stages`, :mod:`.piezo`).
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..transfer import FactoredTF, TFMatrix
from .validation import ConfigError, _unknown_keys


def _tf_matrix_from_dict(d: Any, axes: tuple[str, ...], prefix: str) -> TFMatrix:
    n = len(axes)
    rows = [[FactoredTF(0.0) for _ in range(n)] for _ in range(n)]
    if isinstance(d, (list, tuple)):
        if len(d) != n or any(len(r) != n for r in d):
            raise ConfigError(prefix, f"expected a {n}x{n} nested list of transfer functions")
        items: dict[tuple[int, int], Any] = {(i, j): d[i][j] for i in range(n) for j in range(n)}
    elif isinstance(d, Mapping):
        items = {}
        for key, val in d.items():
            pair = _axis_pair(str(key), axes)
            if pair is None:
                raise ConfigError(f"{prefix}.{key}", f"unknown entry; use '<out><in>' with axes {list(axes)}")
            items[pair] = val
    else:
        raise ConfigError(prefix, "expected a mapping like {xx: {k:…, num:…, den:…}, …}")
    for (i, j), val in items.items():
        name = f"{prefix}.{axes[i]}{axes[j]}"
        if val is None or val == 0:
            continue
        if not isinstance(val, Mapping):
            raise ConfigError(name, "expected {k: gain, num: [[…], …], den: [[…], …]}")
        _unknown_keys(val, ("k", "gain", "num", "den"), name)
        if "den" not in val:
            raise ConfigError(f"{name}.den", "missing (a non-zero entry needs a denominator)")
        try:
            tf = FactoredTF.from_dict(val)
        except (TypeError, ValueError) as exc:
            raise ConfigError(name, f"malformed factors ({exc})") from None
        for part, factors in (("num", tf.num), ("den", tf.den)):
            for f in factors:
                if len(f) == 0 or not all(math.isfinite(c) for c in f):
                    raise ConfigError(f"{name}.{part}", "factors must be non-empty finite polynomials")
                if f[0] == 0.0:
                    raise ConfigError(f"{name}.{part}", f"factor {list(f)} has a zero leading coefficient")
        if not math.isfinite(tf.gain):
            raise ConfigError(f"{name}.k", "not finite")
        rows[i][j] = tf
    return TFMatrix.from_nested(rows)


def _axis_pair(key: str, axes: tuple[str, ...]) -> tuple[int, int] | None:
    for i, a in enumerate(axes):
        for j, b in enumerate(axes):
            if key in (a + b, f"{a},{b}", f"{a}_{b}"):
                return i, j
    return None


def _tf_matrix_to_dict(tfm: TFMatrix, axes: tuple[str, ...]) -> dict[str, Any]:
    out = {}
    for i, a in enumerate(axes):
        for j, b in enumerate(axes):
            tf = tfm[i, j]
            if not tf.is_zero():
                out[f"{a}{b}"] = tf.to_dict()
    return out


def _check_tf_matrix(tfm: TFMatrix, prefix: str, axes: Sequence[str], strictly_proper: bool) -> None:
    n = len(axes)
    for i in range(n):
        for j in range(n):
            tf = tfm[i, j]
            if tf.is_zero():
                continue
            name = f"{prefix}.{axes[i]}{axes[j]}"
            rd = tf.relative_degree
            if rd < 0:
                raise ConfigError(name, "improper (numerator degree above denominator degree)")
            if strictly_proper and rd < 1:
                raise ConfigError(name, "must be strictly proper")
            p = tf.cancelled().poles()
            if np.any(p.real >= 0):
                raise ConfigError(name, f"unstable pole(s) {[complex(x) for x in p[p.real >= 0]]}")
            try:
                tf.modes()
            except ValueError as exc:
                raise ConfigError(name, str(exc)) from None
