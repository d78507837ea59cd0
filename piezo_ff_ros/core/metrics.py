"""Performance figures exactly as the paper's Section VII-A defines them, plus tracking/settling figures.

All functions take plain arrays (SI units, time in seconds) and return floats or small frozen readings
(:class:`HysteresisReading`, :class:`CreepReading`, :class:`OvershootReading`, :class:`StaticError`,
:class:`TrackingErrors`, each with ``to_json()``); ratios are fractions (multiply by 100 for the paper's percentages).

How the levels are read (the paper gives the definitions, not the windows — these are our choices, documented so
that a replay of recorded signals gives the same numbers):

* **Hysteresis** ``h/H`` (Fig. 4/6): over one full period of a periodic input, ``h`` is the largest vertical
  distance between the ascending and the descending branch of the loop (output at the same input value, branches
  interpolated on a common grid of 2001 input values), ``H`` the output's peak-to-peak range over that period.
  :func:`hysteresis_ratio` uses the **last** full period of the record, so start-up (the virgin curve) is excluded.
* **Creep** ``(A_m − A_f)/A_f`` (Fig. 7/10): displacements are taken relative to the mean level before the step.
  ``A_f`` — "the displacement before the creep appears", i.e. just after the fast transient — is the mean over
  ``[t_step + t_transient, t_step + t_transient + window]`` with ``t_transient = 0.2 s`` (the paper: the transient
  lasts less than 200 ms) and ``window = 0.05 s``.  ``A_m`` — the displacement after the creep evaluation time — is
  the mean over the last ``final_window = 1 s`` before ``t_step + t_creep`` (default: the end of the record).
* **Overshoot** ``(A_m − A_f)/A_f`` (Fig. 11/14): relative to the pre-step level, ``A_m`` is the extreme
  displacement after the step in the direction of the final value, ``A_f`` the final value: the mean over the last
  ``final_window = 0.05 s`` of the record.  A response that never passes its final value gives ≈ 0.
* **Cross-coupling** before compensation (Table II, left): ``H^xy/H^xx``, the peak-to-peak range of x when only y
  is driven over the range of x when only x is driven (the Fig. 4 sines); after compensation (right):
  ``A_f^xy/A_f^xx``, the final values of x after a step on y and after a step on x (Fig. 14).  Reported as
  absolute ratios, as the paper does.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .jsonable import JsonResult

__all__ = [
    "peak_to_peak", "last_period", "hysteresis_ratio", "step_levels", "creep_ratio", "overshoot_ratio",
    "cross_coupling_range_ratio", "cross_coupling_final_ratio", "settling_time", "static_error", "tracking_errors",
    "T_TRANSIENT", "AF_WINDOW", "CREEP_FINAL_WINDOW", "STEP_FINAL_WINDOW", "HysteresisReading", "CreepReading",
    "OvershootReading", "StaticError", "TrackingErrors",
]

T_TRANSIENT = 0.2          #: [s] end of the fast transient after a step (creep A_f is read after it)
AF_WINDOW = 0.05           #: [s] averaging window for the creep A_f
CREEP_FINAL_WINDOW = 1.0   #: [s] averaging window for the creep A_m (end of the creep time)
STEP_FINAL_WINDOW = 0.05   #: [s] averaging window for a step's final value A_f


@dataclass(frozen=True)
class HysteresisReading(JsonResult):
    """Hysteresis of one loop (:func:`hysteresis_ratio`).

    Attributes
    ----------
    h : float
        Largest vertical distance between the branches [output unit].
    H : float
        Output range over the period [output unit].
    ratio : float
        ``h/H`` (NaN when ``H`` is 0).
    u_at_max : float
        Input value where the branches are furthest apart.
    """

    h: float
    H: float
    ratio: float
    u_at_max: float


@dataclass(frozen=True)
class CreepReading(JsonResult):
    """Creep of a step response (:func:`creep_ratio`); displacements relative to the pre-step level [m].

    Attributes
    ----------
    A_f : float
        Displacement just after the fast transient.
    A_m : float
        Displacement at the end of the creep time.
    ratio : float
        ``(A_m − A_f)/A_f`` (NaN when ``A_f`` is 0).
    ratio_over_Am : float
        ``(A_m − A_f)/A_m`` (NaN when ``A_m`` is 0).
    """

    A_f: float
    A_m: float
    ratio: float
    ratio_over_Am: float


@dataclass(frozen=True)
class OvershootReading(JsonResult):
    """Overshoot of a step response (:func:`overshoot_ratio`); displacements relative to the pre-step level [m].

    Attributes
    ----------
    A_f : float
        Final value.
    A_m : float
        Extreme displacement after the step in the direction of ``A_f``.
    ratio : float
        ``(A_m − A_f)/A_f`` (NaN when ``A_f`` is 0).
    t_peak : float
        Time of ``A_m`` after the step [s].
    """

    A_f: float
    A_m: float
    ratio: float
    t_peak: float


@dataclass(frozen=True)
class StaticError(JsonResult):
    """Steady-state error at the end of a record (:func:`static_error`).

    Attributes
    ----------
    error : float
        ``mean(y − r)`` [m].
    relative : float
        ``mean(y − r)/mean(r)`` (NaN when ``mean(r)`` is 0).
    """

    error: float
    relative: float


@dataclass(frozen=True)
class TrackingErrors(JsonResult):
    """RMS and maximum tracking error (:func:`tracking_errors`) [m].

    Attributes
    ----------
    rms, max : list of float
        Per axis.
    rms_norm : float
        RMS of the Euclidean error.
    max_norm : float
        Maximum Euclidean error.
    """

    rms: list[float]
    max: list[float]
    rms_norm: float
    max_norm: float


def _vec(x: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float).reshape(-1)
    if a.size == 0:
        raise ValueError(f"{name}: empty signal")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or inf")
    return a


def _pair(t: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    tv = _vec(t, "t")
    yv = _vec(y, "y")
    if tv.shape != yv.shape:
        raise ValueError(f"t and y differ in length ({tv.size} vs {yv.size})")
    return tv, yv


def _window_mean(t: np.ndarray, y: np.ndarray, t0: float, t1: float, what: str) -> float:
    sel = (t >= t0) & (t <= t1)
    if not np.any(sel):
        # a window shorter than the sample period: take the nearest sample
        i = int(np.argmin(np.abs(t - 0.5 * (t0 + t1))))
        if not (t[0] - 1e-12 <= 0.5 * (t0 + t1) <= t[-1] + 1e-12):
            raise ValueError(f"{what}: window [{t0:g}, {t1:g}] s lies outside the record [{t[0]:g}, {t[-1]:g}] s")
        return float(y[i])
    return float(np.mean(y[sel]))


def peak_to_peak(y: ArrayLike) -> float:
    """``max(y) − min(y)``."""
    yv = _vec(y, "y")
    return float(yv.max() - yv.min())


def last_period(t: ArrayLike, period: float, *signals: ArrayLike) -> tuple[np.ndarray, ...]:
    """Slice the last full ``period`` seconds of a record: returns the sliced ``signals`` (arrays along axis 0)."""
    t = _vec(t, "t")
    if period <= 0 or not math.isfinite(period):
        raise ValueError(f"period must be a positive number of seconds, got {period}")
    if t[-1] - t[0] < period * (1 - 1e-9):
        raise ValueError(f"record ({t[-1] - t[0]:g} s) is shorter than one period ({period:g} s)")
    start = t[-1] - period
    # include the sample one period before the last one so the loop is closed
    i0 = int(np.searchsorted(t, start - 1e-9 * max(1.0, abs(start))))
    return tuple(np.asarray(s)[i0:] for s in signals)


def hysteresis_ratio(u: ArrayLike, y: ArrayLike, period_t: ArrayLike | None = None, period: float | None = None,
                     grid: int = 2001, bins: int | None = None) -> HysteresisReading:
    """Hysteresis amplitude ``h/H`` of an input/output loop (paper Fig. 4 and Section VII-A).

    Parameters
    ----------
    u, y : array [N]
        Periodic input (volts or metres) and the output [m].  Without ``period`` they must span exactly one
        period; with ``period`` and ``period_t`` (sample times) the last full period is used.
    period_t : array [N], optional
        Sample times [s], needed with ``period``.
    period : float, optional
        Input period [s].
    grid : int
        Number of input values on which both branches are compared.
    bins : int, optional
        Noise-robust variant for measured data: each branch is averaged in ``bins`` equal input bins (instead of
        interpolated sample by sample) and ``H`` is the range of those bin means, so sensor noise does not
        inflate ``h`` and ``H`` with its extremes.  ``None`` (default): the exact definition.

    Returns
    -------
    dict
        ``{"h": max vertical loop width, "H": output range, "ratio": h/H}`` (units of ``y`` for h and H).
    """
    u = _vec(u, "u")
    y = _vec(y, "y")
    if u.shape != y.shape:
        raise ValueError(f"u and y differ in length ({u.size} vs {y.size})")
    if period is not None:
        if period_t is None:
            raise ValueError("hysteresis_ratio: period needs the sample times period_t")
        u, y = last_period(period_t, period, u, y)
    du = np.diff(u)
    up = du > 0
    down = du < 0
    if up.sum() < 2 or down.sum() < 2:
        raise ValueError("hysteresis_ratio: the input must rise and fall (one full period of a periodic input)")
    # branch samples: the later sample of each rising/falling step
    ua, ya = u[1:][up], y[1:][up]
    ud, yd = u[1:][down], y[1:][down]
    ia, id_ = np.argsort(ua, kind="stable"), np.argsort(ud, kind="stable")
    ua, ya, ud, yd = ua[ia], ya[ia], ud[id_], yd[id_]
    lo = max(ua[0], ud[0])
    hi = min(ua[-1], ud[-1])
    if not hi > lo:
        raise ValueError("hysteresis_ratio: rising and falling branches do not overlap in input")
    if bins is None:
        g = np.linspace(lo, hi, grid)
        width = np.abs(np.interp(g, ua, ya) - np.interp(g, ud, yd))
        H = float(y.max() - y.min())
    else:
        edges = np.linspace(min(ua[0], ud[0]), max(ua[-1], ud[-1]), int(bins) + 1)
        ma, ca = _bin_means(ua, ya, edges)
        md, cd = _bin_means(ud, yd, edges)
        both = (ca > 0) & (cd > 0)
        if not np.any(both):
            raise ValueError("hysteresis_ratio: no input bin holds samples of both branches")
        g = 0.5 * (edges[1:] + edges[:-1])[both]
        width = np.abs(ma[both] - md[both])
        means = np.concatenate([ma[ca > 0], md[cd > 0]])
        H = float(means.max() - means.min())
    h = float(width.max())
    return HysteresisReading(h=h, H=H, ratio=h / H if H > 0 else math.nan, u_at_max=float(g[int(np.argmax(width))]))


def _bin_means(x: np.ndarray, y: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    counts = np.bincount(idx, minlength=len(edges) - 1)
    sums = np.bincount(idx, weights=y, minlength=len(edges) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / np.maximum(counts, 1), counts


def step_levels(t: ArrayLike, y: ArrayLike, t_step: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Times and displacements relative to the step: ``(t − t_step, y − y_before, y_before)``.

    ``y_before`` is the mean of the samples before the step (0 if the record starts at the step).
    """
    tv, yv = _pair(t, y)
    before = tv < t_step
    y0 = float(np.mean(yv[before])) if np.any(before) else 0.0
    return tv - t_step, yv - y0, y0


