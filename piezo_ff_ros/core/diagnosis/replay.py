"""Replay: drive a model with the measured voltages and compare with the measured displacements.

The residual is ``measured − simulated`` with one constant offset per axis removed (the sensor zero is not part of
any model; it is a nuisance estimated on each run).  Long runs are simulated on a few windows spread over the run,
each preceded by a warm-up; :class:`Windows` keeps the bookkeeping so that every candidate model is compared on
exactly the same samples.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .._jit import HAVE_NUMBA, njit
from ..config import PiezoConfig
from ..models.effects import build_plant
from ..models.plant import Plant
from ..recording.run import RunData

__all__ = ["nrmse_percent", "noise_floor", "noise_floor_periodic", "input_period", "Windows", "simulate", "residual", "check_run", "check_excitation",
           "check_sample_rate_metadata", "model_for_run", "check_scale", "timing_sensitivity", "TIMING_OVERSAMPLING",
           "column_means", "centered_difference", "column_rms_about_mean"]


def nrmse_percent(y: np.ndarray, y_hat: np.ndarray, axis: int | None = None) -> float | np.ndarray:
    """``100·‖y − ŷ‖/‖y − ȳ‖`` (over all axes, or per axis with ``axis=0``)."""
    y = np.asarray(y, float)
    e = y - y_hat
    if axis is None:
        den = np.sqrt(np.sum((y - y.mean(axis=0)) ** 2))
        return float(100.0 * np.sqrt(np.sum(e ** 2)) / max(den, 1e-300))
    den = np.sqrt(np.sum((y - y.mean(axis=0)) ** 2, axis=0))
    per_axis: np.ndarray = 100.0 * np.sqrt(np.sum(e ** 2, axis=0)) / np.maximum(den, 1e-300)
    return per_axis


def noise_floor(r: np.ndarray, max_samples: int | None = None) -> np.ndarray:
    """White-noise standard deviation per axis from the second difference of the residual.

    A smooth model error has almost no energy in the second difference at the sample rate, white sensor noise
    has ``6σ²``: ``σ ≈ std(Δ²r)/√6`` (robust: median absolute deviation).  ``max_samples``: a longer residual is
    measured on 8 stretches spread over it (``max_samples`` in all; the differences taken within each stretch).
    """
    r = np.asarray(r, float)
    if max_samples is not None and len(r) > max_samples:
        w = Windows.spread(len(r), max_samples, 8)
        d2 = np.concatenate([np.diff(r[s:e], n=2, axis=0) for _, s, e in w.spans])
    else:
        d2 = np.diff(r, n=2, axis=0)
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    sigma: np.ndarray = 1.4826 * mad / np.sqrt(6.0)
    return sigma


def input_period(u: np.ndarray, max_periods: int = 8, rtol: float = 1e-3) -> int | None:
    """The period (samples) of a voltage record made of ≥ 2 repeated periods (periodic multisines), else None.

    Measured voltages carry noise: periods count as equal when the RMS of their difference is below ``rtol`` of
    the voltage's RMS.
    """
    u = np.asarray(u, float)
    N = len(u)
    scale = float(np.std(u))
    if not scale > 0:
        return None
    thr2 = (rtol * scale) ** 2
    for k in range(max_periods, 1, -1):
        if N % k:
            continue
        P = N // k
        if P < 64:
            continue
        # exact early rejection: var(d) = mean(d²) − mean(d)² with d = u[P:] − u[:-P]; mean(d) needs only the
        # first and last P samples, and mean(d²) is at least the first stretch's share of it
        M = N - P
        md = (u[N - P:].sum(axis=0) - u[:P].sum(axis=0)) / M
        head = min(M, 65_536)
        dh = u[P:P + head] - u[:head]
        if float(np.mean(np.sum(dh * dh, axis=0) / M - md * md)) > thr2 * 1.000001:
            continue
        if float(np.std(u[P:] - u[:-P])) <= rtol * scale:
            return P
    return None


def noise_floor_periodic(y: np.ndarray, period: int) -> np.ndarray:
    """Sensor noise per axis from the difference of the last two periods of the *measured* output (the excitation
    repeats exactly, so whatever differs is noise — valid even when the model error reaches Nyquist)."""
    y = np.asarray(y, float)
    d = y[-period:] - y[-2 * period:-period]
    d = d - d.mean(axis=0)
    out: np.ndarray = np.sqrt(np.mean(d ** 2, axis=0) / 2.0)
    return out


def check_run(run: RunData, name: str) -> None:
    """Raise ``ValueError`` naming the problem when a run cannot be diagnosed."""
    if run.u.ndim != 2 or run.y.ndim != 2 or run.u.shape[0] != run.y.shape[0] or run.u.shape[0] != len(run.t):
        raise ValueError(f"{name}: u, y and t must have the same number of samples (got u {run.u.shape}, "
                         f"y {run.y.shape}, t {np.shape(run.t)})")
    if len(run) < 200:
        raise ValueError(f"{name}: only {len(run)} samples; need at least 200 to diagnose")
    for arr, what in ((run.u, "u"), (run.y, "y"), (run.t, "t")):
        # a finite sum has no NaN/Inf to find (one pass, no mask); an infinite one may be an overflow only
        with np.errstate(over="ignore", invalid="ignore"):
            total = float(np.sum(arr))
        if math.isfinite(total):
            continue
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = np.argwhere(bad)[0]
            raise ValueError(f"{name}: {what} has NaN/Inf (first at sample {int(idx[0])})")
    dt = np.diff(run.t)
    lo, hi = float(dt.min()), float(dt.max())
    # the median is at least the smallest step: when the spread is within 1e-3 of that, it is within 1e-3 of the
    # median too, and the median (a partition of the whole run) is not needed
    if lo <= 0 or (hi - lo > 1e-3 * lo and hi - lo > 1e-3 * np.median(dt)):
        raise ValueError(f"{name}: time is not uniformly increasing (dt from {lo:g} to {hi:g} s)")
    check_sample_rate_metadata(run, name)
    check_excitation(run, name)


def _constant(x: np.ndarray) -> np.ndarray:
    """Per column: whether it does not move (its span is at most 1e-9 of its largest magnitude: rounding only)."""
    span = np.ptp(x, axis=0)
    return np.asarray(span <= 1e-9 * np.max(np.abs(x), axis=0), bool)


def check_excitation(run: RunData, name: str) -> None:
    """Raise ``ValueError`` when the run excites nothing: every voltage constant (all-zero included), or a displacement
    that never moves (a sensor not connected or not recorded).  A diagnosis of such a run can only say "none", which
    would read as "the model is right"."""
    u_const, y_const = _constant(run.u), _constant(run.y)
    if u_const.all():
        levels = ", ".join(f"{a}: {v:.4g} V" for a, v in zip(run.axes, run.u[0]))
        raise ValueError(f"{name}: no excitation: the voltage is constant on every axis ({levels}); a diagnosis "
                         "needs a voltage that moves")
    if y_const.any():
        dead = [a for a, c in zip(run.axes, y_const) if c]
        raise ValueError(f"{name}: no excitation seen: the displacement of axis {', '.join(dead)} is constant "
                         f"({run.y[0, y_const][0]:.4g} m) while the voltage moves; sensor not connected or not "
                         "recorded?")


def check_sample_rate_metadata(run: RunData, name: str) -> None:
    """Raise ``ValueError`` when a recording's metadata states a sample rate its block stamps contradict: which one is
    right cannot be told from the file, and every time constant fitted would be off by their ratio."""
    md = run.meta.get("metadata") if isinstance(run.meta, dict) else None
    if not isinstance(md, dict) or "sample_rate" not in md:
        return
    try:
        stated = float(md["sample_rate"])
    except (TypeError, ValueError):
        return
    fs = run.sample_rate
    if math.isfinite(stated) and stated > 0 and abs(stated - fs) > 1e-6 * fs:
        raise ValueError(f"{name}: the recording's metadata states a sample rate of {stated:g} Hz but its block "
                         f"stamps are {fs:g} Hz apart; fix the recording or state the rate with --sample-rate")


def model_for_run(cfg: PiezoConfig, run: RunData) -> PiezoConfig:
    """The model config at the run's sample rate, after checking the axes agree."""
    if run.u.shape[1] != cfg.n_axes or run.y.shape[1] != cfg.n_axes:
        raise ValueError(f"model '{cfg.name}' has {cfg.n_axes} axes {list(cfg.axes)} but the run has "
                         f"{run.u.shape[1]} input(s) and {run.y.shape[1]} output(s) {list(run.axes)}; give --model "
                         "a config with the run's axes (docs/diagnosis.md: a single-axis, hysteresis-only model)")
    fs = run.sample_rate
    if abs(fs - cfg.sample_rate) > 1e-6 * fs:
        cfg = cfg.with_sample_rate(fs)
    return cfg


