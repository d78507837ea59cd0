"""The diagnosis: replay, localise, fit the candidate effects on TRAIN, score them on TEST, stack greedily.

Decision rule (why a verdict is not ``none``): on the held-out run the candidate must remove more of the gap than
noise can explain, i.e. its drop in residual energy must exceed both

* a complexity penalty ``p·ln(N_eff)·σ²·N/N_eff`` (BIC-like, with ``p`` the number of parameters, σ the measured
  noise floor and ``N_eff`` the effective number of independent samples of the correlated residual), and
* :data:`MIN_EXCESS_SHRINK` of the gap's excess over the noise floor;

and the gap's excess over the noise floor must be positive.  Candidates are ranked by their penalised held-out
residual energy.  Greedy stacking (each new effect followed by one backfitting pass over the earlier ones) stops
when the rest is within :data:`STACK_STOP`·σ of the noise floor, when nothing more is accepted, or at ``max_stack``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..config import PiezoConfig
from ..models.effects import EFFECTS
from ..recording.run import RunData
from .candidates import CANDIDATES, FitContext, FitResult, fit_candidate, n_eff_ratio
from .replay import (Windows, check_run, input_period, model_for_run, noise_floor, noise_floor_periodic,
                     nrmse_percent, residual, simulate)
from .where import localise

__all__ = ["DiagnosisOptions", "diagnose", "signatures", "MIN_EXCESS_SHRINK", "NOISE_MARGIN"]

MIN_EXCESS_SHRINK = 0.2
NOISE_MARGIN = 1.05
STACK_STOP = 1.01


@dataclass
class DiagnosisOptions:
    """Budget and scope of a diagnosis.

    ``fit_samples``/``score_samples``: above these, voltage-side fits / held-out scores use ``n_windows`` windows
    spread over the run (each with ``warmup_s`` of history) instead of the whole run.  ``max_stack``: how many
    effects the greedy stacking may add.  ``stack_pool``: how many of the best first-round candidates it reconsiders.
    """

    candidates: Sequence[str] = tuple(CANDIDATES)
    fit_samples: int = 240_000
    score_samples: int = 480_000
    n_windows: int = 8
    warmup_s: float = 0.5
    max_stack: int = 3
    stack_pool: int = 4
    verbose: bool = False


@dataclass
class _Scored:
    fit: FitResult
    sse_before: float
    sse_after: float
    penalty: float
    before_nrmse: float
    after_nrmse: float
    accepted: bool
    seconds: float
    extra: dict = field(default_factory=dict)


class _Held:
    """The held-out run on its scoring windows, with the base model's output."""

    def __init__(self, cfg, run: RunData, base, windows: Windows, y_base_full=None):
        self.cfg, self.run, self.base, self.windows = cfg, run, list(base), windows
        if windows.is_whole:
            self.y_base_full = simulate(cfg, run.u, base) if y_base_full is None else y_base_full
            self.target = run.y
            self.y_base = self.y_base_full
        else:
            self.y_base_full = y_base_full
            y_win = simulate(cfg, run.u, base, windows)
            if y_base_full is not None:
                self.target = windows.take(run.y) - windows.take(y_base_full) + y_win
            else:
                self.target = windows.take(run.y)
            self.y_base = y_win
        self.r_before = residual(self.target, self.y_base)
        yt = self.target - self.target.mean(axis=0)
        self.den = float(np.sqrt(np.sum(yt ** 2)))

    def nrmse(self, r) -> float:
        return float(100 * np.sqrt(np.sum(r ** 2)) / max(self.den, 1e-300))

    def score(self, effects) -> np.ndarray:
        return residual(self.target, simulate(self.cfg, self.run.u, self.base + list(effects), self.windows))


def _fmt_params(fit: FitResult) -> dict:
    out = {}
    for k, v in fit.params.items():
        out[k] = {"value": v, "stderr": fit.stderr.get(k), "unit": EFFECTS[fit.effect].params[k][0]}
    return out


# ----------------------------------------------------------------------------------------------------------------
# Signatures
# ----------------------------------------------------------------------------------------------------------------

def _corr(a, b) -> float:
    a = np.asarray(a, float).reshape(-1)
    b = np.asarray(b, float).reshape(-1)
    a = a - a.mean()
    b = b - b.mean()
    d = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / d) if d > 0 else 0.0


