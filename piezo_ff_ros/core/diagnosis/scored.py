"""One candidate model fitted on TRAIN and scored on TEST: the record the decision rule ranks and the
discrimination experiment re-scores (its own module so that both import it, neither the other)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .candidates import FitResult

__all__ = ["Scored"]


@dataclass
class Scored:
    """One model fitted on TRAIN and scored on TEST (mutable: judging fills ``penalty``, ``accepted`` and ``extra``).

    Attributes
    ----------
    fit : FitResult
        The fit on TRAIN.
    sse_before, sse_after : float
        Held-out residual energy under the base model, and with the fitted effect added [m²].
    penalty : float
        Complexity penalty added to ``sse_after`` for the ranking.
    before_nrmse, after_nrmse : float
        The same as NRMSE [%].
    accepted : bool
        Significant, and takes enough of the explainable gap and of the gap above the white-noise floor.
    seconds : float
        Wall-clock time of the fit and its scoring [s].
    extra : dict
        ``r_after`` (the held-out residual), then ``delta``, ``sd``, ``z``, ``share``, ``excess_shrink``,
        ``paired_z``, ``absorbs`` as judging sets them.
    """

    fit: FitResult
    sse_before: float
    sse_after: float
    penalty: float
    before_nrmse: float
    after_nrmse: float
    accepted: bool
    seconds: float
    extra: dict[str, Any] = field(default_factory=dict)
