"""Which effect: every model fitted on TRAIN scored on TEST, judged against the residual's own noise and ranked;
the verdict's near ties and how they are resolved (a discrimination run, or a proposed experiment).

Decision rule (:mod:`.stats` states the test):

* H0 includes the nominal model's own timing convention: TRAIN is moved to the nominal model's convention (a DAC
  edge / ADC sampling offset fitted on TRAIN, bounded to ±:data:`TIMING_CONVENTION_SAMPLES`) before any fit, and
  every held-out residual is taken at its best convention within that bound (:func:`align_timing`); a gap the
  nominal model closes by moving its edges within the bound is not an effect;
* every model fitted on TRAIN — each candidate effect and the flexible reference model (:mod:`.flexible`) — gets a
  held-out z: its drop in TEST residual energy over the standard deviation that drop would have if the residual
  were noise of the measured spectrum (white, coloured or quantised alike); significant above the one-sided
  Bonferroni threshold at family-wise α = 1 %;
* a candidate is **accepted** when it is significant and removes at least :data:`MIN_SHARE` of the explainable
  held-out gap (the largest drop any model achieves, the flexible one included), at least :data:`MIN_EXCESS_SHRINK`
  of the gap above the white-noise floor (of the whole residual when it is not above that floor), and is no timing
  artefact (:func:`_timing_artefact`: at the nominal model's timing convention its residual does not grow); the
  verdict is the best accepted candidate (ranked by held-out residual energy plus a small complexity penalty);
* nothing accepted but some significant model, no timing artefact, takes at least :data:`MIN_EXCESS_SHRINK` of the gap
  above the floor → ``unexplained`` (the gap is reproducible, no candidate names it); a significant sliver alone is
  ``none``;
  nothing significant → ``none``;
* a runner-up whose held-out residual is not significantly worse than the verdict's (paired z < :data:`TIE_Z`)
  makes the verdict ambiguous: confidence ``low`` and a proposed discrimination experiment (:mod:`.discriminate`).

The phase hands on two frozen records: :class:`_Judged` (the first round of fits, scored and ranked) and
:class:`_Choice` (the verdict candidate, its runner-up and ties, the discrimination).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..config import PiezoConfig
from ..recording.run import RunData
from . import discriminate as disc
from . import stats
from .baseline import _Effects, _Replay, _Setup
from .candidates import FitContext, FitResult, fit_candidate, n_eff_ratio
from .flexible import fit_flexible
from .replay import Windows, residual, simulate, timing_sensitivity
from .results import DiagnosisOptions
from .scored import Scored

__all__ = ["TIMING_CONVENTION_SAMPLES", "align_timing", "RATE_AMPLITUDE", "CONFOUND_RHO", "excitation_rate_amplitude_correlation", "MIN_SHARE", "RICHER_MIN_GAIN", "MIN_EXCESS_SHRINK", "HIGH_EXCESS_SHRINK", "MIN_DROP", "TIE_Z",
           "HIGH_Z_MARGIN", "HIGH_SHARE", "HIGH_PAIRED_Z", "GENERIC", "GENERIC_MIN_EXTRA", "RICHER", "NESTED"]

#: an accepted candidate removes at least this share of the explainable held-out gap
MIN_SHARE = 0.5
#: a richer candidate ranks above the simpler one it contains only with a paired z >= TIE_Z and this much less
#: held-out residual energy
RICHER_MIN_GAIN = 0.05
#: an accepted candidate removes at least this share of the held-out gap above the white-noise floor ("explains"
#: it, not merely nibbles at it); "high" confidence needs HIGH_EXCESS_SHRINK
MIN_EXCESS_SHRINK = 0.25
HIGH_EXCESS_SHRINK = 0.6
#: a significant model also removes at least this share of the held-out residual energy
MIN_DROP = 0.01
#: a runner-up within this paired z of the verdict explains the held-out run about as well: ambiguous
TIE_Z = 2.0
#: "high" confidence: z above the threshold by this margin, this share of the explainable gap, this paired z
HIGH_Z_MARGIN = 3.0
HIGH_SHARE = 0.7
HIGH_PAIRED_Z = 4.0
#: candidates flexible enough to absorb other dynamics (several free resonances): their verdict is at most medium
GENERIC = ("unmodelled_mode", "amplitude_dependent_dynamics")
#: a generic candidate ranks above an accepted physical (few-parameter) candidate only when it removes at least
#: this much more of the held-out gap above the white-noise floor.  Reason: 10–56 free filter coefficients mimic a
#: delay, a roll-off or a lagged loop almost exactly; when the physical candidate already leaves less than 5 % of
#: the gap above the floor, what the generic family takes beyond it is the physical form's approximation error
#: (e.g. a DAC latency, a modified-ZOH delay, against the interpolated ``input_delay``), not another effect.
#: Set from the tuning split (seeds 11/12: DAC latency, margin 0.01 %) before any run on the fresh held-out seeds.
GENERIC_MIN_EXTRA = 0.05

#: (richer, simpler): the simpler candidate is a special case of the richer one
RICHER = {("amplitude_dependent_dynamics", "unmodelled_mode")}
NESTED = {frozenset(p) for p in RICHER}


class _Held:
    """The held-out run on its scoring windows, with the base model's output."""

    def __init__(self, cfg: PiezoConfig, run: RunData, base: _Effects, windows: Windows,
                 y_base_full: np.ndarray | None = None) -> None:
        self.cfg, self.run, self.base, self.windows = cfg, run, list(base), windows
        self.y_base_full: np.ndarray | None
        if windows.is_whole:
            self.y_base_full = simulate(cfg, run.u, base) if y_base_full is None else y_base_full
            self.target = run.y
            self.y_base: np.ndarray = self.y_base_full
        else:
            self.y_base_full = y_base_full
            y_win = simulate(cfg, run.u, base, windows)
            if y_base_full is not None:
                self.target = windows.take(run.y) - windows.take(y_base_full) + y_win
            else:
                self.target = windows.take(run.y)
            self.y_base = y_win
        # the timing convention is part of the nominal model's H0 (the first round, on the nominal model alone)
        self.timing = timing_sensitivity(cfg, run.u, windows) if not self.base else np.zeros_like(self.y_base)
        self.r_raw = residual(self.target, self.y_base)
        self.r_before = self.align(self.r_raw)
        yt = self.target - self.target.mean(axis=0)
        self.den = float(np.sqrt(np.sum(yt ** 2)))

    def nrmse(self, r: np.ndarray) -> float:
        return float(100 * np.sqrt(np.sum(r ** 2)) / max(self.den, 1e-300))

    def align(self, r: np.ndarray) -> np.ndarray:
        """``r`` with the nominal model's sub-sample timing convention fitted out (:func:`align_timing`)."""
        return align_timing(r, self.timing)

    def score(self, effects: _Effects) -> np.ndarray:
        return self.align(self.score_raw(effects))

    def score_raw(self, effects: _Effects) -> np.ndarray:
        """The held-out residual with ``effects`` added, at the recorded timing (not aligned): what the reported
        held-out NRMSE measures."""
        return residual(self.target, simulate(self.cfg, self.run.u, self.base + list(effects), self.windows))