def creep_ratio(t: ArrayLike, y: ArrayLike, t_step: float = 0.0, t_creep: float | None = None, t_transient: float = T_TRANSIENT,
                window: float = AF_WINDOW, final_window: float = CREEP_FINAL_WINDOW) -> CreepReading:
    """Creep ``(A_m − A_f)/A_f`` of a step response (paper Fig. 7/10, Section VII-A).

    ``A_f``: mean displacement over ``[t_transient, t_transient + window]`` after the step (after the fast
    transient, before the creep develops); ``A_m``: mean over the last ``final_window`` before ``t_creep`` after
    the step (default: end of the record).  Displacements relative to the pre-step level.

    Returns a :class:`CreepReading` (``A_f``, ``A_m``, ``ratio``, ``ratio_over_Am``: divided by ``A_m``).
    """
    tr, yr, _ = step_levels(t, y, t_step)
    t_end = tr[-1] if t_creep is None else float(t_creep)
    if t_end > tr[-1] + 1e-9:
        raise ValueError(f"creep_ratio: creep time {t_end:g} s is beyond the record ({tr[-1]:g} s after the step)")
    if t_end < t_transient + window:
        raise ValueError(f"creep_ratio: record too short ({t_end:g} s after the step; need > "
                         f"{t_transient + window:g} s)")
    A_f = _window_mean(tr, yr, t_transient, t_transient + window, "creep A_f")
    A_m = _window_mean(tr, yr, max(t_end - final_window, t_transient + window), t_end, "creep A_m")
    return CreepReading(A_f=A_f, A_m=A_m, ratio=(A_m - A_f) / A_f if A_f != 0 else math.nan,
                        ratio_over_Am=(A_m - A_f) / A_m if A_m != 0 else math.nan)


