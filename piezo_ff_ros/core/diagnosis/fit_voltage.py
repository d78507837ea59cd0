"""Voltage-side candidates (input delay, slew limit, saturation rails, amplifier roll-off): the model re-run for
every trial value on :class:`~.replay.Windows` of the training run, a coarse grid then a bounded refinement
(:func:`~.fit_common._fit_scalar`) or ``scipy.optimize.least_squares``.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, Callable

import numpy as np
from scipy import optimize

from .fit_common import FitContext, FitResult, _fit_scalar, _rms, _stderr
from .replay import residual

__all__ = ["fit_input_delay", "fit_amplifier_saturation", "fit_amplifier_bandwidth",
           "RAIL_MIN_GAIN"]


def fit_input_delay(ctx: FitContext) -> FitResult:
    """A pure input delay (interpolated): first guess from r ≈ −d·dŶ/dt, a log grid, quarter-sample steps around
    the best point, then a bounded refinement."""
    # first guess from the delay signature: r ≈ −d·dŶ/dt
    r0 = residual(ctx.target, ctx.y_base_win)
    dy = np.gradient(ctx.y_base_win, ctx.dt, axis=0)
    dy -= dy.mean(axis=0)
    d0 = float(-np.sum(r0 * dy) / max(np.sum(dy * dy), 1e-300))
    dmax = max(50 * ctx.dt, 4 * abs(d0))
    grid = np.unique(np.r_[0.0, np.geomspace(0.25 * ctx.dt, dmax, 11), max(d0, 0.0)])
    dt = ctx.dt

    def fine(best: float) -> np.ndarray:
        # linear interpolation makes the cost wiggle between whole samples: quarter-sample steps around the best
        return np.clip(best + dt * np.arange(-3.0, 3.01, 0.25), 0.0, None)

    pure = _fit_scalar(ctx, "input_delay", "delay", lambda z: {"delay": max(z, 0.0)}, grid,
                       lambda z: max(z, 0.0), lambda z: 1.0, fine=fine)
    allpass = _fit_allpass_delay(ctx, float(pure.params["delay"]))
    return allpass if allpass is not None and allpass.train_rms < pure.train_rms else pure


def _fit_allpass_delay(ctx: FitContext, d_pure: float) -> FitResult | None:
    """The delay in all-pass form (``form='allpass'``, the same one parameter): a log grid from half to twice the
    pure delay's estimate, the parabola's vertex, standard error by a central difference.  ``None`` when the pure
    fit found no delay (below a tenth of a sample).

    Two forms of one physical class: the interpolated delay attenuates within the band (linear interpolation
    is a low-pass at fractional delays) and shifts each DAC step; the all-pass keeps the gain and overshoots
    each step within the sample.  Whichever fits TRAIN better is the delay's form; both are ``input_delay``."""
    if not (d_pure > 0.1 * ctx.dt):
        return None

    def make(z: float) -> dict[str, Any]:
        return {"delay": math.exp(z), "form": "allpass"}

    c = math.log(d_pure)
    grid = np.linspace(c - math.log(2.0), c + math.log(2.0), 7)
    cache: dict[float, np.ndarray] = {}

    def res(z: float) -> np.ndarray:
        if z not in cache:
            cache[z] = ctx.sim_residual([("input_delay", make(z))])
        return cache[z]

    vals = [float(np.sum(res(float(z)) ** 2)) for z in grid]
    k = int(np.argmin(vals))
    z = float(grid[k])
    if 0 < k < len(grid) - 1:
        x0, x1, x2 = grid[k - 1:k + 2]
        y0, y1, y2 = vals[k - 1:k + 2]
        den = (x0 - x1) * (x0 - x2) * (x1 - x2)
        a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
        if a > 0:
            zv = float(np.clip(-b / (2 * a), x0, x2))
            if float(np.sum(res(zv) ** 2)) < vals[k]:
                z = zv
    r = res(z)
    h = 1e-3
    J = ((ctx.sim_residual([("input_delay", make(z + h))]) - ctx.sim_residual([("input_delay", make(z - h))]))
         / (2 * h)).reshape(-1, 1)
    se = float(_stderr(J, r)[0]) * math.exp(z)
    p = make(z)
    return FitResult("input_delay", p, {"delay": se, "form": None}, [("input_delay", p)], 1, _rms(r),
                     note="all-pass form (2nd-order Padé): unit gain, the delay's phase lag")