#: the largest sub-sample timing offset between the record's voltages and displacements that is a convention of the
#: discretisation, not an effect [samples].  Where within its sample period a DAC edge settles and where the ADC
#: samples are not stated by a recording: a zero-order hold whose edge settles over up to the first fifth of the
#: period (a real DAC's settling, a first-order-hold edge), or an ADC aperture anywhere in the last fifth, moves the
#: recorded response by up to 0.1 sample against the nominal model's ideal ZOH / point sampling.  The nominal
#: model replayed under any of these conventions is equally valid (H0); a longer lag is an effect (``input_delay``)
TIMING_CONVENTION_SAMPLES = 0.1


def _timing_aligned(cfg: PiezoConfig, run: RunData, y_nom: np.ndarray, windows: Windows) -> tuple[RunData, float]:
    """``run`` with its measured displacement moved to the nominal model's timing convention: the offset ``τ``
    (bounded, :data:`TIMING_CONVENTION_SAMPLES`) that best aligns the nominal replay ``y_nom`` with the measurement
    on ``windows``, and ``y − τ·∂ŷ/∂τ`` (the measurement as the nominal model's convention would have recorded it,
    to first order).  The candidates are fitted on that, so that none of them spends its parameters on the
    convention.  Returns the run (the same object when ``τ = 0``) and ``τ`` [samples]."""
    y_win = windows.take(np.asarray(y_nom, float))
    # the sensitivity on each fitted stretch with its warm-up (nothing else of TRAIN is read by a fit)
    c_spans = [timing_sensitivity(cfg, run.u[w:stop]) for w, _, stop in windows.spans]
    c = np.concatenate([cs[start - w:] for cs, (w, start, _) in zip(c_spans, windows.spans)])
    c = c - c.mean(axis=0)
    r = residual(windows.take(np.asarray(run.y, float)), y_win)
    aligned = align_timing(r, c)
    cc = float(np.sum(c * c))
    tau = float(np.sum((r - aligned) * c) / cc) if cc > 0 and aligned is not r else 0.0
    # an offset at the bound is not a convention but a lag (``input_delay``'s to explain): TRAIN is left as recorded
    # (a first-order correction about the nominal's convention would be wrong that far from it)
    if tau == 0.0 or abs(tau) >= TIMING_CONVENTION_SAMPLES * (1 - 1e-9):
        return run, 0.0
    # measured − nominal(τ) = measured − nominal − τ·c: the measurement minus τ·c is what the convention τ
    # would have recorded
    y_run = np.array(run.y, float)
    for cs, (w, _, stop) in zip(c_spans, windows.spans):
        y_run[w:stop] -= tau * cs
    return dataclasses.replace(run, y=y_run), tau


