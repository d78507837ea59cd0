"""H∞ feedforward vibration compensator by model matching (paper Section VI-C, Eq. 15–23, Fig. 13).

The compensator C(s) (``Y_R → Y_L``) is chosen so that ``T = G_L·C`` follows the reference model ``Wr`` (first
order, settling time t_r) with a weighted error and a weighted command:

    z1 = W2·u,   z2 = W1·(Wr·w − G_L·u),   y = w          (w = Y_R, u = Y_L = C·y)

SLICOT SB10AD (the routine behind ``control.hinfsyn``) computes the central controller for one γ at a time; the
γ iteration is done here (see :func:`synthesize_hinf` for why not inside hinfsyn).  Because the measurement is the
reference itself (``P22 = 0``), the "loop" is open: the controller must be stable on its own; it is then reduced by
balanced truncation.

Checks, all of which raise :class:`HinfSynthesisError` with a message that says what to change:

* no controller exists for any γ ≤ ``cfg.gamma_max`` (provably so when the DC bound is above it);
* a candidate controller is unstable (it runs open loop) or does not achieve its own γ on a dense frequency grid
  (SB10AD can return such a controller; the candidate is then rejected, never used);
* the reduced controller is unstable or its achieved norm exceeds ``cfg.gamma_max``.

The optimum can never be below the DC bound (see :func:`lower_bound_dc`); with the printed G_L the optimum sits on it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from ..config import HinfConfig
from ..lti import TFMatrix
if TYPE_CHECKING:
    from control import StateSpace   # no type information: Any for mypy, documentation here

from .reduction import ReductionError, balanced_truncation, hankel_singular_values, truncation_error_bound

__all__ = [
    "HinfDesign",
    "HinfSynthesisError",
    "weights",
    "generalized_plant",
    "lower_bound_dc",
    "weighted_norm_response",
    "achieved_norm",
    "synthesize_hinf",
]

#: relative tolerance for "the controller achieves its own γ"
GAMMA_TOL = 1e-3


class HinfSynthesisError(RuntimeError):
    """The H∞ synthesis failed or its result does not meet the checks (stability, achieved norm, γ_max)."""


@dataclass(frozen=True)
class HinfDesign:
    """Result of :func:`synthesize_hinf`: the full and the reduced controller with their verified norms."""

    controller: object                 #: control.StateSpace, reduced (cfg.order states), continuous, stable
    controller_full: object            #: control.StateSpace, the hinfsyn result
    gamma: float                       #: γ reported by the synthesis
    gamma_full_achieved: float         #: ‖[W2 C; W1(Wr − G_L C)]‖∞ on a dense grid, full C (NaN if not verified)
    gamma_reduced_achieved: float      #: same with the reduced C (NaN if not verified)
    order_full: int
    order_reduced: int
    generalized_plant_order: int
    hankel_singular_values: np.ndarray  #: of the full controller, largest first
    synthesis_s: float                 #: wall time of synthesis + reduction [s]
    gamma_lower_bound: float = math.nan  #: the DC bound for these weights (:func:`lower_bound_dc` with cfg)
    verify_s: float = math.nan         #: wall time of the frequency-grid verification [s]
    notes: tuple[str, ...] = field(default=())   #: what was done beyond the plain path (retries, cancellations)

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly summary (no matrices; see :meth:`controller_matrices`)."""
        def num(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(float(x)) else float(x)

        return {
            "gamma": num(self.gamma),
            "gamma_full_achieved": num(self.gamma_full_achieved),
            "gamma_reduced_achieved": num(self.gamma_reduced_achieved),
            "gamma_lower_bound": num(self.gamma_lower_bound),
            "order_full": int(self.order_full),
            "order_reduced": int(self.order_reduced),
            "generalized_plant_order": int(self.generalized_plant_order),
            "hankel_singular_values": [float(v) for v in self.hankel_singular_values],
            "synthesis_s": num(self.synthesis_s),
            "verify_s": num(self.verify_s),
            "notes": list(self.notes),
        }

    def controller_matrices(self) -> dict[str, list[list[float]]]:
        """The reduced controller as ``{'A','B','C','D'}`` nested lists, loadable as ``HinfConfig.controller``."""
        c = self.controller
        return {k: np.asarray(getattr(c, k), float).tolist() for k in ("A", "B", "C", "D")}


# ----------------------------------------------------------------------------------------------------------------
# Weights and generalized plant
# ----------------------------------------------------------------------------------------------------------------

def _weight_coefficients(cfg: HinfConfig) -> tuple[float, float]:
    """``a = 3/t_r`` (Wr pole, W1 zero) and ``b = 3·eps_s/(t_r·k_o)`` (W1 pole)."""
    a = 3.0 / cfg.t_r
    b = 3.0 * cfg.eps_s / (cfg.t_r * cfg.k_o)
    return a, b


def weights(cfg: HinfConfig, n_axes: int) -> tuple[StateSpace, StateSpace, StateSpace]:
    """The diagonal weights of Eq. 15–19 as ``control.StateSpace`` systems ``(Wr, W1, W2)``.

    ``Wr = 1/(t_r/3·s + 1)``, ``W1 = (s + 3/t_r)/(k_o·s + 3·eps_s/t_r)``, ``W2 = diag(cfg.W2)``, each n_axes × n_axes.
    """
    import control

    cfg.validate(tuple(range(n_axes)))
    a, b = _weight_coefficients(cfg)
    eye = np.eye(n_axes)
    Wr = control.ss(-a * eye, a * eye, eye, 0 * eye)
    # W1 = (1/k_o)·(s + a)/(s + b) = (1/k_o)·[1 + (a − b)/(s + b)]
    W1 = control.ss(-b * eye, eye, (a - b) / cfg.k_o * eye, eye / cfg.k_o)
    W2 = control.ss(np.zeros((0, 0)), np.zeros((0, n_axes)), np.zeros((n_axes, 0)), np.diag(np.asarray(cfg.W2, float)))
    return Wr, W1, W2


def _square_axes(G_L: TFMatrix) -> int:
    n_out, n_in = G_L.shape
    if n_out != n_in:
        raise HinfSynthesisError(f"G_L must be square (one input per axis), got {n_out}×{n_in}")
    return n_out


def generalized_plant(G_L: TFMatrix, cfg: HinfConfig) -> StateSpace:
    """The augmented plant of Fig. 13 as one ``control.StateSpace``.

    Inputs ``[w (Y_R), u (Y_L)]``, outputs ``[z1 = W2·u, z2 = W1(Wr·w − G_L·u), y = w]``.  States: the real modal
    realisation of G_L (:meth:`TFMatrix.to_control`, factors printed verbatim in numerator and denominator
    cancelled, each entry its own modes), then Wr, then W1.  Built block by block rather than by ``interconnect`` so
    the realisation keeps G_L's well-conditioned block-diagonal form.
    """
    import control

    n = _square_axes(G_L)
    G = G_L.to_control()
    a, b = _weight_coefficients(cfg)
    nG = G.nstates
    N = nG + 2 * n
    eye = np.eye(n)
    gW2 = np.diag(np.asarray(cfg.W2, float))
    A = np.zeros((N, N))
    B = np.zeros((N, 2 * n))
    C = np.zeros((3 * n, N))
    D = np.zeros((3 * n, 2 * n))
    g, r, e = slice(0, nG), slice(nG, nG + n), slice(nG + n, N)
    w, u = slice(0, n), slice(n, 2 * n)
    z1, z2, y = slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n)
    # G_L: x_g' = A_g x_g + B_g u
    A[g, g] = G.A
    B[g, u] = G.B
    # Wr: x_r' = −a x_r + a w  (output x_r)
    A[r, r] = -a * eye
    B[r, w] = a * eye
    # W1 driven by the model error  err = x_r − (C_g x_g + D_g u)
    A[e, e] = -b * eye
    A[e, r] = eye
    A[e, g] = -G.C
    B[e, u] = -G.D
    # z1 = W2 u
    D[z1, u] = gW2
    # z2 = (a − b)/k_o · x_e + err/k_o
    C[z2, e] = (a - b) / cfg.k_o * eye
    C[z2, r] = eye / cfg.k_o
    C[z2, g] = -G.C / cfg.k_o
    D[z2, u] = -G.D / cfg.k_o
    # y = w
    D[y, w] = eye
    ax = range(n)
    return control.ss(A, B, C, D,
                      inputs=[f"w{i}" for i in ax] + [f"u{i}" for i in ax],
                      outputs=[f"z1_{i}" for i in ax] + [f"z2_{i}" for i in ax] + [f"y{i}" for i in ax])