#: the rails are fitted apart when that lowers the training residual energy by at least this share
RAIL_MIN_GAIN = 0.02


def fit_amplifier_saturation(ctx: FitContext) -> FitResult:
    """One symmetric limit first (grid + refinement); then each rail refined with the other held (amplifier
    rails often differ by sign), kept when it lowers the training residual energy by ``RAIL_MIN_GAIN``."""
    a = np.abs(ctx.u)
    amax = float(a.max())
    lo = float(np.quantile(a, 0.5))
    grid = np.linspace(max(lo, 1e-3 * amax), amax * 1.01, 12)
    sym = _fit_scalar(ctx, "amplifier_saturation", "limit", lambda z: {"limit": z}, grid, lambda z: z,
                      lambda z: 1.0)
    L = float(sym.params["limit"])
    top, bot = float(np.max(ctx.u)), float(-np.min(ctx.u))
    if L >= min(top, bot):  # one rail is never reached: nothing to tell the rails apart
        return sym
    cache: dict[tuple[float, float], tuple[float, np.ndarray]] = {}

    def sse(up: float, down: float) -> float:
        key = (round(up, 9), round(down, 9))
        if key not in cache:
            r = ctx.sim_residual([("amplifier_saturation", {"limit": up, "lower_limit": down})])
            cache[key] = (float(np.sum(r ** 2)), r)
        return cache[key][0]

    up, down = L, L
    for _ in range(2):  # coordinate descent, each rail between lo and just above the largest voltage of its sign
        for which in ("up", "down"):
            hi = (top if which == "up" else bot) * 1.01
            f: Callable[[float], float] = (lambda z: sse(z, down)) if which == "up" else (lambda z: sse(up, z))
            sol = optimize.minimize_scalar(f, bounds=(max(lo, 1e-3 * amax), hi), method="bounded",
                                           options={"xatol": 1e-3 * hi, "maxiter": 16})
            cur = up if which == "up" else down
            if sol.fun < f(cur):
                if which == "up":
                    up = float(sol.x)
                else:
                    down = float(sol.x)
    s_sym = float(sym.train_rms ** 2 * ctx.target.size)
    s_asym = sse(up, down)
    if s_asym > (1 - RAIL_MIN_GAIN) * s_sym:
        return sym
    r = cache[(round(up, 9), round(down, 9))][1]
    cols = []
    for k, (du, dd) in enumerate(((1e-3 * up, 0.0), (0.0, 1e-3 * down))):
        rp = ctx.sim_residual([("amplifier_saturation", {"limit": up + du, "lower_limit": down + dd})])
        rm = ctx.sim_residual([("amplifier_saturation", {"limit": up - du, "lower_limit": down - dd})])
        cols.append(((rp - rm) / (2 * max(du, dd))).reshape(-1))
    se = _stderr(np.column_stack(cols), r)
    p = {"limit": up, "lower_limit": down}
    return FitResult("amplifier_saturation", p, {"limit": float(se[0]), "lower_limit": float(se[1])},
                     [("amplifier_saturation", p)], 2, _rms(r), note="rails differ by sign")