def align_timing(r: np.ndarray, direction: np.ndarray,
                 max_samples: float = TIMING_CONVENTION_SAMPLES) -> np.ndarray:
    """The residual ``r`` with its least-squares component along ``direction`` removed, the offset bounded to
    ±``max_samples``.

    ``direction`` is the nominal replay's sensitivity to its timing convention (:func:`~.replay.timing_sensitivity`,
    one offset shared by all axes: one DAC and one ADC clock): ``measured − nominal(τ) ≈ measured − nominal − τ·c``.
    Every held-out residual (before and after each model) is taken at its best convention within the bound, so that
    a gap the nominal model closes by moving its DAC edges within a sample is not evidence of an effect.  One
    parameter fitted on the held-out run for every model alike: it changes no comparison's null distribution to
    first order."""
    r = np.asarray(r, float)
    c = np.asarray(direction, float)
    cc = float(np.sum(c * c))
    if not cc > 0 or c.shape != r.shape:
        return r
    tau = float(np.clip(float(np.sum(r * c)) / cc, -max_samples, max_samples))
    out: np.ndarray = r - tau * c
    return out


def _evaluate(fit: FitResult, held: _Held, t0: float) -> Scored:
    r_raw_after = held.score_raw(fit.effects)
    r_after = held.align(r_raw_after)
    sse_b = float(np.sum(held.r_before ** 2))
    sse_a = float(np.sum(r_after ** 2))
    return Scored(fit, sse_b, sse_a, 0.0, held.nrmse(held.r_before), held.nrmse(r_after), False,
                   time.perf_counter() - t0, {"r_after": r_after, "r_raw_after": r_raw_after})


def _timing_artefact(s: Scored, held: Any) -> bool:
    """Whether the held-out improvement of ``s`` exists only at its own timing convention: its held-out residual
    taken at the nominal model's convention (the offset fitted under H0, a property of the recording) is larger
    than the nominal model's.

    The timing convention is a nuisance of H0 (bounded to ±:data:`TIMING_CONVENTION_SAMPLES`), fitted on the
    nominal model's held-out residual.  Each model's residual is also scored at its own best convention; a model
    that beats the nominal model only there — whose change of the replay, added at the recording's convention,
    moves the replay away from the measurement — has had the nuisance take back what it got wrong (a roll-off
    fitted at its bound far above the sample rate only shifts the held edges, for one).  It is never accepted and
    is no evidence of a reproducible gap.  A real effect, fitted on TRAIN at the nominal model's convention, lowers
    the residual at that convention as well.  (Not the residual at the recorded timing: when the recording's
    convention differs from the nominal model's, that residual is dominated by the offset, and the cross term of a
    real effect's correction with it can have either sign.)"""
    r_raw, r_before = getattr(held, "r_raw", None), getattr(held, "r_before", None)
    r_raw_after = s.extra.get("r_raw_after")
    if r_raw is None or r_before is None or r_raw_after is None:
        return False
    at_nominal_convention = np.asarray(r_before, float) - (np.asarray(r_raw, float) - np.asarray(r_raw_after, float))
    s.extra["sse_after_at_nominal_convention"] = float(np.sum(at_nominal_convention ** 2))
    return bool(s.extra["sse_after_at_nominal_convention"] > float(np.sum(np.asarray(r_before, float) ** 2)))


