"""Effect signatures of a replay residual: how strongly it looks like each kind of effect (a gain, a delay, even
harmonics, a rate-dependent loop, slew, saturation, a slow trend, a resonance), used to explain the ranking.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

__all__ = ["signatures", "SIGNATURE_OF"]


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a = np.asarray(a, float).reshape(-1)
    b = np.asarray(b, float).reshape(-1)
    a = a - a.mean()
    b = b - b.mean()
    d = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / d) if d > 0 else 0.0


def _partial_corr(r: np.ndarray, x: np.ndarray, given: Sequence[np.ndarray]) -> float:
    """Correlation of r with x after removing from both their projection on ``given`` (per axis, pooled)."""
    rs, xs = [], []
    for i in range(r.shape[1]):
        G = np.column_stack([np.ones(len(r))] + [g[:, i] for g in given])
        rr = r[:, i] - G @ np.linalg.lstsq(G, r[:, i], rcond=None)[0]
        xx = x[:, i] - G @ np.linalg.lstsq(G, x[:, i], rcond=None)[0]
        rs.append(rr)
        xs.append(xx)
    return _corr(np.concatenate(rs), np.concatenate(xs))


def signatures(u: np.ndarray, y_hat: np.ndarray, r: np.ndarray, dt: float, sigma: np.ndarray) -> dict[str, float]:
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
    k_ = max(1, len(r) // 200_000)  # correlations on every k-th row: the derivatives are taken on the whole run
    rs, yhs, dys, dus = r[::k_], yh[::k_], dy[::k_], du[::k_]
    sig = {"gain": abs(_corr(rs, yhs)),
           "delay": abs(_partial_corr(rs, dys, [yhs])),
           "even_harmonics": abs(_partial_corr(rs, yhs ** 2, [yhs])),
           "rate": abs(_partial_corr(rs, np.sign(dus) * np.abs(dus), [yhs, dys]))}
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
                "thermal_drift": "slow_trend", "unmodelled_mode": "resonance_peak", "amplifier_bandwidth": "delay",
                "amplitude_dependent_dynamics": "resonance_peak"}
