"""The statistical test behind every verdict: is a held-out improvement more than noise can produce?

A model (a candidate effect, or the flexible model) is fitted on TRAIN only, so on TEST its correction
``d = ŷ_new − ŷ_old`` is independent of the test run's noise.  Under the null hypothesis

    H0: the held-out residual ``r`` is noise — stationary, of *any* spectrum (white, coloured, quantised) —
        independent of the excitation,

the drop in residual energy ``Δ = ‖r‖² − ‖r − d‖² = 2⟨r, d⟩ − ‖d‖²`` has mean ``−‖d‖² ≤ 0`` and standard deviation
``2·sqrt(Var⟨n, d⟩)``, with ``Var⟨n, d⟩ = Σ_k S(f_k)|D_k|²/N`` (``D`` the DFT of ``d``, ``S`` the two-sided noise
spectral density per sample).  ``S`` is estimated by Welch's method on a residual, so the test adapts to the noise's
colour: a slowly wandering noise inflates the variance exactly where a slow correction ``d`` lives.  The statistic
``z = Δ / sd`` is compared with a one-sided normal quantile, Bonferroni-corrected over the models tried.

The same machinery compares two models A and B on the same run (:func:`paired_z`): ``‖r_B‖² − ‖r_A‖²`` against
``2·sqrt(Var⟨n, d_A − d_B⟩)``.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import signal, special

__all__ = ["noise_psd", "inner_sd", "improvement_z", "paired_z", "z_critical", "ALPHA"]

#: family-wise false-alarm rate of the "is there a reproducible gap at all" decision
ALPHA = 0.01


def z_critical(n_tests: int, alpha: float = ALPHA) -> float:
    """One-sided normal quantile for ``n_tests`` Bonferroni-corrected tests at family-wise level ``alpha``."""
    p = alpha / max(int(n_tests), 1)
    return float(-special.ndtri(p))


class NoisePSD:
    """Two-sided spectral density per sample of a residual (per axis), evaluable on any rfft grid."""

    def __init__(self, r: np.ndarray, nperseg: int = 4096):
        r = np.asarray(r, float)
        if r.ndim == 1:
            r = r[:, None]
        N = len(r)
        nper = int(min(N, nperseg))
        # fs = 1: one-sided density on [0, 0.5]; the two-sided density is half of it away from 0 and Nyquist
        self.f, P1 = signal.welch(r - r.mean(axis=0), fs=1.0, nperseg=nper, axis=0, detrend="constant")
        S2 = P1 / 2.0
        S2[0] = P1[0]
        if nper % 2 == 0:
            S2[-1] = P1[-1]
        # the DC bin of a detrended segment is biased low: take its neighbour (the offset is removed anyway)
        if len(S2) > 1:
            S2[0] = S2[1]
        self.S = S2

    def on_grid(self, n: int) -> np.ndarray:
        """Density on the rfft grid of length-``n`` signals, [n//2+1, axes]."""
        fk = np.fft.rfftfreq(n)
        return np.column_stack([np.interp(fk, self.f, self.S[:, i]) for i in range(self.S.shape[1])])


def noise_psd(r: np.ndarray) -> NoisePSD:
    """Welch estimate of the residual's noise spectrum (see :class:`NoisePSD`)."""
    return NoisePSD(r)


def inner_sd(d: np.ndarray, psd: NoisePSD) -> float:
    """Standard deviation of ``⟨n, d⟩`` (summed over axes) for noise ``n`` of spectral density ``psd``."""
    d = np.asarray(d, float)
    if d.ndim == 1:
        d = d[:, None]
    n = len(d)
    D = np.fft.rfft(d - d.mean(axis=0), axis=0)
    w = np.full(D.shape[0], 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    S = psd.on_grid(n)
    var = float(np.sum(w[:, None] * S * np.abs(D) ** 2) / n)
    return math.sqrt(max(var, 0.0))


def improvement_z(r_before: np.ndarray, r_after: np.ndarray, psd: NoisePSD) -> tuple[float, float, float]:
    """``(Δ, sd, z)``: held-out energy drop, its standard deviation under H0, and ``z = Δ/sd``."""
    d = np.asarray(r_before, float) - np.asarray(r_after, float)
    delta = float(np.sum(np.asarray(r_before, float) ** 2) - np.sum(np.asarray(r_after, float) ** 2))
    sd = 2.0 * inner_sd(d, psd)
    if sd <= 0:
        return delta, 0.0, (math.inf if delta > 0 else 0.0)
    return delta, sd, delta / sd


def paired_z(r_a: np.ndarray, r_b: np.ndarray, psd: NoisePSD) -> float:
    """How far model A beats model B on the same run: ``(‖r_B‖² − ‖r_A‖²) / (2·sd⟨n, r_B − r_A⟩)``."""
    delta, sd, z = improvement_z(r_b, r_a, psd)
    return z
