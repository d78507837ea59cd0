"""The diagnosis: replay, localise, fit the candidate effects on TRAIN, score them on TEST, decide, stack.

:func:`diagnose` runs the phases in turn, each a short function that hands the next a frozen record:

1. check the runs and options, replay the nominal model (residual, noise floor, NRMSEs), localise the gap
   (:mod:`.baseline`: ``_Setup``, ``_Replay``, ``_Localised``);
2. which effect: every candidate fitted on TRAIN, scored on TEST, judged; ties and their discrimination
   (:mod:`.decision`, which states the decision rule: ``_Judged``, ``_Choice``);
3. greedy stacking with backfitting (:mod:`.stacking`: ``_Stack``);
4. the verdict's name, confidence and reason (:mod:`.verdict`: ``_Verdict``);
5. the report: ranking, the JSON mapping and the arrays (here; the types are in :mod:`.results`).

The names this module always exported stay importable from it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Callable

import numpy as np

from ..config import PiezoConfig
from ..models.effects import EFFECTS
from ..recording.run import RunData
from . import stats
from ._blas import single_threaded_blas
from .baseline import LOCALISE_SAMPLES as LOCALISE_SAMPLES
from .baseline import LONG_NOISE_SAMPLES as LONG_NOISE_SAMPLES
from .baseline import _centered_nrmse, _check, _localise, _Localised, _replay, _Replay, _Setup, _sim_test
from .decision import GENERIC as GENERIC
from .decision import GENERIC_MIN_EXTRA as GENERIC_MIN_EXTRA
from .decision import HIGH_EXCESS_SHRINK as HIGH_EXCESS_SHRINK
from .decision import HIGH_PAIRED_Z as HIGH_PAIRED_Z
from .decision import HIGH_SHARE as HIGH_SHARE
from .decision import HIGH_Z_MARGIN as HIGH_Z_MARGIN
from .decision import MIN_DROP as MIN_DROP
from .decision import MIN_EXCESS_SHRINK as MIN_EXCESS_SHRINK
from .decision import MIN_SHARE as MIN_SHARE
from .decision import NESTED as NESTED
from .decision import RICHER as RICHER
from .decision import RICHER_MIN_GAIN as RICHER_MIN_GAIN
from .decision import TIE_Z as TIE_Z
from .decision import _choose, _Choice, _first_round, _Judged, _significant
from .replay import residual
from .residual_signatures import SIGNATURE_OF as SIGNATURE_OF
from .residual_signatures import signatures as signatures
from .results import DiagnosisArrays as DiagnosisArrays
from .results import DiagnosisOptions as DiagnosisOptions
from .results import DiagnosisResult as DiagnosisResult
from .results import _fmt_params
from .results import json_ready as json_ready
from .stacking import STACK_MIN_SHARE as STACK_MIN_SHARE
from .stacking import STACK_STOP as STACK_STOP
from .stacking import _stack, _Stack
from .verdict import NOISE_MARGIN as NOISE_MARGIN
from .verdict import _verdict, _Verdict

__all__ = ["DiagnosisOptions", "DiagnosisResult", "DiagnosisArrays", "diagnose", "json_ready", "signatures", "MIN_SHARE", "TIE_Z", "NOISE_MARGIN"]


def diagnose(cfg: PiezoConfig, train: RunData, test: RunData, options: DiagnosisOptions | None = None,
             log: Callable[[str], None] | None = None, test_history: RunData | None = None,
             discriminate: RunData | None = None) -> DiagnosisResult:
    """Diagnose the gap between ``cfg`` and the measured runs.

    ``test_history``: the part of the same record that precedes ``test`` (``--data`` split: the training part).
    Its voltages drive the model before the held-out part so that the held-out part does not start from an
    unknown state (creep has time constants of minutes); only the held-out samples are scored.

    ``discriminate``: a third run (e.g. the experiment a previous diagnosis proposed) on which the candidates that
    tie on ``test`` are compared; the one that explains it better becomes the verdict.

    Returns a :class:`DiagnosisResult`: the JSON report as a read-only mapping, and the arrays the report plots.
    """
    with single_threaded_blas():  # tall-thin products only: BLAS threads cost CPU time and gain nothing
        return _diagnose(cfg, train, test, options, log, test_history, discriminate)


def _diagnose(cfg: PiezoConfig, train: RunData, test: RunData, options: DiagnosisOptions | None = None,
              log: Callable[[str], None] | None = None, test_history: RunData | None = None,
              discriminate: RunData | None = None) -> DiagnosisResult:
    opts = options or DiagnosisOptions()
    log = log or ((lambda m: print(m)) if opts.verbose else (lambda m: None))
    t_start = time.perf_counter()
    setup = _check(cfg, train, test, opts, test_history, discriminate)
    rep = _replay(setup, log, t_start)                      # 1. replay
    loc = _localise(setup, rep, log, t_start)               # 2. where
    judged = _first_round(setup, rep, log)                  # 3. which: fit on TRAIN, score on TEST
    choice = _choose(setup, rep, judged, log)
    stack = _stack(setup, rep, judged, choice.verdict, log)  # 4. greedy stacking
    verdict = _verdict(judged, choice, rep.sigma2)
    return _report(setup, rep, loc, judged, choice, stack, verdict, log, t_start)


@dataclass(frozen=True)
class _Final:
    """The corrected models replayed on the whole held-out run.

    Attributes
    ----------
    y_verdict, y_final : ndarray [N, axes]
        The nominal model with the verdict's effect, with the whole stack (the same array when they are the same).
    r_final : ndarray [N, axes]
        The held-out residual the stack leaves.
    after_nrmse, stacked_nrmse : float
        The NRMSE [%] (offsets removed) of the verdict's and of the stack's replay.
    """

    y_verdict: np.ndarray
    y_final: np.ndarray
    r_final: np.ndarray
    after_nrmse: float
    stacked_nrmse: float


def _final(s: _Setup, rep: _Replay, c: _Choice, st: _Stack) -> _Final:
    """The verdict alone and the final stack on the whole test run (one simulation when they are the same)."""
    test = s.test
    y_test_verdict = _sim_test(s, rep, c.verdict.fit.effects) if c.verdict is not None else rep.y_test_nom
    y_test_final = y_test_verdict if len(st.entries) <= 1 else _sim_test(s, rep, st.effects)
    after_nrmse = _centered_nrmse(test.y, y_test_verdict, rep.test_den)
    stacked_nrmse = after_nrmse if y_test_final is y_test_verdict else \
        _centered_nrmse(test.y, y_test_final, rep.test_den)
    return _Final(y_test_verdict, y_test_final, residual(test.y, y_test_final), after_nrmse, stacked_nrmse)


def _report(s: _Setup, rep: _Replay, loc: _Localised, j: _Judged, c: _Choice, st: _Stack, v: _Verdict,
            log: Callable[[str], None], t_start: float) -> DiagnosisResult:
    """The result: the JSON report (a read-only mapping) and the arrays the report plots."""
    cfg, train, test = s.cfg, s.train, s.test
    fin = _final(s, rep, c, st)
    noise_nrmse = float(100 * math.sqrt(j.held.r_before.size * rep.sigma2) / max(j.held.den, 1e-300))
    result: dict[str, Any] = {
        "verdict": v.name,
        "confidence": v.confidence,
        "confidence_reason": v.reason,
        "heldout": {
            "before_nrmse_percent": rep.before_nrmse,
            "after_nrmse_percent": fin.after_nrmse,
            "stacked_after_nrmse_percent": fin.stacked_nrmse,
            "noise_floor_nrmse_percent": noise_nrmse,
            "noise_floor_method": rep.noise_method,
            "scored_on_samples": int(j.held.r_before.shape[0]),
        },
        "test": {
            "name": "held-out improvement z-test against the residual's own noise spectrum (Welch), one-sided, "
                    f"Bonferroni over {j.n_tests} models at family-wise alpha = {stats.ALPHA:g}",
            "z_critical": j.zc,
            "min_share_of_explainable": MIN_SHARE,
            "min_drop_of_residual_energy": MIN_DROP,
        },
        "explainable": _explainable(j),
        "discrimination": c.discrimination,
        "ranking": _ranking(j, loc.sig),
        "stack": st.entries,
        "where": loc.where,
        "signatures": loc.sig,
        "model": {"name": cfg.name, "axes": list(cfg.axes), "sample_rate": cfg.sample_rate},
        "data": {"train_samples": len(train), "test_samples": len(test),
                 "train_source": str(train.meta.get("source", "")), "test_source": str(test.meta.get("source", ""))},
        "warnings": list(s.warnings),
        "seconds": time.perf_counter() - t_start,
    }
    arrays = DiagnosisArrays(cfg=cfg, test=test, train=train, y_test_nom=rep.y_test_nom, y_test_final=fin.y_final,
                             r_final=fin.r_final, sigma=rep.sigma,
                             verdict_effects=list(c.verdict.fit.effects) if c.verdict is not None else [],
                             stack_effects=list(st.effects))
    log(f"verdict: {result['verdict']} ({v.confidence}); held-out {result['heldout']['before_nrmse_percent']:.3f} % "
        f"-> {result['heldout']['after_nrmse_percent']:.3f} % (stacked {fin.stacked_nrmse:.3f} %, noise "
        f"{noise_nrmse:.3f} %) in {result['seconds']:.1f} s")
    return DiagnosisResult(report=MappingProxyType(result), arrays=arrays)


def _explainable(j: _Judged) -> dict[str, Any] | None:
    """The explainable share: what the flexible model (fitted on TRAIN) removes on TEST (``None`` without it)."""
    flex = j.flex
    if flex is None:
        return None
    sse_b = flex.sse_before
    return {
        "share_percent": 100 * flex.extra["delta"] / sse_b if sse_b > 0 else 0.0,
        "after_nrmse_percent": flex.after_nrmse,
        "before_nrmse_percent": flex.before_nrmse,
        "z": flex.extra["z"],
        "significant": _significant(flex, j.zc),
        "model": "ridge regression of the residual on a filter bank (difference, low-passes, resonators) of "
                 "every voltage and every nominal output, fitted on TRAIN",
    }


def _ranking(j: _Judged, sig: dict[str, float]) -> list[dict[str, Any]]:
    """The report's ``ranking``: every candidate of the first round, best first."""
    ranking = []
    for s in j.scored:
        ranking.append({
            "effect": s.fit.effect,
            "heldout_before_nrmse_percent": s.before_nrmse,
            "heldout_after_nrmse_percent": s.after_nrmse,
            "params": _fmt_params(s.fit),
            "accepted": s.accepted,
            "n_params": s.fit.n_params,
            "train_rms_um": s.fit.train_rms * 1e6,
            "heldout_shrink_percent": 100 * (1 - s.sse_after / s.sse_before) if s.sse_before > 0 else 0.0,
            "z": s.extra["z"],
            "explainable_share_percent": 100 * s.extra.get("share", 0.0),
            "excess_shrink_percent": 100 * s.extra.get("excess_shrink", 0.0)
            if s.extra.get("gap_above_floor", True) else None,
            "paired_z_vs_verdict": s.extra.get("paired_z"),
            "absorbs": s.extra.get("absorbs"),
            "signature": {"name": SIGNATURE_OF.get(s.fit.effect, ""), "value": sig.get(SIGNATURE_OF.get(s.fit.effect, ""))},
            "explanation": EFFECTS[s.fit.effect].signature,
            "note": s.fit.note,
            "fit_seconds": s.seconds,
        })
    return ranking