def fit_amplifier_bandwidth(ctx: FitContext) -> FitResult:
    """Shared cutoff for a 1st-order roll-off, then a 2nd order (its damping fitted) and a 3rd order (1st × 2nd),
    each kept when it earns its parameters on TRAIN (:data:`DAMPING_MIN_GAIN`), then one cutoff per axis refined
    from there (amplifier channels differ).  The stage is the continuous filter on the DAC's staircase (interval-
    averaged), replayed at the intersample rate of :func:`~.replay.simulate`."""
    fs = 1.0 / ctx.dt
    n = ctx.cfg.n_axes
    # up to 10·fs, where the filter is the identity to 1/(2π·10) of one sample's step: "no bandwidth limit" is
    # (nearly) on the grid
    grid = np.linspace(math.log(fs / 2000.0), math.log(10.0 * fs), 14)
    f1 = _fit_scalar(ctx, "amplifier_bandwidth", "cutoff", lambda z: {"cutoff": math.exp(z), "order": 1}, grid,
                     math.exp, math.exp)
    fits = [(f1.train_rms, 1, f1, 2 ** -0.5)]
    c1 = math.log(f1.params["cutoff"])
    if c1 < math.log(fs):  # a finite roll-off was found: try the 2nd order around it (a 2nd-order corner lies
        # above the 1st-order one that mimics it), on a short grid, then its damping
        grid2 = np.linspace(c1 - 0.5, c1 + 2.0, 6)
        f2 = _fit_scalar(ctx, "amplifier_bandwidth", "cutoff", lambda z: {"cutoff": math.exp(z), "order": 2},
                         grid2, math.exp, math.exp)
        z2 = 2 ** -0.5
        # its damping, and a steeper third order (1st × 2nd, Butterworth), only when the data says "not a first
        # order" (the 2nd order earns its keep on TRAIN): a delay-like lag does not pay for these searches
        if f2.train_rms ** 2 < (1 - DAMPING_MIN_GAIN) * f1.train_rms ** 2:
            f2, z2 = _fit_damping(ctx, f2, 2, z2)
        fits.append((f2.train_rms, 2, f2, z2))
        if f2.train_rms ** 2 < (1 - DAMPING_MIN_GAIN) * f1.train_rms ** 2:
            c2 = math.log(f2.params["cutoff"])
            z3c, e3 = _grid_parabola(ctx, lambda z: {"cutoff": math.exp(z), "order": 3, "damping": 0.5},
                                     np.linspace(c2 - 0.5, c2 + 1.0, 5))
            f3, z3 = _fit_damping(ctx, _as_fit(ctx, f2, math.exp(z3c), e3), 3, 0.5)
            if f3.train_rms ** 2 < (1 - DAMPING_MIN_GAIN) * f2.train_rms ** 2:
                fits.append((f3.train_rms, 3, f3, z3))
        # the linear-phase (Bessel) roll-offs: one parameter like the 1st order, but in the band a delay — the 1st
        # order's magnitude loss at the same phase lag is what made them lose to it, and the 2nd order's gate above
        fits += _bessel_fits(ctx, f1, c1)
    _, order, best, zeta = min(fits, key=lambda t: t[0])
    form = str(best.extra.get("form", "filter"))
    c0 = math.log(best.params["cutoff"])
    if n > 1 and c0 < math.log(fs):
        unit = max(_rms(residual(ctx.target, ctx.y_base_win)), 1e-15)

        def resid(theta: np.ndarray) -> np.ndarray:
            p = {"cutoff": np.exp(theta).tolist(), "order": order, "damping": zeta, **_form_key(form)}
            return ctx.sim_residual([("amplifier_bandwidth", p)]).reshape(-1) / unit

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = optimize.least_squares(resid, np.full(n, c0), diff_step=1e-3, max_nfev=4,
                                         bounds=(np.full(n, math.log(fs / 4000.0)), np.full(n, math.log(20 * fs))))
        r = sol.fun.reshape(-1, n) * unit
        if _rms(r) < best.train_rms:
            cut = np.exp(sol.x)
            se = _stderr(sol.jac, r / unit) * cut
            p = {"cutoff": cut.tolist(), "order": order, "damping": zeta, **_form_key(form)}
            return FitResult("amplifier_bandwidth", p, {"cutoff": se.tolist(), "order": None, "damping": None,
                                                        **_form_key(form, None)},
                             [("amplifier_bandwidth", p)], n + 1 + _damping_param(form, zeta), _rms(r),
                             note=_note(form, order, zeta))
    p = {"cutoff": [best.params["cutoff"]] * n, "order": order, "damping": zeta, **_form_key(form)}
    return FitResult("amplifier_bandwidth", p, {"cutoff": [best.stderr["cutoff"]] * n, "order": None,
                                                "damping": None, **_form_key(form, None)},
                     [("amplifier_bandwidth", p)], 2 + _damping_param(form, zeta), best.train_rms,
                     note=_note(form, order, zeta), extra=best.extra)


#: orders of the Bessel (linear-phase) roll-off tried
BESSEL_ORDERS = (2, 3)


def _form_key(form: str, value: Any = "") -> dict[str, Any]:
    """``{"form": …}`` for a Bessel roll-off (``value`` replaces the form's name, e.g. ``None`` for its standard
    error), nothing for the 1st/2nd/3rd-order filters (their parameters stay as they were)."""
    return {"form": form if value == "" else value} if form == "bessel" else {}


