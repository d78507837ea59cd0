"""The flexible reference model: how much of the gap *any* linear correction could explain (the explainable share).

A regularised linear regression of the residual of each output on a filter bank of every input voltage and every
nominal model output (so cross-couplings are included): the signal itself, its first difference (phase/delay),
first-order low-passes (creep-like memory) and second-order resonator pairs at log-spaced frequencies (a Kautz-like
basis: modes, roll-offs, delays).  It is fitted on TRAIN with the ridge weight chosen by two-fold block
cross-validation inside TRAIN, and scored on TEST like a candidate.  It names nothing; it tells how much of the
held-out gap is reproducible — the verdict ``unexplained`` rests on it when no candidate effect explains the gap.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np
from scipy import signal

from .replay import Windows

#: a basis filter ``(name, b, a)`` (transfer function coefficients in z⁻¹)
Filter = tuple[str, np.ndarray, np.ndarray]

__all__ = ["FlexibleModel", "fit_flexible"]

#: at most this many rows enter the normal equations (every k-th sample of the windows)
MAX_ROWS = 60_000
#: resonator damping of the basis (broad: a few per octave cover any mode with a smooth coefficient)
BASIS_DAMPING = 0.15
#: resonators per octave
PER_OCTAVE = 1.5
#: ridge weights tried (relative to the mean diagonal of the standardised normal matrix)
RIDGE_GRID = (1e-3, 3e-3, 1e-2, 3e-2, 1e-1, 3e-1)


def _excited_band(u: np.ndarray, fs: float, energy: float = 0.999) -> float:
    """Frequency below which ``energy`` of the voltage increments' energy lies (what TRAIN excites)."""
    du = np.diff(np.asarray(u, float), axis=0)
    if len(du) < 16:
        return 0.5 * fs
    f, P = signal.welch(du, fs=fs, nperseg=int(min(len(du), 4096)), axis=0)
    c = np.cumsum(P.sum(axis=1))
    if c[-1] <= 0:
        return 0.5 * fs
    return float(f[min(np.searchsorted(c, energy * c[-1]), len(f) - 1)])


def _filters(fs: float, duration: float, f_top: float | None = None) -> list[Filter]:
    """(b, a) pairs of the basis filters for a run at ``fs`` lasting ``duration`` seconds; resonators up to
    ``f_top`` (the band TRAIN excites: above it the regression would only extrapolate)."""
    out: list[Filter] = [("diff", np.array([1.0, -1.0]), np.array([1.0]))]
    for tau in (0.01, 0.1, 1.0, 10.0):
        if tau < duration / 3 and tau > 5 / fs:
            a = math.exp(-1 / (tau * fs))
            out.append((f"lp{tau:g}s", np.array([1 - a]), np.array([1.0, -a])))
    f_lo = max(5.0, 20.0 / max(duration, 1e-9))
    f_hi = 0.42 * fs if f_top is None else min(0.42 * fs, 1.5 * f_top)
    if f_hi > f_lo:
        n = max(1, int(math.ceil(math.log2(f_hi / f_lo) * PER_OCTAVE)))
        for f in np.geomspace(f_lo, f_hi, n):
            w = 2 * math.pi * f
            z = BASIS_DAMPING
            bp = signal.bilinear([2 * z * w, 0.0], [1.0, 2 * z * w, w * w], fs=fs)
            lp = signal.bilinear([w * w], [1.0, 2 * z * w, w * w], fs=fs)
            out.append((f"bp{f:.0f}", bp[0], bp[1]))
            out.append((f"lp2_{f:.0f}", lp[0], lp[1]))
    return out


def _feature_blocks(sig: np.ndarray, filters: list[Filter], scale: np.ndarray,
                    rows: slice = slice(None)) -> Iterator[np.ndarray]:
    """Yield the feature columns block by block: every signal (scaled), then each filter applied to every signal;
    each block filtered on all samples and then cut to ``rows``."""
    x = sig / scale
    yield x[rows]
    for _, b, a in filters:
        zi = signal.lfilter_zi(b, a) if len(a) > 1 or len(b) > 1 else None
        if zi is not None and len(zi):
            y, _ = signal.lfilter(b, a, x, axis=0, zi=zi[:, None] * x[:1])
        else:
            y = signal.lfilter(b, a, x, axis=0)
        yield y[rows]


def _signals(u: np.ndarray, y_nom: np.ndarray, start: int, stop: int) -> np.ndarray:
    """``[u, ŷ]`` on rows ``start:stop``: the rows of ``np.hstack([u, y_nom])``, laid out as numpy lays out that
    whole array (the statistics taken from it then add in the same order)."""
    out: np.ndarray = np.hstack([u[start:stop], y_nom[start:stop]])
    return out