def _judge(scored: list[Scored], flex: "Scored | None", held: _Held, sigma2: float, zc: float) -> "stats.NoisePSD":
    """z of every held-out improvement (noise spectrum from the best residual), share of the explainable gap,
    acceptance; sorts ``scored`` best first.  Returns the noise spectrum used."""
    pool = list(scored) + ([flex] if flex is not None else [])
    r_best = min((s.extra["r_after"] for s in pool), key=lambda r: float(np.sum(r ** 2)), default=held.r_before)
    if float(np.sum(r_best ** 2)) > float(np.sum(held.r_before ** 2)):
        r_best = held.r_before
    psd = stats.noise_psd(r_best)
    for s in pool:
        s.extra["delta"], s.extra["sd"], s.extra["z"] = stats.improvement_z(held.r_before, s.extra["r_after"], psd)
    explainable = max([s.extra["delta"] for s in pool] + [0.0])
    N = held.r_before.size
    ratio = n_eff_ratio(r_best)
    sse_before = float(np.sum(held.r_before ** 2))
    above = sse_before > N * sigma2
    # the gap above the white-noise floor; when the residual is not above that floor (a high-frequency effect can
    # raise the estimate, or there is no gap), the floor is unknown somewhere in [0, floor]: the gap is then at most
    # the whole residual energy, and a share of it is measured against that bound — the smallest share the model
    # can have of the true gap, so that a model is credited only with what it takes whatever the true floor is
    excess = sse_before - N * sigma2 if above else max(sse_before, 1e-300)
    for s in pool:
        s.extra["excess_shrink"] = s.extra["delta"] / excess
        s.extra["gap_above_floor"] = above                # else the share above the floor is no measure of it
        s.extra["timing_artefact"] = _timing_artefact(s, held)
    for s in scored:
        s.extra["share"] = s.extra["delta"] / explainable if explainable > 0 else 0.0
        s.penalty = s.fit.n_params * math.log(max(N / ratio, 2.0)) * sigma2 * ratio
        s.accepted = bool(_significant(s, zc) and s.extra["share"] >= MIN_SHARE
                          and s.extra["excess_shrink"] >= MIN_EXCESS_SHRINK and not s.extra["timing_artefact"])
    scored.sort(key=lambda s: s.sse_after + s.penalty)
    # a richer candidate that nests a simpler one must beat it clearly on held-out data to rank above it: by a paired
    # z, by RICHER_MIN_GAIN of the residual energy, and by GENERIC_MIN_EXTRA of the gap above the white-noise floor
    # (what its extra part names must be a material part of the effect, not of the noise-level rest the simpler one
    # leaves: a linear mode that leaves 0.1 % of the gap above the floor leaves nothing for amplitude dependence)
    for i in range(len(scored)):
        for j in range(i + 1, len(scored)):
            rich, simple = scored[i], scored[j]
            if (rich.fit.effect, simple.fit.effect) in RICHER and simple.accepted and \
                    (stats.paired_z(rich.extra["r_after"], simple.extra["r_after"], psd) < TIE_Z
                     or rich.sse_after > (1 - RICHER_MIN_GAIN) * simple.sse_after
                     or (_contains_linear_modes(rich.fit)
                         and rich.extra["excess_shrink"] - simple.extra["excess_shrink"] < GENERIC_MIN_EXTRA)):
                scored[i], scored[j] = simple, rich
    # amplitude dependence by physics: the linear mode family fits a nonlinear resonance with several linear modes
    # about as well on held-out data, but the resonance refitted on the small- and on the large-motion half of TRAIN
    # moves (fit_modes.mode_level_shift) — then the richer family is named, whatever the held-out tie says.  Not on
    # runs whose motion has one level (``one_level``): their two halves are the same amplitude, so a "shift" between
    # them is no evidence of amplitude dependence (that case is a tie to discriminate, :func:`_one_amplitude`)
    mode = next((x for x in scored if x.fit.effect == "unmodelled_mode" and x.accepted), None)
    rich_ad = next((x for x in scored if x.fit.effect == "amplitude_dependent_dynamics" and x.accepted), None)
    shift = (rich_ad.fit.extra.get("level_shift") or {}) if rich_ad is not None else {}
    # ... and only when the linear mode leaves something above the white-noise floor on the held-out run (at least
    # GENERIC_MIN_EXTRA of the gap above it): amplitude dependence is evidenced by what a linear resonance cannot
    # explain; when the linear mode already takes the whole gap above the floor there is nothing left for a
    # nonlinearity to be, whatever its resonance refitted on two halves of TRAIN does (a misspecified or noisy
    # half-fit moves too)
    if mode is not None and rich_ad is not None and scored.index(rich_ad) > scored.index(mode) and \
            shift.get("significant") and not shift.get("one_level") and \
            (not _contains_linear_modes(rich_ad.fit) or mode.extra["excess_shrink"] < 1.0 - GENERIC_MIN_EXTRA):
        scored.remove(rich_ad)
        scored.insert(scored.index(mode), rich_ad)
    # parsimony: a generic filter family above an accepted physical candidate that leaves it < GENERIC_MIN_EXTRA
    # of the gap above the floor absorbs that candidate; it does not name a different effect.  Nor does it when it
    # does not beat the physical candidate significantly on the held-out run (paired z < TIE_Z): with fewer
    # parameters and a held-out fit the noise cannot tell apart, the physical form is the better model (Occam on
    # held-out data — a held-out score already charges every parameter its variance, so equal scores favour the
    # smaller model)
    top = next((s for s in scored if s.accepted), None)
    if top is not None and top.fit.effect in GENERIC:
        for s in scored:
            if s.accepted and s.fit.effect not in GENERIC and \
                    (top.extra["excess_shrink"] - s.extra["excess_shrink"] < GENERIC_MIN_EXTRA
                     or (s.fit.n_params < top.fit.n_params
                         and stats.paired_z(top.extra["r_after"], s.extra["r_after"], psd) < TIE_Z)) and \
                    not _resonant_remainder(top, s, held, psd):
                scored.remove(s)
                scored.insert(scored.index(top), s)
                for g in scored:
                    if g.fit.effect in GENERIC and g.accepted:
                        g.extra["absorbs"] = s.fit.effect
                        g.extra["absorb_paired_z"] = stats.paired_z(g.extra["r_after"], s.extra["r_after"], psd)
                break
    return psd