def lower_bound_dc(G_L: TFMatrix, cfg: HinfConfig | None = None) -> float:
    """A value the H∞ optimum cannot go below, from the response at ω = 0 alone.

    Without ``cfg``: ``‖G_L(0)⁻¹‖₂`` — the bound for ``W2 = I`` in the limit ``eps_s → 0``.
    With ``cfg``: the exact DC bound for those weights.  At ω = 0, ``Wr = 1`` and ``W1 = 1/eps_s``; with
    ``M = G_L(0)·W2⁻¹`` and ``D = W2·C(0)``, ``min_D ‖[D; (I − M D)/eps_s]‖ = 1/√(σ_min(M)² + eps_s²)`` (rotate by
    the SVD of M; each column is a scalar least-squares problem).  It is slightly below ``‖G_L(0)⁻¹‖``
    (0.947891 vs 0.947933 for the printed G_L).  ``inf`` when G_L(0) is singular.
    """
    G0 = G_L.dc_gain()
    if cfg is None:
        smin = np.linalg.svd(G0, compute_uv=False).min()
        return math.inf if smin == 0.0 else float(1.0 / smin)
    M = G0 @ np.diag(1.0 / np.asarray(cfg.W2, float))
    smin = float(np.linalg.svd(M, compute_uv=False).min())
    return float(1.0 / math.sqrt(smin ** 2 + cfg.eps_s ** 2))