def _features(sig: np.ndarray, filters: list[Filter], scale: np.ndarray, rows: slice = slice(None)) -> np.ndarray:
    """All feature columns, [rows, n_sig·(1 + n_filters)] (filled block by block into one array)."""
    m = sig.shape[1]
    n_rows = len(range(*rows.indices(len(sig))))
    X = np.empty((n_rows, m * (1 + len(filters))))
    for k, F in enumerate(_feature_blocks(sig, filters, scale, rows)):
        X[:, k * m:(k + 1) * m] = F
    return X


@dataclass
class FlexibleModel:
    """The fitted regression: ``r_i ≈ X·θ_i`` with X the filter bank of [u, ŷ]."""

    theta: np.ndarray        # [n_features, n_out]
    mean: np.ndarray         # feature means on TRAIN
    scale: np.ndarray        # per-signal scale
    filters: list[Filter]
    ridge: float
    n_features: int

    def predict(self, u: np.ndarray, y_nom: np.ndarray, windows: Windows) -> np.ndarray:
        """Correction on the scoring windows of a run (features warmed up like the simulations)."""
        outs = []
        m = u.shape[1] + y_nom.shape[1]
        offset = self.mean @ self.theta
        for w, s, e in windows.spans:
            d = -np.broadcast_to(offset, (e - s, self.theta.shape[1])).copy()
            for k, F in enumerate(_feature_blocks(_signals(u, y_nom, w, e), self.filters, self.scale,
                                                  slice(s - w, None))):
                d += F @ self.theta[k * m:(k + 1) * m]
            outs.append(d)
        return np.concatenate(outs)


def fit_flexible(u: np.ndarray, y: np.ndarray, y_nom: np.ndarray, windows: Windows, fs: float) -> FlexibleModel:
    """Fit the flexible model on the training windows (see the module docstring)."""
    # the signals [u, ŷ] of each window only (not of the whole run, which is 12 M rows on a 10-minute record)
    sigs = [_signals(u, y_nom, w, e) for w, _, e in windows.spans]
    # statistics on the fitted samples only
    sample = sigs[0] if windows.is_whole else \
        np.concatenate([sg[s - w:e - w] for sg, (w, s, e) in zip(sigs, windows.spans)])
    scale = np.maximum(np.std(sample, axis=0), 1e-300)
    duration = len(u) / fs
    filters = _filters(fs, duration, _excited_band(sample[:, :u.shape[1]], fs))
    n_rows = windows.n
    stride = max(1, -(-n_rows // MAX_ROWS))
    blocks_X, blocks_r = [], []
    spans = windows.spans
    if len(spans) == 1:  # one span: cut it into chunks for the cross-validation folds
        w, s, e = spans[0]
        Xall = _features(sigs[0], filters, scale)[s - w:]
        rall = y[s:e] - y_nom[s:e]
        k = 8
        edges = np.linspace(0, len(Xall), k + 1).astype(int)
        for i in range(k):
            blocks_X.append(Xall[edges[i]:edges[i + 1]:stride])
            blocks_r.append(rall[edges[i]:edges[i + 1]:stride])
    else:
        for sg, (w, s, e) in zip(sigs, spans):
            blocks_X.append(_features(sg, filters, scale, slice(s - w, None, stride)))
            blocks_r.append(y[s:e:stride] - y_nom[s:e:stride])
    X = np.vstack(blocks_X)
    r = np.vstack(blocks_r)
    mean = X.mean(axis=0)
    rm = r.mean(axis=0)
    Xc = X - mean
    rc = r - rm
    p = Xc.shape[1]
    stats = []
    edges = np.cumsum([0] + [len(b) for b in blocks_X])
    for f in (0, 1):
        A = np.zeros((p, p))
        b = np.zeros((p, rc.shape[1]))
        c = np.zeros(rc.shape[1])
        for i in range(f, len(blocks_X), 2):  # the blocks of fold f (contiguous rows: no masked copies)
            Xi, ri = Xc[edges[i]:edges[i + 1]], rc[edges[i]:edges[i + 1]]
            A += Xi.T @ Xi
            b += Xi.T @ ri
            c += np.sum(ri ** 2, axis=0)
        stats.append((A, b, c))
    A_all = stats[0][0] + stats[1][0]
    b_all = stats[0][1] + stats[1][1]
    lam0 = float(np.trace(A_all)) / p
    best = (math.inf, RIDGE_GRID[-1])
    for rel in RIDGE_GRID:
        cv = 0.0
        for f in (0, 1):
            A, b, _ = stats[f]
            A2, b2, c2 = stats[1 - f]
            try:
                th = np.linalg.solve(A + rel * lam0 * np.eye(p), b)
            except np.linalg.LinAlgError:
                cv = math.inf
                break
            cv += float(np.sum(c2 - 2 * np.sum(th * b2, axis=0) + np.sum(th * (A2 @ th), axis=0)))
        if cv < best[0]:
            best = (cv, rel)
    theta = np.linalg.solve(A_all + best[1] * lam0 * np.eye(p), b_all)
    return FlexibleModel(theta, mean, scale, filters, best[1], p)