@dataclass
class Windows:
    """Simulation windows ``(warm_start, start, stop)``: the model runs from ``warm_start`` and is scored on
    ``start:stop``.  One window ``(0, 0, N)`` means the whole run."""

    spans: list[tuple[int, int, int]]

    @staticmethod
    def whole(n: int) -> "Windows":
        """One window covering all ``n`` samples."""
        return Windows([(0, 0, n)])

    @staticmethod
    def spread(n: int, max_samples: int, n_windows: int = 8, warmup: int = 0, offset: int = 0) -> "Windows":
        """The whole run if it fits in ``max_samples``, else ``n_windows`` windows spread evenly, each with a
        warm-up of ``warmup`` samples (the first window starts at 0 without warm-up).

        ``offset``: the run starts at sample ``offset`` of a longer record whose earlier voltages are known (a
        held-out part split from one file); windows then warm up on those earlier samples too.
        """
        if n <= max_samples:
            if offset == 0:
                return Windows.whole(n)
            return Windows([(max(0, offset - warmup), offset, offset + n)])
        per = max(max_samples // n_windows, 100)
        starts = offset + np.linspace(0, n - per, n_windows).astype(int)
        spans = []
        for s in starts:
            w = max(0, s - warmup)
            spans.append((int(w), int(s), int(s + per)))
        return Windows(spans)

    def apply(self, reset: Callable[[], None], fn: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
        """``fn`` (a stateful block processor) over each window from its warm start, ``reset()`` first; the scored
        samples of every window, concatenated."""
        outs = []
        for w, s, e in self.spans:
            reset()
            outs.append(fn(x[w:e])[s - w:])
        return np.concatenate(outs)

    @property
    def n(self) -> int:
        """Number of scored samples over all windows."""
        return sum(stop - start for _, start, stop in self.spans)

    def take(self, x: np.ndarray) -> np.ndarray:
        """The scored samples of ``x`` (rows ``start:stop`` of every window), concatenated."""
        return np.concatenate([x[start:stop] for _, start, stop in self.spans])

    @property
    def is_whole(self) -> bool:
        """True when the single window is the whole run."""
        return len(self.spans) == 1 and self.spans[0][0] == 0 and self.spans[0][1] == 0


#: voltage-side effects that are continuous filters: the plant behind them sees a smooth voltage, not the DAC's
#: staircase, so it is replayed at an internal rate of at least INTERSAMPLE_RATE (the voltage held over each record
#: sample, the filter and the plant continuous in between) and sampled at the record's rate
INTERSAMPLE_EFFECTS = ("amplifier_bandwidth",)
#: the internal rate [Hz] for them: the rate the nominal model is defined at (20 kHz, 12× its highest resonance), at
#: most MAX_INTERSAMPLE_FACTOR× the record's
INTERSAMPLE_RATE = 20_000.0
MAX_INTERSAMPLE_FACTOR = 8


def lowest_resonance_hz(cfg: PiezoConfig) -> float:
    """The lowest natural frequency [Hz] of the complex pole pairs of the dynamics ``G_L`` (inf without any)."""
    low = math.inf
    G = cfg.dynamics.G_L
    rows, cols = G.shape
    for i in range(rows):
        for j in range(cols):
            for f in G[i, j].den:
                if len(f) == 3 and f[1] ** 2 < 4 * f[0] * f[2] and f[0] != 0:
                    low = min(low, math.sqrt(f[2] / f[0]) / (2 * math.pi))
    return low


def intersample_factor(cfg: PiezoConfig, effects: Sequence[tuple[str, Mapping[str, Any]]]) -> int:
    """How many internal steps per record sample the replay with ``effects`` takes (1: none).

    Only when the record resolves the plant's resonances (the lowest below its Nyquist frequency): above it, the
    plant is quasi-static within the record's band, the filter's interval average is all that reaches it, and
    finer steps would only change the hysteresis' discretisation against the nominal replay's.
    """
    allpass = [float(p["delay"]) for name, p in effects if name == "input_delay" and p.get("form") == "allpass"]
    if allpass:  # the all-pass delay's within-sample excursion reaches the hysteresis: resolve it at any rate
        from ..models.effects.voltage import allpass_steps_per_sample
        return max(allpass_steps_per_sample(min(allpass), cfg.dt),
                   intersample_factor(cfg, [e for e in effects if e[0] != "input_delay"]))
    if not any(name in INTERSAMPLE_EFFECTS for name, _ in effects):
        return 1
    if not lowest_resonance_hz(cfg) < cfg.sample_rate / 2:
        return 1
    return int(min(MAX_INTERSAMPLE_FACTOR, max(1, round(INTERSAMPLE_RATE / cfg.sample_rate))))


def simulate(cfg: PiezoConfig, u: np.ndarray, effects: Sequence[tuple[str, Mapping[str, Any]]] = (),
             windows: Windows | None = None) -> np.ndarray:
    """Model output for the voltages ``u`` on ``windows`` (default: the whole run), concatenated.

    With a continuous voltage-side filter among ``effects`` and a record slower than :data:`INTERSAMPLE_RATE`, the
    model runs ``k`` = :func:`intersample_factor` steps per sample, each voltage held over its sample (the DAC), and
    is read at the record's samples: the plant's exact ZOH model at the finer rate sees the filtered voltage nearly
    as smooth as it is.  The nominal model alone is unchanged by this (its input is the staircase either way).
    """
    k = intersample_factor(cfg, effects)
    if k > 1:
        fine = dataclasses.replace(cfg, sample_rate=cfg.sample_rate * k)
        plant = build_plant(fine, effects)

        def run(x: np.ndarray) -> np.ndarray:
            out: np.ndarray = plant.process(np.repeat(x, k, axis=0))[::k]
            return out

        if windows is None or windows.is_whole:
            return run(u)
        return windows.apply(plant.reset, run, u)
    plant = build_plant(cfg, effects)
    if windows is None or windows.is_whole:
        return _process_blocks(plant, u)
    return windows.apply(plant.reset, plant.process, u)



#: long runs are simulated in blocks of this many samples (the stages are block-invariant: the same output whatever
#: the split), so that the stages' temporaries stay small and are reused instead of being mapped afresh from the
#: system for every stage of a 12 M-sample run (page zeroing cost seconds of system time)
SIM_BLOCK = 1 << 20


def _process_blocks(plant: Plant, u: np.ndarray) -> np.ndarray:
    N = len(u)
    if N <= SIM_BLOCK:
        return plant.process(u)
    first = plant.process(u[:SIM_BLOCK])
    out = np.empty((N,) + first.shape[1:])
    out[:SIM_BLOCK] = first
    for i in range(SIM_BLOCK, N, SIM_BLOCK):
        out[i:i + SIM_BLOCK] = plant.process(u[i:i + SIM_BLOCK])
    return out


def residual(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """``y − ŷ`` with each axis' mean removed (the sensor zero); compiled for the usual tall two-axis arrays, the
    numbers of the plain numpy expression (:func:`centered_difference`)."""
    return centered_difference(y, y_hat)


#: a measured displacement this many times larger (or smaller) than the model's replay is a unit mistake, not a gap
#: a diagnosis could explain (the widest gain error of the benchmark is ±10 %; a factor 30 is 3000 %)
SCALE_FACTOR_LIMIT = 30.0
_UNIT_HINTS = {3: "mm stored as m", 6: "µm stored as m", 9: "nm stored as m",
               -3: "m stored where mm are expected", -6: "m stored where µm are expected"}


def check_scale(run: RunData, y_model: np.ndarray, name: str) -> None:
    """Raise ``ValueError`` when the measured displacement's scale is implausible for the model: on an axis where the
    model moves, the measured RMS (offset removed) is more than :data:`SCALE_FACTOR_LIMIT` times the model's, or less
    than its inverse (µm stored as m, a sensor gain in V instead of m …).

    Parameters
    ----------
    run : RunData
        The measured run.
    y_model : ndarray [N, axes]
        The nominal model's replay of ``run.u`` [m].
    name : str
        The run's name in the message.
    """
    rms_y = column_rms_about_mean(run.y)
    rms_m = column_rms_about_mean(y_model)
    for a, ry, rm in zip(run.axes, rms_y, rms_m):
        if not (rm > 0 and ry > 0):
            continue
        ratio = float(ry / rm)
        if 1 / SCALE_FACTOR_LIMIT <= ratio <= SCALE_FACTOR_LIMIT:
            continue
        k = int(round(math.log10(ratio) / 3)) * 3
        hint = _UNIT_HINTS.get(k, "a unit mistake")
        raise ValueError(f"{name}: the displacement of axis {a} has a scale implausible for the model: {ratio:.3g}× "
                         f"what the model predicts for these voltages (RMS {ry:.3g} m vs {rm:.3g} m; {hint}?); "
                         f"give displacements in metres (scale 1e{k:+d} off)")


#: the nominal model's timing sensitivity is taken with its DAC edges moved by 1/TIMING_OVERSAMPLING of a sample
TIMING_OVERSAMPLING = 16


def timing_sensitivity(cfg: PiezoConfig, u: np.ndarray, windows: Windows | None = None) -> np.ndarray:
    """``∂ŷ/∂τ`` [m per sample] of the nominal model's replay when its held voltages (the DAC's edges) move later by
    ``τ`` samples, on ``windows`` (default: the whole run), each axis's mean removed.

    The nominal plant runs :data:`TIMING_OVERSAMPLING` steps per sample (its exact ZOH model at that rate) on the
    held voltages, once as recorded and once with every edge one fine step later; their difference, read at the
    record's samples, over the step.  Exact for the linear dynamics up to the step (a finite difference in ``τ``), it
    includes the fast modes a central difference of the replay misses near Nyquist."""
    k = TIMING_OVERSAMPLING
    fine = dataclasses.replace(cfg, sample_rate=cfg.sample_rate * k)
    plant = build_plant(fine, [])

    def held(x: np.ndarray) -> np.ndarray:
        out: np.ndarray = plant.process(np.repeat(x, k, axis=0))[::k]
        return out

    def later(x: np.ndarray) -> np.ndarray:
        xf = np.repeat(x, k, axis=0)
        out: np.ndarray = plant.process(np.vstack([xf[:1], xf[:-1]]))[::k]
        return out

    u = np.asarray(u, float)
    w = windows if windows is not None else Windows.whole(len(u))
    d = (w.apply(plant.reset, later, u) - w.apply(plant.reset, held, u)) * k
    out: np.ndarray = d - d.mean(axis=0)
    return out


# ----------------------------------------------------------------------------------------------------------------
# Per-column means of tall [N, axes] arrays in one compiled pass, with numpy's own numbers.
#
# x.mean(axis=0) of a C-ordered [N, k] array (k >= 2) is one of numpy's slow reductions: the reduced axis is the outer
# one, so numpy adds the rows one after the other through a k-element inner loop, ~15 ns a row — on a diagnosis' 100
# k-row fit windows ~1.5 ms per residual, ~0.7 s over the hundreds of replays of a 10-minute record.  It is also a
# plain sequential sum (row 0, then row 1, …; not numpy's pairwise summation, which applies to the inner axis only),
# then one division by N.  The compiled loops here add the rows in that same order and divide once, so they give the
# same numbers bit for bit (test/test_diagnosis_speed6_colstats.py), ~15x faster.  Any other array (another dtype or
# layout, one column, no rows, numba missing) goes to numpy.
# ----------------------------------------------------------------------------------------------------------------

@njit
def _column_sums(x: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Row by row, as numpy's outer-axis reduction adds them."""
    n, k = x.shape
    s = np.zeros(k)
    if k == 2:  # the two-axis case in registers
        s0 = 0.0
        s1 = 0.0
        for i in range(n):
            s0 += x[i, 0]
            s1 += x[i, 1]
        s[0] = s0
        s[1] = s1
        return s
    for i in range(n):
        for j in range(k):
            s[j] += x[i, j]
    return s


@njit
def _centered_square_sums(x: np.ndarray, m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    n, k = x.shape
    s = np.zeros(k)
    for i in range(n):
        for j in range(k):
            d = x[i, j] - m[j]
            s[j] += d * d
    return s


def _fast(x: np.ndarray) -> bool:
    """Whether ``x`` is an array numpy reduces row by row over axis 0 (then the compiled loops give its numbers)."""
    return (HAVE_NUMBA and isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 2
            and x.shape[0] > 0 and x.shape[1] >= 2 and x.flags.c_contiguous)


def column_means(x: np.ndarray) -> np.ndarray:
    """``x.mean(axis=0)``, the same numbers (compiled for a C-ordered float ``[N, k ≥ 2]`` array).

    Parameters
    ----------
    x : ndarray
        ``[N, k]``.

    Returns
    -------
    ndarray
        ``[k]``.
    """
    if not _fast(x):
        out: np.ndarray = np.asarray(x).mean(axis=0)
        return out
    res: np.ndarray = _column_sums(x) / x.shape[0]
    return res


def centered_difference(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """``r − r.mean(axis=0)`` with ``r = y − ŷ``: the numbers and the memory layout of the numpy expression (``r`` as
    numpy lays it out, its column means by :func:`column_means`, removed in place: one temporary less).

    Parameters
    ----------
    y, y_hat : ndarray
        ``[N, k]`` (``y_hat`` may broadcast).

    Returns
    -------
    ndarray
        ``[N, k]``, each column's mean removed.
    """
    r: np.ndarray = np.asarray(y, float) - y_hat
    r -= column_means(r)
    return r


def column_rms_about_mean(x: np.ndarray) -> np.ndarray:
    """``np.sqrt(np.mean((x − x.mean(axis=0)) ** 2, axis=0))``, the same numbers, without the temporaries.

    Parameters
    ----------
    x : ndarray
        ``[N, k]``.

    Returns
    -------
    ndarray
        ``[k]``: each column's RMS about its mean.
    """
    x = np.asarray(x, float)
    if not _fast(x):
        out: np.ndarray = np.sqrt(np.mean((x - x.mean(axis=0)) ** 2, axis=0))
        return out
    m = _column_sums(x) / x.shape[0]
    res: np.ndarray = np.sqrt(_centered_square_sums(x, m) / x.shape[0])
    return res
