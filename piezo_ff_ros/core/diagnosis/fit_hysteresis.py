"""Hysteresis candidates: the rate-dependent loop (rate-widened A, a relaxing hysteretic state, a velocity-damping
term, play widths growing with the rate) and the asymmetric loop (Δ1/Δ2 by least squares with the linear terms
projected out, then the even, branch-dependent and play-operator loop-width terms by regression — on the
displacement, or at the hysteresis output through the linear creep and dynamics chain).

Terms added at the hysteresis output enter the output linearly through the creep and the dynamics (both linear):
their gains are fitted by least squares on the chain's response to each term (:func:`_chain_response`), without
re-running the hysteresis.
"""
from __future__ import annotations

import itertools
import math
import warnings
from collections import OrderedDict
from typing import Any, Callable

import numpy as np
from scipy import linalg, optimize

from ..models import effects as fx
from ..models.plant import Plant
from .fit_common import FitContext, FitResult, _fit_scalar, _lin_per_axis, _rms, _stderr, n_eff_ratio, search_context
from .replay import Windows, column_means, residual, simulate

__all__ = ["fit_hysteresis_rate_dependence", "fit_hysteresis_asymmetry", "search_context", "RELAX_MIN_GAIN",
           "PLAY_FRACTIONS", "RELAY_LEVELS",
           "VELOCITY_EXPONENTS", "VELOCITY_MAX_EXPONENT", "VELOCITY_SMOOTHING_SAMPLES"]


#: a relaxation of the hysteretic state is kept when it lowers the training residual energy by this share
RELAX_MIN_GAIN = 0.02
#: exponents m of the velocity-damping form tried (sub-linear: a term linear in the rate is what a delay or a
#: viscous loop gives; m < 1 is the nonlinear velocity damping of the literature, absent at rest, steep at low rates)
VELOCITY_EXPONENTS = (0.3, 0.45, 0.6, 0.75)
#: the largest exponent the refinement may reach: near m = 1 the term is linear in the rate — a delay's error
#: (∝ dŶ/dt) or a viscous loop's, which their own candidates name — so the form stays clearly nonlinear
VELOCITY_MAX_EXPONENT = 0.85
#: smoothing of the voltage rate the velocity term sees, in sample intervals (the DAC's staircase has a rate only
#: over a sample; how the amplifier spreads it is not known: none, one, a few samples)
VELOCITY_SMOOTHING_SAMPLES = (0.0, 2.0)


def _search_spans(ctx: FitContext) -> tuple[list[tuple[int, int, int]], np.ndarray]:
    """The windows a grid search over a term's shape uses — every other fit window of a long run (the final
    gains are fitted on all of them) — and the mask of their rows in the windows' concatenated samples."""
    spans = ctx.windows.spans
    keep = [i % 2 == 0 for i in range(len(spans))] if len(spans) > 2 else [True] * len(spans)
    mask = np.concatenate([np.full(e_ - s_, k) for (_, s_, e_), k in zip(spans, keep)])
    return [sp for sp, k in zip(spans, keep) if k], mask


def _scalar_searched(ctx: FitContext, sub: FitContext, pname: str, make: Callable[[float], dict[str, Any]],
                     grid: np.ndarray, to_value: Callable[[float], float], dvalue: Callable[[float], float],
                     from_value: Callable[[float], float]) -> FitResult:
    """:func:`~.fit_common._fit_scalar` of ``hysteresis_rate_dependence``'s ``pname``: the grid and the refinement
    on ``sub`` (:func:`search_context`), the residual and the standard error at the point found on every window of
    ``ctx``."""
    name = "hysteresis_rate_dependence"
    if sub is ctx:
        return _fit_scalar(ctx, name, pname, make, grid, to_value, dvalue)
    found = _fit_scalar(sub, name, pname, make, grid, to_value, dvalue)
    z = from_value(float(found.params[pname]))
    full = _fit_scalar(ctx, name, pname, make, np.array([z]), to_value, dvalue)
    full.extra = dict(found.extra)
    return full


