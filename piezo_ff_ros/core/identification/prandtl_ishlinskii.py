"""Rate-independent hysteresis of one axis as a Prandtl–Ishlinskii model, identified by linear least squares.

``y[k] = c + Σ_i w_i·P_{r_i}(u)[k − d] + Σ_{j≥2} a_j·u[k − d]^j``: a weighted sum of classical play operators of
the drive voltage (``P_0 = u``; radii spread evenly over half the drive's span, so the model can bend a loop at
any point of a reversal) plus a static polynomial (saturation, asymmetry of the branches) and an offset, delayed
by ``d`` samples (a sensor that reports one sample late).  The output is linear in every weight, so the fit is one
least-squares solve on the training run (its first seconds left out: the operators start at the first drive
sample, the rig from its earlier history).

Why this model next to the pipeline's Bouc-Wen: for a slow (1 Hz) single-axis drive the hysteresis is the whole
story, and a play sum represents any symmetric rate-independent loop shape — a check of how much of the held-out
error is the Bouc-Wen form's rigidity and how much is not hysteresis at all (start-up settling, drift).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PrandtlIshlinskiiModel", "play_operators", "identify_prandtl_ishlinskii"]


def play_operators(u: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Classical play operators ``[T, len(radii)]`` of the signal ``u [T]``, started at ``u[0]``: each output
    follows ``u`` at a distance of at most its radius, and stays put while ``u`` reverses inside it."""
    u = np.asarray(u, float)
    r = np.asarray(radii, float)
    out = np.empty((len(u), len(r)))
    z = np.full(len(r), u[0] if len(u) else 0.0)
    for k, v in enumerate(u):
        z = np.minimum(np.maximum(z, v - r), v + r)
        out[k] = z
    return out


@dataclass(frozen=True)
class PrandtlIshlinskiiModel:
    """An identified model (module docstring).

    Attributes
    ----------
    radii : ndarray
        Play radii [V] (the first is 0: the drive itself).
    weights : ndarray
        Play weights [m/V].
    poly : ndarray
        Coefficients of ``u²``, ``u³``, … [m/V^j].
    offset : float
        Output offset [m].
    delay : int
        Output delay [samples].
    """

    radii: np.ndarray
    weights: np.ndarray
    poly: np.ndarray
    offset: float
    delay: int

    def simulate(self, u: np.ndarray) -> np.ndarray:
        """The model's output ``[T]`` for the drive ``u [T]`` (operators started at ``u[0]``)."""
        u = np.asarray(u, float).reshape(-1)
        X = _regressors(u, self.radii, len(self.poly))
        y: np.ndarray = X @ np.concatenate([[self.offset], self.weights, self.poly])
        return _delayed(y, self.delay)


def _regressors(u: np.ndarray, radii: np.ndarray, n_poly: int) -> np.ndarray:
    cols = [np.ones((len(u), 1)), play_operators(u, radii)]
    cols += [u[:, None] ** (j + 2) for j in range(n_poly)]
    return np.hstack(cols)


def _delayed(y: np.ndarray, d: int) -> np.ndarray:
    return np.concatenate([np.full(d, y[0]), y[:len(y) - d]]) if d > 0 else y


def identify_prandtl_ishlinskii(u: np.ndarray, y: np.ndarray, n_plays: int = 10, poly_degree: int = 3,
                                delay: int = 0, skip: int = 0) -> PrandtlIshlinskiiModel:
    """Fit the model of the module docstring on one run.

    Parameters
    ----------
    u, y : ndarray
        Drive [V] and measured displacement [m], ``[T]`` each.
    n_plays : int
        Play operators (radius 0 included), radii evenly spaced over ``[0, span/2)`` of the drive.
    poly_degree : int
        Highest power of the static polynomial (≤ 1: none).
    delay : int
        Samples by which the output lags the drive.
    skip : int
        Samples at the start left out of the fit (unknown initial hysteresis state).

    Returns
    -------
    PrandtlIshlinskiiModel

    Raises
    ------
    ValueError
        Mismatched or too short records, or parameters out of range.
    """
    u = np.asarray(u, float).reshape(-1)
    y = np.asarray(y, float).reshape(-1)
    if len(u) != len(y):
        raise ValueError(f"prandtl-ishlinskii: drive and output differ in length ({len(u)} vs {len(y)})")
    if n_plays < 1 or delay < 0 or skip < 0 or poly_degree < 0:
        raise ValueError("prandtl-ishlinskii: n_plays ≥ 1, delay ≥ 0, skip ≥ 0 and poly_degree ≥ 0 expected")
    n_poly = max(poly_degree - 1, 0)
    n_par = 1 + n_plays + n_poly
    if len(u) - skip - delay < 10 * n_par:
        raise ValueError(f"prandtl-ishlinskii: {len(u)} samples (after skip {skip}) are too few for {n_par} "
                         "parameters")
    span = float(np.ptp(u))
    radii = np.arange(n_plays) * span / (2 * n_plays)
    X = _regressors(u, radii, n_poly)
    Xd = np.vstack([np.repeat(X[:1], delay, axis=0), X[:len(X) - delay]]) if delay else X
    sl = slice(skip, None)
    sc = np.linalg.norm(Xd[sl], axis=0)
    sc[sc == 0] = 1.0
    theta = np.linalg.lstsq(Xd[sl] / sc, y[sl], rcond=None)[0] / sc
    return PrandtlIshlinskiiModel(radii=radii, weights=theta[1:1 + n_plays], poly=theta[1 + n_plays:],
                                  offset=float(theta[0]), delay=int(delay))