def overshoot_ratio(t: ArrayLike, y: ArrayLike, t_step: float = 0.0, final_window: float = STEP_FINAL_WINDOW,
                    lowpass_hz: float | None = None) -> OvershootReading:
    """Overshoot ``(A_m − A_f)/A_f`` of a step response (paper Fig. 11/14, Section VII-A).

    ``A_f``: final value, mean over the last ``final_window`` seconds; ``A_m``: the extreme displacement after
    the step in the direction of ``A_f``.  Both relative to the pre-step level.  ``lowpass_hz`` (measured data)
    takes ``A_m`` on the response filtered by a zero-phase 4th-order Butterworth low-pass at that frequency:
    white sensor noise would otherwise bias the peak upwards by several standard deviations.  Choose it above
    the actuator's resonances (the printed model's highest is 1.6 kHz; ``evaluate`` uses 3 kHz).

    Returns an :class:`OvershootReading` (``A_f``, ``A_m``, ``ratio``, ``t_peak`` after the step).
    """
    tr, yr, _ = step_levels(t, y, t_step)
    after = tr >= 0
    if after.sum() < 2:
        raise ValueError("overshoot_ratio: no samples after the step")
    A_f = _window_mean(tr, yr, tr[-1] - final_window, tr[-1], "step final value")
    ya = yr[after]
    if lowpass_hz is not None:
        ya = _zero_phase_lowpass(tr[after], ya, lowpass_hz)
    i = int(np.argmax(ya)) if A_f >= 0 else int(np.argmin(ya))
    A_m = float(ya[i])
    return OvershootReading(A_f=A_f, A_m=A_m, ratio=(A_m - A_f) / A_f if A_f != 0 else math.nan,
                            t_peak=float(tr[after][i]))


