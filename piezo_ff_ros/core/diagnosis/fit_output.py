"""Displacement-side candidates: regression on the base model's output (gain and cross-talk, the creep law, a
thermal drift).  They act on the output, so no re-simulation is needed and they fit on the whole training run
(every k-th row of a long one, see :data:`~.fit_common.MAX_REGRESSION_ROWS`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize, signal

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


@njit
def _creep_bank_decades(y: np.ndarray, a: np.ndarray, yref: float, k: int, O1: np.ndarray, O2: np.ndarray,
                        O3: np.ndarray) -> None:  # pragma: no cover - compiled
    """Each relaxation of the creep bank apart, on y, on y|y|/yref and on y²/yref, kept every k-th row:
    ``O[m, N/k, n]``."""
    N, n = y.shape
    m = a.shape[0]
    for j in range(n):
        s1 = np.zeros(m)
        s2 = np.zeros(m)
        s3 = np.zeros(m)
        for t in range(N):
            x = y[t, j]
            q = x * abs(x) / yref
            e = x * x / yref
            keep = t % k == 0
            for i in range(m):
                s1[i] = a[i] * s1[i] + (1.0 - a[i]) * x
                s2[i] = a[i] * s2[i] + (1.0 - a[i]) * q
                s3[i] = a[i] * s3[i] + (1.0 - a[i]) * e
                if keep:
                    O1[i, t // k, j] = s1[i]
                    O2[i, t // k, j] = s2[i]
                    O3[i, t // k, j] = s3[i]


def _creep_regs(y_base: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The creep candidate's two regressors: the log-time relaxation bank of :class:`~..models.effects.
    CreepNonlinearity` applied to Ŷ and to Ŷ|Ŷ|/Y_ref (what ``CreepNonlinearity(γ=1, β=0)`` adds to its input)."""
    y = np.ascontiguousarray(y_base, dtype=float)
    a = np.exp(-dt / np.asarray(fx.CREEP_TAUS, float))
    S1 = np.empty_like(y)
    S2 = np.empty_like(y)
    _creep_bank2(y, a, fx.CREEP_YREF, S1, S2)
    return S1, S2


#: the creep law's relaxation spectrum (a free weight per decade and axis: a Prony series, any linear creep law over
#: the bank's span) is kept when it lowers the training residual energy by this share below the log law's (the
#: richer law must earn its parameters on TRAIN, like RAIL_MIN_GAIN; set from that definition, not tuned)
CREEP_SPECTRUM_MIN_GAIN = 0.02