#: what a generic mode family takes beyond a physical candidate is a resonance (not that candidate's form error)
#: when its energy density within f·(1 ± RESONANT_BAND) of one of the family's lightly damped modes (ζ ≤
#: RESONANT_ZMAX) is at least RESONANT_PEAK times that in the flanks f·(1 ± 3·RESONANT_BAND) around it.  A
#: resonance of ζ = RESONANT_ZMAX under a flat excitation has a ratio ≈ 4 there (|H|² averaged over the band and
#: over the flanks), a lighter one more; a smooth form error (a delay's, a roll-off's) ≈ 1
RESONANT_BAND = 0.1
RESONANT_ZMAX = 0.1
RESONANT_PEAK = 3.0


def _resonant_remainder(generic: Scored, physical: Scored, held: _Held, psd: "stats.NoisePSD") -> bool:
    """Whether the generic mode family beats the physical candidate by a resonance the physical form cannot have:
    significantly on the held-out run (paired z ≥ TIE_Z), taking at least half (MIN_SHARE) of what the physical
    candidate leaves above the white-noise floor, and with the difference of their held-out predictions peaked
    (RESONANT_PEAK) at one of the family's lightly damped modes.  A frequency-selective
    remainder — a mode in a cross-coupling path, beyond its static gain — is another effect, not the physical
    candidate's approximation error (which is broadband: a delay's grows with frequency)."""
    left = 1.0 - physical.extra["excess_shrink"]
    if left <= 0 or generic.extra["excess_shrink"] - physical.extra["excess_shrink"] < MIN_SHARE * left:
        return False
    if stats.paired_z(generic.extra["r_after"], physical.extra["r_after"], psd) < TIE_Z:
        return False
    freqs = np.atleast_1d(np.asarray(generic.fit.params.get("freq", []), float)).reshape(-1)
    zetas = np.atleast_1d(np.asarray(generic.fit.params.get("damping", []), float)).reshape(-1)
    if freqs.size == 0 or zetas.size != freqs.size:
        return False
    d = np.asarray(physical.extra["r_after"]) - np.asarray(generic.extra["r_after"])
    P = np.sum(np.abs(np.fft.rfft(d - d.mean(axis=0), axis=0)) ** 2, axis=1)
    f = np.fft.rfftfreq(len(d), held.cfg.dt)
    w = RESONANT_BAND
    for fm, zm in zip(freqs, zetas):
        if zm > RESONANT_ZMAX or fm * (1 + 3 * w) > f[-1]:
            continue
        band = (f >= fm * (1 - w)) & (f <= fm * (1 + w))
        flanks = ((f >= fm * (1 - 3 * w)) & (f < fm * (1 - w))) | ((f > fm * (1 + w)) & (f <= fm * (1 + 3 * w)))
        if band.any() and flanks.any() and float(np.mean(P[band])) >= RESONANT_PEAK * float(np.mean(P[flanks])):
            return True
    return False


def _significant(s: Scored, zc: float) -> bool:
    """Statistically (z above the threshold) *and* practically (removes ≥ MIN_DROP of the held-out residual
    energy) significant: a tiny but 'significant' drop is what structured noise — coarse quantisation is a
    deterministic function of the signal — gives a model correlated with the signal."""
    return bool(s.extra["z"] > zc and s.extra["delta"] >= MIN_DROP * s.sse_before)


def _fit_windows(train: RunData, opts: DiagnosisOptions) -> Windows:
    """The stretches of TRAIN every fit uses (the whole run, or ``n_windows`` spread over a long one)."""
    return Windows.spread(len(train), opts.fit_samples, opts.n_windows, int(opts.warmup_s * train.sample_rate))


def _fit_all(cfg: PiezoConfig, train: RunData, y_base_train: np.ndarray, base: _Effects, names: Sequence[str],
             held: _Held, opts: DiagnosisOptions, log: Callable[[str], None]) -> list[Scored]:
    ctx = FitContext(cfg, list(base), train.u, train.y, y_base_train, _fit_windows(train, opts))
    scored = []
    for name in names:
        t0 = time.perf_counter()
        try:
            fit = fit_candidate(name, ctx)
            s = _evaluate(fit, held, t0)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            log(f"  {name}: fit failed ({exc})")
            continue
        log(f"  {name:28s} held-out {s.before_nrmse:7.3f} % -> {s.after_nrmse:7.3f} %  ({s.seconds:.1f} s)")
        scored.append(s)
    return scored


