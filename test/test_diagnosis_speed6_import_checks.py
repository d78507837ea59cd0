"""The importers' non-finite check (a finite column sum first, the mask only when the sum is not finite) names the
same column, row and count as before, and does not mistake an overflowing sum of finite values for a NaN/Inf."""
from __future__ import annotations

import numpy as np
import pytest

from piezo_ff_ros.core.recording.importers import check_run_arrays


def _arrays(n=5000):
    t = np.arange(n) / 1e4
    u = np.asfortranarray(np.stack([np.sin(t * 50) * 50, np.cos(t * 30) * 40], axis=1))   # MATLAB's layout
    y = np.ascontiguousarray(u * 1e-7)
    return t, u, y


def _check(t, u, y):
    check_run_arrays("rec", t, u, y, ["u_x", "u_y"], ["x", "y"], row_offset=1)


def test_clean_run_passes():
    _check(*_arrays())


@pytest.mark.parametrize("where,value,message", [
    ("y", np.nan, r"column 'y': NaN at row 124 \(2 non-finite value\(s\) in total\)"),
    ("u", np.inf, r"column 'u_y': Inf at row 124 \(2 non-finite value\(s\) in total\)"),
    ("u", -np.inf, r"column 'u_y': Inf at row 124 \(2 non-finite value\(s\) in total\)"),
    ("t", np.nan, r"column 't': NaN at row 124 \(2 non-finite value\(s\) in total\)"),
])
def test_non_finite_values_are_named(where, value, message):
    t, u, y = _arrays()
    arr = {"t": t, "u": u, "y": y}[where]
    if arr.ndim == 1:
        arr[123] = value
        arr[3000] = value
    else:
        arr[123, 1] = value
        arr[3000, 1] = value
    with pytest.raises(ValueError, match=message):
        _check(t, u, y)


def test_inf_and_minus_inf_in_one_column_are_found():
    """+Inf and −Inf sum to NaN: still not finite, still found (first one named)."""
    t, u, y = _arrays()
    u[10, 0], u[20, 0] = np.inf, -np.inf
    with pytest.raises(ValueError, match=r"column 'u_x': Inf at row 11 \(2 non-finite"):
        _check(t, u, y)


def test_an_overflowing_sum_of_finite_values_is_not_a_non_finite_value():
    t, u, y = _arrays()
    u[:, 0] = 1e308                       # the sum overflows, every value is finite: the voltage check speaks
    with pytest.raises(ValueError, match=r"column 'u_x': voltage 1e\+308 at row 1 is kV-scale"):
        _check(t, u, y)