# ----------------------------------------------------------------------------------------------------------------
# Frequency-domain verification (independent of the realisation given to hinfsyn: G_L from its printed factors)
# ----------------------------------------------------------------------------------------------------------------

def _ss_response(sys: StateSpace, w: np.ndarray) -> np.ndarray:
    """``C (jωI − A)⁻¹ B + D`` for every ω, shape ``[len(w), n_out, n_in]``."""
    A, B, C, D = (np.asarray(getattr(sys, k), float) for k in ("A", "B", "C", "D"))
    n = A.shape[0]
    if n == 0:
        return np.broadcast_to(D.astype(complex), (len(w),) + D.shape).copy()
    M = (1j * w)[:, None, None] * np.eye(n)[None] - A[None]
    X = np.linalg.solve(M, np.broadcast_to(B.astype(complex), (len(w),) + B.shape))
    H: np.ndarray = C[None].astype(complex) @ X + D[None]
    return H


def weighted_norm_response(G_L: TFMatrix, controller: StateSpace, cfg: HinfConfig, w: ArrayLike) -> np.ndarray:
    """``σ_max([W2·C; W1·(Wr·I − G_L·C)])(jω)`` for each ω in ``w`` [rad/s] (Eq. 20–21)."""
    wv = np.asarray(w, float)
    s = 1j * wv
    n = _square_axes(G_L)
    a, b = _weight_coefficients(cfg)
    wr = a / (s + a)
    w1 = (s + a) / (cfg.k_o * (s + b))
    Cjw = _ss_response(controller, wv)
    Gjw = G_L.eval(s)
    top = np.asarray(cfg.W2, float)[None, :, None] * Cjw
    err = wr[:, None, None] * np.eye(n)[None] - Gjw @ Cjw
    bottom = w1[:, None, None] * err
    stacked = np.concatenate([top, bottom], axis=1)
    sigma: np.ndarray = np.linalg.svd(stacked, compute_uv=False)[:, 0]
    return sigma


def _grid(G_L: TFMatrix, controller: StateSpace, w_min: float, w_max: float, n_points: int) -> np.ndarray:
    """Log grid plus ω = 0 plus every pole's natural and damped frequency (lightly damped peaks are not missed)."""
    poles = [G_L[i, j].poles() for i in range(G_L.shape[0]) for j in range(G_L.shape[1])]
    if controller.nstates:
        poles.append(np.linalg.eigvals(np.asarray(controller.A, float)))
    p = np.concatenate(poles) if poles else np.zeros(0)
    extra = np.concatenate([np.abs(p), np.abs(p.imag)])
    extra = extra[(extra > w_min) & (extra < w_max)]
    return np.unique(np.concatenate([[0.0], np.logspace(np.log10(w_min), np.log10(w_max), n_points), extra]))