def _fit_flexible(cfg: PiezoConfig, train: RunData, y_train_nom: np.ndarray, held: _Held, test_ext: RunData,
                  y_ext_nom: np.ndarray, opts: DiagnosisOptions, log: Callable[[str], None]) -> Scored | None:
    """The flexible reference model on TRAIN, scored on TEST like a candidate (``None`` if it cannot be fitted)."""
    t0 = time.perf_counter()
    try:
        fm = fit_flexible(train.u, train.y, y_train_nom, _fit_windows(train, opts), cfg.sample_rate)
        d = fm.predict(test_ext.u, y_ext_nom, held.windows)
    except (ValueError, np.linalg.LinAlgError) as exc:
        log(f"  flexible model failed ({exc})")
        return None
    r_raw_after = residual(held.r_raw, d)
    r_after = held.align(r_raw_after)
    fit = FitResult("flexible", {}, {}, [], fm.n_features * cfg.n_axes, float("nan"))
    s = Scored(fit, float(np.sum(held.r_before ** 2)), float(np.sum(r_after ** 2)), 0.0,
                held.nrmse(held.r_before), held.nrmse(r_after), False, time.perf_counter() - t0,
                {"r_after": r_after, "ridge": fm.ridge, "r_raw_after": r_raw_after})
    log(f"  {'(flexible reference model)':28s} held-out {s.before_nrmse:7.3f} % -> {s.after_nrmse:7.3f} %  "
        f"({s.seconds:.1f} s, {fm.n_features} features per output)")
    return s


def _confidence(best: Scored, runner: "Scored | None", tie_z: float | None, zc: float) -> tuple[str, str]:
    """high / medium / low from how clearly the verdict beats noise, how much of the explainable gap it takes and
    how clearly it beats the runner-up on the held-out run (paired z)."""
    z, share = best.extra["z"], best.extra["share"]
    why = (f"held-out improvement z = {z:.3g} (threshold {zc:.2f}); it takes {100 * min(share, 9.99):.0f} % of "
           f"the explainable held-out gap")
    if runner is None or tie_z is None:
        tie_z = math.inf
    else:
        why += f"; it beats the runner-up ({runner.fit.effect}) by z = {tie_z:.3g}"
    if best.extra.get("gap_above_floor", True):
        why += f"; it removes {100 * best.extra['excess_shrink']:.0f} % of the gap above the white-noise floor"
    else:
        why += ("; the held-out gap is not above the white-noise floor estimated from the residual (a "
                "high-frequency effect can raise that estimate), so no share of a gap above it is measured")
    if z > zc + HIGH_Z_MARGIN and share >= HIGH_SHARE and tie_z >= HIGH_PAIRED_Z and \
            best.extra["excess_shrink"] >= HIGH_EXCESS_SHRINK:
        if best.fit.effect in GENERIC:
            return "medium", why + (f"; capped at medium: {best.fit.effect} is a generic filter family that can "
                                    "absorb other dynamics")
        return "high", why
    if share >= MIN_SHARE and tie_z >= TIE_Z:
        return "medium", why
    return "low", why


def _contains_linear_modes(fit: FitResult) -> bool:
    """Whether an ``amplitude_dependent_dynamics`` fit contains the linear mode family as a special case: the
    level-modulated filter family does, and so does the base-excited mode fitted on the linear resonances found; the
    base-excited mode alone (2 + 3n parameters) does not — it is a smaller model beside the linear family, not an
    extension of it, and is ranked by its held-out fit like any rival."""
    if fit.params.get("form") != "base_excited":
        return True
    return any(name == "unmodelled_mode" for name, _ in fit.effects)


def _nested(a: str, b: str) -> bool:
    """Whether one of two candidates contains the other as a special case (then they are not rival explanations
    to discriminate: the simpler one stands unless the richer one is better on held-out data)."""
    return frozenset((a, b)) in NESTED

# ----------------------------------------------------------------------------------------------------------------
# The phase: first round, then the verdict candidate's ties
# ----------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Judged:
    """The first round: every candidate (and the flexible reference model) fitted on TRAIN, scored on TEST, judged.

    Attributes
    ----------
    held : _Held
        The held-out run on its scoring windows, under the nominal model.
    scored : list of Scored
        The candidates that could be fitted, best first (:func:`_judge`).
    flex : Scored or None
        The flexible reference model (``None``: not asked for, or its fit failed).
    n_tests : int
        How many models were tested: the Bonferroni family.
    zc : float
        The critical z of that family.
    psd : stats.NoisePSD
        The noise spectrum the z-tests used.
    """

    held: _Held
    scored: list[Scored]
    flex: Scored | None
    n_tests: int
    zc: float
    psd: stats.NoisePSD