def _partial_corr(r, x, given):
    """Correlation of r with x after removing from both their projection on ``given`` (per axis, pooled)."""
    rs, xs = [], []
    for i in range(r.shape[1]):
        G = np.column_stack([np.ones(len(r))] + [g[:, i] for g in given])
        rr = r[:, i] - G @ np.linalg.lstsq(G, r[:, i], rcond=None)[0]
        xx = x[:, i] - G @ np.linalg.lstsq(G, x[:, i], rcond=None)[0]
        rs.append(rr)
        xs.append(xx)
    return _corr(np.concatenate(rs), np.concatenate(xs))


def signatures(u: np.ndarray, y_hat: np.ndarray, r: np.ndarray, dt: float, sigma: np.ndarray) -> dict:
    """Effect signatures of a residual (each in [0, 1], larger = stronger), used to explain the ranking.

    ``gain``: |corr(r, Ŷ)|; ``delay``: |corr(r, dŶ/dt)| beyond Ŷ (linear phase); ``even_harmonics``: |corr(r,
    (Ŷ−Ŷ̄)²)| beyond Ŷ (asymmetry); ``rate``: |corr(r, sign(U̇)·|U̇|)| beyond Ŷ, dŶ/dt (loop width growing with
    rate); ``slew``: share of the residual energy in the 1 % of samples with the largest |dU/dt|; ``saturation``:
    share in the 2 % with the largest |U|; ``slow_trend``: share below 0.1 Hz; ``resonance_peak``: how far the
    largest residual-spectrum peak above 100 Hz stands out of the spectrum's median (0 = none).
    """
    n = r.shape[1]
    k = min(u.shape[1], n)
    yh = y_hat - y_hat.mean(axis=0)
    dy = np.gradient(y_hat, dt, axis=0)
    du = np.gradient(u[:, :k], dt, axis=0)
    if k < n:
        du = np.column_stack([du] + [du[:, :1]] * (n - k))
    sig = {"gain": abs(_corr(r, yh)),
           "delay": abs(_partial_corr(r, dy, [yh])),
           "even_harmonics": abs(_partial_corr(r, yh ** 2, [yh])),
           "rate": abs(_partial_corr(r, np.sign(du) * np.abs(du), [yh, dy]))}
    e = np.sum(r ** 2, axis=1)
    tot = float(e.sum()) or 1.0
    rate = np.abs(du).max(axis=1)
    sel = rate >= np.quantile(rate, 0.99)
    sig["slew"] = float(e[sel].sum() / tot)
    amp = np.abs(u).max(axis=1)
    sel = amp >= np.quantile(amp, 0.98)
    sig["saturation"] = float(e[sel].sum() / tot)
    from scipy import signal

    N = len(r)
    nper = int(min(N, max(256, 2 ** int(math.log2(max(N // 8, 256))))))
    f, P = signal.welch(r, fs=1 / dt, nperseg=nper, axis=0)
    Ps = P.sum(axis=1)
    sig["slow_trend"] = float(Ps[f < 0.1].sum() / max(Ps.sum(), 1e-300))
    hi = f > 100
    if hi.sum() > 8:
        ph = Ps[hi]
        sig["resonance_peak"] = float(np.clip(1 - np.median(ph) / ph.max(), 0, 1)) if ph.max() > 0 else 0.0
        sig["resonance_peak_hz"] = float(f[hi][np.argmax(ph)])
    else:
        sig["resonance_peak"] = 0.0
    return sig


#: which signature explains which effect
SIGNATURE_OF = {"gain_mismatch": "gain", "input_delay": "delay", "hysteresis_asymmetry": "even_harmonics",
                "hysteresis_rate_dependence": "rate", "amplifier_slew_limit": "slew",
                "amplifier_saturation": "saturation", "creep_nonlinearity": "slow_trend",
                "thermal_drift": "slow_trend", "unmodelled_mode": "resonance_peak", "amplifier_bandwidth": "delay"}


# ----------------------------------------------------------------------------------------------------------------
# Main entry point
# ----------------------------------------------------------------------------------------------------------------

def _score(fit: FitResult, held: _Held, sigma2: float, t0: float) -> _Scored:
    r_after = held.score(fit.effects)
    sse_b = float(np.sum(held.r_before ** 2))
    sse_a = float(np.sum(r_after ** 2))
    N = r_after.size
    ratio = n_eff_ratio(r_after)
    n_eff = max(N / ratio, 2.0)
    penalty = fit.n_params * math.log(n_eff) * sigma2 * ratio
    excess = sse_b - N * sigma2
    accepted = (sse_b - sse_a > penalty) and (sse_b - sse_a > MIN_EXCESS_SHRINK * max(excess, 0.0)) and excess > 0
    return _Scored(fit, sse_b, sse_a, penalty, held.nrmse(held.r_before), held.nrmse(r_after), bool(accepted),
                   time.perf_counter() - t0, {"r_after": r_after})


def _fit_all(cfg, train, y_base_train, base, names, held, sigma2, opts, log):
    fs = train.sample_rate
    win = Windows.spread(len(train), opts.fit_samples, opts.n_windows, int(opts.warmup_s * fs))
    ctx = FitContext(cfg, list(base), train.u, train.y, y_base_train, win)
    scored = []
    for name in names:
        t0 = time.perf_counter()
        try:
            fit = fit_candidate(name, ctx)
            s = _score(fit, held, sigma2, t0)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            log(f"  {name}: fit failed ({exc})")
            continue
        log(f"  {name:28s} held-out {s.before_nrmse:7.3f} % -> {s.after_nrmse:7.3f} %  "
            f"{'accepted' if s.accepted else 'rejected'}  ({s.seconds:.1f} s)")
        scored.append(s)
    scored.sort(key=lambda s: s.sse_after + s.penalty)
    return scored


def _confidence(best: _Scored, runner: _Scored | None, sigma2: float, N: int) -> tuple[str, str]:
    ex_b = best.sse_before - N * sigma2
    ex_best = max(best.sse_after - N * sigma2, 0.0)
    shrink = 1 - ex_best / ex_b if ex_b > 0 else 0.0
    if runner is None:
        return "high" if shrink > 0.5 else "medium", f"it removes {100 * shrink:.0f} % of the gap above the noise"
    ex_run = max(runner.sse_after - N * sigma2, 0.0)
    margin = (ex_run + 1e-30) / (ex_best + 1e-3 * max(ex_b, 1e-30))
    why = (f"it removes {100 * shrink:.0f} % of the held-out gap above the noise floor; the runner-up "
           f"({runner.fit.effect}) leaves {margin:.3g}× as much excess")
    if shrink > 0.5 and margin > 2.0:
        return "high", why
    if shrink > 0.3 and margin > 1.2:
        return "medium", why
    return "low", why


def diagnose(cfg: PiezoConfig, train: RunData, test: RunData, options: DiagnosisOptions | None = None,
             log=None, test_history: RunData | None = None) -> dict:
    """Diagnose the gap between ``cfg`` and the measured runs; returns the JSON-ready result (issue 5 §5).

    ``test_history``: the part of the same record that precedes ``test`` (``--data`` split: the training part).
    Its voltages drive the model before the held-out part so that the held-out part does not start from an
    unknown state (creep has time constants of minutes); only the held-out samples are scored.

    The result also carries, under the key ``"_arrays"`` (not JSON), the arrays the report plots.
    """
    opts = options or DiagnosisOptions()
    log = log or ((lambda m: print(m)) if opts.verbose else (lambda m: None))
    t_start = time.perf_counter()
    check_run(train, "train")
    check_run(test, "test")
    cfg = model_for_run(cfg, train)
    if abs(test.sample_rate - cfg.sample_rate) > 1e-6 * cfg.sample_rate:
        raise ValueError(f"train is sampled at {cfg.sample_rate:g} Hz but test at {test.sample_rate:g} Hz")
    model_for_run(cfg, test)
    unknown = [c for c in opts.candidates if c not in CANDIDATES]
    if unknown:
        raise ValueError(f"unknown candidate effect(s) {unknown}; known: {list(CANDIDATES)}")
    fs = cfg.sample_rate
    axes = tuple(cfg.axes)
    # the held-out run, extended by its history when it was split from a longer record
    H = 0
    test_ext = test
    if test_history is not None:
        check_run(test_history, "test history")
        H = len(test_history)
        test_ext = RunData(np.arange(H + len(test)) * cfg.dt, np.vstack([test_history.u, test.u]),
                           np.vstack([test_history.y, test.y]), test.axes)

    def sim_test(effects):
        return simulate(cfg, test_ext.u, effects)[H:]

    # 1. replay
    y_ext_nom = simulate(cfg, test_ext.u, [])
    y_test_nom = y_ext_nom[H:]
    y_train_nom = y_ext_nom[:H] if test_history is train else simulate(cfg, train.u, [])
    r_test = residual(test.y, y_test_nom)
    period = input_period(test.u)
    # periodic excitation: the noise is what differs between periods; else the residual's second difference
    sigma = noise_floor_periodic(test.y, period) if period else noise_floor(r_test)
    noise_method = f"period-to-period difference (period {period} samples)" if period else "second difference"
    sigma2 = float(np.mean(sigma ** 2))
    log(f"replay: train {nrmse_percent(train.y - train.y.mean(0), y_train_nom - y_train_nom.mean(0)):.3f} %, "
        f"test {nrmse_percent(test.y - test.y.mean(0), y_test_nom - y_test_nom.mean(0)):.3f} % NRMSE; "
        f"noise floor {np.round(sigma * 1e9, 1).tolist()} nm by {noise_method} ({time.perf_counter() - t_start:.1f} s)")
    # 2. where
    where = localise(test.u, test.y, y_test_nom, cfg.dt, axes, sigma)
    where["train_nrmse_percent"] = nrmse_percent(train.y - train.y.mean(0), y_train_nom - y_train_nom.mean(0))
    sig = signatures(test.u, y_test_nom, r_test, cfg.dt, sigma)
    # 3. which: fit on TRAIN, score on TEST
    score_win = Windows.spread(len(test), opts.score_samples, opts.n_windows, int(opts.warmup_s * fs), offset=H)
    held = _Held(cfg, test_ext, [], score_win, y_ext_nom)
    N = held.r_before.size
    # informational: whether the gap is within NOISE_MARGIN of the noise floor (acceptance itself is the test)
    at_floor = math.sqrt(float(np.mean(held.r_before ** 2))) <= NOISE_MARGIN * math.sqrt(sigma2)
    log("candidates (fitted on train, scored on test):")
    scored = _fit_all(cfg, train, y_train_nom, [], list(opts.candidates), held, sigma2, opts, log)
    accepted = [s for s in scored if s.accepted]
    verdict = accepted[0] if accepted else None
    # 4. greedy stacking
    stack = []
    base = []
    if verdict is not None:
        base = list(verdict.fit.effects)
        fits = [verdict.fit]
        stack.append({"effect": verdict.fit.effect, "params": _fmt_params(verdict.fit),
                      "heldout_nrmse_percent": verdict.after_nrmse})
        pool = [s.fit.effect for s in scored if s.fit.effect != verdict.fit.effect][:opts.stack_pool]
        while len(stack) < opts.max_stack and pool:
            held_k = _Held(cfg, test_ext, base, score_win,
                           simulate(cfg, test_ext.u, base) if not score_win.is_whole else None)
            if math.sqrt(float(np.mean(held_k.r_before ** 2))) <= STACK_STOP * math.sqrt(sigma2):
                break
            log(f"stacking on {[e for e, _ in base]}:")
            y_tr = simulate(cfg, train.u, base)
            sc = _fit_all(cfg, train, y_tr, base, pool, held_k, sigma2, opts, log)
            acc = [s for s in sc if s.accepted]
            if not acc:
                break
            best = acc[0]
            fits.append(best.fit)
            # one backfitting pass: each earlier effect refitted with the others in place, since an effect fitted
            # alone absorbs part of the ones found later (a delay fitted under a gain error is biased, etc.)
            win = Windows.spread(len(train), opts.fit_samples, opts.n_windows, int(opts.warmup_s * fs))
            for i in range(len(fits) - 1):
                others = [e for j, f in enumerate(fits) if j != i for e in f.effects]
                try:
                    ctx = FitContext(cfg, others, train.u, train.y, simulate(cfg, train.u, others), win)
                    fits[i] = fit_candidate(fits[i].effect, ctx)
                except (ValueError, np.linalg.LinAlgError) as exc:  # keep the earlier fit
                    log(f"  backfit of {fits[i].effect} failed ({exc})")
            base = [e for f in fits for e in f.effects]
            after = held.nrmse(held.score(base))
            log(f"  added {best.fit.effect}; after backfitting the stack leaves {after:.3f} %")
            stack = [{"effect": f.effect, "params": _fmt_params(f), "heldout_nrmse_percent": e["heldout_nrmse_percent"]}
                     for f, e in zip(fits, stack)]
            stack.append({"effect": best.fit.effect, "params": _fmt_params(fits[-1]),
                          "heldout_nrmse_percent": after})
            pool = [p for p in pool if p != best.fit.effect]
    # the verdict alone and the final stack on the whole test run (one simulation when they are the same)
    y_test_verdict = sim_test(verdict.fit.effects) if verdict is not None else y_test_nom
    y_test_final = y_test_verdict if len(stack) <= 1 else sim_test(base)
    r_final = residual(test.y, y_test_final)
    runner = next((s for s in scored if verdict is not None and s is not verdict), None)
    conf, why = ("n/a", "")
    if verdict is not None:
        conf, why = _confidence(verdict, runner, sigma2, N)
    elif at_floor:
        why = "the held-out gap is at the measured noise floor and no candidate removes a significant part of it"
    else:
        why = ("no candidate removes more of the held-out gap than noise and its number of parameters explain"
               + (f" (best: {scored[0].fit.effect}, {scored[0].before_nrmse:.3g} % -> {scored[0].after_nrmse:.3g} %)"
                  if scored else ""))
    noise_nrmse = float(100 * math.sqrt(N * sigma2) / max(held.den, 1e-300))
    ranking = []
    for s in scored:
        ranking.append({
            "effect": s.fit.effect,
            "heldout_before_nrmse_percent": s.before_nrmse,
            "heldout_after_nrmse_percent": s.after_nrmse,
            "params": _fmt_params(s.fit),
            "accepted": s.accepted,
            "n_params": s.fit.n_params,
            "train_rms_um": s.fit.train_rms * 1e6,
            "heldout_shrink_percent": 100 * (1 - s.sse_after / s.sse_before) if s.sse_before > 0 else 0.0,
            "signature": {"name": SIGNATURE_OF[s.fit.effect], "value": sig.get(SIGNATURE_OF[s.fit.effect])},
            "explanation": EFFECTS[s.fit.effect].signature,
            "fit_seconds": s.seconds,
        })
    stacked_nrmse = nrmse_percent(test.y - test.y.mean(0), y_test_final - y_test_final.mean(0))
    result = {
        "verdict": verdict.fit.effect if verdict is not None else "none",
        "confidence": conf,
        "confidence_reason": why,
        "heldout": {
            "before_nrmse_percent": nrmse_percent(test.y - test.y.mean(0), y_test_nom - y_test_nom.mean(0)),
            "after_nrmse_percent": nrmse_percent(test.y - test.y.mean(0), y_test_verdict - y_test_verdict.mean(0)),
            "stacked_after_nrmse_percent": stacked_nrmse,
            "noise_floor_nrmse_percent": noise_nrmse,
            "noise_floor_method": noise_method,
            "scored_on_samples": int(held.r_before.shape[0]),
        },
        "ranking": ranking,
        "stack": stack,
        "where": where,
        "signatures": sig,
        "model": {"name": cfg.name, "axes": list(axes), "sample_rate": fs},
        "data": {"train_samples": len(train), "test_samples": len(test),
                 "train_source": str(train.meta.get("source", "")), "test_source": str(test.meta.get("source", ""))},
        "seconds": time.perf_counter() - t_start,
    }
    result["_arrays"] = {"cfg": cfg, "test": test, "train": train, "y_test_nom": y_test_nom,
                         "y_test_final": y_test_final, "r_final": r_final, "sigma": sigma,
                         "verdict_effects": verdict.fit.effects if verdict is not None else [],
                         "stack_effects": base}
    log(f"verdict: {result['verdict']} ({conf}); held-out {result['heldout']['before_nrmse_percent']:.3f} % -> "
        f"{result['heldout']['after_nrmse_percent']:.3f} % (stacked {stacked_nrmse:.3f} %, noise "
        f"{noise_nrmse:.3f} %) in {result['seconds']:.1f} s")
    return result


def json_ready(result: dict) -> dict:
    """The result without the arrays, with floats made JSON-safe (NaN/Inf → None)."""
    def clean(v):
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items() if not k.startswith("_")}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, (np.floating, float)):
            return float(v) if math.isfinite(v) else None
        if isinstance(v, (np.integer,)):
            return int(v)
        if isinstance(v, np.ndarray):
            return clean(v.tolist())
        if isinstance(v, np.bool_):
            return bool(v)
        return v
    return clean(result)
