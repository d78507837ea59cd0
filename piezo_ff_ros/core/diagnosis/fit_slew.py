"""The slew-limit candidate of either form: one rate for both directions, then a rate per direction
(:class:`~..models.effects.slew.AsymmetricSlewLimit`), kept when it earns its extra parameter on TRAIN.

Why two forms: a driver's slew rate is its current limit over the load capacitance, and the current it sources
(voltage rising) and sinks (falling) often differ.  With the rates apart, a fast excitation is followed on the fast
side and lags on the slow side, so the acting voltage drifts towards the fast side: a rectified, slowly wandering
error that no single rate reproduces (one rate either leaves the slow side unlimited or limits the fast side that
is not) — it was taken for a very low amplifier roll-off.

Why a wider rate grid than the median-to-maximum one: an excitation bounded in slew by its trajectory generator
commands its largest rate most of the time, so the median rate can equal the largest and leave no grid at all;
every rate between a fiftieth of the largest commanded rate and the largest is a limit this excitation can reveal.
"""
from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
from scipy import optimize

from .fit_common import FitContext, FitResult, _fit_scalar, _rms, _stderr, search_context
from .fit_voltage import RAIL_MIN_GAIN

__all__ = ["fit_amplifier_slew_limit_any", "SLEW_ASYM_MIN_GAIN", "SLEW_SPAN", "SLEW_GRID"]

#: the rate per direction is kept when it lowers the training residual energy by this share below the one rate's
#: (the richer form earns its parameter on TRAIN: the rule of RAIL_MIN_GAIN, the same figure)
SLEW_ASYM_MIN_GAIN = RAIL_MIN_GAIN
#: slew rates searched: from the largest commanded rate over SLEW_SPAN up to just above it
SLEW_SPAN = 50.0
#: points of the log grid of one rate (the coarse grid of the pair has SLEW_GRID_PAIR per direction)
SLEW_GRID = 14
SLEW_GRID_PAIR = 5


def _rate_bounds(ctx: FitContext) -> tuple[float, float]:
    rates = np.abs(np.diff(ctx.u, axis=0)) / ctx.dt
    rmax = float(rates.max()) if rates.size else 1.0
    rmax = max(rmax, 1e-6)
    return math.log(rmax / SLEW_SPAN), math.log(rmax * 1.05)


def _fit_symmetric(ctx: FitContext, bounds: tuple[float, float]) -> FitResult:
    lo, hi = bounds
    grid = np.linspace(lo, hi, SLEW_GRID)
    return _fit_scalar(ctx, "amplifier_slew_limit", "rate", lambda z: {"rate": math.exp(z)}, grid, math.exp,
                       math.exp)


def _pair(theta: np.ndarray) -> dict[str, Any]:
    return {"rate": float(math.exp(theta[0])), "rate_down": float(math.exp(theta[1]))}


def fit_amplifier_slew_limit_any(ctx: FitContext) -> FitResult:
    """One slew rate (log grid + bounded refinement), then a rate per direction: a coarse log grid of the pair and
    a simplex refinement on half the windows of a long run, the result and its standard errors on all of them;
    the pair replaces the one rate when it lowers the training residual energy by :data:`SLEW_ASYM_MIN_GAIN`."""
    lo, hi = _rate_bounds(ctx)      # once: a pass over the whole record
    sym = _fit_symmetric(ctx, (lo, hi))
    unit = max(sym.train_rms, 1e-15)
    sub = search_context(ctx)
    cache: dict[tuple[float, float], float] = {}

    def sse(theta: np.ndarray) -> float:
        th = (float(np.clip(theta[0], lo, hi)), float(np.clip(theta[1], lo, hi)))
        if th not in cache:
            r = sub.sim_residual([("amplifier_slew_limit", _pair(np.array(th)))])
            cache[th] = float(np.sum((r / unit) ** 2))
        return cache[th]

    g = np.linspace(lo, hi, SLEW_GRID_PAIR)
    z_sym = math.log(float(sym.params["rate"]))
    starts = [np.array([a, b]) for a in g for b in g if a != b] + [np.array([z_sym, z_sym])]
    best = min(starts, key=sse)
    step = float(g[1] - g[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = optimize.minimize(sse, best, method="Nelder-Mead",
                                options={"xatol": 1e-3, "fatol": 0.0, "maxfev": 40, "initial_simplex":
                                         np.array([best, best + [0.5 * step, 0.0], best + [0.0, 0.5 * step]])})
    theta = np.clip(sol.x if sol.fun <= sse(best) else best, lo, hi)
    r = ctx.sim_residual([("amplifier_slew_limit", _pair(theta))])
    sse_pair = float(np.sum(r ** 2))
    sse_sym = float(sym.train_rms ** 2 * ctx.target.size)
    if not sse_pair < (1 - SLEW_ASYM_MIN_GAIN) * sse_sym:
        return sym
    h = 1e-3 * step
    cols = []
    for k in range(2):
        d = np.zeros(2)
        d[k] = h
        rp = ctx.sim_residual([("amplifier_slew_limit", _pair(theta + d))])
        rm = ctx.sim_residual([("amplifier_slew_limit", _pair(theta - d))])
        cols.append(((rp - rm) / (2 * h)).reshape(-1))
    se = _stderr(np.column_stack(cols), r) * np.exp(theta)       # d(value) = value·d(log value)
    p = _pair(theta)
    return FitResult("amplifier_slew_limit", p, {"rate": float(se[0]), "rate_down": float(se[1])},
                     [("amplifier_slew_limit", p)], 2, _rms(r),
                     note=f"rising {p['rate']:.4g} V/s, falling {p['rate_down']:.4g} V/s")
