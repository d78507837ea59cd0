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
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize

from .._jit import njit
from ..config import PiezoConfig
from ..models import effects as fx
from .replay import Windows, residual, simulate

__all__ = ["FitContext", "FitResult", "fit_candidate", "CANDIDATES", "n_eff_ratio"]


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


# ----------------------------------------------------------------------------------------------------------------
# Displacement-side effects: regression on the base model's output
# ----------------------------------------------------------------------------------------------------------------

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


def _creep_regs(y_base: np.ndarray, dt: float, beta: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The creep candidate's two regressors: the log-time relaxation bank of :class:`~..models.effects.
    CreepNonlinearity` applied to Ŷ and to Ŷ|Ŷ|/Y_ref (what ``CreepNonlinearity(γ=1, β=0)`` adds to its input)."""
    y = np.ascontiguousarray(y_base, dtype=float)
    a = np.exp(-dt / np.asarray(fx.CREEP_TAUS, float))
    S1 = np.empty_like(y)
    S2 = np.empty_like(y)
    _creep_bank2(y, a, fx.CREEP_YREF, S1, S2)
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


def _mode_design(y_base: np.ndarray, freq: float, damping: float, dt: float, windows: Windows | None) -> np.ndarray:
    n = y_base.shape[1]
    st = fx.UnmodelledMode(freq, damping, np.zeros(n), dt, n)
    if windows is None or windows.is_whole:
        return st.bandpass(y_base)
    return windows.apply(st.reset, st.bandpass, y_base)


#: at most this many modes per fit, and the share of the current training residual a new mode must remove
MAX_MODES = 4
MODE_MIN_GAIN = 0.02
#: a structural mode lies above MODE_FMIN [Hz] and is lightly damped (ζ ≤ MODE_ZMAX): a broad band-pass at the
#: excitation's own frequencies would otherwise pass for a "mode" while only patching the gain and phase there
MODE_FMIN = 20.0
MODE_ZMAX = 0.5


def _hp_design(y_base: np.ndarray, freq: float, damping: float, dt: float, windows: Windows | None) -> np.ndarray:
    n = y_base.shape[1]
    st = fx.UnmodelledMode(freq, damping, np.zeros(n), dt, n)
    if windows is None or windows.is_whole:
        return st.highpass(y_base)
    return windows.apply(st.reset, st.highpass, y_base)


def _level_design(y_base: np.ndarray, dt: float, windows: Windows | None) -> np.ndarray:
    n = y_base.shape[1]
    st = fx.AmplitudeDependentDynamics(10.0, 0.1, np.zeros(n), np.zeros(n), dt, n)
    if windows is None or windows.is_whole:
        return st.level(y_base)
    return windows.apply(st.reset, st.level, y_base)


@njit
def _bp_hp_run(y: np.ndarray, spans: np.ndarray, k: int, cb: np.ndarray, ch: np.ndarray, B: np.ndarray,
               H: np.ndarray) -> None:  # pragma: no cover - compiled
    """Band-pass and high-pass biquads (coefficients ``cb``, ``ch``: b0, b1, b2, a1, a2) of every column of ``y``
    on each window ``(warm, start, stop)`` (state reset at ``warm``), every k-th scored sample kept."""
    n = y.shape[1]
    g = 0
    row = 0
    for w in range(spans.shape[0]):
        w0, s0, e0 = spans[w, 0], spans[w, 1], spans[w, 2]
        for j in range(n):
            zb0 = 0.0
            zb1 = 0.0
            zh0 = 0.0
            zh1 = 0.0
            gj = g
            rj = row
            for t in range(w0, e0):
                x = y[t, j]
                yb = cb[0] * x + zb0
                zb0 = cb[1] * x - cb[3] * yb + zb1
                zb1 = cb[2] * x - cb[4] * yb
                yh = ch[0] * x + zh0
                zh0 = ch[1] * x - ch[3] * yh + zh1
                zh1 = ch[2] * x - ch[4] * yh
                if t >= s0:
                    if gj % k == 0:
                        B[rj, j] = yb
                        H[rj, j] = yh
                        rj += 1
                    gj += 1
        # every column advanced the counters alike
        for t in range(s0, e0):
            if g % k == 0:
                row += 1
            g += 1


def _bp_hp_design(y: np.ndarray, spans: np.ndarray, k: int, freq: float, damping: float,
                  dt: float) -> np.ndarray:
    """``[BP | HP]`` (columns) of the mode (freq, damping) on the windows ``spans``, every k-th row: the same filters as
    :class:`~piezo_ff_ros.core.models.effects.UnmodelledMode` in one compiled pass."""
    total = int(np.sum(spans[:, 2] - spans[:, 1]))
    rows = -(-total // k)
    n = y.shape[1]
    BH = np.empty((rows, 2 * n))
    cb = np.array(fx._bandpass_coeffs(freq, damping, dt))
    ch = np.array(fx._highpass_coeffs(freq, damping, dt))
    _bp_hp_run(y, spans, int(k), cb, ch, BH[:, :n], BH[:, n:])
    return BH


def _solve_normal(A: np.ndarray, B: np.ndarray, X_of: Callable[[], np.ndarray], T: np.ndarray) -> np.ndarray:
    """Solution of the normal equations ``A C = B`` (``A = XᵀX``, ``B = XᵀT``), column-scaled; when they are
    ill-conditioned, the minimum-norm least-squares solution of ``X C ≈ T`` (``X_of()`` builds X)."""
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    As = A / np.outer(d, d)
    try:
        C = np.linalg.solve(As, B / d[:, None])
        if not np.all(np.isfinite(C)) or np.linalg.cond(As) > 1e10:
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        X = X_of()
        dx = np.sqrt(np.einsum("ij,ij->j", X, X))
        dx[dx == 0] = 1.0
        C_ls: np.ndarray = np.linalg.lstsq(X / dx, T, rcond=None)[0] / dx[:, None]
        return C_ls
    out: np.ndarray = C / d[:, None]
    return out


def _explained(X: np.ndarray, T: np.ndarray) -> float:
    """Energy of the least-squares projection of every column of ``T`` on the columns of ``X``
    (``Σ_i ‖X c_i‖²`` with ``c_i`` the solution of ``X c ≈ T[:, i]``), by the normal equations."""
    A = X.T @ X
    B = X.T @ T
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    As = A / np.outer(d, d)
    Bs = B / d[:, None]
    try:
        C = np.linalg.solve(As, Bs)
        if not np.all(np.isfinite(C)) or np.linalg.cond(As) > 1e10:
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        C = np.linalg.lstsq(As, Bs, rcond=1e-10)[0]
    return float(np.sum(Bs * C))


#: a resonance ``(frequency [Hz], damping ratio)``
Mode = tuple[float, float]


class _ModeSearch:
    """Greedy search of resonances in the training residual: each mode adds band-pass regressors of the base
    output; ``kind='cross'``: output i regresses on BP(Ŷ_j) of every axis j (cross-coupled gains);
    ``kind='level'``: on BP(Ŷ_i) and A_i(t)·BP(Ŷ_i) (amplitude-dependent)."""

    def __init__(self, ctx: FitContext, kind: str):
        self.ctx, self.kind = ctx, kind
        win = ctx.windows
        r0 = residual(ctx.y, ctx.y_base) if win.is_whole else residual(win.take(ctx.y), win.take(ctx.y_base))
        self.k = max(1, -(-len(r0) // 60_000))  # rows kept in the regressions (the filters run on every sample)
        self.r0 = r0[::self.k] - r0[::self.k].mean(axis=0)
        self.n = ctx.cfg.n_axes
        self.lev: np.ndarray | None = _level_design(ctx.y_base, ctx.dt, win)[::self.k] if kind == "level" else None
        self.unit = max(_rms(self.r0), 1e-15)
        self._regs_cache: dict[tuple[float, float], list[np.ndarray]] = {}
        self.y_base_c = np.ascontiguousarray(ctx.y_base, dtype=float)
        self.spans = np.array([(0, 0, len(ctx.y_base))] if win.is_whole else win.spans, dtype=np.int64)
        self.cube: np.ndarray | None = (np.ascontiguousarray(self.y_base_c * (self.y_base_c / fx.LEVEL_REF) ** 2)
                     if kind == "level" else None)
        self._gram_cache: dict[tuple[Mode, Mode, int], np.ndarray] = {}
        self._xtr_cache: dict[tuple[Mode, int], np.ndarray] = {}

    def _grid_regs(self, f: float, z: float) -> list[np.ndarray]:
        """:meth:`regs` without filling the cache (the coarse grid visits each pole pair once per mode)."""
        hit = self._regs_cache.get((float(f), float(z)))
        return hit if hit is not None else self._design(f, z)

    def regs(self, f: float, z: float) -> list[np.ndarray]:
        """Per output i, the regressors [rows, p] this mode adds (cached per pole pair: the greedy search
        refits every earlier mode's gains each time it tries a new one)."""
        key = (float(f), float(z))
        hit = self._regs_cache.get(key)
        if hit is not None:
            return hit
        out = self._design(f, z)
        if len(self._regs_cache) >= 64:  # keep the memory bounded (only the modes being refitted recur)
            self._regs_cache.pop(next(iter(self._regs_cache)))
        self._regs_cache[key] = out
        return out

    def _design(self, f: float, z: float) -> list[np.ndarray]:
        BH = _bp_hp_design(self.y_base_c, self.spans, self.k, f, z, self.ctx.dt)
        BH -= np.full(len(BH), 1.0 / len(BH)) @ BH  # column means (a product: faster than an axis-0 mean)
        B, Hp = BH[:, :self.n], BH[:, self.n:]
        if self.kind == "cross":
            out = [BH] * self.n
        else:
            assert self.cube is not None and self.lev is not None   # kind "level"
            out = []
            CH = _bp_hp_design(self.cube, self.spans, self.k, f, z, self.ctx.dt)
            CH -= np.full(len(CH), 1.0 / len(CH)) @ CH
            for i in range(self.n):  # the cross-coupled mode, its level-modulated and its cubic direct terms
                LB = self.lev[:, i] * B[:, i]
                LH = self.lev[:, i] * Hp[:, i]
                out.append(np.column_stack([B, Hp, LB - LB.mean(), LH - LH.mean(), CH[:, i], CH[:, self.n + i]]))
        return out

    def _gram(self, a: Mode, b: Mode, i: int) -> np.ndarray:
        """``X_aᵀ X_b`` of output i's designs of pole pairs a and b (cached: the earlier modes recur)."""
        key = (a, b, i if self.kind != "cross" else 0)
        G = self._gram_cache.get(key)
        if G is None:
            G = self.regs(*a)[i].T @ self.regs(*b)[i]
            if len(self._gram_cache) >= 256:
                self._gram_cache.pop(next(iter(self._gram_cache)))
            self._gram_cache[key] = G
        return G

    def solve(self, modes: list[Mode]) -> tuple[list[np.ndarray], np.ndarray]:
        """Joint least squares of all modes' gains per output: (coefficients per output, residual).

        Normal equations assembled from cached blocks ``X_aᵀX_b`` and ``X_aᵀr`` (column-scaled, with a
        minimum-norm fallback when they are ill-conditioned): the greedy search refits the earlier modes' gains
        for every trial of a new one, and only the new mode's blocks are new."""
        keys = [(float(f), float(z)) for f, z in modes]
        R = [self.regs(*k) for k in keys]
        res = np.empty_like(self.r0)
        coefs: list[np.ndarray] = []
        outs = [0] if self.kind == "cross" else range(self.n)
        for i in outs:
            A = np.block([[self._gram(a, b, i) for b in keys] for a in keys])
            cols = slice(None) if self.kind == "cross" else slice(i, i + 1)
            Bv = np.vstack([self._xtr(k, i) for k in keys])[:, cols]
            C = _solve_normal(A, Bv, lambda: np.hstack([Ri[i] for Ri in R]), self.r0[:, cols])
            fit = np.zeros((len(self.r0), C.shape[1]))
            o = 0
            for Ri in R:
                p = Ri[i].shape[1]
                fit += Ri[i] @ C[o:o + p]
                o += p
            if self.kind == "cross":
                res[:] = self.r0 - fit
                coefs = [C[:, j] for j in range(self.n)]
            else:
                res[:, i] = self.r0[:, i] - fit[:, 0]
                coefs.append(C[:, 0])
        return coefs, res

    def _xtr(self, key: Mode, i: int) -> np.ndarray:
        """``X_keyᵀ r0`` (all outputs' columns) of output i's design (cached)."""
        ck = (key, i if self.kind != "cross" else 0)
        v = self._xtr_cache.get(ck)
        if v is None:
            v = self.regs(*key)[i].T @ self.r0
            if len(self._xtr_cache) >= 256:
                self._xtr_cache.pop(next(iter(self._xtr_cache)))
            self._xtr_cache[ck] = v
        return v

    def run(self, fmin: float, fmax: float) -> tuple[list[Mode], list[np.ndarray], np.ndarray]:
        """Add modes greedily between ``fmin`` and ``fmax`` [Hz]: ``(modes (f, ζ), coefficients per output,
        residual)``."""
        modes: list[Mode] = []
        coefs: list[np.ndarray] = []
        res = self.r0.copy()
        sse = float(np.sum(res ** 2))
        freqs = np.geomspace(fmin, fmax, 40)
        g = max(1, len(res) // 40_000)  # the coarse grid scores on fewer rows
        for _ in range(MAX_MODES):
            best: tuple[float, Mode | None] = (0.0, None)
            for f in freqs:
                for z in (0.01, 0.05, 0.2):
                    R = self._grid_regs(f, z)
                    gain = 0.0
                    if self.kind == "cross":  # one design shared by every output: one Gram matrix
                        gain = _explained(R[0][::g], res[::g]) * g
                    else:
                        for i in range(self.n):
                            gain += _explained(R[i][::g], res[::g, i:i + 1]) * g
                    if gain > best[0]:
                        best = (gain, (f, z))
            if best[1] is None or best[0] < MODE_MIN_GAIN * sse:
                break
            f0, z0 = best[1]

            def resid(theta: np.ndarray, modes: list[Mode] = modes) -> np.ndarray:
                _, rr = self.solve(modes + [(math.exp(theta[0]), math.exp(theta[1]))])
                return rr.reshape(-1) / self.unit

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sol = optimize.least_squares(resid, [math.log(f0), math.log(z0)], diff_step=1e-3, max_nfev=12,
                                             bounds=([math.log(fmin), math.log(1e-3)],
                                                     [math.log(0.49 / self.ctx.dt), math.log(MODE_ZMAX)]))
            cand = modes + [(math.exp(sol.x[0]), math.exp(sol.x[1]))]
            c_new, r_new = self.solve(cand)
            sse_new = float(np.sum(r_new ** 2))
            if sse - sse_new < MODE_MIN_GAIN * sse:
                break
            modes, coefs, res, sse = cand, c_new, r_new, sse_new
        return modes, coefs, res


def fit_unmodelled_mode(ctx: FitContext) -> FitResult:
    n = ctx.cfg.n_axes
    fs = 1.0 / ctx.dt
    T = len(ctx.y) * ctx.dt
    fmin = min(max(MODE_FMIN, 20.0 / T), 0.2 * fs)
    ms = _ModeSearch(ctx, "cross")
    modes, coefs, res = ms.run(fmin, 0.45 * fs)
    ctx.cache["modes"] = list(modes)
    if not modes:
        raise ValueError("no resonance found in the training residual")
    K = len(modes)
    G = np.zeros((K, n, n))
    Hg = np.zeros((K, n, n))
    for i in range(n):
        c = np.asarray(coefs[i]).reshape(K, 2, n)  # per mode: band-pass gains of every axis, then high-pass
        G[:, i, :] = c[:, 0, :]
        Hg[:, i, :] = c[:, 1, :]
    params = {"freq": [m[0] for m in modes] if K > 1 else modes[0][0],
              "damping": [m[1] for m in modes] if K > 1 else modes[0][1], "gains": G.tolist(),
              "hp_gains": Hg.tolist()}
    return FitResult("unmodelled_mode", params, {"freq": None, "damping": None, "gains": None, "hp_gains": None},
                     [("unmodelled_mode", params)], K * (2 + 2 * n * n), _rms(res),
                     note=f"{K} mode(s) at {', '.join(f'{m[0]:.4g} Hz' for m in modes)}")


def fit_amplitude_dependent_dynamics(ctx: FitContext) -> FitResult:
    n = ctx.cfg.n_axes
    fs = 1.0 / ctx.dt
    T = len(ctx.y) * ctx.dt
    fmin = min(max(MODE_FMIN, 20.0 / T), 0.2 * fs)
    ms = _ModeSearch(ctx, "level")
    if ctx.cache.get("modes"):
        # the resonances the mode search found on this context; the level terms are then linear
        modes = ctx.cache["modes"]
        coefs, res = ms.solve(modes)
    else:
        modes, coefs, res = ms.run(fmin, 0.45 * fs)
    if not modes:
        raise ValueError("no amplitude-dependent resonance found in the training residual")
    K = len(modes)
    G, Hg = np.zeros((K, n, n)), np.zeros((K, n, n))
    Kl, Kh = np.zeros((K, n)), np.zeros((K, n))
    Kc, Hc = np.zeros((K, n)), np.zeros((K, n))
    for i in range(n):
        c = np.asarray(coefs[i]).reshape(K, 2 * n + 4)
        G[:, i, :], Hg[:, i, :] = c[:, :n], c[:, n:2 * n]
        Kl[:, i], Kh[:, i] = c[:, 2 * n], c[:, 2 * n + 1]
        Kc[:, i], Hc[:, i] = c[:, 2 * n + 2], c[:, 2 * n + 3]
    params = {"freq": [m[0] for m in modes], "damping": [m[1] for m in modes], "gains": G.tolist(),
              "hp_gains": Hg.tolist(), "level_gains": Kl.tolist(), "level_hp_gains": Kh.tolist(),
              "cubic_gains": Kc.tolist(), "cubic_hp_gains": Hc.tolist()}
    return FitResult("amplitude_dependent_dynamics", params,
                     {k: None for k in params},
                     [("amplitude_dependent_dynamics", params)], K * (2 + 2 * n * n + 4 * n), _rms(res),
                     note=f"{K} mode(s) at {', '.join(f'{m[0]:.4g} Hz' for m in modes)}")


# ----------------------------------------------------------------------------------------------------------------
# Voltage-side and hysteresis effects: the model re-run per trial
# ----------------------------------------------------------------------------------------------------------------

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


def fit_input_delay(ctx: FitContext) -> FitResult:
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

    return _fit_scalar(ctx, "input_delay", "delay", lambda z: {"delay": max(z, 0.0)}, grid,
                       lambda z: max(z, 0.0), lambda z: 1.0, fine=fine)


def fit_amplifier_slew_limit(ctx: FitContext) -> FitResult:
    rates = np.abs(np.diff(ctx.u, axis=0)) / ctx.dt
    rmax = float(rates.max()) if rates.size else 1.0
    lo = max(float(np.quantile(rates, 0.5)), 1e-3 * rmax, 1e-6)
    grid = np.linspace(math.log(lo), math.log(rmax * 1.05), 12)
    return _fit_scalar(ctx, "amplifier_slew_limit", "rate", lambda z: {"rate": math.exp(z)}, grid, math.exp,
                       math.exp)


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
    """Shared cutoff for a 1st- and a 2nd-order (ζ = 0.707) roll-off, the better order kept, then one cutoff per
    axis refined from there (amplifier channels differ)."""
    fs = 1.0 / ctx.dt
    n = ctx.cfg.n_axes
    # up to 10·fs, where the pole-matched filter is the identity to 1e-27: "no bandwidth limit" is on the grid
    grid = np.linspace(math.log(fs / 2000.0), math.log(10.0 * fs), 14)
    f1 = _fit_scalar(ctx, "amplifier_bandwidth", "cutoff", lambda z: {"cutoff": math.exp(z), "order": 1}, grid,
                     math.exp, math.exp)
    fits = [(f1.train_rms, 1, f1)]
    c1 = math.log(f1.params["cutoff"])
    if c1 < math.log(fs):  # a finite roll-off was found: try the 2nd order around it (a 2nd-order corner lies
        # above the 1st-order one that mimics it), on a short grid
        grid2 = np.linspace(c1 - 0.5, c1 + 2.0, 6)
        f2 = _fit_scalar(ctx, "amplifier_bandwidth", "cutoff", lambda z: {"cutoff": math.exp(z), "order": 2},
                         grid2, math.exp, math.exp)
        fits.append((f2.train_rms, 2, f2))
    _, order, best = min(fits, key=lambda t: t[0])
    c0 = math.log(best.params["cutoff"])
    if n > 1 and c0 < math.log(fs):
        unit = max(_rms(residual(ctx.target, ctx.y_base_win)), 1e-15)

        def resid(theta: np.ndarray) -> np.ndarray:
            p = {"cutoff": np.exp(theta).tolist(), "order": order}
            return ctx.sim_residual([("amplifier_bandwidth", p)]).reshape(-1) / unit

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = optimize.least_squares(resid, np.full(n, c0), diff_step=1e-3, max_nfev=4,
                                         bounds=(np.full(n, math.log(fs / 4000.0)), np.full(n, math.log(20 * fs))))
        r = sol.fun.reshape(-1, n) * unit
        if _rms(r) < best.train_rms:
            cut = np.exp(sol.x)
            se = _stderr(sol.jac, r / unit) * cut
            p = {"cutoff": cut.tolist(), "order": order}
            return FitResult("amplifier_bandwidth", p, {"cutoff": se.tolist(), "order": None},
                             [("amplifier_bandwidth", p)], n + 1, _rms(r), note=f"order {order}")
    p = {"cutoff": [best.params["cutoff"]] * n, "order": order}
    return FitResult("amplifier_bandwidth", p, {"cutoff": [best.stderr["cutoff"]] * n, "order": None},
                     [("amplifier_bandwidth", p)], 2, best.train_rms, note=f"order {order}", extra=best.extra)


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
    "amplitude_dependent_dynamics": fit_amplitude_dependent_dynamics,
    "gain_mismatch": fit_gain_mismatch,
}


def fit_candidate(name: str, ctx: FitContext) -> FitResult:
    """Fit one candidate (a name from :data:`CANDIDATES`) on the training data of ``ctx``."""
    if name not in CANDIDATES:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(CANDIDATES)}")
    return CANDIDATES[name](ctx)