def _zero_phase_lowpass(t: np.ndarray, y: np.ndarray, cutoff_hz: float) -> np.ndarray:
    from scipy import signal

    if len(t) < 30:
        return y
    fs = 1.0 / float(np.median(np.diff(t)))
    if not 0 < cutoff_hz < 0.5 * fs:
        return y  # nothing to remove below Nyquist
    sos = signal.butter(4, cutoff_hz, fs=fs, output="sos")
    # padding with the edge values: no start-up transient at the step or at the end
    pad = min(len(y) - 1, int(3 * fs / cutoff_hz) + 1)
    yp = np.concatenate([np.full(pad, y[0]), y, np.full(pad, y[-1])])
    out: np.ndarray = signal.sosfiltfilt(sos, yp, padtype=None)[pad:pad + len(y)]
    return out


def cross_coupling_range_ratio(y_cross: ArrayLike, y_direct: ArrayLike, smooth: int = 1) -> float:
    """``H^xy / H^xx``: range of an axis when only the other axis is driven over its range when driven itself.

    ``smooth`` > 1: ranges of centred moving averages of that many samples (noise-robust variant).
    """
    def rng(x: ArrayLike) -> float:
        v = _vec(x, "y")
        if smooth > 1:
            v = np.convolve(v, np.ones(int(smooth)) / int(smooth), mode="valid")
        return float(v.max() - v.min())

    H_direct = rng(y_direct)
    return rng(y_cross) / H_direct if H_direct > 0 else math.nan


