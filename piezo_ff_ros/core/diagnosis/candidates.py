"""Fitting the candidate unmodelled effects on the training run (scipy least squares, few parameters each).

Every candidate is fitted on top of a *base* model (the nominal one, or the nominal one with effects already
accepted) and returns its parameters, their standard errors from the Jacobian (inflated by the residual's
correlation, see :func:`_stderr`) and the effect list to add to the base.

Displacement-side effects (gain, creep, drift, mode) act on the base model's output, so they are fitted by (mostly
linear) regression on that output: cheap, and run on the whole training run.  Voltage-side and hysteresis effects
need the model re-run for every trial value; they are fitted on :class:`~.replay.Windows` of the training run
(the whole run when it is short), with a coarse grid followed by a bounded refinement (1 parameter) or
``scipy.optimize.least_squares`` (several).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import optimize

from ..config import PiezoConfig
from ..models import effects as fx
from .replay import Windows, residual, simulate

__all__ = ["FitContext", "FitResult", "fit_candidate", "CANDIDATES", "n_eff_ratio"]


@dataclass
class FitContext:
    """What every fit needs: the model, the base effects, the training data and the base model's output."""

    cfg: PiezoConfig
    base: list
    u: np.ndarray                 # training voltages [N, k]
    y: np.ndarray                 # measured displacements [N, n]
    y_base: np.ndarray            # base model output on the whole run [N, n]
    windows: Windows              # where voltage-side fits simulate
    target: np.ndarray = None     # y on the windows, corrected for the windows' truncated history
    y_base_win: np.ndarray = None

    def __post_init__(self):
        if self.windows.is_whole:
            self.target = self.y
            self.y_base_win = self.y_base
        else:
            self.y_base_win = simulate(self.cfg, self.u, self.base, self.windows)
            # the nominal error made by starting each window at rest is the same for every candidate: remove it
            self.target = self.windows.take(self.y) - self.windows.take(self.y_base) + self.y_base_win

    @property
    def dt(self) -> float:
        return self.cfg.dt

    def sim_residual(self, extra: Sequence) -> np.ndarray:
        return residual(self.target, simulate(self.cfg, self.u, list(self.base) + list(extra), self.windows))


@dataclass
class FitResult:
    effect: str
    params: dict
    stderr: dict
    effects: list                 # [(name, params)] to append to the base model
    n_params: int
    train_rms: float              # RMS residual on the fitted samples [m]
    note: str = ""
    extra: dict = field(default_factory=dict)


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


def _rms(r) -> float:
    return float(np.sqrt(np.mean(np.asarray(r) ** 2)))


# ----------------------------------------------------------------------------------------------------------------
# Displacement-side effects: regression on the base model's output
# ----------------------------------------------------------------------------------------------------------------

def _lin_per_axis(y: np.ndarray, regs: list[np.ndarray]):
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


def fit_gain_mismatch(ctx: FitContext) -> FitResult:
    k = _stride(len(ctx.y))
    r0 = residual(ctx.y[::k], ctx.y_base[::k])
    coef, res, se = _lin_per_axis(r0, [ctx.y_base[::k]])
    g = 1.0 + coef[0]
    return FitResult("gain_mismatch", {"gains": g.tolist()}, {"gains": se[0].tolist()},
                     [("gain_mismatch", {"gains": g.tolist()})], ctx.cfg.n_axes, _rms(res))


def _creep_regs(y_base: np.ndarray, dt: float, beta: float | None = None):
    n = y_base.shape[1]
    lin = fx.CreepNonlinearity(np.ones(n), 0.0, dt, n)
    S1 = lin.process(y_base) - y_base
    q = y_base * np.abs(y_base) / fx.CREEP_YREF
    lin.reset()
    S2 = lin.process(q) - q
    return S1, S2


def fit_creep_nonlinearity(ctx: FitContext) -> FitResult:
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
    k = _stride(len(ctx.y))
    r0 = residual(ctx.y[::k], ctx.y_base[::k])
    N = len(r0)
    T = len(ctx.y) * ctx.dt
    n = ctx.cfg.n_axes
    tk = np.arange(N) * ctx.dt * k  # times of the kept rows

    def sse(log_tau):
        shape = -np.expm1(-tk / math.exp(log_tau))[:, None] * np.ones(n)
        _, res, _ = _lin_per_axis(r0, [shape])
        return float(np.sum(res ** 2))

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