def achieved_norm(G_L: TFMatrix, controller: StateSpace, cfg: HinfConfig, *, w_min: float = 1e-3, w_max: float = 1e6,
                  n_points: int = 3000) -> tuple[float, float]:
    """``(peak, ω_peak)`` of :func:`weighted_norm_response` on a dense log grid (ω = 0 included), each of the five
    largest local maxima refined by a bounded scalar search between its neighbours."""
    from scipy.optimize import minimize_scalar

    w = _grid(G_L, controller, w_min, w_max, n_points)
    f = weighted_norm_response(G_L, controller, cfg, w)
    if not np.all(np.isfinite(f)):
        return math.inf, float(w[np.argmax(~np.isfinite(f))])
    best, w_best = float(f.max()), float(w[f.argmax()])
    interior = np.nonzero((f[1:-1] >= f[:-2]) & (f[1:-1] >= f[2:]))[0] + 1
    for k in interior[np.argsort(f[interior])[::-1][:5]]:
        lo, hi = w[k - 1], w[k + 1]
        if lo <= 0.0:
            continue
        res = minimize_scalar(lambda lw: -weighted_norm_response(G_L, controller, cfg, [10.0 ** lw])[0],
                              bounds=(np.log10(lo), np.log10(hi)), method="bounded", options={"xatol": 1e-7})
        if -res.fun > best:
            best, w_best = float(-res.fun), float(10.0 ** res.x)
    return best, w_best


# ----------------------------------------------------------------------------------------------------------------
# Synthesis
# ----------------------------------------------------------------------------------------------------------------

def _max_real_pole(sys: StateSpace) -> float:
    return float(np.max(np.linalg.eigvals(np.asarray(sys.A, float)).real)) if sys.nstates else -math.inf


def _central_controller(P: StateSpace, n: int, gamma: float) -> tuple[StateSpace | None, str]:
    """SB10AD with JOB = 4 (no γ iteration): the central controller for the given γ, or None if none exists."""
    import control
    from slycot import sb10ad

    try:
        out = sb10ad(P.nstates, P.ninputs, P.noutputs, n, n, gamma, np.array(P.A), np.array(P.B), np.array(P.C),
                     np.array(P.D), job=4)
    except Exception as exc:  # slycot reports "no solution for this γ" and numerical failures as exceptions
        return None, str(exc)
    return control.ss(out[1], out[2], out[3], out[4]), ""


def _describe_weights(cfg: HinfConfig) -> str:
    return f"t_r={cfg.t_r}, eps_s={cfg.eps_s}, k_o={cfg.k_o}, W2={list(cfg.W2)}"


#: first γ tried: the certified DC lower bound relaxed by this much (the optimum sits on that bound for G_L as printed)
GAMMA_FIRST_RELAX = 1e-4
#: relative width at which the γ bisection stops
GAMMA_BISECT_RTOL = 1e-3


def _checked_axes(G_L: TFMatrix, cfg: HinfConfig) -> int:
    """Check the synthesis inputs and return the number of axes.

    Parameters
    ----------
    G_L : TFMatrix
        The plant; must be square with every non-zero entry stable (after cancelling duplicated factors).
    cfg : HinfConfig
        The weights; validated for that many axes.

    Returns
    -------
    int
        Number of axes (rows = columns of ``G_L``).

    Raises
    ------
    HinfSynthesisError
        ``G_L`` is not square, or an entry is unstable.
    ConfigError
        A weight is out of range (from ``cfg.validate``).
    """
    n = _square_axes(G_L)
    cfg.validate(tuple(range(n)))
    for i in range(n):
        for j in range(n):
            if not G_L[i, j].is_zero() and not G_L[i, j].cancelled().is_stable():
                raise HinfSynthesisError(f"G_L[{i},{j}] is not stable: a feedforward cannot compensate an unstable plant")
    return n


def _duplicated_factor_notes(G_L: TFMatrix, n: int) -> list[str]:
    """The design note naming the factors printed in both numerator and denominator of an entry (none: empty).

    Parameters
    ----------
    G_L : TFMatrix
        The plant, ``n × n``.
    n : int
        Number of axes.

    Returns
    -------
    list of str
        Zero or one note.
    """
    dups = {f"G_L[{i},{j}]": G_L[i, j].duplicated_factors() for i in range(n) for j in range(n)}
    dups = {k: v for k, v in dups.items() if v}
    if not dups:
        return []
    return ["cancelled factors printed in both numerator and denominator: "
            + "; ".join(f"{k}: {v}" for k, v in dups.items())]


