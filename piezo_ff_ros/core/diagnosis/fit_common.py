"""What every candidate fit shares: its context (the training run under a base model), its result, the standard
errors from the Jacobian and the one-parameter grid-then-refine fit used by the voltage-side and hysteresis
families.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize

from ..config import PiezoConfig
from .replay import Windows, residual, simulate

__all__ = ["FitContext", "FitResult", "n_eff_ratio", "search_context", "MAX_REGRESSION_ROWS"]


@dataclass
class FitContext:
    """What every fit needs: the model, the base effects, the training data and the base model's output."""

    cfg: PiezoConfig
    base: list[Any]
    u: np.ndarray                 # training voltages [N, k]
    y: np.ndarray                 # measured displacements [N, n]
    y_base: np.ndarray            # base model output on the whole run [N, n]
    windows: Windows              # where voltage-side fits simulate
    # y on the windows, corrected for the windows' truncated history
    target: np.ndarray = None     # type: ignore[assignment]  # always set by __post_init__
    y_base_win: np.ndarray = None  # type: ignore[assignment]  # always set by __post_init__
    cache: dict[Any, Any] = field(default_factory=dict)  # shared between the candidates fitted on this context

    def __post_init__(self) -> None:
        if self.windows.is_whole:
            self.target = self.y
            self.y_base_win = self.y_base
        else:
            self.y_base_win = simulate(self.cfg, self.u, self.base, self.windows)
            # the nominal error made by starting each window at rest is the same for every candidate: remove it
            self.target = self.windows.take(self.y) - self.windows.take(self.y_base) + self.y_base_win

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return self.cfg.dt

    def sim_residual(self, extra: Sequence[Any]) -> np.ndarray:
        """Residual on the windows of the base model plus ``extra`` effects, ``[(name, params)]``."""
        return residual(self.target, simulate(self.cfg, self.u, list(self.base) + list(extra), self.windows))


@dataclass
class FitResult:
    """One candidate's fit: parameters, their standard errors, the effects to append and the training RMS."""

    effect: str
    params: dict[str, Any]
    stderr: dict[str, Any]
    effects: list[Any]            # [(name, params)] to append to the base model
    n_params: int
    train_rms: float              # RMS residual on the fitted samples [m]
    note: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def n_eff_ratio(r: np.ndarray) -> float:
    """``N / N_eff`` for an autocorrelated residual (lag-1 AR approximation, averaged over axes), ≥ 1."""
    r = np.asarray(r, float)
    if len(r) < 3:
        return 1.0
    num = np.sum(r[1:] * r[:-1], axis=0)
    den = np.maximum(np.sum(r * r, axis=0), 1e-300)
    rho = float(np.clip(np.mean(num / den), 0.0, 0.999))
    return min((1 + rho) / (1 - rho), len(r) / 10.0)


def _stderr(J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Standard errors ``sqrt(diag(s²(JᵀJ)⁻¹)·N/N_eff)``; ``J`` is ∂r/∂θ over the flattened residual ``r``."""
    rf = r.reshape(-1)
    n, p = J.shape
    s2 = float(rf @ rf) / max(n - p, 1)
    try:
        cov = np.linalg.pinv(J.T @ J) * s2 * n_eff_ratio(r)
    except np.linalg.LinAlgError:  # pragma: no cover
        return np.full(p, np.nan)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


#: regressions of displacement-side effects use at most this many rows (every k-th sample of a long run): the
#: regressors are computed on the whole run, only the least-squares rows are thinned
MAX_REGRESSION_ROWS = 400_000


def _stride(n: int) -> int:
    return max(1, -(-n // MAX_REGRESSION_ROWS))


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(r) ** 2)))


def _lin_per_axis(y: np.ndarray, regs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per axis i: least squares ``y_i − mean ≈ Σ_k c_ki·(reg_k,i − mean)``; returns coeffs [K, n], residual, std."""
    n = y.shape[1]
    K = len(regs)
    coef = np.zeros((K, n))
    se = np.zeros((K, n))
    res = np.empty_like(y)
    for i in range(n):
        X = np.column_stack([g[:, i] - g[:, i].mean() for g in regs])
        t = y[:, i] - y[:, i].mean()
        c, *_ = np.linalg.lstsq(X, t, rcond=None)
        coef[:, i] = c
        res[:, i] = t - X @ c
        se[:, i] = _stderr(-X, res[:, [i]])
    return coef, res, se


def _fit_scalar(ctx: FitContext, name: str, pname: str, make: Callable[[float], dict[str, Any]], grid: np.ndarray,
                to_value: Callable[[float], float], dvalue: Callable[[float], float],
                fine: Callable[[float], np.ndarray] | None = None) -> FitResult:
    """Grid over a transformed parameter ``z``, optionally a finer grid ``fine(best)`` around the best point (for
    costs that are not unimodal between grid points), then a bounded refinement around the best point."""
    cache: dict[float, tuple[float, np.ndarray]] = {}

    def sse(z: float) -> float:
        z = float(z)
        if z not in cache:
            r = ctx.sim_residual([(name, make(z))])
            cache[z] = (float(np.sum(r ** 2)), r)
        return cache[z][0]

    vals = [sse(z) for z in grid]
    k = int(np.argmin(vals))
    if fine is not None:
        grid = np.unique(np.r_[grid, fine(float(grid[k]))])
        vals = [sse(z) for z in grid]
        k = int(np.argmin(vals))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    if hi > lo:
        sol = optimize.minimize_scalar(sse, bounds=(lo, hi), method="bounded",
                                       options={"xatol": 1e-3 * (hi - lo), "maxiter": 14})
        z = float(sol.x) if sol.fun <= vals[k] else float(grid[k])
    else:
        z = float(grid[k])
    r = cache[z][1] if z in cache else ctx.sim_residual([(name, make(z))])
    # Jacobian by a central difference in z
    h = 1e-3 * max(hi - lo, 1e-6)
    rp = ctx.sim_residual([(name, make(z + h))])
    rm = ctx.sim_residual([(name, make(z - h))])
    J = ((rp - rm) / (2 * h)).reshape(-1, 1)
    se_z = _stderr(J, r)[0]
    value = to_value(z)
    p = make(z)
    return FitResult(name, {pname: value}, {pname: float(abs(dvalue(z)) * se_z)}, [(name, p)], 1, _rms(r),
                     extra={"grid": [float(to_value(g)) for g in grid], "grid_sse": vals})


def search_context(ctx: FitContext) -> FitContext:
    """The context a search over a nonlinear parameter runs on: every other fit window of a long run (the windows
    are spread evenly over TRAIN, so half of them see the same excitation; the found parameter is then evaluated on
    all of them), ``ctx`` itself when there are two windows or fewer.  Each trial replays the model, so the search
    costs half."""
    spans = ctx.windows.spans
    if len(spans) <= 2:
        return ctx
    return FitContext(ctx.cfg, list(ctx.base), ctx.u, ctx.y, ctx.y_base, Windows(spans[::2]))
