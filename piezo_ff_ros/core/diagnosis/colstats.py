"""Per-column means of tall ``[N, axes]`` arrays in one compiled pass, with numpy's own numbers (pure).

``x.mean(axis=0)`` of a C-ordered ``[N, k]`` array (k ≥ 2) is one of numpy's slow reductions: the reduced axis is the
outer one, so numpy adds the rows one after the other through a k-element inner loop, ~15 ns a row — on a
diagnosis' 100 k-row fit windows ~1.5 ms per residual, ~0.7 s over the hundreds of replays of a 10-minute record.
It is also a plain sequential sum (row 0, then row 1, …; not numpy's pairwise summation, which applies to the
inner axis only), then one division by N.  The compiled loops here add the rows in that same order and divide
once, so they give the same numbers bit for bit (``test/test_diagnosis_speed6_colstats.py``), ~15× faster.  Any
other array (another dtype or layout, one column, no rows, numba missing) goes to numpy.
"""
from __future__ import annotations

import numpy as np

from .._jit import HAVE_NUMBA, njit

__all__ = ["column_means", "centered_difference", "column_rms_about_mean"]


@njit
def _column_sums(x: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Row by row, as numpy's outer-axis reduction adds them."""
    n, k = x.shape
    s = np.zeros(k)
    if k == 2:  # the two-axis case in registers
        s0 = 0.0
        s1 = 0.0
        for i in range(n):
            s0 += x[i, 0]
            s1 += x[i, 1]
        s[0] = s0
        s[1] = s1
        return s
    for i in range(n):
        for j in range(k):
            s[j] += x[i, j]
    return s


@njit
def _centered_square_sums(x: np.ndarray, m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    n, k = x.shape
    s = np.zeros(k)
    for i in range(n):
        for j in range(k):
            d = x[i, j] - m[j]
            s[j] += d * d
    return s


def _fast(x: np.ndarray) -> bool:
    """Whether ``x`` is an array numpy reduces row by row over axis 0 (then the compiled loops give its numbers)."""
    return (HAVE_NUMBA and isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 2
            and x.shape[0] > 0 and x.shape[1] >= 2 and x.flags.c_contiguous)


def column_means(x: np.ndarray) -> np.ndarray:
    """``x.mean(axis=0)``, the same numbers (compiled for a C-ordered float ``[N, k ≥ 2]`` array).

    Parameters
    ----------
    x : ndarray
        ``[N, k]``.

    Returns
    -------
    ndarray
        ``[k]``.
    """
    if not _fast(x):
        out: np.ndarray = np.asarray(x).mean(axis=0)
        return out
    res: np.ndarray = _column_sums(x) / x.shape[0]
    return res


def centered_difference(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """``r − r.mean(axis=0)`` with ``r = y − ŷ``: the numbers and the memory layout of the numpy expression (``r`` as
    numpy lays it out, its column means by :func:`column_means`, removed in place: one temporary less).

    Parameters
    ----------
    y, y_hat : ndarray
        ``[N, k]`` (``y_hat`` may broadcast).

    Returns
    -------
    ndarray
        ``[N, k]``, each column's mean removed.
    """
    r: np.ndarray = np.asarray(y, float) - y_hat
    r -= column_means(r)
    return r


def column_rms_about_mean(x: np.ndarray) -> np.ndarray:
    """``np.sqrt(np.mean((x − x.mean(axis=0)) ** 2, axis=0))``, the same numbers, without the temporaries.

    Parameters
    ----------
    x : ndarray
        ``[N, k]``.

    Returns
    -------
    ndarray
        ``[k]``: each column's RMS about its mean.
    """
    x = np.asarray(x, float)
    if not _fast(x):
        out: np.ndarray = np.sqrt(np.mean((x - x.mean(axis=0)) ** 2, axis=0))
        return out
    m = _column_sums(x) / x.shape[0]
    res: np.ndarray = np.sqrt(_centered_square_sums(x, m) / x.shape[0])
    return res
