"""The verdict: its name (an effect, ``unexplained`` or ``none``), its confidence and the reason given for it."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .decision import (GENERIC_MIN_EXTRA, HIGH_Z_MARGIN, MIN_DROP, MIN_EXCESS_SHRINK, MIN_SHARE, TIE_Z,
                       TIMING_CONVENTION_SAMPLES, _Choice, _confidence, _Held, _Judged, _significant)
from .scored import Scored

__all__ = ["NOISE_MARGIN"]

#: informational: the held-out gap is "at the white-noise floor" within this factor (RMS)
NOISE_MARGIN = 1.05


@dataclass(frozen=True)
class _Verdict:
    """The verdict of a diagnosis.

    Attributes
    ----------
    name : str
        The effect named, ``unexplained`` (a reproducible gap no candidate names) or ``none``.
    confidence : str
        ``high``, ``medium`` or ``low``.
    reason : str
        Why, in one paragraph (the report's ``confidence_reason``).
    """

    name: str
    confidence: str
    reason: str


def _verdict(j: _Judged, c: _Choice, sigma2: float) -> _Verdict:
    """Name the verdict, rate its confidence and say why."""
    if c.verdict is not None:
        return _named(j, c, c.verdict)
    if c.any_significant and _material(j):
        return _unexplained(j)
    return _none(j, sigma2)


def _material(j: _Judged) -> list[Scored]:
    """The models (candidates and the flexible one) that reproduce a material part of the held-out gap: significant,
    not a timing artefact (:func:`~.decision._timing_artefact`), and taking at least :data:`MIN_EXCESS_SHRINK` of the
    gap above the white-noise floor — the share an accepted candidate must take to "explain" a gap.  ``unexplained``
    claims a reproducible gap that no candidate names; a gap of which no model, the flexible one included, repeats
    a material part on the held-out run is not one: a significant sliver of it is what coloured noise or the nominal
    model's own error leaves (both partly repeat between runs of the same plant)."""
    pool = list(j.scored) + ([j.flex] if j.flex is not None else [])
    return [x for x in pool if _significant(x, j.zc) and not x.extra.get("timing_artefact", False)
            and x.extra.get("excess_shrink", 0.0) >= MIN_EXCESS_SHRINK]


def _named(j: _Judged, c: _Choice, verdict: Scored) -> _Verdict:
    """An accepted candidate: confidence from :func:`~.decision._confidence`, at most medium when a generic family
    absorbs it, low while a tie is undecided."""
    name = verdict.fit.effect
    conf, why = _confidence(verdict, c.runner, c.tie_z, j.zc)
    absorbing = [s for s in j.scored if s.extra.get("absorbs") == name]
    if absorbing:
        g = absorbing[0]
        extra = g.extra["excess_shrink"] - verdict.extra["excess_shrink"]
        if extra < GENERIC_MIN_EXTRA:
            why += (f"; {g.fit.effect} ({g.fit.n_params} parameters) fits the held-out run slightly better "
                    f"({g.after_nrmse:.3g} % vs {verdict.after_nrmse:.3g} %) but takes only {100 * extra:.1f} % "
                    f"more of the gap above the white-noise floor (< {100 * GENERIC_MIN_EXTRA:.0f} %): the generic "
                    f"family absorbs {name}, whose form is approximate")
        else:
            why += (f"; {g.fit.effect} ({g.fit.n_params} parameters) fits the held-out run "
                    f"({g.after_nrmse:.3g} % vs {verdict.after_nrmse:.3g} %) but not significantly better than "
                    f"{name} ({verdict.fit.n_params} parameters): paired z = {g.extra.get('absorb_paired_z', 0):.3g} "
                    f"< {TIE_Z:g}; with fewer parameters and an equal held-out fit, the physical form is the model")
        if conf == "high":
            conf = "medium"
    if c.discrimination is not None and "decided_on_run" not in c.discrimination:
        conf = "low"
        why += (f"; ambiguous with {', '.join(s.fit.effect for s in c.ties)} on this held-out run — run the "
                "proposed discrimination experiment")
    return _Verdict(name, conf, why)


def _unexplained(j: _Judged) -> _Verdict:
    """Nothing accepted but something significant: a reproducible gap that no candidate names."""
    scored, flex, zc = j.scored, j.flex, j.zc
    best_c = max(scored, key=lambda s: s.extra["delta"]) if scored else None
    fz = flex.extra["z"] if flex is not None else 0.0
    why = (f"the held-out gap is reproducible (flexible model z = {fz:.3g}, threshold {zc:.2f}) but no "
           f"candidate explains at least {100 * MIN_SHARE:.0f} % of what can be explained and "
           f"{100 * MIN_EXCESS_SHRINK:.0f} % of the gap above the white-noise floor")
    if best_c is not None:
        why += f" (best: {best_c.fit.effect}, {100 * max(best_c.extra['share'], 0):.0f} %)"
    # never high: "no candidate takes half" also happens when a candidate's fit on TRAIN went astray
    conf = "medium" if (fz > zc + HIGH_Z_MARGIN and (best_c is None or best_c.extra["share"] < 0.25)) \
        else "low"
    return _Verdict("unexplained", conf, why)


def _none(j: _Judged, sigma2: float) -> _Verdict:
    """Nothing significant: the held-out gap is not reproducible from the training run.

    The reason states what was tested and what is known, nothing more: every held-out residual is taken at the
    nominal model's best timing convention (:func:`~.decision.align_timing`, the offset fitted here is reported), the
    z-test uses the residual's measured noise spectrum, and a remainder above the white-noise floor is reported as
    not reproducible — its cause (non-white noise, or an error of the nominal model that no model fitted on TRAIN
    repeats) is not something these runs tell apart."""
    scored, flex, zc, held = j.scored, j.flex, j.zc, j.held
    zmax = max([s.extra["z"] for s in scored] + ([flex.extra["z"]] if flex is not None else []) + [-math.inf])
    sig = [s for s in scored + ([flex] if flex is not None else []) if _significant(s, zc)]
    if not sig:
        why = (f"no model fitted on TRAIN reproduces the held-out gap beyond noise (largest z = {zmax:.3g}, "
               f"threshold {zc:.2f}, or less than {100 * MIN_DROP:g} % of the residual energy; the z-test uses the "
               "residual's measured noise spectrum)")
    else:
        real = [s for s in sig if not s.extra.get("timing_artefact", False)]
        most = max([s.extra.get("excess_shrink", 0.0) for s in real] + [0.0])
        above = sig[0].extra.get("gap_above_floor", True)
        of_what = "of the gap above the white-noise floor" if above else \
            "of the held-out residual (it is not above the white-noise floor estimate)"
        why = (f"models fitted on TRAIN repeat a sliver of the held-out residual beyond noise (largest z = "
               f"{zmax:.3g}, threshold {zc:.2f}) but none a material part of the gap: at most "
               f"{100 * most:.0f} % {of_what} (naming an effect, or calling the gap unexplained, needs "
               f"{100 * MIN_EXCESS_SHRINK:.0f} %)")
        artefacts = [s.fit.effect for s in sig if s.extra.get("timing_artefact", False)]
        if artefacts:
            one = len(artefacts) == 1
            why += (f"; {', '.join(artefacts)} {'improves' if one else 'improve'} the held-out fit only at "
                    f"{'its' if one else 'their'} own timing convention (at the nominal model's convention "
                    f"{'its' if one else 'their'} held-out residual grows): not counted")
    tau = _timing_offset(held)
    if tau is not None:
        why += (f"; the held-out gap is taken at the nominal model's own timing convention: a DAC-edge / ADC-sampling "
                f"offset of {tau:+.3f} sample (bound ±{TIMING_CONVENTION_SAMPLES:g}) is fitted out as part of the "
                "null hypothesis, not counted as an effect")
    at_floor = math.sqrt(float(np.mean(held.r_before ** 2))) <= NOISE_MARGIN * math.sqrt(sigma2)
    conf = "high" if (zmax < zc - 1.0 and at_floor) else "medium"
    if not at_floor:
        why += (f"; what is left is {math.sqrt(float(np.mean(held.r_before ** 2)) / max(sigma2, 1e-300)):.3g}× the "
                "white-noise floor and no model fitted on TRAIN repeats it on TEST: non-white noise or an error of "
                "the nominal model that differs between the runs — these runs do not tell which, and neither is an "
                "effect they can name")
    return _Verdict("none", conf, why)


def _timing_offset(held: "_Held") -> float | None:
    """The timing offset [samples] fitted out of the held-out residual under the nominal model (``None`` when no
    timing sensitivity was used)."""
    c = np.asarray(held.timing, float)
    cc = float(np.sum(c * c))
    if not cc > 0 or c.shape != held.r_raw.shape:
        return None
    return float(np.sum((np.asarray(held.r_raw, float) - held.r_before) * c) / cc)
