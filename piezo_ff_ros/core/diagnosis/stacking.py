"""Greedy stacking: on top of the verdict, the next effect fitted on TRAIN and judged on TEST, then one backfitting
pass over the earlier ones (an effect fitted alone absorbs part of the ones found later).  It stops when the rest is
within :data:`STACK_STOP`·σ of the white-noise floor, when nothing more is significant, or at ``max_stack``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from . import stats
from .baseline import _Effects, _Replay, _Setup
from .candidates import FitContext, FitResult, fit_candidate
from .decision import _fit_all, _fit_windows, _Held, _Judged, _nested
from .replay import simulate
from .results import _fmt_params
from .scored import Scored

__all__ = ["STACK_STOP", "STACK_MIN_SHARE"]

#: stacking stops when the held-out residual's RMS is within this factor of the white-noise floor
STACK_STOP = 1.01
#: a stacked effect must also remove this share of what is left above the white-noise floor
STACK_MIN_SHARE = 0.1


@dataclass(frozen=True)
class _Stack:
    """The effects stacked on the nominal model.

    Attributes
    ----------
    entries : list of dict
        The report's ``stack``: per effect its name, (backfitted) parameters and the held-out NRMSE [%] once added.
    effects : list
        The stacked effect stages ``[(name, params)]`` (the verdict's alone when nothing was added).
    """

    entries: list[dict[str, Any]]
    effects: list[Any]


def _stack(s: _Setup, rep: _Replay, j: _Judged, verdict: Scored | None, log: Callable[[str], None]) -> _Stack:
    """Add effects greedily to the verdict, each followed by one backfitting pass over the earlier ones."""
    if verdict is None:
        return _Stack([], [])
    opts = s.opts
    base = list(verdict.fit.effects)
    fits = [verdict.fit]
    stack = [{"effect": verdict.fit.effect, "params": _fmt_params(verdict.fit),
              "heldout_nrmse_percent": verdict.after_nrmse}]
    pool = [x.fit.effect for x in j.scored if x.fit.effect != verdict.fit.effect and x.extra["z"] > 0
            and not _nested(verdict.fit.effect, x.fit.effect)][:opts.stack_pool]
    r_k = verdict.extra["r_after"]
    while len(stack) < opts.max_stack and pool:
        best = _next_effect(s, rep, j.held, j.zc, base, r_k, pool, log)
        if best is None:
            break
        fits = _backfit(s, fits + [best.fit], log)
        base = [e for f in fits for e in f.effects]
        r_k = j.held.score(base)
        after = j.held.nrmse(r_k)
        log(f"  added {best.fit.effect}; after backfitting the stack leaves {after:.3f} %")
        stack = [{"effect": f.effect, "params": _fmt_params(f), "heldout_nrmse_percent": e["heldout_nrmse_percent"]}
                 for f, e in zip(fits, stack)]
        stack.append({"effect": best.fit.effect, "params": _fmt_params(fits[-1]),
                      "heldout_nrmse_percent": after})
        pool = [p for p in pool if p != best.fit.effect]
    return _Stack(stack, base)


def _next_effect(s: _Setup, rep: _Replay, held: _Held, zc: float, base: _Effects, r_k: np.ndarray, pool: list[str],
                 log: Callable[[str], None]) -> Scored | None:
    """The best of ``pool`` fitted on TRAIN on top of ``base`` and significant on TEST (``None``: the rest ``r_k`` is
    at the white-noise floor, or nothing is significant)."""
    cfg, test_ext, sigma2 = s.cfg, s.test_ext, rep.sigma2
    if math.sqrt(float(np.mean(r_k ** 2))) <= STACK_STOP * math.sqrt(sigma2):
        return None  # the rest is at the white-noise floor: nothing left to stack
    win = held.windows
    held_k = _Held(cfg, test_ext, base, win, simulate(cfg, test_ext.u, base) if not win.is_whole else None)
    if math.sqrt(float(np.mean(held_k.r_before ** 2))) <= STACK_STOP * math.sqrt(sigma2):
        return None
    log(f"stacking on {[e for e, _ in base]}:")
    y_tr = simulate(cfg, s.train.u, base)
    sc = _fit_all(cfg, s.train, y_tr, base, pool, held_k, s.opts, log)
    if not sc:
        return None
    psd_k = stats.noise_psd(min((x.extra["r_after"] for x in sc), key=lambda r: float(np.sum(r ** 2))))
    excess = float(np.sum(held_k.r_before ** 2)) - held_k.r_before.size * sigma2
    acc = []
    for x in sc:
        x.extra["delta"], _, x.extra["z"] = stats.improvement_z(held_k.r_before, x.extra["r_after"], psd_k)
        if x.extra["z"] > zc and x.extra["delta"] > STACK_MIN_SHARE * max(excess, 0.0):
            acc.append(x)
    acc.sort(key=lambda x: x.sse_after)
    return acc[0] if acc else None


def _backfit(s: _Setup, fits: list[FitResult], log: Callable[[str], None]) -> list[FitResult]:
    """One backfitting pass: each earlier effect (all but the last of ``fits``) refitted on TRAIN with the others in
    place, since an effect fitted alone absorbs part of the ones found later (a delay fitted under a gain error is
    biased, etc.); a refit that fails keeps the earlier fit."""
    cfg, train, opts = s.cfg, s.train, s.opts
    fits = list(fits)
    win = _fit_windows(train, opts)
    for i in range(len(fits) - 1):
        others_fx = [e for j, f in enumerate(fits) if j != i for e in f.effects]
        try:
            ctx = FitContext(cfg, others_fx, train.u, train.y, simulate(cfg, train.u, others_fx), win)
            fits[i] = fit_candidate(fits[i].effect, ctx)
        except (ValueError, np.linalg.LinAlgError) as exc:  # keep the earlier fit
            log(f"  backfit of {fits[i].effect} failed ({exc})")
    return fits