def _damping_param(form: str, zeta: float) -> int:
    """1 when the damping was fitted (not a Bessel shape, not Butterworth's)."""
    return int(form != "bessel" and zeta not in (2 ** -0.5, 0.5))


def _note(form: str, order: int, zeta: float) -> str:
    return f"Bessel (linear phase), order {order}" if form == "bessel" else f"order {order}, damping {zeta:.3g}"


def _bessel_fits(ctx: FitContext, f1: FitResult, c1: float) -> list[tuple[float, int, FitResult, float]]:
    """Bessel roll-offs of :data:`BESSEL_ORDERS`, their shared cutoff on a short log grid above the 1st order's
    (a Bessel filter of the same DC lag has a higher −3 dB point), then the parabola's vertex: one parameter each."""
    out = []
    for order in BESSEL_ORDERS:
        def make(z: float, order: int = order) -> dict[str, Any]:
            return {"cutoff": math.exp(z), "order": order, "form": "bessel"}
        zc, e = _grid_parabola(ctx, make, np.linspace(c1 - 0.3, c1 + 1.5, 6))
        fit = dataclasses.replace(_as_fit(ctx, f1, math.exp(zc), e), extra={**f1.extra, "form": "bessel"})
        out.append((fit.train_rms, order, fit, 2 ** -0.5))
    return out


#: a 2nd-order roll-off's damping other than 0.707 (Butterworth) is kept when it lowers the training residual energy
#: by this share (the richer form must earn its parameter on TRAIN, like RAIL_MIN_GAIN; set from that definition)
DAMPING_MIN_GAIN = 0.02


def _grid_parabola(ctx: FitContext, make: Callable[[float], dict[str, Any]], grid: np.ndarray) -> tuple[float, float]:
    """A lean 1-D search for the richer roll-off forms: the grid, then the vertex of the parabola through the best
    point and its neighbours (one more simulation).  Returns ``(z, training residual energy)``."""
    vals = [float(np.sum(ctx.sim_residual([("amplifier_bandwidth", make(float(z)))]) ** 2)) for z in grid]
    k = int(np.argmin(vals))
    z, e = float(grid[k]), vals[k]
    if 0 < k < len(grid) - 1:
        x0, x1, x2 = grid[k - 1:k + 2]
        y0, y1, y2 = vals[k - 1:k + 2]
        den = (x0 - x1) * (x0 - x2) * (x1 - x2)
        a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
        if a > 0:
            zv = float(np.clip(-b / (2 * a), x0, x2))
            ev = float(np.sum(ctx.sim_residual([("amplifier_bandwidth", make(zv))]) ** 2))
            if ev < e:
                z, e = zv, ev
    return z, e


def _as_fit(ctx: FitContext, best: FitResult, cutoff: float, energy: float) -> FitResult:
    """``best`` with another shared cutoff and training residual energy (its standard error kept)."""
    return dataclasses.replace(best, params={"cutoff": cutoff}, stderr={"cutoff": best.stderr["cutoff"]},
                               train_rms=math.sqrt(energy / max(ctx.target.size, 1)))


def _fit_damping(ctx: FitContext, best: FitResult, order: int, zeta0: float) -> tuple[FitResult, float]:
    """The damping of a 2nd-order section (0.3 … 1.5: a resonant amplifier to an over-damped, Bessel-like one) at
    the shared cutoff found, then the cutoff again at that damping (lean grid + parabola searches); kept when it
    earns its parameter on TRAIN."""
    cut = float(best.params["cutoff"])
    z, e = _grid_parabola(ctx, lambda z: {"cutoff": cut, "order": order, "damping": math.exp(z)},
                          np.linspace(math.log(0.3), math.log(1.5), 5))
    zeta = math.exp(z)
    if e >= (1 - DAMPING_MIN_GAIN) * best.train_rms ** 2 * ctx.target.size:
        return best, zeta0
    c = math.log(cut)
    zc, ec = _grid_parabola(ctx, lambda x: {"cutoff": math.exp(x), "order": order, "damping": zeta},
                            np.array([c - 0.3, c, c + 0.3]))
    if ec < e:
        return _as_fit(ctx, best, math.exp(zc), ec), zeta
    return _as_fit(ctx, best, cut, e), zeta