def _feasible_dc_bound(G_L: TFMatrix, cfg: HinfConfig) -> float:
    """The DC lower bound of the optimum (:func:`lower_bound_dc` with ``cfg``), checked against ``cfg.gamma_max``.

    Parameters
    ----------
    G_L : TFMatrix
        The plant.
    cfg : HinfConfig
        The weights and γ_max.

    Returns
    -------
    float
        The bound.

    Raises
    ------
    HinfSynthesisError
        The bound is above ``cfg.gamma_max``: no controller can meet it.
    """
    bound = lower_bound_dc(G_L, cfg)
    if bound > cfg.gamma_max:
        raise HinfSynthesisError(
            f"H∞ synthesis infeasible: no controller can reach vibration.gamma_max = {cfg.gamma_max:g}; the norm at "
            f"ω = 0 alone is at least {bound:.6g} (≈ ‖G_L(0)⁻¹‖ = {lower_bound_dc(G_L):.6g}) with weights "
            f"{_describe_weights(cfg)}. Relax gamma_max, raise W2 bounds or eps_s, or check G_L's DC gains.")
    return bound


@dataclass
class _GammaTrials:
    """The candidates of the γ iteration: each one synthesised, checked, and its time and rejection recorded.

    Mutable on purpose: every :meth:`attempt` adds its SB10AD time to ``synthesis_s``, its frequency-grid time to
    ``verify_s`` and, when the candidate is rejected, the reason to ``rejected``.
    """

    G_L: TFMatrix
    cfg: HinfConfig
    P: StateSpace                                 #: the generalized plant (:func:`generalized_plant`)
    n: int                                        #: number of axes (measurements = controls)
    synthesis_s: float = 0.0
    verify_s: float = 0.0
    rejected: list[str] = field(default_factory=list)

    def attempt(self, gamma: float) -> tuple[StateSpace | None, float]:
        """Central controller at γ, accepted only if it exists, is stable and achieves γ on the grid.

        Parameters
        ----------
        gamma : float
            The γ to synthesise for.

        Returns
        -------
        controller : control.StateSpace or None
            The controller, or None when rejected.
        achieved : float
            Its norm on the frequency grid (NaN when it was not measured).
        """
        t = time.perf_counter()
        K, why = _central_controller(self.P, self.n, gamma)
        self.synthesis_s += time.perf_counter() - t
        if K is None:
            self.rejected.append(f"γ={gamma:.6g}: SB10AD found no controller ({why.strip().splitlines()[0][:120]})")
            return None, math.nan
        if not _max_real_pole(K) < 0.0:
            self.rejected.append(f"γ={gamma:.6g}: unstable controller (pole real part {_max_real_pole(K):.4g})")
            return None, math.nan
        t = time.perf_counter()
        ach, w_at = achieved_norm(self.G_L, K, self.cfg)
        self.verify_s += time.perf_counter() - t
        if not ach <= gamma * (1.0 + GAMMA_TOL):
            self.rejected.append(f"γ={gamma:.6g}: controller misses its own γ (achieved {ach:.6g} at "
                                 f"ω={w_at:.4g} rad/s)")
            return None, ach
        return K, ach


class _Accepted(NamedTuple):
    """The outcome of the γ iteration: the full controller, its γ and verified norm, and what to note about it."""

    K: StateSpace                 #: the full (unreduced) controller
    gamma: float                  #: the γ it was synthesised for
    achieved: float               #: its norm on the frequency grid
    notes: tuple[str, ...]        #: bisection and rejected candidates, if any


