"""Displacement-side candidates: regression on the base model's output (gain and cross-talk, the creep law, a
thermal drift).  They act on the output, so no re-simulation is needed and they fit on the whole training run
(every k-th row of a long one, see :data:`~.fit_common.MAX_REGRESSION_ROWS`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from .._jit import njit
from ..models import effects as fx
from .fit_common import FitContext, FitResult, _lin_per_axis, _rms, _stderr, _stride
from .replay import residual

__all__ = ["fit_gain_mismatch", "fit_creep_nonlinearity", "fit_thermal_drift"]


def fit_gain_mismatch(ctx: FitContext) -> FitResult:
    """Per-axis gains and cross-talk: each output's residual regressed on every axis' base output."""
    k = _stride(len(ctx.y))
    r0 = residual(ctx.y[::k], ctx.y_base[::k])
    n = ctx.cfg.n_axes
    yb = ctx.y_base[::k]
    regs = [np.repeat(yb[:, [j]], n, axis=1) for j in range(n)]  # reg j, column i = Ŷ_j (for output i)
    coef, res, se = _lin_per_axis(r0, regs)  # coef[j, i]: effect of Ŷ_j on output i
    E = coef.T
    g = 1.0 + np.diag(E)
    C = E.copy()
    np.fill_diagonal(C, 0.0)
    se_m = se.T.copy()
    params = {"gains": g.tolist(), "cross_gains": C.tolist()}
    return FitResult("gain_mismatch", params, {"gains": np.diag(se_m).tolist(), "cross_gains": None},
                     [("gain_mismatch", params)], n * n, _rms(res))


@njit
def _creep_bank2(y: np.ndarray, a: np.ndarray, yref: float, S1: np.ndarray,
                 S2: np.ndarray) -> None:  # pragma: no cover - compiled
    """Σ_τ LP_τ(y) and Σ_τ LP_τ(y|y|/yref) per column, the relaxations started at rest (one pass)."""
    N, n = y.shape
    m = a.shape[0]
    for j in range(n):
        s1 = np.zeros(m)
        s2 = np.zeros(m)
        for t in range(N):
            x = y[t, j]
            q = x * abs(x) / yref
            acc1 = 0.0
            acc2 = 0.0
            for i in range(m):
                s1[i] = a[i] * s1[i] + (1.0 - a[i]) * x
                s2[i] = a[i] * s2[i] + (1.0 - a[i]) * q
                acc1 += s1[i]
                acc2 += s2[i]
            S1[t, j] = acc1
            S2[t, j] = acc2


def _creep_regs(y_base: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The creep candidate's two regressors: the log-time relaxation bank of :class:`~..models.effects.
    CreepNonlinearity` applied to Ŷ and to Ŷ|Ŷ|/Y_ref (what ``CreepNonlinearity(γ=1, β=0)`` adds to its input)."""
    y = np.ascontiguousarray(y_base, dtype=float)
    a = np.exp(-dt / np.asarray(fx.CREEP_TAUS, float))
    S1 = np.empty_like(y)
    S2 = np.empty_like(y)
    _creep_bank2(y, a, fx.CREEP_YREF, S1, S2)
    return S1, S2


def fit_creep_nonlinearity(ctx: FitContext) -> FitResult:
    """The level-dependent creep law: γ per axis and a shared β, by regression on the relaxation bank applied to
    Ŷ and to Ŷ|Ŷ|/Y_ref."""
    k = _stride(len(ctx.y))
    r0 = residual(ctx.y[::k], ctx.y_base[::k])
    S1, S2 = _creep_regs(ctx.y_base, ctx.dt)
    S1, S2 = S1[::k], S2[::k]
    coef, _, _ = _lin_per_axis(r0, [S1, S2])
    g1, g2 = coef
    beta = float(np.sum(g1 * g2) / max(np.sum(g1 * g1), 1e-300))
    beta = float(np.clip(beta, -50.0, 50.0))
    # γ per axis with β shared: regress on S1 + β S2, then the joint Jacobian for the uncertainties
    Sb = S1 + beta * S2
    c, res, _ = _lin_per_axis(r0, [Sb])
    gamma = c[0]
    n = ctx.cfg.n_axes
    cols = []
    for i in range(n):
        col = np.zeros_like(r0)
        col[:, i] = -(Sb[:, i] - Sb[:, i].mean())
        cols.append(col.reshape(-1))
    col = -(S2 - S2.mean(axis=0)) * gamma
    cols.append(col.reshape(-1))
    se = _stderr(np.column_stack(cols), res)
    params = {"gamma": gamma.tolist(), "beta": beta}
    return FitResult("creep_nonlinearity", params, {"gamma": se[:n].tolist(), "beta": float(se[n])},
                     [("creep_nonlinearity", params)], n + 1, _rms(res))


def fit_thermal_drift(ctx: FitContext) -> FitResult:
    """One exponential drift shared in time by the axes: its time constant on a log grid + refinement (closed-form
    residual energy), the amplitude per axis by regression."""
    k = _stride(len(ctx.y))
    r0 = residual(ctx.y[::k], ctx.y_base[::k])
    N = len(r0)
    T = len(ctx.y) * ctx.dt
    n = ctx.cfg.n_axes
    tk = np.arange(N) * ctx.dt * k  # times of the kept rows

    rc = r0 - r0.mean(axis=0)
    ss_r = float(np.sum(rc ** 2))

    def sse(log_tau: float) -> float:
        # one regressor shared by the axes: the least-squares residual energy in closed form
        shape = -np.expm1(-tk / math.exp(log_tau))
        shape -= shape.mean()
        ss = float(shape @ shape)
        if ss <= 0:
            return ss_r
        proj = shape @ rc
        return ss_r - float(np.sum(proj * proj)) / ss

    grid = np.log(T) + np.linspace(math.log(0.02), math.log(20.0), 13)
    vals = [sse(z) for z in grid]
    k = int(np.argmin(vals))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    z = optimize.minimize_scalar(sse, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3}).x if hi > lo \
        else grid[k]
    tau = math.exp(z)
    shape = -np.expm1(-tk / tau)
    coef, res, _ = _lin_per_axis(r0, [shape[:, None] * np.ones(n)])
    a = coef[0]
    # Jacobian over (a_1..a_n, log τ) for the uncertainties
    dshape = -np.exp(-tk / tau) * (tk / tau)
    cols = []
    for i in range(n):
        col = np.zeros_like(r0)
        col[:, i] = -(shape - shape.mean())
        cols.append(col.reshape(-1))
    cols.append((-(dshape - dshape.mean())[:, None] * a).reshape(-1))
    se = _stderr(np.column_stack(cols), res)
    params = {"amplitudes": a.tolist(), "time_constant": tau}
    return FitResult("thermal_drift", params, {"amplitudes": se[:n].tolist(), "time_constant": float(se[n] * tau)},
                     [("thermal_drift", params)], n + 1, _rms(res))
