"""Where the gap lives: the replay residual split by axis, input→output pair, frequency band, amplitude, branch and
time regime, each part as NRMSE % and as a share of the residual energy, against the measured noise floor.

The input→output split regresses each output's residual on a small filter bank of each input (the voltage through
first-order low-passes at 0.05…200 Hz and its derivative): the energy explained by input j is attributed to pair
j→i.  With both inputs moving at once this is an attribution, not a measurement; the part no input explains is
reported as ``unexplained``.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy import signal

from .replay import nrmse_percent

__all__ = ["localise", "BANDS"]

#: frequency bands [Hz]: creep ≪ 0.1 Hz, hysteresis (the voltage's own band) and dynamics (resonances)
BANDS = (("creep", 0.0, 0.1), ("hysteresis", 0.1, 100.0), ("dynamics", 100.0, math.inf))


def _lp(x: np.ndarray, fc: float, dt: float) -> np.ndarray:
    a = math.exp(-2 * math.pi * fc * dt)
    y: np.ndarray
    y = signal.lfilter([1 - a], [1, -a], x, axis=0, zi=None) if x.ndim == 1 else \
        signal.lfilter([1 - a], [1, -a], x, axis=0)
    return y


def _pairs(u: np.ndarray, r: np.ndarray, dt: float, axes: Sequence[str]) -> dict[str, dict[str, Any]]:
    n, k = r.shape[1], u.shape[1]
    fs = 1.0 / dt
    fcs = [f for f in (0.05, 0.5, 5.0, 50.0, 200.0) if f < 0.4 * fs]
    banks = []
    for j in range(k):
        cols = [u[:, j]] + [_lp(u[:, j], f, dt) for f in fcs] + [np.gradient(u[:, j]) / dt]
        X = np.column_stack(cols)
        X -= X.mean(axis=0)
        X /= np.maximum(X.std(axis=0), 1e-300)
        banks.append(X)
    out: dict[str, dict[str, Any]] = {}
    # the filters run on every sample; the regression uses every k-th row of a long run (≤ 200 k rows)
    step = max(1, len(r) // 200_000)
    banks = [b[::step] for b in banks]
    r = r[::step]
    for i in range(n):
        ri = r[:, i] - r[:, i].mean()
        Xall = np.column_stack(banks)
        c, *_ = np.linalg.lstsq(Xall, ri, rcond=None)
        tot = float(ri @ ri)
        m = banks[0].shape[1]
        explained: dict[int, float] = {}
        for j in range(k):
            part = banks[j] @ c[j * m:(j + 1) * m]
            explained[j] = float(part @ part)
        fit = Xall @ c
        unexplained = float((ri - fit) @ (ri - fit))
        s = sum(explained.values()) + unexplained
        for j in range(k):
            kind = "direct" if i == j else "cross"
            out[f"{axes[j]}->{axes[i]}"] = {"kind": kind, "energy_share_of_axis": explained[j] / s if s else 0.0}
        out[f"unexplained->{axes[i]}"] = {"kind": "unexplained", "energy_share_of_axis": unexplained / s if s else 0.0}
    return out


def _steps(u: np.ndarray, dt: float, window_s: float = 0.1) -> np.ndarray:
    """Boolean mask of samples within ``window_s`` after a voltage step (a jump > 5 % of the range in ≤ 2 ms)."""
    k = max(1, int(round(2e-3 / dt)))
    du = np.abs(u[k:] - u[:-k]).max(axis=1) if len(u) > k else np.zeros(0)
    rng = np.ptp(u, axis=0).max() if len(u) else 0.0
    mask = np.zeros(len(u), bool)
    if rng <= 0 or du.size == 0:
        return mask
    # a step is fast compared with the run's typical rate: a jump above 5 % of the range within 2 ms, where the
    # median rate would move less than 0.5 % of the range
    typical = np.median(du)
    hits = np.flatnonzero((du > 0.05 * rng) & (du > 10 * typical))
    w = int(round(window_s / dt))
    for h in hits:
        mask[h:h + k + w] = True
    return mask


def localise(u: np.ndarray, y: np.ndarray, y_hat: np.ndarray, dt: float, axes: Sequence[str],
             sigma: np.ndarray) -> dict[str, Any]:
    """Split the gap ``r = y − ŷ`` (offset removed) of one run; see the module docstring.

    Parameters
    ----------
    u, y, y_hat : arrays [N, axes]
        Voltages [V], measured and simulated displacements [m].
    dt : float
        Sample period [s].
    axes : sequence of str
    sigma : array [axes]
        White-noise floor per axis [m] (:func:`~.replay.noise_floor`).
    """
    r = y - y_hat
    r = r - r.mean(axis=0)
    N, n = r.shape
    total = float(np.sum(r ** 2))
    yc = y - y.mean(axis=0)
    den_all = float(np.sqrt(np.sum(yc ** 2)))
    out: dict[str, Any] = {"total": {"nrmse_percent": nrmse_percent(y - y.mean(0), y_hat - y_hat.mean(0)),
                           "rms_um": float(np.sqrt(total / r.size)) * 1e6,
                           "noise_floor_rms_um": float(np.sqrt(np.mean(sigma ** 2))) * 1e6,
                           "noise_floor_nrmse_percent": float(100 * np.sqrt(N * np.sum(sigma ** 2)) / den_all)
                           if den_all > 0 else 0.0}}
    # -- axes
    ax: dict[str, dict[str, float]] = {}
    for i, a in enumerate(axes):
        e = float(np.sum(r[:, i] ** 2))
        d = float(np.sqrt(np.sum(yc[:, i] ** 2)))
        ax[a] = {"nrmse_percent": 100 * math.sqrt(e) / d if d > 0 else float("inf"),
                 "energy_share": e / total if total > 0 else 0.0,
                 "rms_um": math.sqrt(e / N) * 1e6, "noise_floor_um": float(sigma[i]) * 1e6}
    out["axis"] = ax
    # -- input→output pairs
    out["pair"] = _pairs(u, r, dt, axes)
    # -- frequency bands (Welch), against the white noise floor
    fs = 1.0 / dt
    nper = int(min(N, max(256, 2 ** int(math.log2(max(N // 8, 256))))))
    f, P = signal.welch(r, fs=fs, nperseg=nper, axis=0, detrend="constant")
    df = f[1] - f[0]
    bands: dict[str, dict[str, Any]] = {}
    band_e: dict[str, float] = {}
    for name, lo, hi in BANDS:
        if lo >= fs / 2:
            continue  # the band lies above Nyquist at this sample rate
        sel = (f >= lo) & (f < hi) if lo > 0 else (f < hi)
        e = float(np.sum(P[sel]) * df)  # variance in the band, summed over axes
        width = float(min(hi, fs / 2) - lo) if sel.any() else 0.0
        noise = float(np.sum(sigma ** 2) * 2 * width / fs)
        band_e[name] = e
        bands[name] = {"range_hz": [lo, min(hi, fs / 2)], "rms_um": math.sqrt(max(e, 0)) * 1e6,
                       "noise_floor_rms_um": math.sqrt(noise) * 1e6,
                       "above_noise_ratio": e / noise if noise > 0 else float("inf")}
    tot_b = sum(band_e.values())
    for name in bands:
        bands[name]["energy_share"] = band_e[name] / tot_b if tot_b > 0 else 0.0
    out["band"] = bands
    # -- amplitude level: quartiles of the measured displacement's distance from its centre, per axis
    amp: dict[str, dict[str, float]] = {}
    lev = np.abs(yc) / np.maximum(np.abs(yc).max(axis=0), 1e-300)
    for q, (lo, hi) in enumerate(((0, .25), (.25, .5), (.5, .75), (.75, 1.01))):
        sel = (lev >= lo) & (lev < hi)
        e = float(np.sum(r[sel] ** 2))
        cnt = int(sel.sum())
        amp[f"{int(lo * 100)}-{int(min(hi, 1) * 100)}%"] = {
            "rms_um": math.sqrt(e / max(cnt, 1)) * 1e6, "energy_share": e / total if total > 0 else 0.0,
            "sample_share": cnt / r.size}
    out["amplitude"] = amp
    # -- branch: ascending/descending direct voltage
    br: dict[str, dict[str, float]] = {}
    k = min(u.shape[1], n)
    du = np.gradient(u[:, :k], axis=0)
    for name, sel in (("ascending", du > 0), ("descending", du < 0), ("at rest", du == 0)):
        rr = r[:, :k][sel]
        e = float(np.sum(rr ** 2))
        br[name] = {"rms_um": math.sqrt(e / max(rr.size, 1)) * 1e6,
                    "mean_um": float(rr.mean()) * 1e6 if rr.size else 0.0,
                    "energy_share": e / total if total > 0 else 0.0, "sample_share": rr.size / r.size}
    out["branch"] = br
    # -- time regime: transient after a step, steady state, and the slow drift over the run
    mask = _steps(u, dt)
    slow_fc = max(0.02, 5.0 / (N * dt))
    drift = _lp(r, slow_fc, dt) if N > 10 else r
    e_drift = float(np.sum(drift ** 2))
    e_tr = float(np.sum(r[mask] ** 2))
    e_ss = total - e_tr
    out["regime"] = {
        "transient_after_step": {"energy_share": e_tr / total if total > 0 else 0.0,
                                 "sample_share": float(mask.mean()),
                                 "rms_um": math.sqrt(e_tr / max(mask.sum() * n, 1)) * 1e6},
        "steady_state": {"energy_share": e_ss / total if total > 0 else 0.0, "sample_share": float(1 - mask.mean()),
                         "rms_um": math.sqrt(e_ss / max((~mask).sum() * n, 1)) * 1e6},
        "long_term_drift": {"energy_share": e_drift / total if total > 0 else 0.0,
                            "below_hz": slow_fc, "rms_um": math.sqrt(e_drift / r.size) * 1e6},
    }
    out["summary"] = _sentence(out, axes)
    return out


def _sentence(w: dict[str, Any], axes: Sequence[str]) -> str:
    tot = w["total"]
    if tot["rms_um"] <= 1.02 * tot["noise_floor_rms_um"]:
        return (f"The gap ({tot['rms_um']:.3g} µm RMS) is at the sensor noise floor "
                f"({tot['noise_floor_rms_um']:.3g} µm): nothing left to localise.")
    ax = max(w["axis"].items(), key=lambda kv: kv[1]["energy_share"])
    band = max(w["band"].items(), key=lambda kv: kv[1]["energy_share"])
    pairs = {k: v for k, v in w["pair"].items() if v["kind"] != "unexplained" and k.endswith(ax[0])}
    pair = max(pairs.items(), key=lambda kv: kv[1]["energy_share_of_axis"]) if pairs else None
    reg = w["regime"]
    parts = [f"Most of the gap ({tot['rms_um']:.3g} µm RMS, {tot['nrmse_percent']:.3g} % NRMSE; noise floor "
             f"{tot['noise_floor_rms_um']:.3g} µm) lives on axis {ax[0]} ({100 * ax[1]['energy_share']:.0f} % of "
             f"the residual energy)"]
    if pair is not None and pair[1]["energy_share_of_axis"] > 0.2:
        parts.append(f"attributed mostly to the {pair[1]['kind']} pair {pair[0]} "
                     f"({100 * pair[1]['energy_share_of_axis']:.0f} %)")
    parts.append(f"in the {band[0]} band {band[1]['range_hz'][0]:g}–{band[1]['range_hz'][1]:g} Hz "
                 f"({100 * band[1]['energy_share']:.0f} %, {band[1]['above_noise_ratio']:.3g}× the noise there)")
    if reg["transient_after_step"]["energy_share"] > 2 * max(reg["transient_after_step"]["sample_share"], 0.05):
        parts.append(f"concentrated in the transients after steps "
                     f"({100 * reg['transient_after_step']['energy_share']:.0f} % of the energy in "
                     f"{100 * reg['transient_after_step']['sample_share']:.0f} % of the time)")
    if reg["long_term_drift"]["energy_share"] > 0.3:
        parts.append(f"with a slow drift below {reg['long_term_drift']['below_hz']:.2g} Hz carrying "
                     f"{100 * reg['long_term_drift']['energy_share']:.0f} %")
    amp = max(w["amplitude"].items(), key=lambda kv: kv[1]["energy_share"] / max(kv[1]["sample_share"], 1e-9))
    if amp[1]["energy_share"] > 1.8 * amp[1]["sample_share"]:
        parts.append(f"and at displacement levels {amp[0]} of the stroke")
    return ", ".join(parts) + "."