def _search_gamma(trials: _GammaTrials, bound: float) -> _Accepted:
    """The smallest γ with an accepted controller: the DC bound ·(1 + GAMMA_FIRST_RELAX), else bisected.

    Parameters
    ----------
    trials : _GammaTrials
        Where the candidates are tried (and their times and rejections recorded).
    bound : float
        The DC lower bound (:func:`_feasible_dc_bound`).

    Returns
    -------
    _Accepted

    Raises
    ------
    HinfSynthesisError
        No candidate up to ``cfg.gamma_max`` is accepted.
    """
    gam = bound * (1.0 + GAMMA_FIRST_RELAX)
    K, achieved = trials.attempt(gam) if gam <= trials.cfg.gamma_max else (None, math.nan)
    if K is None:
        accepted = _bisect_gamma(trials, bound, min(gam, trials.cfg.gamma_max))
    else:
        accepted = _Accepted(K, gam, achieved, ())
    if trials.rejected:
        accepted = accepted._replace(notes=accepted.notes + ("rejected candidates: " + "; ".join(trials.rejected),))
    return accepted


def _bisect_gamma(trials: _GammaTrials, bound: float, lo: float) -> _Accepted:
    """γ bisected between ``lo`` (no controller accepted) and ``cfg.gamma_max`` to a relative width of
    ``GAMMA_BISECT_RTOL``.

    Parameters
    ----------
    trials : _GammaTrials
        Where the candidates are tried.
    bound : float
        The DC lower bound (quoted in the note and the error).
    lo : float
        The largest γ known to have no accepted controller.

    Returns
    -------
    _Accepted
        The controller at the upper end of the final interval, with the note saying the interval.

    Raises
    ------
    HinfSynthesisError
        No controller is accepted at ``cfg.gamma_max`` itself.
    """
    cfg = trials.cfg
    gam = cfg.gamma_max
    K, achieved = trials.attempt(gam)
    if K is None:
        raise HinfSynthesisError(
            f"H∞ synthesis found no stable controller achieving γ ≤ vibration.gamma_max = {cfg.gamma_max:g} "
            f"(DC lower bound {bound:.6g}, weights {_describe_weights(cfg)}): " + "; ".join(trials.rejected)
            + ". Relax the weights or raise gamma_max.")
    while (gam - lo) > GAMMA_BISECT_RTOL * gam:
        mid = 0.5 * (lo + gam)
        K_mid, ach_mid = trials.attempt(mid)
        if K_mid is None:
            lo = mid
        else:
            K, gam, achieved = K_mid, mid, ach_mid
    return _Accepted(K, gam, achieved, (f"γ bisected in [{lo:.6g}, {gam:.6g}] (DC bound {bound:.6g} not reachable)",))


class _Reduced(NamedTuple):
    """The controller after balanced truncation (or the full one), with its Hankel singular values."""

    Kr: StateSpace                #: the reduced controller (``K`` itself when not reduced)
    hsv: np.ndarray               #: Hankel singular values of the full controller, largest first
    seconds: float                #: wall time of the reduction
    notes: tuple[str, ...]        #: a note when truncation kept fewer states than asked


def _reduce_controller(K: StateSpace, cfg: HinfConfig, reduce: bool) -> _Reduced:
    """Balanced truncation of ``K`` to ``cfg.order`` states (``reduce``), else ``K`` with its Hankel values.

    Parameters
    ----------
    K : control.StateSpace
        The full controller.
    cfg : HinfConfig
        ``cfg.order``: the reduced order.
    reduce : bool
        Whether to truncate.

    Returns
    -------
    _Reduced

    Raises
    ------
    HinfSynthesisError
        The truncation failed (:class:`~.reduction.ReductionError`).
    """
    t1 = time.perf_counter()
    try:
        if reduce:
            Kr, hsv = balanced_truncation(K, cfg.order)
        else:
            Kr, hsv = K, hankel_singular_values(K)
    except ReductionError as exc:
        raise HinfSynthesisError(f"controller reduction failed: {exc}") from exc
    seconds = time.perf_counter() - t1
    notes: tuple[str, ...] = ()
    if reduce and Kr.nstates < min(cfg.order, K.nstates):
        notes = (f"balanced truncation returned {Kr.nstates} states (< vibration.order = {cfg.order}): the "
                 "controller has no more controllable and observable states",)
    return _Reduced(Kr, hsv, seconds, notes)