def cross_coupling_final_ratio(A_f_cross: float, A_f_direct: float) -> float:
    """``|A_f^xy / A_f^xx|``: final value of an axis after a step on the other axis over that after its own step."""
    return abs(A_f_cross / A_f_direct) if A_f_direct != 0 else math.nan


def settling_time(t: ArrayLike, y: ArrayLike, t_step: float = 0.0, band: float = 0.02, final: float | None = None,
                  final_window: float = STEP_FINAL_WINDOW) -> float:
    """Time after the step from which the response stays within ``band·|final|`` of its final value.

    ``final`` defaults to the step's final value (mean of the last ``final_window`` s, relative to the pre-step
    level).  Returns ``nan`` if the response is not settled at the end of the record.
    """
    tr, yr, _ = step_levels(t, y, t_step)
    if final is None:
        final = _window_mean(tr, yr, tr[-1] - final_window, tr[-1], "step final value")
    after = tr >= 0
    ta, ya = tr[after], yr[after]
    outside = np.abs(ya - final) > band * abs(final)
    if not np.any(outside):
        return 0.0
    last = int(np.nonzero(outside)[0][-1])
    if last == len(ya) - 1:
        return math.nan
    return float(ta[last + 1])


def static_error(t: ArrayLike, y: ArrayLike, reference: ArrayLike,
                 final_window: float = STEP_FINAL_WINDOW) -> StaticError:
    """Steady-state error at the end of a record: ``{"error": mean(y − r), "relative": mean(y − r)/mean(r)}``.

    Means over the last ``final_window`` seconds.
    """
    tv, yv = _pair(t, y)
    r = _vec(reference, "reference")
    if r.shape != yv.shape:
        raise ValueError(f"reference and y differ in length ({r.size} vs {yv.size})")
    sel = tv >= tv[-1] - final_window
    e = float(np.mean(yv[sel] - r[sel]))
    rm = float(np.mean(r[sel]))
    return StaticError(error=e, relative=e / rm if rm != 0 else math.nan)


def tracking_errors(reference: ArrayLike, y: ArrayLike, mask: ArrayLike | None = None) -> TrackingErrors:
    """RMS and maximum tracking error.

    Parameters
    ----------
    reference, y : array [N, axes] (or [N])
        Reference and measured output [m].
    mask : bool array [N], optional
        Samples to include (e.g. after the start-up transient).

    Returns
    -------
    TrackingErrors
        ``rms``, ``max`` per axis, ``rms_norm`` (RMS of the Euclidean error), ``max_norm`` (its maximum).
    """
    r = np.asarray(reference, float)
    yy = np.asarray(y, float)
    if r.ndim == 1:
        r, yy = r[:, None], yy.reshape(-1, 1)
    if r.shape != yy.shape:
        raise ValueError(f"reference {r.shape} and output {yy.shape} differ in shape")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(yy))):
        raise ValueError("tracking_errors: signals contain NaN or inf")
    e = yy - r
    if mask is not None:
        e = e[np.asarray(mask, bool)]
    if len(e) == 0:
        raise ValueError("tracking_errors: no samples selected")
    norm = np.sqrt(np.sum(e * e, axis=1))
    return TrackingErrors(rms=np.sqrt(np.mean(e * e, axis=0)).tolist(), max=np.max(np.abs(e), axis=0).tolist(),
                          rms_norm=float(np.sqrt(np.mean(norm * norm))), max_norm=float(norm.max()))