def _chain_response(ctx: FitContext, make: Callable[[], Any], terms: Callable[[Any, np.ndarray], np.ndarray],
                    spans: list[tuple[int, int, int]] | None = None) -> np.ndarray:
    """The model output's response (on the fit windows, flattened, each axis' mean removed) to terms added at the
    hysteresis output: ``terms(stage, u)`` gives [N, B, n] (B basis signals per axis) for a fresh ``make()``
    stage; column (b, i) is the response to basis b on axis i alone.  The creep and the dynamics behind the
    hysteresis are linear, so the output is linear in the terms' gains: the chain is run alone, without re-running
    the hysteresis."""
    n = ctx.cfg.n_axes
    chain = Plant(ctx.cfg, stages=("creep", "dynamics"))
    parts: list[list[np.ndarray]] = []
    for w, s_, e_ in (ctx.windows.spans if spans is None else spans):   # each from its warm start
        T = terms(make(), ctx.u[w:e_])
        if not parts:
            parts = [[] for _ in range(T.shape[1] * n)]
        for b in range(T.shape[1]):
            for i in range(n):
                x = np.zeros((T.shape[0], n))
                x[:, i] = T[:, b, i]
                chain.reset()
                parts[b * n + i].append(chain.process(x)[s_ - w:])
    cols = []
    for p in parts:
        yi = np.concatenate(p)
        cols.append((yi - column_means(yi)).reshape(-1))
    return np.column_stack(cols)


def _velocity_basis(ctx: FitContext, m: float, smoothing: float,
                    spans: list[tuple[int, int, int]] | None = None) -> np.ndarray:
    """The response to a unit velocity gain on each axis: columns [axis] (see :func:`_chain_response`)."""
    n = ctx.cfg.n_axes
    dp = np.diag(ctx.cfg.hysteresis.arrays()["Dp"])
    return _chain_response(ctx, lambda: fx.VelocityTerm(dp, np.ones(n), m, smoothing, ctx.dt),
                           lambda st, u: st.process(u)[:, None, :], spans)


def _velocity_form(ctx: FitContext) -> FitResult | None:
    """The velocity-damping form: ``Y_H,i += Dp_ii·c_i·sgn(r_i)·|r_i/r_ref|^m``.  Given (m, smoothing) the output
    is linear in the c_i (the creep and the dynamics behind the hysteresis are linear): the response to a unit c_i
    is computed per axis and the c_i found by least squares; (m, smoothing) on the grids
    :data:`VELOCITY_EXPONENTS` × :data:`VELOCITY_SMOOTHING_SAMPLES`, then refined (simplex).  Fitted on the
    nominal model only (a base with other effects changes the voltage the loop sees)."""
    n = ctx.cfg.n_axes
    if ctx.base or ctx.cfg.hysteresis.n_in != n or ctx.cfg.hysteresis.n_out != n:
        return None
    r_all = residual(ctx.target, ctx.y_base_win)
    spans, mask = _search_spans(ctx)
    r0 = (r_all[mask] - r_all[mask].mean(axis=0)).reshape(-1)
    cache: dict[tuple[float, float], float] = {}

    def fit(m: float, k: float) -> float:
        key = (round(m, 4), round(k, 3))
        if key not in cache:
            X = _velocity_basis(ctx, m, k * ctx.dt, spans)
            c, *_ = np.linalg.lstsq(X, r0, rcond=None)
            res = r0 - X @ c
            cache[key] = float(res @ res)
        return cache[key]

    grid = [(m, k) for m in VELOCITY_EXPONENTS for k in VELOCITY_SMOOTHING_SAMPLES]
    m0, k0 = min(grid, key=lambda mk: fit(*mk))

    def cost(z: np.ndarray) -> float:
        m, k = float(np.clip(z[0], 0.1, VELOCITY_MAX_EXPONENT)), float(np.clip(z[1], 0.0, 20.0))
        return fit(m, k)

    sol = optimize.minimize(cost, np.array([m0, k0]), method="Nelder-Mead",
                            options={"maxfev": 14, "xatol": 0.01, "fatol": 0.0,
                                     "initial_simplex": np.array([[m0, k0], [m0 + 0.08, k0], [m0, k0 + 1.0]])})
    m, k = (float(np.clip(sol.x[0], 0.1, VELOCITY_MAX_EXPONENT)), float(np.clip(sol.x[1], 0.0, 20.0))) \
        if sol.fun < fit(m0, k0) \
        else (m0, k0)
    m, k = round(m, 4), round(k, 3)
    X = _velocity_basis(ctx, m, k * ctx.dt)          # the gains on every fit window
    r_full = r_all.reshape(-1)
    c, *_ = np.linalg.lstsq(X, r_full, rcond=None)
    res = r_full - X @ c
    p = {"alpha": 0.0, "velocity_gain": c.tolist(), "velocity_exponent": m, "velocity_smoothing": k * ctx.dt}
    se = _stderr(-X, res.reshape(-1, n))
    return FitResult("hysteresis_rate_dependence", p,
                     {"alpha": None, "velocity_gain": se.tolist(), "velocity_exponent": None,
                      "velocity_smoothing": None},
                     [("hysteresis_rate_dependence", p)], n + 2, _rms(res),
                     note=f"velocity-damping term, exponent {m:.3g}, rate smoothed over {k:.3g} samples")