def _first_round(s: _Setup, rep: _Replay, log: Callable[[str], None]) -> _Judged:
    """Fit every candidate and the flexible model on TRAIN, score them on TEST, judge and rank them."""
    opts = s.opts
    fs = s.cfg.sample_rate
    score_win = Windows.spread(len(s.test), opts.score_samples, opts.n_windows, int(opts.warmup_s * fs),
                               offset=s.history)
    held = _Held(s.cfg, s.test_ext, [], score_win, rep.y_ext_nom)
    train, tau = _timing_aligned(s.cfg, s.train, rep.y_train_nom, _fit_windows(s.train, opts))
    if tau != 0.0:
        log(f"timing convention: TRAIN aligned by {tau:+.3f} sample (bound ±{TIMING_CONVENTION_SAMPLES:g})")
    log("candidates (fitted on train, scored on test):")
    scored = _fit_all(s.cfg, train, rep.y_train_nom, [], list(opts.candidates), held, opts, log)
    flex = _fit_flexible(s.cfg, train, rep.y_train_nom, held, s.test_ext, rep.y_ext_nom, opts, log) \
        if opts.flexible else None
    n_tests = len(scored) + (flex is not None)
    zc = stats.z_critical(n_tests)
    psd = _judge(scored, flex, held, rep.sigma2, zc)
    return _Judged(held, scored, flex, n_tests, zc, psd)


@dataclass(frozen=True)
class _Choice:
    """The verdict candidate and what stands beside it.

    Attributes
    ----------
    verdict : Scored or None
        The best accepted candidate (after a discrimination run, the one it named); ``None``: nothing accepted.
    runner : Scored or None
        The runner-up on the held-out run (``None`` after a discrimination run).
    tie_z : float or None
        The paired z by which the verdict beats the runner-up (or, after a discrimination run, its winner the
        next best there).
    ties : list of Scored
        Significant rivals within :data:`TIE_Z` of the verdict, neither nesting the other.
    any_significant : bool
        Whether any model (a candidate or the flexible one) is significant.
    discrimination : dict or None
        The report's ``discrimination`` (``None``: no ties).
    """

    verdict: Scored | None
    runner: Scored | None
    tie_z: float | None
    ties: list[Scored]
    any_significant: bool
    discrimination: dict[str, Any] | None


def _choose(s: _Setup, rep: _Replay, j: _Judged, log: Callable[[str], None]) -> _Choice:
    """The best accepted candidate, its runner-up and near ties; ties decided on the discrimination run, or an
    experiment proposed to decide them."""
    accepted = [x for x in j.scored if x.accepted]
    significant = [x for x in j.scored + ([j.flex] if j.flex is not None else []) if _significant(x, j.zc)]
    verdict = accepted[0] if accepted else None
    if verdict is None:
        return _Choice(None, None, None, [], bool(significant), None)
    runner, tie_z, ties = _ties(verdict, j)
    confound = _rate_amplitude_confounded(s, verdict, j)
    if confound is not None:
        ties = ties + [confound[0]]
    one_level = _one_amplitude(verdict, j)
    if one_level is not None and one_level[0] not in ties:
        ties = ties + [one_level[0]]
    if not ties:
        return _Choice(verdict, runner, tie_z, ties, bool(significant), None)
    discrimination: dict[str, Any] = {"ambiguous_between": [verdict.fit.effect] + [x.fit.effect for x in ties],
                                      "paired_z": {x.fit.effect: x.extra.get("paired_z") for x in ties}}
    if confound is not None:
        discrimination["confounded"] = confound[1]
    if one_level is not None:
        discrimination["one_amplitude"] = one_level[1]
    if s.discriminate is not None:
        pick = disc.decide_on_run(s.cfg, [verdict] + ties, s.discriminate)
        discrimination["decided_on_run"] = pick
        winner = next(x for x in [verdict] + ties if x.fit.effect == pick["winner"])
        log(f"discrimination run: {pick['summary']}")
        tie_z = pick["paired_z"] if pick["paired_z"] is not None else None
        return _Choice(winner, None, tie_z, ties, bool(significant), discrimination)
    try:
        discrimination["experiment"] = disc.propose(s.cfg, verdict.fit, [x.fit for x in ties], j.psd, rep.sigma,
                                                    s.test.u)
    except (ValueError, np.linalg.LinAlgError) as exc:  # the proposal is advice: never fail the diagnosis
        discrimination["experiment"] = {"error": str(exc)}
    return _Choice(verdict, runner, tie_z, ties, bool(significant), discrimination)


#: rate and amplitude dependence of the hysteresis/dynamics: told apart only by an excitation whose rate and amplitude
#: vary independently
RATE_AMPLITUDE = ("hysteresis_rate_dependence", "amplitude_dependent_dynamics")
#: the excitation confounds them when, over stretches of both runs, the log peak rate and the log amplitude of the
#: voltage correlate at least this much (the rate explains ≥ 81 % of the amplitude's variance): then neither verdict
#: can be told from the other by these runs, whatever the held-out scores say
CONFOUND_RHO = 0.9
#: stretches per run for that measure
CONFOUND_STRETCHES = 8