def _verify_reduced(G_L: TFMatrix, cfg: HinfConfig, full: _Accepted, red: _Reduced,
                    verify: bool) -> tuple[float, float]:
    """The reduced controller's achieved norm, checked against ``cfg.gamma_max``.

    Parameters
    ----------
    G_L : TFMatrix
        The plant the weighted norm is taken with.
    cfg : HinfConfig
        The norm's weights, and γ_max the reduced controller must stay under.
    full : _Accepted
        The full controller (its norm is reused when the reduction returned it unchanged).
    red : _Reduced
        The reduced controller.
    verify : bool
        Measure the reduced controller's norm (otherwise NaN, unless it is the full controller).

    Returns
    -------
    achieved : float
        The reduced controller's norm (NaN if not verified).
    seconds : float
        Wall time of the verification (0 when none ran).

    Raises
    ------
    HinfSynthesisError
        The reduced controller's norm is above ``cfg.gamma_max``.
    """
    if red.Kr is full.K:
        return full.achieved, 0.0
    if not verify:
        return math.nan, 0.0
    tv = time.perf_counter()
    achieved_red, w_at = achieved_norm(G_L, red.Kr, cfg)
    seconds = time.perf_counter() - tv
    if not achieved_red <= cfg.gamma_max:
        raise HinfSynthesisError(
            f"reduced controller ({red.Kr.nstates} states) achieves {achieved_red:.6g} at ω = {w_at:.4g} rad/s > "
            f"vibration.gamma_max = {cfg.gamma_max:g} (full: {full.achieved:.6g}; truncation error bound "
            f"{truncation_error_bound(red.hsv, red.Kr.nstates):.3g}); raise vibration.order")
    return achieved_red, seconds


def synthesize_hinf(G_L: TFMatrix, cfg: HinfConfig, *, reduce: bool = True, verify: bool = True) -> HinfDesign:
    """Synthesise the H∞ model-matching feedforward C(s) for ``G_L`` with the weights of ``cfg``, then reduce it.

    The γ iteration is done here, not inside ``control.hinfsyn``: hinfsyn always runs SLICOT SB10AD's own
    bisection, which on this problem (measurement = reference, ``C2 = 0``) can stop at a γ no controller achieves
    (γ = 0.065, achieved 42, for the ``gyx_gain_div10`` variant) and takes seconds.  Instead SB10AD is called for
    one γ at a time (JOB = 4, the central controller) and every candidate is accepted only if it is stable and
    achieves that γ on the frequency grid.  The first candidate is the certified DC lower bound ·(1 + 1e-4): when it
    is accepted (the case for G_L as printed and its variant) γ is within 1e-4 of the optimum, with a proof.
    Otherwise γ is bisected between that bound and ``cfg.gamma_max`` to a relative width of 1e-3.

    Parameters
    ----------
    G_L : TFMatrix
        Square, stable plant ``Y_L → Y`` (paper Eq. 14).
    cfg : HinfConfig
        Weights (t_r, eps_s, k_o, W2), reduction order and γ_max; validated first (``ConfigError`` on bad values).
    reduce : bool
        Balanced truncation to ``cfg.order`` states; otherwise the reduced controller is the full one.
    verify : bool
        Also check the reduced controller's achieved norm (the full one is always checked: it is how γ is accepted).

    Returns
    -------
    HinfDesign

    Raises
    ------
    HinfSynthesisError
        No stable controller achieving γ ≤ ``cfg.gamma_max``, unstable reduced controller, reduced achieved norm above
        ``cfg.gamma_max``.
    """
    n = _checked_axes(G_L, cfg)
    notes = _duplicated_factor_notes(G_L, n)
    bound = _feasible_dc_bound(G_L, cfg)
    P = generalized_plant(G_L, cfg)
    trials = _GammaTrials(G_L, cfg, P, n)
    full = _search_gamma(trials, bound)
    red = _reduce_controller(full.K, cfg, reduce)
    achieved_red, verify_red_s = _verify_reduced(G_L, cfg, full, red, verify)
    K, Kr = full.K, red.Kr
    return HinfDesign(controller=Kr, controller_full=K, gamma=float(full.gamma),
                      gamma_full_achieved=float(full.achieved), gamma_reduced_achieved=float(achieved_red),
                      order_full=int(K.nstates), order_reduced=int(Kr.nstates), generalized_plant_order=int(P.nstates),
                      hankel_singular_values=np.asarray(red.hsv, float),
                      synthesis_s=float(trials.synthesis_s + red.seconds),
                      gamma_lower_bound=float(bound), verify_s=float(trials.verify_s + verify_red_s),
                      notes=(*notes, *full.notes, *red.notes))
