"""Resonance candidates: a greedy search of modes in the training residual (band-pass and high-pass regressors of
the base output, compiled filters, cached normal equations), cross-coupled (``unmodelled_mode``) or with level- and
cube-modulated terms (``amplitude_dependent_dynamics``).
"""
from __future__ import annotations

import inspect
import math
import warnings
from typing import Any, Callable, Iterable

import numpy as np
from scipy import optimize

from .._jit import njit
from ..models import effects as fx
from ..models.effects.modes import base_excited_deflections
from . import stats
from .fit_common import FitContext, FitResult, _rms, _stderr, n_eff_ratio, search_context
from .replay import Windows, residual

__all__ = ["fit_unmodelled_mode", "fit_amplitude_dependent_dynamics", "fit_base_excited_mode", "mode_level_shift", "MAX_MODES",
           "MODE_MIN_GAIN", "MODE_FMIN", "MODE_ZMAX", "Mode", "LEVEL_SHIFT_Z", "LEVEL_RATIO_MIN"]


#: at most this many modes per fit, and the share of the current training residual a new mode must remove
MAX_MODES = 4
MODE_MIN_GAIN = 0.02
#: a structural mode lies above MODE_FMIN [Hz] and is lightly damped (ζ ≤ MODE_ZMAX): a broad band-pass at the
#: excitation's own frequencies would otherwise pass for a "mode" while only patching the gain and phase there
MODE_FMIN = 20.0
MODE_ZMAX = 0.5


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
    ill-conditioned, their minimum-norm solution with the directions below 1e-12 of the largest singular value
    dropped (≈ 1e-6 of X's: collinear regressors, e.g. the low-passes of two modes above the excited band, which are
    both ≈ Ŷ), from the small scaled matrix — not a least-squares pass over every row of X (``X_of`` is kept for
    the callers' signature)."""
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    As = A / np.outer(d, d)
    try:
        C = np.linalg.solve(As, B / d[:, None])
        if not np.all(np.isfinite(C)) or np.linalg.cond(As) > 1e10:
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        C_ls: np.ndarray = np.linalg.lstsq(As, B / d[:, None], rcond=1e-12)[0] / d[:, None]
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
    output; ``kind='cross'``: output i regresses on BP(Ŷ_j) and HP(Ŷ_j) of every axis j (cross-coupled gains) and on
    the low-pass LP(Ŷ_j) of every other axis j ≠ i (a mode in an off-diagonal path has a static gain: without it a
    static cross gain takes that path's low-frequency part and the mode's peak is left over); ``kind='level'``: the
    same plus A_i(t)·BP(Ŷ_i), A_i(t)·HP(Ŷ_i) and the cubic terms (amplitude-dependent)."""

    def __init__(self, ctx: FitContext, kind: str):
        self.ctx, self.kind = ctx, kind
        win = ctx.windows
        r0 = residual(ctx.y, ctx.y_base) if win.is_whole else residual(win.take(ctx.y), win.take(ctx.y_base))
        self.k = max(1, -(-len(r0) // 60_000))  # rows kept in the regressions (the filters run on every sample)
        self.r0 = r0[::self.k] - r0[::self.k].mean(axis=0)
        self.n = ctx.cfg.n_axes
        yb = (ctx.y_base if win.is_whole else win.take(ctx.y_base))[::self.k]
        self.yb = yb - yb.mean(axis=0)  # the base output on the regression rows (LP = Ŷ − BP − HP)
        self.lev: np.ndarray | None = _level_design(ctx.y_base, ctx.dt, win)[::self.k] if kind == "level" else None
        self.unit = max(_rms(self.r0), 1e-15)
        self._regs_cache: dict[tuple[float, float], list[np.ndarray]] = {}
        self.y_base_c = np.ascontiguousarray(ctx.y_base, dtype=float)
        self.spans = np.array([(0, 0, len(ctx.y_base))] if win.is_whole else win.spans, dtype=np.int64)
        self.cube: np.ndarray | None = (np.ascontiguousarray(self.y_base_c * (self.y_base_c / fx.LEVEL_REF) ** 2)
                     if kind == "level" else None)
        self._gram_cache: dict[tuple[Mode, Mode, int], np.ndarray] = {}
        self._xtr_cache: dict[tuple[Mode, int], np.ndarray] = {}
        self._yy: tuple[int, np.ndarray] | None = None  # Ŷᵀ Ŷ on every g-th regression row (the grid's)

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
        LP = self.yb - B - Hp
        others = [[j for j in range(self.n) if j != i] for i in range(self.n)]
        if self.kind == "cross":
            out = [np.column_stack([BH, LP[:, others[i]]]) for i in range(self.n)]
        else:
            assert self.cube is not None and self.lev is not None   # kind "level"
            out = []
            CH = _bp_hp_design(self.cube, self.spans, self.k, f, z, self.ctx.dt)
            CH -= np.full(len(CH), 1.0 / len(CH)) @ CH
            for i in range(self.n):  # the cross-coupled mode, its level-modulated and its cubic direct terms
                LB = self.lev[:, i] * B[:, i]
                LH = self.lev[:, i] * Hp[:, i]
                out.append(np.column_stack([B, Hp, LB - LB.mean(), LH - LH.mean(), CH[:, i], CH[:, self.n + i],
                                            LP[:, others[i]]]))
        return out

    def _grid_gain(self, f: float, z: float, res: np.ndarray, g: int) -> float:
        """Energy of ``res`` (every g-th row) the mode (f, z) would explain, summed over the outputs.  For the cross
        kind one Gram matrix of ``[BP | HP | LP]`` of every axis serves every output (each output's design is a
        subset of its columns): the coarse grid is the search's bulk."""
        if self.kind != "cross" or (float(f), float(z)) in self._regs_cache:
            R = self._grid_regs(f, z)
            return sum(_explained(R[i][::g], res[::g, i:i + 1]) * g for i in range(self.n))
        n = self.n
        BH = _bp_hp_design(self.y_base_c, self.spans, self.k * g, f, z, self.ctx.dt)
        BH -= np.full(len(BH), 1.0 / len(BH)) @ BH
        yb, T = self.yb[::g], res[::g]
        if len(BH) != len(yb) or len(BH) != len(T):  # pragma: no cover - the row counts agree by construction
            rows = min(len(BH), len(yb), len(T))
            BH, yb, T = BH[:rows], yb[:rows], T[:rows]
        # [BH | LP] = [BH | Ŷ]·M with LP_j = Ŷ_j − BP_j − HP_j: the Gram matrix from the small products of BH and Ŷ
        # (Ŷ's own ones computed once per row thinning) instead of building the 3n-column design
        if self._yy is None or self._yy[0] != g:
            self._yy = (g, yb.T @ yb)
        YY, YT = self._yy[1], yb.T @ T
        BB, BY, BT = BH.T @ BH, BH.T @ yb, BH.T @ T
        Z = np.block([[BB, BY], [BY.T, YY]])
        M = np.eye(3 * n)
        for j in range(n):
            M[j, 2 * n + j] = -1.0
            M[n + j, 2 * n + j] = -1.0
        A = M.T @ Z @ M
        Bm = M.T @ np.vstack([BT, YT])
        gain = 0.0
        for i in range(n):
            cols = list(range(2 * n)) + [2 * n + j for j in range(n) if j != i]
            Ai = A[np.ix_(cols, cols)]
            bi = Bm[cols, i]
            d = np.sqrt(np.maximum(np.diag(Ai), 1e-300))
            As, bs = Ai / np.outer(d, d), bi / d
            try:
                c = np.linalg.solve(As, bs)
                if not np.all(np.isfinite(c)) or np.linalg.cond(As) > 1e10:
                    raise np.linalg.LinAlgError
            except np.linalg.LinAlgError:
                c = np.linalg.lstsq(As, bs, rcond=1e-10)[0]
            gain += float(bs @ c) * g
        return gain

    def _gram(self, a: Mode, b: Mode, i: int) -> np.ndarray:
        """``X_aᵀ X_b`` of output i's designs of pole pairs a and b (cached: the earlier modes recur)."""
        key = (a, b, i)
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
        for i in range(self.n):
            A = np.block([[self._gram(a, b, i) for b in keys] for a in keys])
            cols = slice(i, i + 1)
            Bv = np.vstack([self._xtr(k, i) for k in keys])[:, cols]
            C = _solve_normal(A, Bv, lambda: np.hstack([Ri[i] for Ri in R]), self.r0[:, cols])
            fit = np.zeros((len(self.r0), C.shape[1]))
            o = 0
            for Ri in R:
                p = Ri[i].shape[1]
                fit += Ri[i] @ C[o:o + p]
                o += p
            res[:, i] = self.r0[:, i] - fit[:, 0]
            coefs.append(C[:, 0])
        return coefs, res

    def _xtr(self, key: Mode, i: int) -> np.ndarray:
        """``X_keyᵀ r0`` (all outputs' columns) of output i's design (cached)."""
        ck = (key, i)
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
                    gain = self._grid_gain(f, z, res, g)
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
    """Up to :data:`MAX_MODES` lightly damped resonances above :data:`MODE_FMIN`, each output regressed on the
    band-pass and high-pass of every axis' base output (cross-coupled gains) and on the low-pass of every other
    axis' (a mode in an off-diagonal path, with its static gain)."""
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
    Lg = np.zeros((K, n, n))
    for i in range(n):
        # per mode: band-pass gains of every axis, high-pass gains of every axis, low-pass gains of the others
        c = np.asarray(coefs[i]).reshape(K, 3 * n - 1)
        G[:, i, :] = c[:, :n]
        Hg[:, i, :] = c[:, n:2 * n]
        Lg[:, i, [j for j in range(n) if j != i]] = c[:, 2 * n:]
    params = {"freq": [m[0] for m in modes] if K > 1 else modes[0][0],
              "damping": [m[1] for m in modes] if K > 1 else modes[0][1], "gains": G.tolist(),
              "hp_gains": Hg.tolist(), "lp_gains": Lg.tolist()}
    return FitResult("unmodelled_mode", params, {"freq": None, "damping": None, "gains": None, "hp_gains": None,
                                                 "lp_gains": None},
                     [("unmodelled_mode", params)], K * (2 + 2 * n * n + n * (n - 1)), _rms(res),
                     note=f"{K} mode(s) at {', '.join(f'{m[0]:.4g} Hz' for m in modes)}")


def fit_amplitude_dependent_dynamics(ctx: FitContext) -> FitResult:
    """The better of two forms on TRAIN by :func:`_bic` (the residual's effective sample size): the level-modulated
    filter family (:func:`_fit_level_filters`, several parameters per mode and axis pair) and the physical
    base-excited mode with a cubic spring and a quadratic damping (:func:`fit_base_excited_mode`, 2 + 3n
    parameters).  The family can mimic the physical form with many more parameters; named by the one that earns
    them."""
    filters = _fit_level_filters(ctx)
    ratio = n_eff_ratio(residual(ctx.target, ctx.y_base_win))
    rows = ctx.target.size
    # the mode alone first; on top of the linear resonances found only when alone it does not earn its place (the
    # nominal output may lack a linear mode as well)
    best = filters
    try:
        alone = fit_base_excited_mode(ctx)
        if _bic(alone, rows, ratio) <= _bic(best, rows, ratio):
            best = alone
        else:
            found = list(zip(np.atleast_1d(filters.params["freq"]).tolist(),
                             np.atleast_1d(filters.params["damping"]).tolist()))
            on_linear = fit_base_excited_mode(ctx, _linear_modes(ctx, found))
            if _bic(on_linear, rows, ratio) <= _bic(best, rows, ratio):
                best = on_linear
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return filters
    if best is not filters:
        best.extra["level_shift"] = filters.extra.get("level_shift")
        best.extra["filter_family_train_rms"] = filters.train_rms
    return best


def _fit_level_filters(ctx: FitContext) -> FitResult:
    """The resonances :func:`fit_unmodelled_mode` found on this context (else a search of its own), with gains that
    grow with the output's level and a cubic (instantaneous-stiffness) term: linear in the gains."""
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
    Lg = np.zeros((K, n, n))
    for i in range(n):
        c = np.asarray(coefs[i]).reshape(K, 3 * n + 3)
        G[:, i, :], Hg[:, i, :] = c[:, :n], c[:, n:2 * n]
        Kl[:, i], Kh[:, i] = c[:, 2 * n], c[:, 2 * n + 1]
        Kc[:, i], Hc[:, i] = c[:, 2 * n + 2], c[:, 2 * n + 3]
        Lg[:, i, [j for j in range(n) if j != i]] = c[:, 2 * n + 4:]
    params = {"freq": [m[0] for m in modes], "damping": [m[1] for m in modes], "gains": G.tolist(),
              "hp_gains": Hg.tolist(), "level_gains": Kl.tolist(), "level_hp_gains": Kh.tolist(),
              "cubic_gains": Kc.tolist(), "cubic_hp_gains": Hc.tolist(), "lp_gains": Lg.tolist()}
    shift = mode_level_shift(ctx, modes[0])
    note = f"{K} mode(s) at {', '.join(f'{m[0]:.4g} Hz' for m in modes)}"
    if shift is not None:
        note += (f"; the {shift['freq_hz'][0]:.4g} Hz resonance on the small- / large-motion half of TRAIN: "
                 f"{shift['freq_hz'][0]:.5g} / {shift['freq_hz'][1]:.5g} Hz, ζ {shift['damping'][0]:.3g} / "
                 f"{shift['damping'][1]:.3g} (z = {shift['z_freq']:.3g}, {shift['z_damping']:.3g})")
    return FitResult("amplitude_dependent_dynamics", params,
                     {k: None for k in params},
                     [("amplitude_dependent_dynamics", params)], K * (2 + 2 * n * n + 4 * n + n * (n - 1)),
                     _rms(res), note=note, extra={"level_shift": shift})


#: the resonance's frequency or damping differs between the small- and large-motion halves of TRAIN beyond this z
#: (two-sided, two parameters, family-wise α = stats.ALPHA)
LEVEL_SHIFT_Z = stats.z_critical(4)
#: the large-motion half of TRAIN moves less than this many times more than the small-motion half (medians of the
#: level): the run has one amplitude, and the level test cannot see a shift that grows with it
LEVEL_RATIO_MIN = 1.5
#: the level test is for a structural resonance: lightly damped (ζ ≤ LEVEL_SHIFT_ZMAX, fitted on the whole of TRAIN and
#: on each half); broad "modes" are the family imitating a delay or a roll-off, whose fitted shape moves with
#: whatever the halves' spectra differ by
LEVEL_SHIFT_ZMAX = 0.1


def mode_level_shift(ctx: FitContext, mode: Mode) -> dict[str, Any] | None:
    """The resonance ``mode`` refitted (frequency, damping; every output's mode gains free) on the rows of TRAIN
    where the motion is small and on those where it is large (below / above the median of the level
    :meth:`~piezo_ff_ros.core.models.effects.AmplitudeDependentDynamics.level`, the largest over the axes), with
    standard errors (:func:`~.fit_common._stderr`: inflated by the residual's correlation).

    Only for a lightly damped resonance (:data:`LEVEL_SHIFT_ZMAX`, on the whole run and on both halves).  A linear
    resonance has the same frequency and damping at every amplitude (what the halves differ by is noise);
    a hardening/softening spring or an amplitude-dependent damping moves them.  Returns the two fits, the z of their
    log-frequency and log-damping differences and ``significant`` (either z > :data:`LEVEL_SHIFT_Z`); ``None`` when
    it cannot be fitted.  ``level_ratio``: how many times more the large-motion half moves (medians of the level);
    ``one_level`` below :data:`LEVEL_RATIO_MIN` (the test then has no power)."""
    if not float(mode[1]) <= LEVEL_SHIFT_ZMAX:
        return None
    ms = _ModeSearch(ctx, "cross")
    L = _level_design(ctx.y_base, ctx.dt, ctx.windows)[::ms.k].max(axis=1)
    if len(L) != len(ms.r0) or not np.any(L > np.median(L)):
        return None
    halves = (L <= np.median(L), L > np.median(L))
    f0, z0 = float(mode[0]), float(mode[1])
    hi_f = min(2 * f0, 0.49 / ctx.dt)
    fits = []
    for rows in halves:
        def resid(th: np.ndarray, rows: np.ndarray = rows) -> np.ndarray:
            R = ms._design(math.exp(th[0]), math.exp(th[1]))
            out = []
            for i in range(ms.n):
                X, t = R[i][rows], ms.r0[rows, i]
                c = np.linalg.lstsq(X, t, rcond=None)[0]
                out.append(t - X @ c)
            return np.concatenate(out) / ms.unit

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                sol = optimize.least_squares(resid, [math.log(f0), math.log(min(max(z0, 2e-3), 0.45))],
                                             diff_step=1e-3, max_nfev=20,
                                             bounds=([math.log(0.5 * f0), math.log(1e-3)],
                                                     [math.log(hi_f), math.log(MODE_ZMAX)]))
            except (ValueError, np.linalg.LinAlgError):
                return None
        se = _stderr(sol.jac, sol.fun)
        fits.append((sol.x, se))
    (a, sa), (b, sb) = fits
    z = np.abs(b - a) / np.maximum(np.hypot(sa, sb), 1e-300)
    ratio = float(np.median(L[halves[1]]) / max(float(np.median(L[halves[0]])), 1e-300))
    return {"freq_hz": [math.exp(a[0]), math.exp(b[0])], "damping": [math.exp(a[1]), math.exp(b[1])],
            "z_freq": float(z[0]), "z_damping": float(z[1]), "z_critical": LEVEL_SHIFT_Z,
            "significant": bool(np.max(z) > LEVEL_SHIFT_Z and max(math.exp(a[1]), math.exp(b[1])) <= LEVEL_SHIFT_ZMAX),
            "level_ratio": ratio,
            "one_level": bool(ratio < LEVEL_RATIO_MIN)}


#: the base-excited nonlinear mode (form ``base_excited``) is named instead of the level-modulated filter family when
#: it explains TRAIN at least as well by a Bayesian information criterion on the residual's effective sample size
#: (:func:`~.fit_common.n_eff_ratio`): each of the family's extra parameters must buy log(N_eff)/N_eff of the
#: training residual energy
BASE_EXCITED_FREQS = 24
BASE_EXCITED_ZETAS = (0.01, 0.03, 0.1)


def _base_excited_change(ctx: FitContext, freq: float, damping: float, cubic: np.ndarray,
                         quad: np.ndarray, y_base: np.ndarray | None = None,
                         participation: np.ndarray | float = 1.0) -> np.ndarray:
    """What the base-excited mode's nonlinearity adds to the base output (``y_base``: another output it is shaken
    by, on the whole run) on the fit's windows (rows as the training residual's)."""
    st = fx.BaseExcitedNonlinearMode(freq, damping, cubic, quad, ctx.dt, ctx.cfg.n_axes, participation)
    yb = ctx.y_base if y_base is None else y_base
    if ctx.windows.is_whole:
        return st.deflection_change(yb)
    return ctx.windows.apply(st.reset, st.deflection_change, yb)


def _base_excited_deflections(ctx: FitContext, freq: float, damping: Any, cubic: np.ndarray, quad: np.ndarray,
                              y_base: np.ndarray) -> np.ndarray:
    """Deflections ``[K, rows, n]`` of K base-excited modes (coefficient rows of ``cubic``, ``quad``; a row of
    zeros is the linear twin; ``damping`` one or per mode) shaken by ``y_base`` over the fit's windows, each from
    rest at its warm start (rows as the training residual's): one pass over the base for all K, the numbers of
    :func:`_base_excited_change`'s stage (nonlinear − linear twin = its change)."""
    if ctx.windows.is_whole:
        return base_excited_deflections(y_base, freq, damping, cubic, quad, ctx.dt)
    return np.concatenate([base_excited_deflections(y_base[w:e], freq, damping, cubic, quad, ctx.dt)[:, s - w:]
                           for w, s, e in ctx.windows.spans], axis=1)


def _linear_modes(ctx: FitContext, found: list[Mode]) -> tuple[dict[str, Any], int] | None:
    """The linear resonances :func:`fit_unmodelled_mode` found on this context (else ``found``), their gains
    refitted: the ``unmodelled_mode`` parameters and their count (``None`` when there are none)."""
    modes = ctx.cache.get("modes") or found
    if not modes:
        return None
    n = ctx.cfg.n_axes
    ms = _ModeSearch(ctx, "cross")
    coefs, _ = ms.solve(list(modes))
    K = len(modes)
    G, Hg, Lg = np.zeros((K, n, n)), np.zeros((K, n, n)), np.zeros((K, n, n))
    for i in range(n):
        c = np.asarray(coefs[i]).reshape(K, 3 * n - 1)
        G[:, i, :], Hg[:, i, :] = c[:, :n], c[:, n:2 * n]
        Lg[:, i, [j for j in range(n) if j != i]] = c[:, 2 * n:]
    params = {"freq": [m[0] for m in modes], "damping": [m[1] for m in modes], "gains": G.tolist(),
              "hp_gains": Hg.tolist(), "lp_gains": Lg.tolist()}
    return params, K * (2 + 2 * n * n + n * (n - 1))


#: whether ``scipy.optimize.least_squares`` takes ``workers`` (the map its finite differences are evaluated with;
#: scipy ≥ 1.16): the base-excited refinement then integrates the Jacobian's columns together
_LSQ_WORKERS = "workers" in inspect.signature(optimize.least_squares).parameters

#: on a long run the grid and the refinement run on every other fit window (:func:`~.fit_common.search_context`);
#: the point found is refined on all windows with at most this many further evaluations (and its standard errors
#: taken there)
BASE_EXCITED_FULL_NFEV = 3


def fit_base_excited_mode(ctx: FitContext, linear: tuple[dict[str, Any], int] | None = None) -> FitResult:
    """One lightly damped mode shaken by the base output with a cubic spring and a quadratic damping
    (:class:`~piezo_ff_ros.core.models.effects.BaseExcitedNonlinearMode`, form ``base_excited``): 2 + 3n parameters.
    Start: on a grid of (frequency, damping), the first-order (small-nonlinearity) response to each coefficient —
    linear in the coefficients — regressed on the training residual per axis; then every parameter refined by
    simulation (``scipy.optimize.least_squares``).  Each trial replays the mode over the fit windows: on a long run
    the search runs on half of them and the point found is refined briefly on all of them."""
    sub = search_context(ctx)
    # on top of the linear resonances the mode is shaken by the output they shape, on the whole run: filtered once
    # for the search and the refinement
    yb_linear = None if linear is None else _linear_stage(ctx, linear).process(ctx.y_base)
    found = _fit_base_excited_on(sub, linear, yb_linear=yb_linear)
    if sub is ctx:
        return found
    return _fit_base_excited_on(ctx, linear, np.asarray(found.extra["theta"], float), BASE_EXCITED_FULL_NFEV,
                                yb_linear)


def _linear_stage(ctx: FitContext, linear: tuple[dict[str, Any], int]) -> Any:
    """The ``unmodelled_mode`` stage of the linear resonances ``linear`` (at rest)."""
    p = linear[0]
    return fx.UnmodelledMode(p["freq"], p["damping"], p["gains"], ctx.dt, ctx.cfg.n_axes, p["hp_gains"],
                             p["lp_gains"])


def _fit_base_excited_on(ctx: FitContext, linear: tuple[dict[str, Any], int] | None,
                         start: np.ndarray | None = None, max_nfev: int = 60,
                         yb_linear: np.ndarray | None = None) -> FitResult:
    """:func:`fit_base_excited_mode` on the windows of ``ctx``: the grid start unless ``start`` (the parameter
    vector, log frequency and log damping first) is given, then at most ``max_nfev`` evaluations of refinement.
    ``yb_linear``: the base output through the ``linear`` stage on the whole run, when already computed."""
    n = ctx.cfg.n_axes
    fs = 1.0 / ctx.dt
    T = len(ctx.y) * ctx.dt
    yb, yb_win = ctx.y_base, ctx.y_base_win
    lin_effects: list[Any] = []
    if linear is not None:
        # on top of the linear resonances: the mode is shaken by the output they shape
        lin_effects = [("unmodelled_mode", linear[0])]
        stage = _linear_stage(ctx, linear)
        yb = stage.process(ctx.y_base) if yb_linear is None else yb_linear
        stage.reset()
        yb_win = (stage.process(ctx.y_base_win) if ctx.windows.is_whole else
                  ctx.windows.apply(stage.reset, stage.process, ctx.y_base) - ctx.windows.take(ctx.y_base)
                  + ctx.y_base_win)
    r0 = residual(ctx.target, yb_win)
    unit = max(_rms(r0), 1e-15)
    fmin = min(max(MODE_FMIN, 20.0 / T), 0.2 * fs)
    eps = 1e-3
    zeros = np.zeros(n)
    best: tuple[float, float, float, np.ndarray, np.ndarray] = (0.0, 0.0, 0.0, zeros, zeros)
    nz = len(BASE_EXCITED_ZETAS)
    grid_cubic = np.tile(np.stack([np.full(n, eps), zeros, zeros]), (nz, 1))
    grid_quad = np.tile(np.stack([zeros, np.full(n, eps), zeros]), (nz, 1))
    grid_zetas = np.repeat(np.asarray(BASE_EXCITED_ZETAS, float), 3)
    for f in (np.geomspace(fmin, 0.45 * fs, BASE_EXCITED_FREQS) if start is None else ()):
        # for every damping of the grid, the cubic-only and quadratic-only modes and their linear twin: all in one
        # pass over the base
        D_all = _base_excited_deflections(ctx, float(f), grid_zetas, grid_cubic, grid_quad, yb)
        for iz, z in enumerate(BASE_EXCITED_ZETAS):
            D = D_all[3 * iz:3 * iz + 3]
            Sc = (D[0] - D[2]) / eps
            Sq = (D[1] - D[2]) / eps
            if not (np.all(np.isfinite(Sc)) and np.all(np.isfinite(Sq))):
                continue
            gain, c, q = 0.0, np.zeros(n), np.zeros(n)
            for i in range(n):
                X = np.column_stack([Sc[:, i] - Sc[:, i].mean(), Sq[:, i] - Sq[:, i].mean()])
                coef = np.linalg.lstsq(X, r0[:, i], rcond=None)[0]
                gain += float(np.sum((X @ coef) ** 2))
                c[i], q[i] = coef
            if gain > best[0]:
                best = (gain, float(f), z, c, q)
    if start is None and best[0] <= 0.0:
        raise ValueError("no base-excited nonlinear mode explains the training residual")
    _, f0, z0, c0, q0 = best
    # the first-order coefficients are good when the nonlinearity is weak; keep them within a physical range
    c0 = np.clip(c0, -50.0, 50.0)
    q0 = np.clip(q0, 0.0, 50.0)

    # the deflections a trial needs, remembered: a finite-difference column that moves only the coefficients
    # reuses the linear twin, one that moves only the participation the nonlinear mode too
    memo: dict[tuple[float, ...], np.ndarray] = {}

    def deflection(freq: float, zeta: float, cubic: np.ndarray, quad: np.ndarray) -> np.ndarray:
        key = (freq, zeta, *cubic.tolist(), *quad.tolist())
        if key not in memo:
            if len(memo) >= 16:
                memo.pop(next(iter(memo)))
            memo[key] = _base_excited_deflections(ctx, freq, zeta, cubic[None], quad[None], yb)[0]
        return memo[key]

    def batched(fun: Callable[[np.ndarray], np.ndarray], points: Iterable[np.ndarray]) -> list[np.ndarray]:
        """``map(fun, points)`` for the finite-difference columns of the Jacobian: the deflections the points need
        and ``memo`` lacks are first integrated together, one pass over the base per frequency (most columns share
        the current one), each the numbers of its own pass; ``fun`` then finds them all in ``memo``."""
        pts = [np.asarray(p, float) for p in points]
        # by frequency, the nonlinear modes apart from the linear twins (a pass of twins alone is the cheaper one)
        todo: dict[tuple[float, bool], dict[tuple[float, ...], tuple[float, np.ndarray, np.ndarray]]] = {}
        for th in pts:
            freq, zeta = math.exp(th[0]), math.exp(th[1])
            for cubic, quad, twin in ((th[2:2 + n], th[2 + n:2 + 2 * n], False), (zeros, zeros, True)):
                key = (freq, zeta, *cubic.tolist(), *quad.tolist())
                if key not in memo:
                    todo.setdefault((freq, twin), {})[key] = (zeta, cubic, quad)
        for (freq, _), lanes in todo.items():
            zetas = np.array([v[0] for v in lanes.values()])
            D = _base_excited_deflections(ctx, freq, zetas, np.array([v[1] for v in lanes.values()]),
                                          np.array([v[2] for v in lanes.values()]), yb)
            for key, d in zip(lanes, D):
                memo[key] = d
        return [fun(p) for p in pts]

    def resid(th: np.ndarray) -> np.ndarray:
        freq, zeta = math.exp(th[0]), math.exp(th[1])
        d = ((deflection(freq, zeta, th[2:2 + n], th[2 + n:2 + 2 * n]) - deflection(freq, zeta, zeros, zeros))
             * th[2 + 2 * n:])
        r = residual(ctx.target, yb_win + d)
        if not np.all(np.isfinite(r)):
            return np.full(r.size, 1e6)
        out: np.ndarray = r.reshape(-1) / unit
        return out

    # participation per axis: how much of the mode's motion the output sees (1 to first order, where it only
    # scales the coefficients; apart from them when the nonlinearity is strong)
    lo = np.r_[math.log(fmin), math.log(2e-3), np.full(n, -50.0), np.zeros(n), np.zeros(n)]
    hi = np.r_[math.log(0.49 * fs), math.log(MODE_ZMAX), np.full(n, 50.0), np.full(n, 50.0), np.full(n, 2.0)]
    x0 = np.clip(np.r_[math.log(f0), math.log(z0), c0, q0, np.ones(n)] if start is None else start,
                 lo + 1e-9, hi - 1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = optimize.least_squares(resid, x0, diff_step=1e-3, max_nfev=max_nfev, bounds=(lo, hi),
                                     **({"workers": batched} if _LSQ_WORKERS else {}))
    th = sol.x
    r = sol.fun.reshape(-1, n) * unit
    se = _stderr(sol.jac, sol.fun)
    freq, zeta = math.exp(th[0]), math.exp(th[1])
    params = {"form": "base_excited", "freq": freq, "damping": zeta, "cubic": th[2:2 + n].tolist(),
              "quadratic_damping": th[2 + n:2 + 2 * n].tolist(), "participation": th[2 + 2 * n:].tolist()}
    stderr = {"form": None, "freq": float(se[0]) * freq, "damping": float(se[1]) * zeta,
              "cubic": se[2:2 + n].tolist(), "quadratic_damping": se[2 + n:2 + 2 * n].tolist(),
              "participation": se[2 + 2 * n:].tolist()}
    extra_n = 0 if linear is None else linear[1]
    return FitResult("amplitude_dependent_dynamics", params, stderr,
                     lin_effects + [("amplitude_dependent_dynamics", params)], 2 + 3 * n + extra_n, _rms(r),
                     extra={"theta": th.tolist()},
                     note=("on the linear resonances found, " if linear is not None else "") +
                          f"base-excited mode at {freq:.4g} Hz, ζ {zeta:.3g}: cubic spring "
                          f"{', '.join(f'{v:.3g}' for v in th[2:2 + n])}, quadratic damping "
                          f"{', '.join(f'{v:.3g}' for v in th[2 + n:2 + 2 * n])}, participation "
                          f"{', '.join(f'{v:.3g}' for v in th[2 + 2 * n:])} (at {fx.LEVEL_REF:g} m)")


def _bic(fit: FitResult, n_rows: int, ratio: float) -> float:
    """Bayesian information criterion of a fit on TRAIN with N_eff = rows / ``ratio`` effective samples."""
    n_eff = max(n_rows / max(ratio, 1.0), 2.0)
    return n_eff * math.log(max(fit.train_rms, 1e-300) ** 2) + fit.n_params * math.log(n_eff)