def _mode_design(y_base, freq, damping, dt, windows: Windows | None):
    n = y_base.shape[1]
    st = fx.UnmodelledMode(freq, damping, np.zeros(n), dt, n)
    if windows is None or windows.is_whole:
        return st.bandpass(y_base)
    outs = []
    for w, s, e in windows.spans:
        st.reset()
        outs.append(st.bandpass(y_base[w:e])[s - w:])
    return np.concatenate(outs)


def fit_unmodelled_mode(ctx: FitContext) -> FitResult:
    r_full = residual(ctx.y, ctx.y_base)
    win = ctx.windows
    r0 = r_full if win.is_whole else residual(win.take(ctx.y), win.take(ctx.y_base))
    n = ctx.cfg.n_axes
    fs = 1.0 / ctx.dt
    T = len(ctx.y) * ctx.dt
    fmin = max(2.0, 20.0 / T)
    freqs = np.geomspace(fmin, 0.45 * fs, 40)
    best = (np.inf, None)
    rc = r0 - r0.mean(axis=0)
    for f in freqs:
        for z in (0.01, 0.05):
            X = _mode_design(ctx.y_base, f, z, ctx.dt, win)
            X = X - X.mean(axis=0)
            # closed-form per-axis regression: energy removed = <X, r>²/<X, X>
            v = -float(np.sum(np.sum(X * rc, axis=0) ** 2 / np.maximum(np.sum(X * X, axis=0), 1e-300)))
            if v < best[0]:
                best = (v, (f, z))
    f0, z0 = best[1]

    unit = max(_rms(r0), 1e-15)  # scipy's tolerances are absolute: work in units of the base RMS error

    def resid(theta):
        f, z = math.exp(theta[0]), math.exp(theta[1])
        X = _mode_design(ctx.y_base, f, z, ctx.dt, win)
        _, res, _ = _lin_per_axis(r0, [X])
        return res.reshape(-1) / unit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = optimize.least_squares(resid, [math.log(f0), math.log(z0)], diff_step=1e-3, max_nfev=40,
                                     bounds=([math.log(fmin), math.log(1e-3)], [math.log(0.49 * fs), math.log(2.0)]))
    f, z = math.exp(sol.x[0]), math.exp(sol.x[1])
    X = _mode_design(ctx.y_base, f, z, ctx.dt, win)
    coef, res, se_g = _lin_per_axis(r0, [X])
    se_log = _stderr(sol.jac, res / unit) if sol.jac is not None else np.full(2, np.nan)
    params = {"freq": f, "damping": z, "gains": coef[0].tolist()}
    return FitResult("unmodelled_mode", params,
                     {"freq": float(se_log[0] * f), "damping": float(se_log[1] * z), "gains": se_g[0].tolist()},
                     [("unmodelled_mode", params)], n + 2, _rms(res))


# ----------------------------------------------------------------------------------------------------------------
# Voltage-side and hysteresis effects: the model re-run per trial
# ----------------------------------------------------------------------------------------------------------------

def _fit_scalar(ctx: FitContext, name: str, pname: str, make: Callable[[float], dict], grid: np.ndarray,
                to_value: Callable[[float], float], dvalue: Callable[[float], float],
                fine: Callable[[float], np.ndarray] | None = None) -> FitResult:
    """Grid over a transformed parameter ``z``, optionally a finer grid ``fine(best)`` around the best point (for
    costs that are not unimodal between grid points), then a bounded refinement around the best point."""
    cache = {}

    def sse(z):
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


def fit_input_delay(ctx: FitContext) -> FitResult:
    # first guess from the delay signature: r ≈ −d·dŶ/dt
    r0 = residual(ctx.target, ctx.y_base_win)
    dy = np.gradient(ctx.y_base_win, ctx.dt, axis=0)
    dy -= dy.mean(axis=0)
    d0 = float(-np.sum(r0 * dy) / max(np.sum(dy * dy), 1e-300))
    dmax = max(50 * ctx.dt, 4 * abs(d0))
    grid = np.unique(np.r_[0.0, np.geomspace(0.25 * ctx.dt, dmax, 11), max(d0, 0.0)])
    dt = ctx.dt

    def fine(best):
        # linear interpolation makes the cost wiggle between whole samples: quarter-sample steps around the best
        return np.clip(best + dt * np.arange(-3.0, 3.01, 0.25), 0.0, None)

    return _fit_scalar(ctx, "input_delay", "delay", lambda z: {"delay": max(z, 0.0)}, grid,
                       lambda z: max(z, 0.0), lambda z: 1.0, fine=fine)


