"""Controller order reduction: balanced truncation of a stable continuous state space.

The feedforward controller C(s) runs open loop, so it must be stable; balanced truncation of a stable system stays
stable and its error is bounded by twice the sum of the discarded Hankel singular values
(``‖C − C_r‖∞ ≤ 2 Σ_{i>r} σ_i``).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from control import StateSpace   # no type information: Any for mypy, documentation here

__all__ = ["ReductionError", "hankel_singular_values", "balanced_truncation", "truncation_error_bound"]


class ReductionError(RuntimeError):
    """The system cannot be reduced (unstable, or the routine failed)."""


def _stable_or_raise(sys: StateSpace, what: str) -> None:
    if sys.nstates == 0:
        return
    worst = float(np.max(np.linalg.eigvals(sys.A).real))
    if not worst < 0.0:
        raise ReductionError(f"{what} is not stable (largest pole real part {worst:.4g} rad/s); balanced truncation "
                             "needs a stable system and an open-loop feedforward controller must be stable")


def _ab09ad(sys: StateSpace, nr: int | None) -> tuple[Any, ...]:
    """SLICOT AB09AD (square-root balance & truncate) — the routine ``control.balred(method='truncate')`` calls
    for stable systems; called directly because it also returns the Hankel singular values."""
    from slycot import ab09ad

    n, m, p = sys.nstates, sys.ninputs, sys.noutputs
    try:
        out: tuple[Any, ...] = ab09ad("C", "B", "N", n, m, p, np.array(sys.A, float), np.array(sys.B, float),
                                      np.array(sys.C, float), nr=nr)
        return out
    except Exception as exc:  # slycot raises its own error types with the SLICOT info code
        raise ReductionError(f"balanced truncation (SLICOT AB09AD) failed: {exc}") from exc


def hankel_singular_values(sys: StateSpace) -> np.ndarray:
    """Hankel singular values of a stable continuous system, largest first.

    Computed by the square-root method (SLICOT AB09AD); ``control.hsvd`` forms the Gramian product explicitly and
    returns NaN for the tiny ones of a 38-state H∞ controller.

    Parameters
    ----------
    sys : control.StateSpace
        A stable continuous system.

    Returns
    -------
    numpy.ndarray
        The Hankel singular values, largest first.

    Raises
    ------
    ReductionError
        If ``sys`` is not stable or SLICOT fails.
    """
    _stable_or_raise(sys, "system")
    if sys.nstates == 0:
        return np.zeros(0)
    # nr=None: AB09AD picks the minimal order itself (no warning when it is below n) and still returns all σ_i
    return np.asarray(_ab09ad(sys, None)[4], float).copy()


def balanced_truncation(sys: StateSpace, order: int) -> tuple[StateSpace, np.ndarray]:
    """Balanced truncation of a stable continuous ``control.StateSpace`` to ``order`` states.

    If ``order`` ≥ the number of states, ``sys`` is returned unchanged.  AB09AD may return fewer states when ``sys``
    has fewer than ``order`` controllable-and-observable ones.

    Parameters
    ----------
    sys : control.StateSpace
        A stable continuous system.
    order : int
        Number of states to keep.

    Returns
    -------
    reduced : control.StateSpace
        The reduced system (same D: truncation, not singular perturbation).
    hsv : numpy.ndarray
        The Hankel singular values of ``sys``.

    Raises
    ------
    ReductionError
        If ``sys`` or the reduced system is not stable, or SLICOT fails.
    """
    import control

    _stable_or_raise(sys, "system to reduce")
    if order >= sys.nstates:
        return sys, hankel_singular_values(sys)
    nr, Ar, Br, Cr, hsv = _ab09ad(sys, int(order))
    reduced = control.ss(Ar[:nr, :nr], Br[:nr, :], Cr[:, :nr], np.array(sys.D, float))
    _stable_or_raise(reduced, "reduced system")
    return reduced, np.asarray(hsv, float).copy()


def truncation_error_bound(hsv: np.ndarray, order: int) -> float:
    """``2 Σ_{i>order} σ_i``: an upper bound on ``‖C − C_r‖∞`` after balanced truncation to ``order``.

    Parameters
    ----------
    hsv : numpy.ndarray
        Hankel singular values, largest first.
    order : int
        The reduced order.

    Returns
    -------
    float
        The bound.
    """
    return float(2.0 * np.sum(np.asarray(hsv)[order:]))