def excitation_rate_amplitude_correlation(runs: Sequence[RunData]) -> float:
    """Correlation of log amplitude (largest deviation from the run's mean) and log peak rate (95th percentile of
    |dU/dt|) of the voltage over
    :data:`CONFOUND_STRETCHES` stretches of each run and each axis (stretches with < 1 % of the largest amplitude
    left out); NaN with fewer than 4 stretches."""
    amps, rates = [], []
    for run in runs:
        u = np.asarray(run.u, float)
        u = u - u.mean(axis=0)
        n = len(u) // CONFOUND_STRETCHES
        if n < 8:
            continue
        for k in range(CONFOUND_STRETCHES):
            seg = u[k * n:(k + 1) * n]
            amps.append(np.max(np.abs(seg), axis=0))
            rates.append(np.quantile(np.abs(np.diff(seg, axis=0)), 0.95, axis=0) / run.dt)
    if not amps:
        return float("nan")
    A, R = np.concatenate(amps), np.concatenate(rates)
    keep = (A > 0.01 * A.max()) & (R > 0)
    if keep.sum() < 4:
        return float("nan")
    la, lr = np.log(A[keep]), np.log(R[keep])
    if np.std(la) == 0 or np.std(lr) == 0:
        return 1.0   # one amplitude (or one rate) throughout: nothing to tell them apart
    return float(np.corrcoef(la, lr)[0, 1])


def _rate_amplitude_confounded(s: _Setup, verdict: Scored, j: _Judged) -> tuple[Scored, dict[str, Any]] | None:
    """The rival of a rate- or amplitude-dependence verdict, when it is significant too and the runs' excitation
    cannot tell the two apart (:data:`CONFOUND_RHO`): ``(rival, report)``; else None."""
    if verdict.fit.effect not in RATE_AMPLITUDE:
        return None
    other = next((x for x in j.scored if x.fit.effect in RATE_AMPLITUDE and x.fit.effect != verdict.fit.effect), None)
    if other is None or not _significant(other, j.zc):
        return None
    rho = excitation_rate_amplitude_correlation([s.train, s.test])
    if not (rho >= CONFOUND_RHO):
        return None
    other.extra.setdefault("paired_z", stats.paired_z(verdict.extra["r_after"], other.extra["r_after"], j.psd))
    return other, {"between": [verdict.fit.effect, other.fit.effect], "rate_amplitude_correlation": rho,
                   "threshold": CONFOUND_RHO,
                   "why": "the voltage's rate and amplitude vary together in these runs (log-correlation "
                          f"{rho:.3g} ≥ {CONFOUND_RHO:g}): a rate-dependent loop and an amplitude-dependent one "
                          "predict the same here; the proposed experiment varies them apart"}


def _one_amplitude(verdict: Scored, j: _Judged) -> tuple[Scored, dict[str, Any]] | None:
    """A linear-mode verdict whose amplitude-dependent rival is significant too, on runs whose motion has one
    amplitude (:func:`~.fit_modes.mode_level_shift`: ``one_level``): a resonance that moves with amplitude cannot be
    seen here, so the two are a tie to discriminate (``(rival, report)``); else None."""
    if verdict.fit.effect != "unmodelled_mode":
        return None
    rich = next((x for x in j.scored if x.fit.effect == "amplitude_dependent_dynamics"), None)
    shift = (rich.fit.extra.get("level_shift") or {}) if rich is not None else {}
    if rich is None or not shift.get("one_level") or not _significant(rich, j.zc):
        return None
    rich.extra.setdefault("paired_z", stats.paired_z(verdict.extra["r_after"], rich.extra["r_after"], j.psd))
    return rich, {"between": [verdict.fit.effect, rich.fit.effect], "level_ratio": shift.get("level_ratio"),
                  "why": f"the large-motion half of TRAIN moves only {shift.get('level_ratio', 0):.3g}× the "
                         "small-motion half: a resonance that shifts with amplitude cannot be told from a linear "
                         "one on these runs; the proposed experiment varies the amplitude"}


def _ties(verdict: Scored, j: _Judged) -> tuple[Scored | None, float | None, list[Scored]]:
    """Near ties: other effects that explain the held-out run about as well (paired test).  Returns the runner-up,
    the paired z by which the verdict beats it, and the ties; sets every rival's ``paired_z``."""
    runner, tie_z = None, None
    # a generic family that absorbs the verdict (see GENERIC_MIN_EXTRA) is not a rival explanation
    others = [x for x in j.scored if x is not verdict and x.extra["delta"] > 0
              and x.extra.get("absorbs") != verdict.fit.effect]
    for x in others:
        x.extra["paired_z"] = stats.paired_z(verdict.extra["r_after"], x.extra["r_after"], j.psd)
    if others:
        runner = min(others, key=lambda x: x.extra["paired_z"])
        tie_z = runner.extra["paired_z"]
    ties = [x for x in others if x.extra["paired_z"] < TIE_Z and _significant(x, j.zc)
            and not _nested(verdict.fit.effect, x.fit.effect)]
    return runner, tie_z, ties