def fit_amplifier_slew_limit(ctx: FitContext) -> FitResult:
    rates = np.abs(np.diff(ctx.u, axis=0)) / ctx.dt
    rmax = float(rates.max()) if rates.size else 1.0
    lo = max(float(np.quantile(rates, 0.5)), 1e-3 * rmax, 1e-6)
    grid = np.linspace(math.log(lo), math.log(rmax * 1.05), 12)
    return _fit_scalar(ctx, "amplifier_slew_limit", "rate", lambda z: {"rate": math.exp(z)}, grid, math.exp,
                       math.exp)


def fit_amplifier_saturation(ctx: FitContext) -> FitResult:
    a = np.abs(ctx.u)
    amax = float(a.max())
    lo = float(np.quantile(a, 0.5))
    grid = np.linspace(max(lo, 1e-3 * amax), amax * 1.01, 12)
    return _fit_scalar(ctx, "amplifier_saturation", "limit", lambda z: {"limit": z}, grid, lambda z: z,
                       lambda z: 1.0)


def fit_amplifier_bandwidth(ctx: FitContext) -> FitResult:
    fs = 1.0 / ctx.dt
    # up to 10·fs, where the pole-matched filter is the identity to 1e-27: "no bandwidth limit" is on the grid
    grid = np.linspace(math.log(fs / 2000.0), math.log(10.0 * fs), 14)
    return _fit_scalar(ctx, "amplifier_bandwidth", "cutoff", lambda z: {"cutoff": math.exp(z)}, grid, math.exp,
                       math.exp)


def fit_hysteresis_rate_dependence(ctx: FitContext) -> FitResult:
    grid = np.array([-0.6, -0.3, -0.1, 0.0, 0.1, 0.3, 0.6, 1.2, 2.5, 5.0])
    return _fit_scalar(ctx, "hysteresis_rate_dependence", "alpha", lambda z: {"alpha": z}, grid, lambda z: z,
                       lambda z: 1.0)


def fit_hysteresis_asymmetry(ctx: FitContext) -> FitResult:
    n = ctx.cfg.n_axes
    B = np.abs(np.diag(ctx.cfg.hysteresis.arrays()["B"]))
    scale = np.r_[np.maximum(B, 1e-4), np.maximum(B, 1e-4)]

    def make(theta):
        d = theta * scale
        return {"Delta1": d[:n].tolist(), "Delta2": d[n:].tolist()}

    # residuals in units of the base model's RMS error: scipy's tolerances are absolute, metres are too small
    unit = max(_rms(residual(ctx.target, ctx.y_base_win)), 1e-15)

    def resid(theta):
        return ctx.sim_residual([("hysteresis_asymmetry", make(theta))]).reshape(-1) / unit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # unbounded trust region: the problem is nearly linear in Δ and converges in a few steps (bounds slow it)
        sol = optimize.least_squares(resid, np.zeros(2 * n), diff_step=1e-3, max_nfev=40)
    r = sol.fun.reshape(-1, n)
    se = _stderr(sol.jac, r) * scale
    p = make(sol.x)
    return FitResult("hysteresis_asymmetry", p, {"Delta1": se[:n].tolist(), "Delta2": se[n:].tolist()},
                     [("hysteresis_asymmetry", p)], 2 * n, _rms(r) * unit)


CANDIDATES: dict[str, Callable[[FitContext], FitResult]] = {
    "hysteresis_asymmetry": fit_hysteresis_asymmetry,
    "hysteresis_rate_dependence": fit_hysteresis_rate_dependence,
    "creep_nonlinearity": fit_creep_nonlinearity,
    "thermal_drift": fit_thermal_drift,
    "input_delay": fit_input_delay,
    "amplifier_slew_limit": fit_amplifier_slew_limit,
    "amplifier_saturation": fit_amplifier_saturation,
    "amplifier_bandwidth": fit_amplifier_bandwidth,
    "unmodelled_mode": fit_unmodelled_mode,
    "gain_mismatch": fit_gain_mismatch,
}


def fit_candidate(name: str, ctx: FitContext) -> FitResult:
    """Fit one candidate (a name from :data:`CANDIDATES`) on the training data of ``ctx``."""
    if name not in CANDIDATES:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(CANDIDATES)}")
    return CANDIDATES[name](ctx)
