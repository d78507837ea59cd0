"""Hysteresis candidates: the rate-widened loop with a relaxing hysteretic state, and the asymmetric loop (Δ1/Δ2
by least squares, then the even, branch-dependent and play-operator loop-width terms by regression).
"""
from __future__ import annotations

import math
import warnings
from typing import Any, Callable

import numpy as np
from scipy import optimize

from ..models import effects as fx
from .fit_common import FitContext, FitResult, _fit_scalar, _lin_per_axis, _rms, _stderr
from .replay import Windows, residual, simulate

__all__ = ["fit_hysteresis_rate_dependence", "fit_hysteresis_asymmetry", "RELAX_MIN_GAIN", "PLAY_FRACTIONS"]


#: a relaxation of the hysteretic state is kept when it lowers the training residual energy by this share
RELAX_MIN_GAIN = 0.02


def fit_hysteresis_rate_dependence(ctx: FitContext) -> FitResult:
    """The rate-widened loop (``alpha``, grid + refinement), then a relaxation of the hysteretic state
    (``relaxation`` τ, log grid 20 µs … 20 ms + refinement, with ``alpha`` refitted once under it); the
    relaxation is kept when it lowers the training residual energy by ``RELAX_MIN_GAIN``."""
    grid = np.array([-0.6, -0.3, -0.1, 0.0, 0.1, 0.3, 0.6, 1.2, 2.5, 5.0])
    base = _fit_scalar(ctx, "hysteresis_rate_dependence", "alpha", lambda z: {"alpha": z}, grid, lambda z: z,
                       lambda z: 1.0)
    alpha = float(base.params["alpha"])
    lo = math.log(max(20e-6, 0.3 * ctx.dt))
    tgrid = np.linspace(lo, math.log(20e-3), 10)
    rel = _fit_scalar(ctx, "hysteresis_rate_dependence", "relaxation",
                      lambda z: {"alpha": alpha, "relaxation": math.exp(z)}, tgrid, math.exp, math.exp)
    tau = float(rel.params["relaxation"])
    agrid = alpha + np.array([-0.4, -0.15, -0.05, 0.0, 0.05, 0.15, 0.4])
    both = _fit_scalar(ctx, "hysteresis_rate_dependence", "alpha",
                       lambda z: {"alpha": z, "relaxation": tau}, agrid, lambda z: z, lambda z: 1.0)
    best = min((rel, both), key=lambda f: f.train_rms)
    if best.train_rms ** 2 > (1 - RELAX_MIN_GAIN) * base.train_rms ** 2:
        return base
    p = dict(best.effects[0][1])
    se = {"alpha": both.stderr.get("alpha") if best is both else base.stderr.get("alpha"),
          "relaxation": rel.stderr.get("relaxation")}
    return FitResult("hysteresis_rate_dependence", p, se, [("hysteresis_rate_dependence", p)], 2, best.train_rms,
                     note=f"hysteretic state relaxes over {1e3 * p['relaxation']:.3g} ms")


def fit_hysteresis_asymmetry(ctx: FitContext) -> FitResult:
    """Δ1/Δ2 of the generalized Bouc-Wen loop by least squares (the model re-run per trial), then the even,
    branch-dependent and play-operator loop-width terms by linear regression on their regressors."""
    n = ctx.cfg.n_axes
    B = np.abs(np.diag(ctx.cfg.hysteresis.arrays()["B"]))
    scale = np.r_[np.maximum(B, 1e-4), np.maximum(B, 1e-4)]

    def make(theta: np.ndarray) -> dict[str, Any]:
        d = theta * scale
        return {"Delta1": d[:n].tolist(), "Delta2": d[n:].tolist()}

    # residuals in units of the base model's RMS error: scipy's tolerances are absolute, metres are too small
    unit = max(_rms(residual(ctx.target, ctx.y_base_win)), 1e-15)

    def resid(theta: np.ndarray) -> np.ndarray:
        return ctx.sim_residual([("hysteresis_asymmetry", make(theta))]).reshape(-1) / unit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # unbounded trust region: the problem is nearly linear in Δ and converges in a few steps (bounds slow it)
        sol = optimize.least_squares(resid, np.zeros(2 * n), diff_step=1e-3, max_nfev=40)
    r = sol.fun.reshape(-1, n)
    se = _stderr(sol.jac, r) * scale
    p = make(sol.x)
    # then the even, branch-dependent term, linear given the generalized Bouc-Wen: regression on its regressors
    y_w = simulate(ctx.cfg, ctx.u, list(ctx.base) + [("hysteresis_asymmetry", p)], ctx.windows)
    r_w = residual(ctx.target, y_w)
    q, dq = _windowed(lambda yy: fx.BranchEvenTerm(0.0, 0.0, ctx.dt, n).terms(yy), y_w, ctx.windows, 2)
    # loop-width terms: classical plays on the displacement, radii a fixed share of the stroke
    half = float(np.mean(0.5 * (np.max(y_w, axis=0) - np.min(y_w, axis=0))))
    radii = [f * max(half, 1e-12) for f in PLAY_FRACTIONS]
    W = _windowed(lambda yy: tuple(np.moveaxis(fx.PlayWidthTerm(radii, np.zeros((len(radii), n)), n).terms(yy),
                                               1, 0)), y_w, ctx.windows, len(radii))
    coef, res, se2 = _lin_per_axis(r_w, [q, dq] + list(W))
    p = dict(p, even=coef[0].tolist(), branch_even=coef[1].tolist(), play_radii=radii,
             play_gains=coef[2:].tolist())
    return FitResult("hysteresis_asymmetry", p, {"Delta1": se[:n].tolist(), "Delta2": se[n:].tolist(),
                                                 "even": se2[0].tolist(), "branch_even": se2[1].tolist(),
                                                 "play_radii": None, "play_gains": se2[2:].tolist()},
                     [("hysteresis_asymmetry", p)], (4 + len(radii)) * n, _rms(res))


#: radii of the loop-width play operators, as shares of half the displacement stroke on TRAIN
PLAY_FRACTIONS = (0.05, 0.15, 0.4)


def _windowed(fn: Callable[[np.ndarray], tuple[np.ndarray, ...]], y_w: np.ndarray, windows: Windows,
              n_out: int) -> tuple[np.ndarray, ...]:
    """Apply a stateful term ``fn`` (a fresh stage per call) to each window of ``y_w`` (the windows' scored
    samples, concatenated) separately, so that no state leaks from one window into the next."""
    if windows.is_whole:
        return fn(y_w)
    outs: list[list[np.ndarray]] = [[] for _ in range(n_out)]
    o = 0
    for _, s_, e_ in windows.spans:
        parts = fn(y_w[o:o + e_ - s_])
        for k in range(n_out):
            outs[k].append(parts[k])
        o += e_ - s_
    return tuple(np.concatenate(v) for v in outs)