#: radii of the rate-dependent plays, as shares of half the voltage range of TRAIN
RATE_PLAY_FRACTIONS = (0.05, 0.15, 0.3, 0.5)
#: reference rates of the rate-dependent plays tried, as multiples of the 90th percentile of |dU/dt| on TRAIN
RATE_PLAY_REFS = (0.3, 1.0, 3.0)
#: smoothing of the rate the plays see tried, in sample intervals
RATE_PLAY_SMOOTHING_SAMPLES = (1.0, 5.0, 20.0)


def _rate_play_form(ctx: FitContext) -> FitResult | None:
    """Play widths that grow with the rate (:class:`~..models.effects.RatePlayTerm`): the gains by least squares
    on the chain's responses, the reference rate and the smoothing on the grids :data:`RATE_PLAY_REFS` ×
    :data:`RATE_PLAY_SMOOTHING_SAMPLES`.  Fitted on the nominal model only."""
    n = ctx.cfg.n_axes
    h = ctx.cfg.hysteresis
    if ctx.base or h.n_in != n or h.n_out != n:
        return None
    half = float(np.mean(0.5 * (np.max(ctx.u, axis=0) - np.min(ctx.u, axis=0))))
    typical = float(np.quantile(np.abs(np.diff(ctx.u, axis=0)), 0.9)) / ctx.dt
    if not (half > 0 and typical > 0):
        return None
    radii = [f * half for f in RATE_PLAY_FRACTIONS]
    K = len(radii)
    dp = np.diag(h.arrays()["Dp"])
    r_all = residual(ctx.target, ctx.y_base_win)
    spans, mask = _search_spans(ctx)
    r0 = (r_all[mask] - r_all[mask].mean(axis=0)).reshape(-1)

    def basis(ref: float, sm: float, sp: list[tuple[int, int, int]] | None) -> np.ndarray:
        return _chain_response(ctx, lambda: fx.RatePlayTerm(dp, radii, np.zeros((K, n)), ref, sm, ctx.dt),
                               lambda st, u: st.terms(u), sp)

    def sse(ref: float, sm: float) -> float:
        X = basis(ref, sm, spans)
        c, *_ = np.linalg.lstsq(X, r0, rcond=None)
        res = r0 - X @ c
        return float(res @ res)

    # the reference rate at a middle smoothing, then the smoothing at that rate
    k_mid = RATE_PLAY_SMOOTHING_SAMPLES[len(RATE_PLAY_SMOOTHING_SAMPLES) // 2]
    ref = min((mult * typical for mult in RATE_PLAY_REFS), key=lambda r: sse(r, k_mid * ctx.dt))
    sm = min((k * ctx.dt for k in RATE_PLAY_SMOOTHING_SAMPLES), key=lambda v: sse(ref, v))
    X = basis(ref, sm, None)                            # the gains on every fit window
    r_full = r_all.reshape(-1)
    c, *_ = np.linalg.lstsq(X, r_full, rcond=None)
    res = r_full - X @ c
    se = _stderr(-X, res.reshape(-1, n))
    p = {"alpha": 0.0, "rate_play_radii": radii, "rate_play_gains": c.reshape(K, n).tolist(), "rate_play_ref": ref,
         "rate_play_smoothing": sm}
    return FitResult("hysteresis_rate_dependence", p,
                     {"alpha": None, "rate_play_radii": None, "rate_play_gains": se.reshape(K, n).tolist(),
                      "rate_play_ref": None, "rate_play_smoothing": None},
                     [("hysteresis_rate_dependence", p)], K * n + 2, _rms(res),
                     note=f"play widths growing with the rate (reference {ref:.3g} V/s, smoothed over "
                          f"{sm / ctx.dt:.3g} samples)")


def fit_hysteresis_rate_dependence(ctx: FitContext) -> FitResult:
    """The rate-widened loop (``alpha``, grid + refinement), then a relaxation of the hysteretic state
    (``relaxation`` τ, log grid 20 µs … 20 ms + refinement, with ``alpha`` refitted once under it), then the general
    forms — a velocity-damping term, play widths growing with the rate; each richer form is kept when it lowers the
    training residual energy by ``RELAX_MIN_GAIN`` below the one before it."""
    sub = search_context(ctx)          # the searches on half the windows, each result evaluated on all of them
    grid = np.array([-0.6, -0.3, -0.1, 0.0, 0.1, 0.3, 0.6, 1.2, 2.5, 5.0])
    same: Callable[[float], float] = lambda z: z  # noqa: E731
    one: Callable[[float], float] = lambda z: 1.0  # noqa: E731
    base = _scalar_searched(ctx, sub, "alpha", lambda z: {"alpha": z}, grid, same, one, same)
    alpha = float(base.params["alpha"])
    lo = math.log(max(20e-6, 0.3 * ctx.dt))
    tgrid = np.linspace(lo, math.log(20e-3), 10)
    rel = _scalar_searched(ctx, sub, "relaxation", lambda z: {"alpha": alpha, "relaxation": math.exp(z)}, tgrid,
                           math.exp, math.exp, math.log)
    tau = float(rel.params["relaxation"])
    agrid = alpha + np.array([-0.4, -0.15, -0.05, 0.0, 0.05, 0.15, 0.4])
    both = _scalar_searched(ctx, sub, "alpha", lambda z: {"alpha": z, "relaxation": tau}, agrid, same, one, same)
    best = min((rel, both), key=lambda f: f.train_rms)
    if best.train_rms ** 2 > (1 - RELAX_MIN_GAIN) * base.train_rms ** 2:
        chosen = base
    else:
        p = dict(best.effects[0][1])
        se = {"alpha": both.stderr.get("alpha") if best is both else base.stderr.get("alpha"),
              "relaxation": rel.stderr.get("relaxation")}
        chosen = FitResult("hysteresis_rate_dependence", p, se, [("hysteresis_rate_dependence", p)], 2,
                           best.train_rms, note=f"hysteretic state relaxes over {1e3 * p['relaxation']:.3g} ms")
    # the general rate-dependent forms, by parameter count (a velocity term; play widths growing with the rate):
    # each richer form is kept when it lowers the training residual energy by RELAX_MIN_GAIN below the current one
    for form in (_velocity_form(ctx), _rate_play_form(ctx)):
        if form is not None and form.train_rms ** 2 < (1 - RELAX_MIN_GAIN) * chosen.train_rms ** 2:
            chosen = form
    return chosen


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

    def regressors(y_w: np.ndarray) -> tuple[list[np.ndarray], list[float]]:
        """The even, branch-dependent term and the loop-width plays (radii a fixed share of the stroke) on y_w."""
        q, dq = _windowed(lambda yy: fx.BranchEvenTerm(0.0, 0.0, ctx.dt, n).terms(yy), y_w, ctx.windows, 2)
        half = float(np.mean(0.5 * (np.max(y_w, axis=0) - np.min(y_w, axis=0))))
        radii = [f * max(half, 1e-12) for f in PLAY_FRACTIONS]
        W = _windowed(lambda yy: tuple(np.moveaxis(fx.PlayWidthTerm(radii, np.zeros((len(radii), n)), n).terms(yy),
                                                   1, 0)), y_w, ctx.windows, len(radii))
        return [q, dq] + list(W), radii

    # the linear terms, near enough on the base model's output, are projected out of the residual while Δ is
    # fitted (variable projection): Δ must not take what the even and loop-width terms explain
    Q = np.linalg.qr(_per_axis_columns(regressors(ctx.y_base_win)[0], n))[0]
    output = _trial_outputs(ctx, make, keep=4 * n + 2)

    def resid(theta: np.ndarray) -> np.ndarray:
        r = residual(ctx.target, output(theta)).reshape(-1)
        out: np.ndarray = (r - Q @ (Q.T @ r)) / unit
        return out

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # unbounded trust region: the problem is nearly linear in Δ and converges in a few steps (bounds slow it)
        sol = optimize.least_squares(resid, np.zeros(2 * n), diff_step=1e-3, max_nfev=40)
    r = sol.fun.reshape(-1, n)
    se = _stderr(sol.jac, r) * scale
    p = make(sol.x)
    # then the even, branch-dependent and loop-width terms, linear given the generalized Bouc-Wen: regression
    y_w = output(sol.x)                           # the solution's replay: one of the trials already run
    r_w = residual(ctx.target, y_w)
    regs, radii = regressors(y_w)
    coef, res, se2 = _lin_per_axis(r_w, regs)
    p = dict(p, even=coef[0].tolist(), branch_even=coef[1].tolist(), play_radii=radii,
             play_gains=coef[2:].tolist())
    disp = FitResult("hysteresis_asymmetry", p, {"Delta1": se[:n].tolist(), "Delta2": se[n:].tolist(),
                                                 "even": se2[0].tolist(), "branch_even": se2[1].tolist(),
                                                 "play_radii": None, "play_gains": se2[2:].tolist()},
                     [("hysteresis_asymmetry", p)], (4 + len(radii)) * n, _rms(res))
    best = disp
    shape = _loop_shape_form(ctx, make, output, scale, unit, sol.x) if not ctx.base else None
    if shape is not None and shape.train_rms ** 2 < (1 - LOOP_SHAPE_MIN_GAIN) * best.train_rms ** 2:
        best = shape
    relays = _relay_plane_form(ctx) if not ctx.base else None
    if relays is not None and relays.train_rms ** 2 < (1 - LOOP_SHAPE_MIN_GAIN) * best.train_rms ** 2:
        best = relays
    return best


#: threshold levels of the discretised Preisach plane, spread evenly over the voltage range of TRAIN: the relays
#: are every pair (α, β) of levels with β < α (RELAY_LEVELS·(RELAY_LEVELS − 1)/2 per axis)
RELAY_LEVELS = 9
#: a relay enters the fit when it switches at least this often on TRAIN (two round trips of its own loop)
RELAY_MIN_SWITCHES = 4


def _relay_plane_form(ctx: FitContext) -> FitResult | None:
    """An added hysteretic term with its own loop (:class:`~..models.effects.RelayPlaneTerm`): a discretised
    Preisach plane on the voltage at the hysteresis output, the nominal Bouc-Wen kept.  The output is linear in
    the relays' weights (the creep and the dynamics behind the hysteresis are linear): the chain's response to
    each relay, then the weights by least squares on TRAIN, of one sign per axis (:func:`_signed_density`).  Only
    relays of nonzero width (β < α): a weight on them is a loop — area, and an output that depends on the
    reversal history — not a memoryless gain or compression, whose own candidates name those."""
    n = ctx.cfg.n_axes
    h = ctx.cfg.hysteresis
    if h.n_in != n or h.n_out != n:
        return None
    lo, hi = float(np.min(ctx.u)), float(np.max(ctx.u))
    if not hi > lo:
        return None
    step = (hi - lo) / RELAY_LEVELS
    levels = lo + step * (np.arange(RELAY_LEVELS) + 0.5)
    ia, ib = np.triu_indices(RELAY_LEVELS, 1)
    alpha, beta = levels[ib].tolist(), levels[ia].tolist()     # β = levels[i] < α = levels[j]
    R = len(alpha)
    dp = np.diag(h.arrays()["Dp"])
    # a relay's weight is told by its loop only where TRAIN runs round it: one that switches a few times is a step
    # in time (it would take a slow trend, a creep's); kept when it switches RELAY_MIN_SWITCHES times on its axis
    switches = _relay_switches(ctx, alpha, beta)                              # [R, n], on the fit windows
    if not np.any(switches >= RELAY_MIN_SWITCHES):
        return None
    gate = (switches >= RELAY_MIN_SWITCHES).astype(float)
    X = _chain_response(ctx, lambda: fx.RelayPlaneTerm(dp, alpha, beta, np.zeros((R, n))),
                        lambda st, u: st.terms(u) * gate)
    used = np.flatnonzero(gate.reshape(-1))                                   # columns relay-major, axis-minor
    r = residual(ctx.target, ctx.y_base_win).reshape(-1)
    Xu = X[:, used]
    # [Xu r] = Q·[R Qᵀr; 0 ρ]: the triangular factor alone (Q never formed) gives the weights and XᵀX = RᵀR
    Ra = np.asarray(linalg.qr(np.column_stack([Xu, r]), mode="r", check_finite=False)[0])
    k = len(used)
    Rm, b = Ra[:k, :k], Ra[:k, k]
    c = np.zeros(R * n)
    c[used] = _signed_density(Rm, b, used % n, n)
    res = (r - X @ c).reshape(-1, n)
    se = np.zeros(R * n)
    s2 = float(np.sum(res ** 2)) / max(res.size - k, 1) * n_eff_ratio(res)
    se[used] = np.sqrt(np.maximum(np.diag(np.linalg.pinv(Rm.T @ Rm)) * s2, 0.0))
    p = {"Delta1": [0.0] * n, "Delta2": [0.0] * n, "relay_alpha": alpha, "relay_beta": beta,
         "relay_gains": c.reshape(R, n).tolist()}
    return FitResult("hysteresis_asymmetry", p, {"Delta1": None, "Delta2": None, "relay_alpha": None,
                                                 "relay_beta": None, "relay_gains": se.reshape(R, n).tolist()},
                     [("hysteresis_asymmetry", p)], R * n, _rms(res),
                     note=f"an added hysteretic term: a Preisach plane of {R} relays per axis on the voltage")


def _relay_switches(ctx: FitContext, alpha: list[float], beta: list[float], block: int = 20_000) -> np.ndarray:
    """How often each relay switches on each axis over the fit windows' scored samples, [R, n] (the relays run
    from each window's warm start, block by block: the states are never held for a whole window)."""
    n = ctx.cfg.n_axes
    count = np.zeros((len(alpha), n), dtype=np.int64)
    for w, s_, e_ in ctx.windows.spans:
        term = fx.RelayPlaneTerm(np.ones(n), alpha, beta, np.zeros((len(alpha), n)))
        last: np.ndarray | None = None
        for a in range(w, e_, block):
            st = term.terms(ctx.u[a:min(a + block, e_)])
            st = st[max(s_ - a, 0):]
            if len(st) == 0:
                continue
            if last is not None:
                count += st[0] != last
            count += np.count_nonzero(np.diff(st, axis=0), axis=0)
            last = st[-1]
    return count


def _signed_density(Rm: np.ndarray, b: np.ndarray, axis_of: np.ndarray, n: int) -> np.ndarray:
    """Relay weights of one sign per axis minimising ``‖Rm·c − b‖`` (``Rm``, ``b``: the triangular factor of the
    relays' responses and the residual rotated with it — the same minimiser as on the responses themselves; column
    k on axis ``axis_of[k]``): a Preisach density does not change sign (an added loop runs one way round), and the
    constraint keeps neighbouring, nearly collinear relays from taking large weights of opposite signs that cancel
    on TRAIN and not on another record.  Non-negative least squares for each of the 2ⁿ sign patterns, the best
    kept."""
    best: tuple[float, np.ndarray] | None = None
    for signs in itertools.product((1.0, -1.0), repeat=n):
        d = np.asarray(signs)[axis_of]
        w, rnorm = optimize.nnls(Rm * d, b)
        if best is None or rnorm < best[0]:
            best = (float(rnorm), d * w)
    assert best is not None
    return best[1]


#: the loop-shape terms at the hysteresis output replace the displacement-side ones when they lower the training
#: residual energy by this share (the family with more parameters earns them on TRAIN: the RAIL_MIN_GAIN rule)
LOOP_SHAPE_MIN_GAIN = 0.02


def _trial_outputs(ctx: FitContext, make: Callable[[np.ndarray], dict[str, Any]],
                   keep: int) -> Callable[[np.ndarray], np.ndarray]:
    """``output(theta)``: the model's replay on the fit windows with ``("hysteresis_asymmetry", make(theta))``
    added, the last ``keep`` trials remembered — a least-squares solver returns one of the points it evaluated, and
    the next fit starts from it, so neither re-runs the (costly) Bouc-Wen replay at that point."""
    store: OrderedDict[bytes, np.ndarray] = OrderedDict()

    def output(theta: np.ndarray) -> np.ndarray:
        key = np.asarray(theta, float).tobytes()
        if key in store:
            store.move_to_end(key)
            return store[key]
        y = simulate(ctx.cfg, ctx.u, list(ctx.base) + [("hysteresis_asymmetry", make(theta))], ctx.windows)
        store[key] = y
        while len(store) > keep:
            store.popitem(last=False)
        return y

    return output


def _loop_shape_form(ctx: FitContext, make: Callable[[np.ndarray], dict[str, Any]],
                     output: Callable[[np.ndarray], np.ndarray], scale: np.ndarray, unit: float,
                     theta0: np.ndarray) -> FitResult | None:
    """Δ1/Δ2 and the loop-shape terms at the hysteresis output (:class:`~..models.effects.LoopShapeTerm`): the
    terms' gains are linear and do not depend on Δ (they are functions of the voltage), so Δ is fitted on the
    residual with the terms' responses projected out (variable projection), from the displacement family's Δ
    ``theta0`` (the problem is nearly linear in Δ: a Gauss-Newton step or two), then the gains by least squares.
    ``output``: the replay of a trial Δ (:func:`_trial_outputs`, shared with the displacement family's fit)."""
    n = ctx.cfg.n_axes
    cols = _loop_shape_columns(ctx)
    if cols is None:
        return None
    X, uradii = cols
    Q, _ = np.linalg.qr(X)

    def resid(theta: np.ndarray) -> np.ndarray:
        r = residual(ctx.target, output(theta)).reshape(-1)
        out: np.ndarray = (r - Q @ (Q.T @ r)) / unit
        return out

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = optimize.least_squares(resid, np.asarray(theta0, float), diff_step=1e-3, max_nfev=4 * n + 2)
    p = make(sol.x)
    r = residual(ctx.target, output(sol.x)).reshape(-1)
    c, *_ = np.linalg.lstsq(X, r, rcond=None)
    res = (r - X @ c).reshape(-1, n)
    se_d = _stderr(sol.jac, res / unit) * scale
    se_c = _stderr(-X, res)
    K = len(uradii)
    cs, ss = c.reshape(1 + 2 * K, n), se_c.reshape(1 + 2 * K, n)   # rows: even, plays k, level-weighted plays k
    p = dict(p, input_even=cs[0].tolist(), input_play_radii=uradii, input_play_gains=cs[1:1 + K].tolist(),
             input_play_level_gains=cs[1 + K:].tolist())
    return FitResult("hysteresis_asymmetry", p, {"Delta1": se_d[:n].tolist(), "Delta2": se_d[n:].tolist(),
                                                 "input_even": ss[0].tolist(), "input_play_radii": None,
                                                 "input_play_gains": ss[1:1 + K].tolist(),
                                                 "input_play_level_gains": ss[1 + K:].tolist()},
                     [("hysteresis_asymmetry", p)], 2 * n + X.shape[1], _rms(res),
                     note="loop-shape terms at the hysteresis output (even bend, play widths, level-dependent width)")


def _per_axis_columns(regs: list[np.ndarray], n: int) -> np.ndarray:
    """Per-axis regressors [N, n] as flattened columns (each nonzero on its own axis only, mean removed)."""
    cols = []
    for g in regs:
        for i in range(n):
            c = np.zeros_like(g)
            c[:, i] = g[:, i] - g[:, i].mean()
            cols.append(c.reshape(-1))
    return np.column_stack(cols)


#: radii of the loop-shape play operators on the voltage, as shares of half the voltage range of TRAIN
INPUT_PLAY_FRACTIONS = (0.05, 0.15, 0.4)


def _loop_shape_columns(ctx: FitContext) -> tuple[np.ndarray, list[float]] | None:
    """The responses to the loop-shape terms (:class:`~..models.effects.LoopShapeTerm`) at the hysteresis output:
    columns (even, plays, level-weighted plays) × axis, and the play radii [V]."""
    n = ctx.cfg.n_axes
    h = ctx.cfg.hysteresis
    if h.n_in != n or h.n_out != n:
        return None
    half = float(np.mean(0.5 * (np.max(ctx.u, axis=0) - np.min(ctx.u, axis=0))))
    if not half > 0:
        return None
    radii = [f * half for f in INPUT_PLAY_FRACTIONS]
    dp = np.diag(h.arrays()["Dp"])
    K = len(radii)
    zero = np.zeros((K, n))

    def terms(st: Any, u: np.ndarray) -> np.ndarray:
        q, w, wl = st.terms(u)
        return np.concatenate([q[:, None, :], w, wl], axis=1)

    X = _chain_response(ctx, lambda: fx.LoopShapeTerm(dp, 0.0, radii, zero, zero), terms)
    return X, radii


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
