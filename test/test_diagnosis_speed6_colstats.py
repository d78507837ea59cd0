"""The compiled column statistics of the diagnosis give numpy's numbers bit for bit, and the replay residual with them."""
from __future__ import annotations

import numpy as np
import pytest

from piezo_ff_ros.core.diagnosis.replay import (centered_difference, check_scale, column_means,
                                                 column_rms_about_mean, residual)

SHAPES = [(1, 2), (2, 2), (3, 2), (7501, 2), (100_000, 2), (1_000_003, 2), (5, 3), (40_000, 3), (10, 1),
          (20_000, 1), (64, 6)]


def _data(shape, seed):
    rng = np.random.default_rng(seed)
    # displacement-like: an offset far above the wiggle (the case where summation order shows in the last bits)
    return rng.standard_normal(shape) * 1e-7 + rng.uniform(-3e-5, 3e-5, shape[1])


@pytest.mark.parametrize("shape", SHAPES)
def test_column_means_equal_numpy_bit_for_bit(shape):
    x = _data(shape, 1)
    assert np.array_equal(column_means(x), x.mean(axis=0))


@pytest.mark.parametrize("shape", SHAPES)
def test_centered_difference_equals_numpy_bit_for_bit(shape):
    y, y_hat = _data(shape, 2), _data(shape, 3)
    r = y - y_hat
    assert np.array_equal(centered_difference(y, y_hat), r - r.mean(axis=0))


@pytest.mark.parametrize("shape", SHAPES)
def test_column_rms_equals_numpy_bit_for_bit(shape):
    x = _data(shape, 4)
    assert np.array_equal(column_rms_about_mean(x), np.sqrt(np.mean((x - x.mean(axis=0)) ** 2, axis=0)))


def test_other_layouts_and_types_give_numpy_numbers():
    base = _data((30_001, 4), 5)
    cases = [base[:, :2], base[::3, :2], np.asfortranarray(base[:, :2]), base.astype(np.float32),
             base[:, :2].tolist()]
    for x in cases:
        arr = np.asarray(x)
        assert np.array_equal(column_means(x), arr.mean(axis=0))
    y, y_hat = base[:, :2], base[:, 2:]          # strided views: the numpy path
    r = y - y_hat
    assert np.array_equal(centered_difference(y, y_hat), r - r.mean(axis=0))
    # a broadcast model output (one row) is the numpy path too
    one = base[:1, :2]
    r = base[:, :2] - one
    assert np.array_equal(centered_difference(np.ascontiguousarray(base[:, :2]), one), r - r.mean(axis=0))


@pytest.mark.parametrize("y_order,yhat_order", [("C", "C"), ("F", "C"), ("C", "F"), ("F", "F")])
def test_residual_keeps_numpys_numbers_and_layout(y_order, yhat_order):
    """A MATLAB record's columns are Fortran-ordered: whatever numpy lays ``y − ŷ`` out as, the result has its
    numbers and its layout (a later full-array sum adds in memory order)."""
    y = np.asarray(_data((50_001, 2), 10), order=y_order)
    y_hat = np.asarray(_data((50_001, 2), 11), order=yhat_order)
    r = y - y_hat
    want = r - r.mean(axis=0)
    got = centered_difference(y, y_hat)
    assert np.array_equal(got, want)
    assert (got.flags.c_contiguous, got.flags.f_contiguous) == (want.flags.c_contiguous, want.flags.f_contiguous)
    assert np.sum(got ** 2) == np.sum(want ** 2)


def test_long_columns_equal_numpy_bit_for_bit():
    x = _data((3_000_000, 2), 12)
    assert np.array_equal(column_means(x), x.mean(axis=0))


def test_non_finite_values_propagate_like_numpy():
    x = _data((1000, 2), 6)
    x[10, 1] = np.nan
    x[20, 0] = np.inf
    with np.errstate(invalid="ignore"):
        assert np.array_equal(column_means(x), x.mean(axis=0), equal_nan=True)
        r = x - np.ones_like(x)
        assert np.array_equal(centered_difference(x, np.ones_like(x)), r - r.mean(axis=0), equal_nan=True)


def test_replay_residual_is_the_numpy_expression():
    y, y_hat = _data((123_457, 2), 7), _data((123_457, 2), 8)
    r = np.asarray(y, float) - y_hat
    assert np.array_equal(residual(y, y_hat), r - r.mean(axis=0))


def test_check_scale_still_refuses_a_unit_mistake():
    from piezo_ff_ros.core.recording.run import RunData

    y_model = _data((20_000, 2), 9) * 100
    n = len(y_model)
    run = RunData(np.arange(n) / 1e4, np.zeros((n, 2)), y_model * 1e6, ("x", "y"))
    with pytest.raises(ValueError, match="implausible"):
        check_scale(run, y_model, "train")
    ok = RunData(np.arange(n) / 1e4, np.zeros((n, 2)), y_model * 1.1, ("x", "y"))
    check_scale(ok, y_model, "train")
