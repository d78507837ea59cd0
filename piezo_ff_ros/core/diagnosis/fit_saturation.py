"""The saturation candidate of any shape: the hard clip (symmetric or per rail, :func:`.fit_voltage.
fit_amplifier_saturation`), then a soft knee per rail (Rapp's law, :class:`~..models.effects.saturation.
SoftSaturation`), kept when it earns its extra parameter on TRAIN.

Why: an amplifier that compresses smoothly from well below its rails (a soft knee from ~100 V) is a static,
memoryless function of the commanded voltage concentrated at large |U| — a hard clip at the largest voltage cannot
follow it, and what is left looks like a gain (the compression is roughly proportional over the stroke) or an
asymmetric loop (when the rails differ).  Rapp's law spans hard clip (large sharpness) to a gentle knee (sharpness
≈ 1–2) with one parameter more than the hard clip.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import optimize

from .fit_common import FitContext, FitResult, _rms, _stderr
from .fit_voltage import RAIL_MIN_GAIN, fit_amplifier_saturation
from .fit_hysteresis import search_context
from .replay import residual

__all__ = ["fit_amplifier_saturation_any", "SOFT_KNEE_MIN_GAIN", "KNEE_GRID", "SHARPNESS_GRID"]

#: the soft knee is kept when it lowers the training residual energy by this share below the hard clip's (the
#: richer form earns its parameter on TRAIN: the rule of RAIL_MIN_GAIN, the same figure)
SOFT_KNEE_MIN_GAIN = RAIL_MIN_GAIN
#: rails tried for the soft knee, as multiples of the largest |U| of TRAIN (a soft knee's rail may lie beyond the
#: largest voltage reached: the compression starts well below it)
KNEE_GRID = (0.9, 1.4)
#: sharpness p tried (2: a gentle knee; 8: close to the hard clip); the least squares refines from the best
SHARPNESS_GRID = (2.0, 8.0)


def _soft(up: float, down: float, p: float) -> dict[str, float]:
    return {"limit": up, "lower_limit": down, "sharpness": p}


def fit_amplifier_saturation_any(ctx: FitContext) -> FitResult:
    """The hard clip, then the soft knee per rail: a grid over a shared rail and the sharpness, then both rails and
    the sharpness by least squares (log parameters, the model re-run per trial); the soft knee replaces the hard
    clip when it lowers the training residual energy by :data:`SOFT_KNEE_MIN_GAIN`."""
    hard = fit_amplifier_saturation(ctx)
    amax = float(np.max(np.abs(ctx.u)))
    if not amax > 0:
        return hard
    unit = max(_rms(residual(ctx.target, ctx.y_base_win)), 1e-15)    # the base replay: no re-run
    sub = search_context(ctx)           # the search on half the windows of a long run, the result on all of them

    def resid_on(c: FitContext, theta: np.ndarray) -> np.ndarray:
        up, down, p = (float(math.exp(x)) for x in theta)
        return c.sim_residual([("amplifier_saturation", _soft(up, down, min(p, 100.0)))]).reshape(-1) / unit

    grid = [(math.log(k * amax), math.log(p)) for k in KNEE_GRID for p in SHARPNESS_GRID]
    vals = [float(np.sum(resid_on(sub, np.array([lk, lk, lp])) ** 2)) for lk, lp in grid]
    lk, lp = grid[int(np.argmin(vals))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = optimize.least_squares(lambda th: resid_on(sub, th), np.array([lk, lk, lp]), diff_step=1e-3,
                                     max_nfev=20, bounds=([math.log(0.3 * amax)] * 2 + [math.log(0.7)],
                                                          [math.log(20 * amax)] * 2 + [math.log(100.0)]))
    jac = sol.jac
    if sub is not ctx:                  # the residual and the Jacobian (standard errors) on every window
        r0 = resid_on(ctx, sol.x)
        jac = np.column_stack([(resid_on(ctx, sol.x + h) - r0) / h[k]
                               for k, h in enumerate(np.diag(1e-3 * np.maximum(np.abs(sol.x), 1.0)))])
        sol.fun = r0
    r = sol.fun.reshape(-1, ctx.cfg.n_axes)
    sse_soft = float(np.sum(r ** 2)) * unit ** 2
    sse_hard = float(hard.train_rms ** 2 * ctx.target.size)
    if sse_soft > (1 - SOFT_KNEE_MIN_GAIN) * sse_hard:
        return hard
    up, down, p = (float(math.exp(x)) for x in sol.x)
    se = _stderr(jac, r) * np.exp(sol.x)    # d(value) = value·d(log value)
    params = _soft(up, down, p)
    return FitResult("amplifier_saturation", params,
                     {"limit": float(se[0]), "lower_limit": float(se[1]), "sharpness": float(se[2])},
                     [("amplifier_saturation", params)], 3, _rms(r) * unit,
                     note=f"soft knee (Rapp's law), sharpness {p:.3g}")