def _creep_at(r0: np.ndarray, S1: np.ndarray, S2: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """γ per axis and the shared β of the level-dependent creep for the regressors S1, S2: ``(γ, β, residual, Sβ)``."""
    coef, _, _ = _lin_per_axis(r0, [S1, S2])
    g1, g2 = coef
    beta = float(np.sum(g1 * g2) / max(np.sum(g1 * g1), 1e-300))
    beta = float(np.clip(beta, -50.0, 50.0))
    # γ per axis with β shared: regress on S1 + β S2
    Sb = S1 + beta * S2
    c, res, _ = _lin_per_axis(r0, [Sb])
    return c[0], beta, res, Sb


def _lin_sse(y: np.ndarray, regs: list[np.ndarray]) -> float:
    """The residual energy of :func:`~.fit_common._lin_per_axis` (per axis, columns centred) without its standard
    errors: what a parameter search needs."""
    total = 0.0
    for i in range(y.shape[1]):
        X = np.column_stack([g[:, i] - g[:, i].mean() for g in regs])
        t = y[:, i] - y[:, i].mean()
        c, *_ = np.linalg.lstsq(X, t, rcond=None)
        r = t - X @ c
        total += float(r @ r)
    return total


def _creep_spectrum(r0: np.ndarray, O1: np.ndarray, O2: np.ndarray,
                    O3: np.ndarray) -> tuple[np.ndarray, tuple[float, float], np.ndarray, np.ndarray]:
    """The Prony-series creep: a weight per decade and axis on the bank of F = Ŷ + β·Ŷ|Ŷ|/Y_ref + β_e·Ŷ²/Y_ref, β and
    β_e shared by the axes (the weights are linear given them: a 5×5 grid over ±3 — the creep's relative growth at
    10 µm — then a simplex refinement).  Returns ``(weights [m, n], (β, β_e), residual, Jacobian)``."""
    m = O1.shape[0]
    q = max(1, -(-len(r0) // _DRIFT_SEARCH_ROWS))   # the level terms' search on a thinned copy (smooth in β)
    rq = np.ascontiguousarray(r0[::q])
    O1q, O2q, O3q = (np.ascontiguousarray(O[:, ::q]) for O in (O1, O2, O3))

    def bank(b: np.ndarray, A: np.ndarray = O1, B: np.ndarray = O2, C: np.ndarray = O3) -> list[np.ndarray]:
        return [A[d] + b[0] * B[d] + b[1] * C[d] for d in range(m)]

    def sse(b: np.ndarray) -> float:
        return _lin_sse(rq, bank(b, O1q, O2q, O3q))

    grid = np.linspace(-3.0, 3.0, 5)
    b0 = min(((x, y) for x in grid for y in grid), key=lambda b: sse(np.array(b)))
    sol = optimize.minimize(sse, np.array(b0), method="Nelder-Mead",
                            options={"xatol": 1e-3, "fatol": 0.0, "maxfev": 40, "initial_simplex":
                                     np.array([b0, (b0[0] + 0.5, b0[1]), (b0[0], b0[1] + 0.5)])})
    b = np.clip(sol.x if sol.fun <= sse(np.array(b0)) else np.array(b0), -50.0, 50.0)
    F = bank(b)
    w, res, _ = _lin_per_axis(r0, F)
    n = r0.shape[1]
    cols = []
    for i in range(n):
        for d in range(m):
            col = np.zeros_like(r0)
            col[:, i] = -(F[d][:, i] - F[d][:, i].mean())
            cols.append(col.reshape(-1))
    for O in (O2, O3):
        dF = np.einsum("dn,dtn->tn", w, O)
        cols.append((-(dF - dF.mean(axis=0))).reshape(-1))
    return w, (float(b[0]), float(b[1])), res, np.column_stack(cols)


def fit_creep_nonlinearity(ctx: FitContext) -> FitResult:
    """The level-dependent creep law: γ per axis and a shared β, by regression on the relaxation bank applied to
    Ŷ and to Ŷ|Ŷ|/Y_ref (the log-time law); then one Kelvin–Voigt element of free retardation time fed by Ŷ and
    Ŷ|Ŷ|/Y_ref (:func:`_kelvin_voigt_creep`: a creep that saturates within the record, growing with the level);
    then the relaxation spectrum (a weight per decade and axis, any linear creep law).  Each richer form is kept
    when it earns its parameters on TRAIN (:data:`CREEP_SPECTRUM_MIN_GAIN` below the best simpler form)."""
    k = _stride(len(ctx.y))
    r0 = residual(ctx.y[::k], ctx.y_base[::k])
    taus = np.asarray(fx.CREEP_TAUS, float)
    a = np.exp(-ctx.dt / taus)
    y = np.ascontiguousarray(ctx.y_base, dtype=float)
    rows = -(-len(y) // k)
    O1 = np.empty((len(taus), rows, y.shape[1]))
    O2 = np.empty_like(O1)
    O3 = np.empty_like(O1)
    _creep_bank_decades(y, a, fx.CREEP_YREF, k, O1, O2, O3)
    S1, S2 = O1.sum(axis=0), O2.sum(axis=0)
    gamma, beta, res, Sb = _creep_at(r0, S1, S2)
    n = ctx.cfg.n_axes
    sse_log = float(np.sum(res ** 2))
    # the forms in order of their parameter count, each richer one kept only when it earns its parameters on TRAIN
    # (CREEP_SPECTRUM_MIN_GAIN below the best simpler form's residual energy)
    kv = _kelvin_voigt_creep(ctx, r0, k)
    sse_best = sse_log
    if kv is not None and kv.train_rms ** 2 * r0.size < (1 - CREEP_SPECTRUM_MIN_GAIN) * sse_best:
        sse_best = kv.train_rms ** 2 * r0.size
    else:
        kv = None
    w, (beta_s, beta_e), res_s, jac_s = _creep_spectrum(r0, O1, O2, O3)
    if float(np.sum(res_s ** 2)) < (1 - CREEP_SPECTRUM_MIN_GAIN) * sse_best:
        # γ_i: the mean weight (the log law's γ when the spectrum is flat); the spectrum relative to it
        g = w.mean(axis=0)
        g = np.where(np.abs(g) > 1e-12, g, 1.0)
        params = {"gamma": g.tolist(), "beta": beta_s, "beta_even": beta_e, "spectrum": (w / g).tolist()}
        se = _stderr(jac_s, res_s)
        stderr = {"gamma": None, "beta": float(se[-2]), "beta_even": float(se[-1]), "spectrum": None}
        return FitResult("creep_nonlinearity", params, stderr, [("creep_nonlinearity", params)],
                         w.size + 2, _rms(res_s),
                         note="relaxation spectrum per decade " + ", ".join(f"{t:g} s" for t in taus))
    if kv is not None:
        return kv
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


#: the Kelvin–Voigt creep's retardation time is searched between KV_TAU_MIN [s] (or KV_TAU_MIN_SAMPLES samples, the
#: longer) and the training record's duration: a relaxation slower than the record is a ramp over it, its time
#: constant not measured
KV_TAU_MIN = 0.01
KV_TAU_MIN_SAMPLES = 20
KV_GRID = 13


@njit
def _kv_bank(y: np.ndarray, a: np.ndarray, yref: float, k: int, out: np.ndarray) -> None:  # pragma: no cover
    """:func:`_kv_regs` for several retardations at once, kept every k-th row: ``out[m, 0|1, N/k, n]``, the same
    numbers as ``lfilter([1 - a], [1, -a], ·)[::k]`` (the same operations in the same order) without the full-length
    outputs (a 10-minute 20 kHz record: 12 M rows a regressor)."""
    N, n = y.shape
    for j in range(n):
        for i in range(a.shape[0]):
            ai = a[i]
            bi = 1.0 - ai
            s1 = 0.0
            s2 = 0.0
            for t in range(N):
                x = y[t, j]
                q = x * abs(x) / yref
                s1 = bi * x + ai * s1
                s2 = bi * q + ai * s2
                if t % k == 0:
                    out[i, 0, t // k, j] = s1
                    out[i, 1, t // k, j] = s2


def _kv_regs(y: np.ndarray, tau: float, dt: float) -> list[np.ndarray]:
    """The Kelvin–Voigt creep's regressors: the unit-DC relaxation of Ŷ and of Ŷ|Ŷ|/Y_ref, from rest."""
    a = math.exp(-dt / tau)
    b, den = [1.0 - a], [1.0, -a]
    return [signal.lfilter(b, den, y, axis=0), signal.lfilter(b, den, y * np.abs(y) / fx.CREEP_YREF, axis=0)]


def _kelvin_voigt_creep(ctx: FitContext, r0: np.ndarray, k: int) -> FitResult | None:
    """One Kelvin–Voigt creep element (:class:`~..models.effects.creep_kv.KelvinVoigtCreep`): its retardation time
    on a log grid and a bounded refinement (the gains are linear given it: closed-form energy, the search on a
    thinned copy of a long run), the gains per axis by regression on every kept row.  ``None`` on a run too short
    for the grid."""
    dt = ctx.dt
    T = len(ctx.y) * dt
    lo, hi = max(KV_TAU_MIN, KV_TAU_MIN_SAMPLES * dt), T
    if not hi > 2 * lo:
        return None
    q = max(1, -(-len(ctx.y) // _DRIFT_SEARCH_ROWS))
    yq = np.ascontiguousarray(ctx.y_base[::q], dtype=float)
    rq = residual(ctx.y[::q], ctx.y_base[::q])

    def sse(z: float) -> float:
        return _lin_sse(rq, _kv_regs(yq, math.exp(z), dt * q))

    grid = np.linspace(math.log(lo), math.log(hi), KV_GRID)
    vals = [sse(z) for z in grid]
    j = int(np.argmin(vals))
    a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    z = float(optimize.minimize_scalar(sse, bounds=(a, b), method="bounded", options={"xatol": 1e-3}).x)
    if sse(z) > vals[j]:
        z = float(grid[j])
    tau = math.exp(z)
    y = np.ascontiguousarray(ctx.y_base, dtype=float)
    # the regressors at τ and, for the Jacobian over (a_1..a_n, b_1..b_n, log τ) of the standard errors, at τ·e^±h:
    # one pass over the record, every k-th row kept
    h = 1e-3
    bank = np.empty((3, 2, -(-len(y) // k), y.shape[1]))
    _kv_bank(y, np.array([math.exp(-dt / t) for t in (tau, tau * math.exp(h), tau * math.exp(-h))]), fx.CREEP_YREF,
             k, bank)
    R, Rp, Rm = list(bank[0]), list(bank[1]), list(bank[2])
    coef, res, _ = _lin_per_axis(r0, R)
    n = r0.shape[1]
    cols = []
    for m in range(2):
        for i in range(n):
            col = np.zeros_like(r0)
            col[:, i] = -(R[m][:, i] - R[m][:, i].mean())
            cols.append(col.reshape(-1))
    dF = sum(coef[m] * (Rp[m] - Rm[m]) / (2 * h) for m in range(2))
    cols.append((-(dF - dF.mean(axis=0))).reshape(-1))
    se = _stderr(np.column_stack(cols), res)
    params = {"retardation": tau, "kv_gains": coef[0].tolist(), "kv_level_gains": coef[1].tolist()}
    stderr = {"retardation": float(se[-1] * tau), "kv_gains": se[:n].tolist(), "kv_level_gains": se[n:2 * n].tolist()}
    return FitResult("creep_nonlinearity", params, stderr, [("creep_nonlinearity", params)], 2 * n + 1, _rms(res),
                     note=f"one Kelvin–Voigt element, retardation time {tau:.3g} s, fed by the level and its "
                          "signed square")


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
    simple = FitResult("thermal_drift", params, {"amplitudes": se[:n].tolist(), "time_constant": float(se[n] * tau)},
                       [("thermal_drift", params)], n + 1, _rms(res))
    two = _two_body_drift(r0, ctx.y_base[::_stride(len(ctx.y))], tk, T)
    if two is not None and two.train_rms ** 2 < (1 - DRIFT_TWO_BODY_MIN_GAIN) * simple.train_rms ** 2:
        return two
    return simple


#: the two-body thermal drift (two time constants, the gain following the temperature) is kept when it lowers the
#: training residual energy by this share below the one-exponential offset drift's (the richer form must earn its
#: parameters on TRAIN, like RAIL_MIN_GAIN; set from that definition, not tuned)
DRIFT_TWO_BODY_MIN_GAIN = 0.02
#: the time-constant search of the two-body drift runs on at most this many rows (the shapes are smooth)
_DRIFT_SEARCH_ROWS = 20_000


def _two_body_drift(r0: np.ndarray, y_base: np.ndarray, tk: np.ndarray, T: float) -> FitResult | None:
    """Two first-order thermal responses to the switch-on (stack and mount), each moving the offset and the gain of
    every axis: ``r_i ≈ a_i·s1 + b_i·s2 + (g_i·s1 + h_i·s2)·Ŷ_i``; τ1 < τ2 on a log grid (closed-form energy on a
    thinned copy), refined one at a time, the coefficients by regression on every row."""
    n = r0.shape[1]
    q = max(1, -(-len(r0) // _DRIFT_SEARCH_ROWS))

    def regs(t: np.ndarray, yb: np.ndarray, t1: float, t2: float) -> list[np.ndarray]:
        # the last regressor, Ŷ itself, is a nuisance: a constant gain error is not a drift (a drift is a function
        # of time; with it in the regression the drift's gain terms can only take a gain that *changes* over the
        # run — a fast time constant would otherwise turn them into a constant gain)
        s1 = -np.expm1(-t / t1)[:, None]
        s2 = -np.expm1(-t / t2)[:, None]
        return [np.repeat(s1, n, axis=1), np.repeat(s2, n, axis=1), s1 * yb, s2 * yb, yb]

    rs, ts, ys = r0[::q], tk[::q], y_base[::q]

    def sse(z1: float, z2: float) -> float:
        return _lin_sse(rs, regs(ts, ys, math.exp(z1), math.exp(z2)))

    grid = np.log(T) + np.linspace(math.log(0.02), math.log(20.0), 10)
    pairs = [(z1, z2) for i, z1 in enumerate(grid) for z2 in grid[i + 1:]]
    z1, z2 = min(pairs, key=lambda p: sse(*p))
    step = grid[1] - grid[0]
    top = grid[-1]   # 20 T: beyond it every shape is a straight line over the run
    for _ in range(2):  # coordinate refinement within one grid step
        z1 = optimize.minimize_scalar(lambda z: sse(z, z2), bounds=(z1 - step, min(z1 + step, z2 - 1e-3)),
                                      method="bounded", options={"xatol": 1e-3}).x
        z2 = optimize.minimize_scalar(lambda z: sse(z1, z), bounds=(max(z2 - step, z1 + 1e-3), min(z2 + step, top)),
                                      method="bounded", options={"xatol": 1e-3}).x
    t1, t2 = math.exp(z1), math.exp(z2)
    try:
        R = regs(tk, y_base, t1, t2)
        coef, _, se = _lin_per_axis(r0, R)
    except np.linalg.LinAlgError:
        return None
    a, b, g, h, _gain = coef
    # what the drift itself explains (the nuisance gain left out): its training residual
    fit = sum(c * x for c, x in zip((a, b, g, h), R[:4]))
    res = r0 - fit
    res = res - res.mean(axis=0)
    params = {"amplitudes": a.tolist(), "time_constant": t1, "amplitudes2": b.tolist(), "time_constant2": t2,
              "gain_drift": g.tolist(), "gain_drift2": h.tolist()}
    stderr = {"amplitudes": se[0].tolist(), "time_constant": None, "amplitudes2": se[1].tolist(),
              "time_constant2": None, "gain_drift": se[2].tolist(), "gain_drift2": se[3].tolist()}
    return FitResult("thermal_drift", params, stderr, [("thermal_drift", params)], 4 * n + 2, _rms(res),
                     note="two-body drift: offset and gain follow two thermal time constants")
