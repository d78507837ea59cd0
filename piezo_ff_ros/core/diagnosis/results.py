"""What a diagnosis takes and gives: its options, its result (a read-only mapping of the JSON report plus the arrays
the report plots) and the JSON cleaning of that result.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from ..config import PiezoConfig
from ..jsonable import JsonResult
from ..models.effects import EFFECTS
from ..recording.run import RunData
from .candidates import CANDIDATES, FitResult

__all__ = ["DiagnosisOptions", "DiagnosisResult", "DiagnosisArrays", "json_ready"]


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
    #: runs longer than this many samples (a 10-minute 20 kHz record has 12 M) fit on ``long_fit_samples`` and
    #: score on ``long_score_samples``: a fixed time budget (10 minutes at 20 kHz in <= 20 s CPU), the
    #: parameters of an effect that lasts the whole run are as well determined by 8 windows of 7.5 k samples as
    #: of 30 k (on the 10-minute benchmark record: delay 0.49968 ms vs 0.49977 ms, truth 0.5 ms)
    long_run_samples: int = 2_000_000
    long_fit_samples: int = 60_000
    long_score_samples: int = 120_000
    #: and warm each window up over this long (the nominal model's truncation error is removed from every
    #: window; what is left is the candidate's own start-up, ≪ 0.25 s for the voltage-side effects)
    long_warmup_s: float = 0.25
    n_windows: int = 8
    warmup_s: float = 0.5
    max_stack: int = 3
    stack_pool: int = 4
    flexible: bool = True
    verbose: bool = False


def _fmt_params(fit: FitResult) -> dict[str, dict[str, Any]]:
    out = {}
    for k, v in fit.params.items():
        out[k] = {"value": v, "stderr": fit.stderr.get(k), "unit": EFFECTS[fit.effect].params[k][0]}
    return out


@dataclass(frozen=True)
class DiagnosisArrays:
    """What a diagnosis computed besides its JSON: the signals the report plots and ``--apply`` uses.

    Attributes
    ----------
    cfg : PiezoConfig
        The nominal model diagnosed.
    train, test : RunData
        The runs (``test``: the held-out one).
    y_test_nom, y_test_final : ndarray [N, axes]
        The nominal model's and the verdict-corrected (stacked) model's replay of ``test`` [m].
    r_final : ndarray [N, axes]
        The held-out residual left by the corrected model [m].
    sigma : ndarray [axes]
        The noise floor per axis [m].
    verdict_effects, stack_effects : list
        The fitted effect stages of the verdict and of the stack.
    """

    cfg: PiezoConfig
    test: RunData
    train: RunData
    y_test_nom: np.ndarray
    y_test_final: np.ndarray
    r_final: np.ndarray
    sigma: np.ndarray
    verdict_effects: list[Any]
    stack_effects: list[Any]


@dataclass(frozen=True, eq=False)
class DiagnosisResult(JsonResult, Mapping[str, Any]):
    """The result of :func:`diagnose`: a read-only mapping of its JSON report (``res["verdict"]``,
    ``res["heldout"]`` …, the keys of docs/diagnosis.md) plus the arrays (``res.arrays``), which stay out of
    :meth:`to_json`.
    """

    report: Mapping[str, Any]
    arrays: DiagnosisArrays

    def __getitem__(self, key: str) -> Any:
        return self.report[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.report)

    def __len__(self) -> int:
        return len(self.report)

    def to_json(self) -> dict[str, Any]:
        """The report as plain JSON values (NaN/Inf → None): what ``piezo-ff diagnose --json`` writes."""
        out: dict[str, Any] = json_ready(dict(self.report))
        return out


def json_ready(result: Any) -> Any:
    """``result`` (a :class:`DiagnosisResult`, or dicts/lists holding them) as JSON-safe values: floats NaN/Inf →
    None, numpy types → Python ones, keys starting with ``_`` left out; non-string keys are kept."""
    def clean(v: Any) -> Any:
        if isinstance(v, DiagnosisResult):
            return clean(dict(v.report))
        if isinstance(v, JsonResult):
            return v.to_json()
        if isinstance(v, (dict, MappingProxyType)):
            return {k: clean(x) for k, x in v.items() if not (isinstance(k, str) and k.startswith("_"))}
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
