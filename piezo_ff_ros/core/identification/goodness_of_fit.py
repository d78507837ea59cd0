"""Goodness of fit as MATLAB ``compare`` reports it (normalised RMSE, in percent)."""
from __future__ import annotations

from typing import Callable, Collection, Hashable, Mapping, TypeVar

import numpy as np

__all__ = ["fit_percent", "rmse"]


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """``100·(1 − ‖y − ŷ‖ / ‖y − ȳ‖)`` per output column (MATLAB ``compare``/``goodnessOfFit('NRMSE')``).

    Parameters
    ----------
    y, y_hat : array [N] or [N, outputs]
        Measured and simulated outputs (same units).

    Returns
    -------
    numpy.ndarray
        One fit per output (100 = perfect, 0 = no better than the mean, negative = worse).  An output that does not
        vary (‖y − ȳ‖ = 0) gets NaN.
    """
    y = np.asarray(y, float)
    y_hat = np.asarray(y_hat, float)
    if y.shape != y_hat.shape:
        raise ValueError(f"fit_percent: shapes differ ({y.shape} vs {y_hat.shape})")
    if y.ndim == 1:
        y, y_hat = y[:, None], y_hat[:, None]
    num = np.linalg.norm(y - y_hat, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit: np.ndarray = np.where(den > 0, 100.0 * (1.0 - num / np.where(den > 0, den, 1.0)), np.nan)
    return fit


def rmse(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """Root-mean-square error per output column.

    Parameters
    ----------
    y, y_hat : array [N] or [N, outputs]
        Measured and simulated outputs (same units).

    Returns
    -------
    numpy.ndarray
        One RMSE per output, in the outputs' unit.
    """
    y = np.asarray(y, float)
    y_hat = np.asarray(y_hat, float)
    if y.ndim == 1:
        y, y_hat = y[:, None], y_hat[:, None]
    err: np.ndarray = np.sqrt(np.mean((y - y_hat) ** 2, axis=0))
    return err


_K = TypeVar("_K", bound=Hashable)
_M = TypeVar("_M")


def _quiet(msg: str) -> None:
    pass


def greedy_order_search(excited: Collection[_K], start_orders: Mapping[_K, int], max_order: int,
                        step: Callable[[int], int], fit_with: Callable[[dict[_K, int]], _M],
                        score: Callable[[_M], Mapping[_K, float]], tol: float, label: Callable[[_K, int], str],
                        say: Callable[[str], None] = _quiet) -> tuple[dict[_K, int], _M]:
    """Raise one entry's order at a time while its held-out fit improves by more than ``tol`` points.

    ``fit_with(orders) -> models``, ``score(models) -> {j: fit %}``, ``step(order) -> next order``,
    ``label(j, order) -> str`` for progress.  An entry whose raise does not pay is frozen; the search ends when a
    whole pass improves nothing (the paper stopped at orders 1–3 "when the matching percent does not anymore
    increase substantially").

    Parameters
    ----------
    excited : collection
        The entries whose order may rise.
    start_orders : mapping
        The starting order of every entry ``fit_with`` needs.
    max_order : int
        No entry goes above it.
    step, fit_with, score, label : callable
        See above.
    tol : float
        Minimum held-out fit gain [percentage points] for a raise to be kept.
    say : callable, optional
        Progress messages.

    Returns
    -------
    orders : dict
        The chosen order per entry.
    models
        ``fit_with(orders)``.
    """
    orders = dict(start_orders)
    models = fit_with(orders)
    cur = score(models)
    frozen: set[_K] = set()
    while True:
        improved = False
        for j in excited:
            if j in frozen or orders[j] >= max_order:
                continue
            trial = dict(orders)
            trial[j] = min(max_order, step(trial[j]))
            m2 = fit_with(trial)
            f2 = score(m2)
            gain = f2.get(j, -np.inf) - cur.get(j, -np.inf)
            say(f"{label(j, trial[j])}: held-out fit {f2.get(j, float('nan')):.2f} % (gain {gain:+.2f})")
            if gain > tol:
                orders, models, cur = trial, m2, f2
                improved = True
            else:
                frozen.add(j)
        if not improved:
            return orders, models
