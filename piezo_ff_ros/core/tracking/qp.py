"""A small dense convex QP, ``min ½xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u``, by ADMM (the OSQP iteration).

Why here: no QP solver is among the dependencies, and scipy's general solvers (SLSQP, trust-constr) take tenths
of a second on the preview stage's problems, which recur every few milliseconds of signal.  The preview problems
are small (≈ 100 variables), and their P and A do not change between solves, so the KKT matrix is factorised once.
The result is cross-checked in the tests against ``scipy.optimize.lsq_linear`` (box constraints) and SLSQP.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["QPSolver", "QPResult"]


def _big(*vs: np.ndarray) -> float:
    """Largest absolute entry over ``vs`` (0 for empty arrays): the scale of the residual tolerances."""
    return max(np.max(np.abs(v), initial=0.0) for v in vs)  # type: ignore[no-any-return]  # numpy max is Any

@dataclass(frozen=True)
class QPResult:
    """Solution ``x``, multipliers ``y``, iterations used, and the final primal/dual residuals (∞-norm)."""

    x: np.ndarray
    y: np.ndarray
    iterations: int
    primal_residual: float
    dual_residual: float
    converged: bool


class QPSolver:
    """ADMM for ``min ½xᵀPx + qᵀx s.t. l ≤ Ax ≤ u`` with P, A fixed and q, l, u given per solve.

    Rows of A are scaled to unit norm (bounds scaled alike) and ρ is set to ``rho_scale`` times the ratio that makes
    ρ·AᵀA match P in scale (active constraints dominate the preview problems: a stiffer ρ converges faster); the
    matrix ``P + σI + ρAᵀA`` is Cholesky-factorised once.

    Parameters
    ----------
    P : ndarray [n, n]
        Symmetric positive semidefinite.
    A : ndarray [m, n]
        Constraint matrix.
    eps_abs, eps_rel : float
        Stopping tolerances on the primal and dual residuals (OSQP's definition).
    max_iter : int
        Iteration cap (the last iterate is returned, ``converged=False``).
    """

    def __init__(self, P: np.ndarray, A: np.ndarray, eps_abs: float = 1e-6, eps_rel: float = 1e-6,
                 max_iter: int = 4000, sigma: float = 1e-8, alpha: float = 1.6, rho_scale: float = 10.0):
        self.P = np.asarray(P, float)
        A = np.asarray(A, float)
        norms = np.linalg.norm(A, axis=1)
        norms[norms == 0] = 1.0
        self.row_scale = 1.0 / norms
        self.A = A * self.row_scale[:, None]
        AtA = self.A.T @ self.A
        self.rho = rho_scale * (float(np.trace(self.P) / max(np.trace(AtA), 1e-300)) or 1.0)
        self.sigma = sigma * self.rho
        self.alpha = alpha
        self.eps_abs, self.eps_rel, self.max_iter = eps_abs, eps_rel, max_iter
        n = self.P.shape[0]
        self._chol = scipy.linalg.cho_factor(self.P + self.sigma * np.eye(n) + self.rho * AtA)

    def solve(self, q: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              x0: np.ndarray | None = None) -> QPResult:
        """Solve for one ``q``, ``l``, ``u`` (warm start from ``x0`` when given)."""
        q = np.asarray(q, float)
        lo = np.asarray(lower, float) * self.row_scale
        hi = np.asarray(upper, float) * self.row_scale
        if np.any(lo > hi):
            raise ValueError("QP: a lower bound exceeds its upper bound")
        A, P, rho, sig, a = self.A, self.P, self.rho, self.sigma, self.alpha
        x = np.zeros(P.shape[0]) if x0 is None else np.array(x0, float)
        z = np.clip(A @ x, lo, hi)
        y = np.zeros(A.shape[0])
        rp = rd = np.inf
        it = 0
        for it in range(1, self.max_iter + 1):
            xt = scipy.linalg.cho_solve(self._chol, sig * x - q + A.T @ (rho * z - y))
            zt = A @ xt
            x = a * xt + (1 - a) * x
            zr = a * zt + (1 - a) * z
            z_new = np.clip(zr + y / rho, lo, hi)
            y = y + rho * (zr - z_new)
            z = z_new
            if it % 10 == 0 or it == self.max_iter:
                Ax = A @ x
                Px = P @ x
                Aty = A.T @ y
                rp = float(np.max(np.abs(Ax - z), initial=0.0))
                rd = float(np.max(np.abs(Px + q + Aty), initial=0.0))
                tol_p = self.eps_abs + self.eps_rel * _big(Ax, z)
                tol_d = self.eps_abs + self.eps_rel * _big(Px, Aty, q)
                if rp <= tol_p and rd <= tol_d:
                    return QPResult(x, y * self.row_scale, it, rp, rd, True)
        return QPResult(x, y * self.row_scale, it, rp, rd, False)
