"""Bouc-Wen kernels (paper Eq. 1–6): one generic increment, the model and the compensator loops (compiled, pure).

The increment of h for a voltage step dU (``dÛ = P·dU``)::

    dh = A·dU − B(|dÛ|∘h) − Γ(dÛ∘|h|) − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)
       = A·dU − Σ_j (|dÛ_j|·φ_ij + dÛ_j·ψ_ij),   φ_ij = B_ij h_j + Δ2_ij |h_j|,   ψ_ij = Γ_ij |h_j| + Δ1_ij h_j

(the grouped form is the one computed: φ and ψ depend on h only) is written once for any size (:func:`bw_increment`) and once for two axes with the parameters in registers
(:func:`bw2_increment`, 2.5–8× faster on the 2-axis tube).

Bouc-Wen is rate independent: h depends on the voltage path, not on how fast it is followed.  One explicit step per
sample is accurate only while the step is small: its relative error grows with ``κ = σ·max_j |dÛ_j|``, σ the largest
row sum of ``|B| + |Γ| + |Δ1| + |Δ2|`` (42 % off on 100 V steps, ~0.1 % of the output with 1 V steps on the paper's
tube).  So a sample's increment is integrated along the straight voltage path (:func:`path_weight`,
:func:`bw_path_increment`, :func:`bw2_path_increment`): one explicit step while ``κ ≤`` :data:`KAPPA_MAX` (0.11 V per
sample on the paper's tube: its 0.1 Hz hysteresis sines and open-loop circles at 20 kHz), with exactly the numbers of
the single-step form; beyond, the exact solution along the path (:func:`bw_exact_path`, :func:`bw2_exact_path`:
along a straight step ``dÛ`` is constant, so the ODE in the path parameter is linear in h inside each sign orthant
of h, and is summed by its Taylor series piece by piece, stopping where a component of h changes sign), blended
with the one explicit step for ``KAPPA_MAX < κ < 2·KAPPA_MAX`` so that h is a continuous function of the step (the
compensator inverts it).  The model follows the continuous Bouc-Wen equally well at 100 Hz and at 20 kHz, and a
100 V step costs a few series instead of ~1000 explicit sub-steps.  A path longer than :data:`LONG_PIECES` pieces
(``κ > 16``: the compensator's Newton steps on a reference far beyond the stage's reach ask for kV to TV) goes by
propagators of doubling length per orthant (:func:`_long_path`): its cost grows with log κ, not κ, and a state
driven far saturates at the orthant's fixed point, where the walk stops.  The compensator inverts the same path
increment (Newton, :func:`bw_refine`, :func:`bw2_refine`), so the model and its inverse stay exact inverses and
share h bit for bit.

Parameters travel as :class:`BoucWenParams` (named arrays), the compensator's state as :class:`CompState`, its
options as :class:`CompOptions`, and its counters in an int64 array indexed by :data:`FALLBACKS` and
:data:`SATURATED`.
"""
from __future__ import annotations

import math
from typing import Mapping, NamedTuple

import numpy as np

from .._jit import njit
from .limits import CLAMPED, SLEWED, limit_step

__all__ = ["BoucWenParams", "CompState", "CompOptions", "FALLBACKS", "SATURATED", "N_COUNTERS", "params_of",
           "KAPPA_MAX", "PIECE_KAPPA", "SERIES_TERMS", "MAX_PIECES", "LONG_PIECES", "path_weight", "path_scratch",
           "bw_sigma",
           "bw_exact_path", "bw_path_increment", "bw_refine", "bw2_sigma", "bw2_path_weight", "bw2_exact_path",
           "bw2_path_increment", "bw2_refine",
           "bw_increment", "bw_model_run", "bw_model_rate_run", "bw_model_run_2x2", "bw_comp_run", "bw_comp_run_2x2", "solve_small",
           "coeffs_2x2", "bw2_factors", "bw2_increment", "bw2_model_step", "bw2_comp_step", "bw2_comp_first", "comp_coeffs_2x2",
           "coeff_tuple", "model_coeff_tuple"]

#: index in the compensator's counters: samples where no sign pattern was consistent (delayed formula used)
FALLBACKS = 0
#: index in the compensator's counters: axis-samples clamped to ±limit, plus axis-samples held back by the slew limit
SATURATED = 1
#: length of the compensator's counters array
N_COUNTERS = 2
#: the largest ``κ = σ·max_j |dÛ_j|`` one explicit Bouc-Wen step may take (the relative change of the h-dependent
#: terms in one step; the explicit step's error on h is about κ/3 of the loop's amplitude, ~0.01 % of the output here)
KAPPA_MAX = 1.0e-3
#: the largest ``‖M‖·Δλ`` of one piece of the exact path (its Taylor series then reaches rounding in ~16 terms)
PIECE_KAPPA = 0.5
#: the most terms of one piece's Taylor series
SERIES_TERMS = 30
#: ``1/k`` for the series' terms (a multiplication per term instead of a division: the per-sample latency)
_INV = tuple(1.0 / k if k else 0.0 for k in range(SERIES_TERMS + 1))
#: cap on the pieces of one sample's exact path (~2κ plus the sign changes of h: a 400 V step on the paper's tube
#: takes ~8)
MAX_PIECES = 1 << 20
#: pieces of one sample's exact path summed one by one; a longer path (``κ > PIECE_KAPPA·LONG_PIECES = 16``: beyond
#: 1.7 kV on the paper's tube, 4× the largest step ±200 V allow, or more sign changes of h than that) goes by
#: propagators of doubling length (:func:`_long_path`), so that its cost grows with log κ, not κ.  Every other path
#: keeps its numbers bit for bit.
LONG_PIECES = 32
#: a derivative within this fraction of the size of its terms is rounding (the long path's turning test)
_ROUNDING = 64.0 * 2.2e-16


class BoucWenParams(NamedTuple):
    """The model's matrices: ``Dp``, ``A`` [n×k], ``B``, ``G`` (Γ), ``D1``, ``D2`` (Δ1, Δ2) [n×n], ``P`` [n×k]."""

    Dp: np.ndarray
    A: np.ndarray
    B: np.ndarray
    G: np.ndarray
    D1: np.ndarray
    D2: np.ndarray
    P: np.ndarray


class CompState(NamedTuple):
    """The compensator's carried state: ``h`` [n], last voltage ``u_prev`` [k], ``started`` [1], ``signs`` [n]."""

    h: np.ndarray
    u_prev: np.ndarray
    started: np.ndarray
    signs: np.ndarray


class CompOptions(NamedTuple):
    """How the compensator solves Eq. 6 and limits its output."""

    exact: bool      #: solve the implicit equation per sample (else the one-sample-delayed formula)
    ulim: float      #: |U| ≤ ulim [V] (inf = none)
    dulim: float     #: |ΔU| ≤ dulim per sample [V] (inf = none)


def params_of(arrays: Mapping[str, np.ndarray]) -> BoucWenParams:
    """:class:`BoucWenParams` from ``BoucWenConfig.arrays()`` (contiguous float copies).

    Parameters
    ----------
    arrays : mapping
        ``Dp``, ``A``, ``B``, ``Gamma``, ``Delta1``, ``Delta2``, ``P``.

    Returns
    -------
    BoucWenParams
    """
    def c(name: str) -> np.ndarray:
        return np.ascontiguousarray(arrays[name], dtype=float)
    return BoucWenParams(c("Dp"), c("A"), c("B"), c("Gamma"), c("Delta1"), c("Delta2"), c("P"))


# ------------------------------------------------------------------------------------------------ generic (any n, k)

@njit
def bw_increment(p: BoucWenParams, h: np.ndarray, du: np.ndarray, dh: np.ndarray,
                 duh: np.ndarray) -> None:  # pragma: no cover - compiled
    """``dh`` ← the increment of h for the voltage step ``du``; ``duh`` is scratch (``P·du``), no allocation."""
    n = h.shape[0]
    k = du.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(k):
            acc += p.P[i, j] * du[j]
        duh[i] = acc
    for i in range(n):
        acc = 0.0
        for j in range(k):
            acc += p.A[i, j] * du[j]
        for j in range(n):
            # grouped by what multiplies |dÛ_j| (φ) and dÛ_j (ψ): φ and ψ depend on h only, so a compensator has
            # them before it knows dU (the latency of its per-sample recursion)
            ah = abs(h[j])
            phi = p.B[i, j] * h[j] + p.D2[i, j] * ah
            psi = p.G[i, j] * ah + p.D1[i, j] * h[j]
            acc -= abs(duh[j]) * phi + duh[j] * psi
        dh[i] = acc


@njit
def path_weight(sigma: float, duh_max: float) -> float:  # pragma: no cover - compiled
    """How a sample whose largest ``|dÛ_j|`` is ``duh_max`` is integrated: the weight ``w`` of the exact path.

    ``w < 0``: one explicit step (``κ = σ·duh_max ≤ KAPPA_MAX``, NaN included: the result is non-finite anyway).
    ``0 ≤ w < 1`` (``KAPPA_MAX < κ < 2·KAPPA_MAX``): the blend ``(1 − w)·H_1 + w·H_exact`` of the one explicit step
    and the exact path (:func:`bw_exact_path`), ``w = κ / KAPPA_MAX − 1``, so that h is a continuous function of
    the step (the compensator inverts it).  ``w = 1``: the exact path alone.
    """
    x = sigma * duh_max
    if not x > KAPPA_MAX:
        return -1.0
    if x < 2.0 * KAPPA_MAX:
        return x / KAPPA_MAX - 1.0
    return 1.0


@njit
def bw_sigma(p: BoucWenParams) -> float:  # pragma: no cover - compiled
    """σ: the largest row sum of ``|B| + |Γ| + |Δ1| + |Δ2|`` (``κ = σ·max|dÛ|`` bounds a step's relative change)."""
    n = p.B.shape[0]
    sigma = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc = acc + abs(p.B[i, j]) + abs(p.G[i, j]) + abs(p.D1[i, j]) + abs(p.D2[i, j])
        if acc > sigma:
            sigma = acc
    return sigma


@njit
def path_scratch(n: int) -> np.ndarray:  # pragma: no cover - compiled
    """The scratch :func:`bw_exact_path` needs for n outputs (allocated once per block, not per sample).

    Parameters
    ----------
    n : int
        Number of outputs (size of h).

    Returns
    -------
    ndarray
        ``[n + 8, n]``.
    """
    return np.zeros((n + 8, n))


@njit
def _orthant_matrix(B: np.ndarray, G: np.ndarray, D1: np.ndarray, D2: np.ndarray, q: np.ndarray, s: np.ndarray,
                    M: np.ndarray) -> None:  # pragma: no cover - compiled
    """``M`` ← the matrix of the flow ``dh/dλ = A·dU + M·h`` where ``sgn(h) = s`` (``q = P·dU``; Γ = ``G``,
    Δ1 = ``D1``, Δ2 = ``D2``).

    ``|h_j| = s_j·h_j`` there, so ``−(|q_j|·φ_ij + q_j·ψ_ij) = M_ij·h_j``.
    """
    n = q.shape[0]
    for i in range(n):
        for j in range(n):
            M[i, j] = -(abs(q[j]) * (B[i, j] + D2[i, j] * s[j]) + q[j] * (G[i, j] * s[j] + D1[i, j]))


@njit
def _orthant_signs(M: np.ndarray, a: np.ndarray, he: np.ndarray, s: np.ndarray, B: np.ndarray, G: np.ndarray,
                   D1: np.ndarray, D2: np.ndarray, q: np.ndarray, tmp: np.ndarray) -> None:  # pragma: no cover - compiled
    """``s`` ← the sign orthant the path continues in from ``he`` and ``M`` ← its matrix (as :func:`bw_exact_path`:
    a component at zero leaves it in the direction of its derivative)."""
    n = he.shape[0]
    zero = False
    for j in range(n):
        s[j] = 1.0 if he[j] > 0.0 else (-1.0 if he[j] < 0.0 else 0.0)
        if s[j] == 0.0:
            zero = True
    _orthant_matrix(B, G, D1, D2, q, s, M)
    if zero:
        for i in range(n):
            acc = a[i]
            for j in range(n):
                acc += M[i, j] * he[j]
            tmp[i] = acc
        for j in range(n):
            if s[j] == 0.0:
                s[j] = -1.0 if tmp[j] < 0.0 else 1.0
        _orthant_matrix(B, G, D1, D2, q, s, M)


@njit
def _long_path(B: np.ndarray, G: np.ndarray, D1: np.ndarray, D2: np.ndarray, q: np.ndarray, a: np.ndarray,
               tau0: float, he: np.ndarray, lam: float) -> None:  # pragma: no cover - compiled
    """``he`` ← h at the end of the path (``λ = 1``), from ``he`` at ``lam``: a long path (:func:`bw_exact_path`
    beyond :data:`LONG_PIECES` pieces: from its start, or after that many sign changes of h; ``q = P·dU``,
    ``a = A·dU``, ``tau0`` the length of one Taylor piece).

    Inside an orthant the flow ``dh/dλ = a + M·h`` is affine with constant coefficients, so the map over a length
    ``τ`` is ``h ← Φ(τ)·h + ψ(τ)`` whatever h is.  ``Φ, ψ`` of ``τ0`` come from the same Taylor series
    (:func:`_flow`, on the unit vectors and on 0), those of ``τ0·2^m`` by squaring (``Φ(2τ) = Φ(τ)²``,
    ``ψ(2τ) = Φ(τ)·ψ(τ) + ψ(τ)``): ``log2(1/τ0)`` levels, ~log2(2κ).  The path then goes on by pieces whose length
    doubles after each one taken and halves when a component of h would change sign at its end (or, on a stretch
    where a component moves back towards zero and then away again, could have: its derivative changed sign beyond
    rounding), down to ``τ0``, where the sign change is located as :func:`bw_exact_path` does and the next orthant
    starts.  Each orthant costs O(log κ) small matrix products instead of ~2κ series.  A Bouc-Wen state driven far
    saturates: once ``Φ`` of a piece taken has underflowed to zero, h is the orthant's fixed point ``−M⁻¹a`` to
    rounding and the rest of the path leaves it there (the walk stops).
    """
    n = he.shape[0]
    rem = 1.0 - lam
    if not rem > 0.0:
        return
    L = 0
    span = tau0
    while span < rem and L < 4096:
        span *= 2.0
        L += 1
    lens = np.empty(L + 1)
    lens[0] = tau0
    for m in range(1, L + 1):
        lens[m] = 2.0 * lens[m - 1]
    Phi = np.empty((L + 1, n, n))
    psi = np.empty((L + 1, n))
    M = np.empty((n, n))
    s = np.empty(n)
    zero = np.zeros(n)
    unit = np.zeros(n)
    hx = np.empty(n)
    hr = np.empty(n)
    term = np.empty(n)
    tmp = np.empty(n)
    d0 = np.empty(n)
    pieces = 0
    while pieces < MAX_PIECES:
        rem = 1.0 - lam
        if not rem > 0.0:
            return
        _orthant_signs(M, a, he, s, B, G, D1, D2, q, tmp)
        for j in range(n):
            unit[j] = 1.0
            _flow(M, zero, unit, tau0, hx, term, tmp)
            unit[j] = 0.0
            for i in range(n):
                Phi[0, i, j] = hx[i]
        _flow(M, a, zero, tau0, hx, term, tmp)
        for i in range(n):
            psi[0, i] = hx[i]
        for m in range(1, L + 1):
            for i in range(n):
                acc = psi[m - 1, i]
                for l in range(n):
                    acc += Phi[m - 1, i, l] * psi[m - 1, l]
                psi[m, i] = acc
                for j in range(n):
                    acc = 0.0
                    for l in range(n):
                        acc += Phi[m - 1, i, l] * Phi[m - 1, l, j]
                    Phi[m, i, j] = acc
        m = 0
        new_orthant = False
        while pieces < MAX_PIECES and not new_orthant:
            pieces += 1
            rem = 1.0 - lam
            if not rem > 0.0:
                return
            while m > 0 and lens[m] > rem:
                m -= 1
            if lens[m] <= rem:
                # the derivative here (rounding scale: what its evaluation cannot resolve)
                for i in range(n):
                    acc = a[i]
                    mag = abs(a[i])
                    for l in range(n):
                        acc += M[i, l] * he[l]
                        mag += abs(M[i, l] * he[l])
                    d0[i] = acc
                    tmp[i] = _ROUNDING * mag
                for i in range(n):
                    acc = psi[m, i]
                    for l in range(n):
                        acc += Phi[m, i, l] * he[l]
                    hx[i] = acc
                ok = True
                for j in range(n):
                    if s[j] * hx[j] < 0.0:
                        ok = False
                if ok and m > 0:
                    for i in range(n):
                        acc = a[i]
                        mag = abs(a[i])
                        for l in range(n):
                            acc += M[i, l] * hx[l]
                            mag += abs(M[i, l] * hx[l])
                        # s_i·h_i went down, then up again: its minimum inside the piece may lie across zero
                        if s[i] * d0[i] < -tmp[i] and s[i] * acc > _ROUNDING * mag:
                            ok = False
                if ok:
                    for i in range(n):
                        he[i] = hx[i]
                    lam += lens[m]
                    saturated = True
                    for i in range(n):
                        for l in range(n):
                            if Phi[m, i, l] != 0.0:
                                saturated = False
                    if saturated:
                        # Φ underflowed: h is the orthant's fixed point −M⁻¹a to rounding, where the rest of the
                        # path leaves it (every longer piece maps any h to exactly this ψ)
                        return
                    if m < L:
                        m += 1
                    continue
                if m > 0:
                    m -= 1
                    continue
            # one piece of at most τ0 as bw_exact_path takes it: a sign change located on the series
            tau = rem if rem < tau0 else tau0
            tc, jc = _piece(M, a, he, s, tau, hx, hr, term, tmp)
            lam += tc
            if jc >= 0:
                new_orthant = True
            for i in range(n):
                he[i] = hx[i]
            if jc < 0 and tau == rem:
                return
            m = 1 if L >= 1 else 0


@njit
def _flow(M: np.ndarray, a: np.ndarray, hc: np.ndarray, t: float, out: np.ndarray, term: np.ndarray,
          tmp: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out`` ← the solution of ``dh/dλ = a + M·h`` at ``λ = t`` from ``hc`` (its Taylor series, summed until
    the terms are below rounding: ``‖M‖·t ≤`` :data:`PIECE_KAPPA`, so at most :data:`SERIES_TERMS` terms)."""
    n = hc.shape[0]
    for i in range(n):
        acc = a[i]
        for j in range(n):
            acc += M[i, j] * hc[j]
        term[i] = t * acc
        out[i] = hc[i] + term[i]
    for kk in range(2, SERIES_TERMS + 1):
        f = t * _INV[kk]
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += M[i, j] * term[j]
            tmp[i] = f * acc
        big = 0.0
        scale = 0.0
        for i in range(n):
            term[i] = tmp[i]
            out[i] += tmp[i]
            if abs(tmp[i]) > big:
                big = abs(tmp[i])
            if abs(out[i]) > scale:
                scale = abs(out[i])
        if not big > 1e-17 * scale:
            break


@njit
def _piece(M: np.ndarray, a: np.ndarray, he: np.ndarray, s: np.ndarray, tau: float, hx: np.ndarray, hr: np.ndarray,
           term: np.ndarray, tmp: np.ndarray) -> tuple[float, int]:  # pragma: no cover - compiled
    """One piece of at most ``tau`` in the orthant ``s`` from ``he``: ``hx`` ← the flow (:func:`_flow`) up to the
    first component that changes sign (set to exactly 0 there), or up to ``tau``; returns ``(λ covered, that
    component or -1)``."""
    _flow(M, a, he, tau, hx, term, tmp)
    tc = tau
    jc = -1
    for j in range(he.shape[0]):
        if s[j] * hx[j] < 0.0:
            t = _crossing(M, a, he, j, s[j], tau, s[j] * hx[j], hr, term, tmp)
            if t < tc:
                tc = t
                jc = j
    if jc >= 0:
        _flow(M, a, he, tc, hx, term, tmp)
        hx[jc] = 0.0
    return tc, jc


@njit
def _crossing(M: np.ndarray, a: np.ndarray, hc: np.ndarray, j: int, sj: float, tau: float, fhi: float,
              hr: np.ndarray, term: np.ndarray, tmp: np.ndarray) -> float:  # pragma: no cover - compiled
    """The λ in ``(0, tau)`` where ``h_j`` of :func:`_flow` crosses zero (``sj·h_j ≥ 0`` at 0, ``sj·h_j = fhi < 0``
    at ``tau``): Newton safeguarded by bisection, to rounding."""
    lo = 0.0
    hi = tau
    flo = float(sj * hc[j])
    t = tau * flo / (flo - fhi)
    if not (t > lo and t < hi):
        t = 0.5 * (lo + hi)
    for _ in range(100):
        _flow(M, a, hc, t, hr, term, tmp)
        f = float(sj * hr[j])
        if f > 0.0:
            lo = t
        elif f < 0.0:
            hi = t
        else:
            return t
        acc = a[j]
        for l in range(hc.shape[0]):
            acc += M[j, l] * hr[l]
        d = sj * acc
        tn = 0.5 * (lo + hi)
        if d != 0.0:
            tn = t - f / d
            if not (tn > lo and tn < hi):
                tn = 0.5 * (lo + hi)
        if not abs(tn - t) > 4e-16 * tau or not hi - lo > 4e-16 * tau:
            return tn
        t = tn
    return t


@njit
def bw_exact_path(p: BoucWenParams, sigma: float, h: np.ndarray, du: np.ndarray, he: np.ndarray,
                  ws: np.ndarray) -> None:  # pragma: no cover - compiled
    """``he`` ← h at the end of the straight voltage path ``du``, integrated exactly.

    Along the path ``U + λ·dU`` (λ from 0 to 1) the increment is the ODE ``dh/dλ = A·dU − Σ_j (|dÛ_j|·φ_ij +
    dÛ_j·ψ_ij)``, linear in h inside each sign orthant of h (``dÛ = P·dU`` is constant): ``dh/dλ = a + M·h``
    (:func:`_orthant_matrix`).  It is solved piece by piece by its Taylor series (:func:`_flow`: pieces with
    ``‖M‖·Δλ ≤`` :data:`PIECE_KAPPA`, ~2κ of them), stopping where a component of h changes sign
    (:func:`_crossing`) to continue in the next orthant.  A component at zero leaves it in the direction of its
    derivative (which does not depend on its own sign).  ``ws`` is :func:`path_scratch`; nothing is allocated.
    """
    n = h.shape[0]
    k = du.shape[0]
    M = ws[:n]
    q = ws[n]
    a = ws[n + 1]
    s = ws[n + 2]
    term = ws[n + 3]
    tmp = ws[n + 4]
    hx = ws[n + 5]
    hr = ws[n + 6]
    big = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(k):
            acc += p.P[i, j] * du[j]
        q[i] = acc
        if abs(acc) > big:
            big = abs(acc)
    for i in range(n):
        acc = 0.0
        for j in range(k):
            acc += p.A[i, j] * du[j]
        a[i] = acc
    kap = sigma * big
    if not kap < np.inf:
        # non-finite step: the one explicit step (non-finite too)
        bw_increment(p, h, du, tmp, term)
        for i in range(n):
            he[i] = h[i] + tmp[i]
        return
    tau_max = 1.0
    if kap > PIECE_KAPPA:
        tau_max = PIECE_KAPPA / kap
    for i in range(n):
        he[i] = h[i]
    if kap > PIECE_KAPPA * LONG_PIECES:
        # a long path (more than LONG_PIECES pieces): by propagators, cost ~log κ instead of ~2κ
        _long_path(p.B, p.G, p.D1, p.D2, q, a, tau_max, he, 0.0)
        return
    lam = 0.0
    for piece in range(MAX_PIECES):
        rem = 1.0 - lam
        if not rem > 0.0:
            break
        if piece == LONG_PIECES:
            # many sign changes of h: the rest by propagators too
            _long_path(p.B, p.G, p.D1, p.D2, q, a, tau_max, he, lam)
            return
        _orthant_signs(M, a, he, s, p.B, p.G, p.D1, p.D2, q, tmp)
        tau = rem if rem < tau_max else tau_max
        tc, jc = _piece(M, a, he, s, tau, hx, hr, term, tmp)
        lam += tc
        for i in range(n):
            he[i] = hx[i]
        if jc < 0 and tau == rem:
            break


@njit
def bw_path_increment(p: BoucWenParams, sigma: float, h: np.ndarray, du: np.ndarray, dh: np.ndarray,
                      duh: np.ndarray, hw: np.ndarray, he: np.ndarray,
                      ws: np.ndarray) -> None:  # pragma: no cover - compiled
    """``dh`` ← the increment of h along the straight voltage path ``du`` (:func:`path_weight`): exactly
    :func:`bw_increment` when one step is enough, else the exact path (:func:`bw_exact_path`), blended with the
    one step just above :data:`KAPPA_MAX`.

    ``duh``, ``hw``, ``he`` [n] and ``ws`` (:func:`path_scratch`) are scratch; nothing is allocated.
    """
    n = h.shape[0]
    k = du.shape[0]
    big = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(k):
            acc += p.P[i, j] * du[j]
        if abs(acc) > big:
            big = abs(acc)
    w = path_weight(sigma, big)
    if w < 0.0:
        bw_increment(p, h, du, dh, duh)
        return
    bw_exact_path(p, sigma, h, du, he, ws)
    if w < 1.0:
        bw_increment(p, h, du, dh, duh)
        for i in range(n):
            hw[i] = h[i] + dh[i]
        for i in range(n):
            dh[i] = (hw[i] + w * (he[i] - hw[i])) - h[i]
    else:
        for i in range(n):
            dh[i] = he[i] - h[i]


@njit
def _coeffs_2x2_or_zeros(p: BoucWenParams) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`coeffs_2x2` inside compiled code (28 zeros unless two voltages and two outputs)."""
    c = np.zeros(28)
    if p.A.shape[0] == 2 and p.A.shape[1] == 2:
        mats = (p.Dp, p.A, p.B, p.G, p.D1, p.D2, p.P)
        for m in range(7):
            for i in range(2):
                for j in range(2):
                    c[4 * m + 2 * i + j] = mats[m][i, j]
    return c


@njit
def bw_model_run(p: BoucWenParams, h: np.ndarray, u_prev: np.ndarray, started: np.ndarray, u: np.ndarray,
                 y: np.ndarray, hs: np.ndarray) -> None:  # pragma: no cover - compiled
    """The model ``Y = Dp·U − h`` over a block ``u [N, k]``: ``y``, ``hs`` [N, n] written, state carried."""
    bw_model_rate_run(p, 0.0, 1.0, 0.0, 1.0, np.zeros(u.shape[1]), h, u_prev, started, u, y, hs)


@njit
def bw_model_rate_run(p: BoucWenParams, alpha: float, rate_ref: float, a_smooth: float, dt: float,
                      rate: np.ndarray, h: np.ndarray, u_prev: np.ndarray, started: np.ndarray, u: np.ndarray,
                      y: np.ndarray, hs: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`bw_model_run` with an optional rate dependence of the A term (``alpha = 0``: the model itself).

    ``A·dU`` becomes ``A·((1 + α·tanh(r/r_ref))∘dU)``, r the voltage rate ``|dU|/dt`` smoothed by
    ``r ← a_smooth·r + (1 − a_smooth)·|dU|/dt`` (state ``rate`` [k]); B/Γ/Δ still see the true dU (the increment
    along the path, :func:`bw_path_increment`; the extra A term is added to it).  Used by the
    hysteresis-replacement effect (:class:`~piezo_ff_ros.core.models.effects.HysteresisStage`).
    """
    N = u.shape[0]
    k = u.shape[1]
    n = h.shape[0]
    du = np.zeros(k)
    dus = np.zeros(k)
    dh = np.zeros(n)
    duh = np.zeros(n)
    hw = np.zeros(n)
    he = np.zeros(n)
    ws = path_scratch(n)
    sigma = bw_sigma(p)
    # two axes: the increment from the two-axis kernel (the same numbers, parameters in registers)
    two = n == 2 and k == 2
    c = model_coeff_tuple(_coeffs_2x2_or_zeros(p))
    for t in range(N):
        if not started[0]:
            for j in range(k):
                u_prev[j] = u[t, j]
            started[0] = True
        for j in range(k):
            du[j] = u[t, j] - u_prev[j]
        if two:
            dh[0], dh[1] = _bw2_path_dh(c, sigma, h[0], h[1], du[0], du[1])
        else:
            bw_path_increment(p, sigma, h, du, dh, duh, hw, he, ws)
        if alpha != 0.0:
            # the rate only enlarges the A term: added separately, so the nominal increment stays the same numbers
            for j in range(k):
                rate[j] = a_smooth * rate[j] + (1.0 - a_smooth) * abs(du[j]) / dt
                dus[j] = du[j] * (1.0 + alpha * math.tanh(rate[j] / rate_ref))
            for i in range(n):
                acc = 0.0
                for j in range(k):
                    acc += p.A[i, j] * (dus[j] - du[j])
                dh[i] += acc
        for i in range(n):
            h[i] += dh[i]
        for j in range(k):
            u_prev[j] = u[t, j]
        for i in range(n):
            acc = 0.0
            for j in range(k):
                acc += p.Dp[i, j] * u[t, j]
            y[t, i] = acc - h[i]
            hs[t, i] = h[i]


@njit
def solve_small(M: np.ndarray, r: np.ndarray, x: np.ndarray, a: np.ndarray,
                b: np.ndarray) -> bool:  # pragma: no cover - compiled
    """Solve a small dense system (Cramer's rule for 2×2, else Gaussian elimination with partial pivoting); False
    if singular.

    ``a`` (n×n) and ``b`` (n) are scratch for the factorisation: nothing is allocated per call.
    """
    n = r.shape[0]
    if n == 2:
        # Cramer's rule: two independent divisions instead of three dependent ones (the compensator's per-sample
        # latency); M is well conditioned here (≈ Dp − A).  The two-axis kernel uses the same expressions.
        det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
        if abs(det) < 1e-300:
            return False
        x[0] = (r[0] * M[1, 1] - M[0, 1] * r[1]) / det
        x[1] = (M[0, 0] * r[1] - M[1, 0] * r[0]) / det
        return True
    for i in range(n):
        b[i] = r[i]
        for j in range(n):
            a[i, j] = M[i, j]
    for c in range(n):
        q = c
        for i in range(c + 1, n):
            if abs(a[i, c]) > abs(a[q, c]):
                q = i
        if abs(a[q, c]) < 1e-300:
            return False
        if q != c:
            for j in range(n):
                tmp = a[c, j]
                a[c, j] = a[q, j]
                a[q, j] = tmp
            tmp = b[c]
            b[c] = b[q]
            b[q] = tmp
        for i in range(c + 1, n):
            f = a[i, c] / a[c, c]
            for j in range(c, n):
                a[i, j] -= f * a[c, j]
            b[i] -= f * b[c]
    for i in range(n - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, n):
            acc -= a[i, j] * x[j]
        x[i] = acc / a[i, i]
    return True


@njit
def _comp_residual(p: BoucWenParams, sigma: float, h: np.ndarray, r: np.ndarray, du: np.ndarray, F: np.ndarray,
                   dh: np.ndarray, duh: np.ndarray, hw: np.ndarray, he: np.ndarray,
                   ws: np.ndarray) -> None:  # pragma: no cover - compiled
    """``F`` ← ``Dp·du − Δh(du) − r``, Δh the path increment (:func:`bw_path_increment`)."""
    n = h.shape[0]
    k = du.shape[0]
    bw_path_increment(p, sigma, h, du, dh, duh, hw, he, ws)
    for i in range(n):
        acc = -r[i] - dh[i]
        for j in range(k):
            acc += p.Dp[i, j] * du[j]
        F[i] = acc


@njit
def bw_refine(p: BoucWenParams, sigma: float, h: np.ndarray, r: np.ndarray, du: np.ndarray, F0: np.ndarray,
              Fj: np.ndarray, x: np.ndarray, M: np.ndarray, lu: np.ndarray, rhs: np.ndarray, dh: np.ndarray,
              duh: np.ndarray, hw: np.ndarray, he: np.ndarray, ws: np.ndarray) -> None:  # pragma: no cover - compiled
    """Refine the one-step solution ``du`` of ``Dp·du − Δh(du) = r`` for the path increment (Newton).

    Nothing to do (``du`` untouched) when ``du`` takes one step; else Newton's iterations on the path increment
    (:func:`bw_path_increment`, its Jacobian by forward differences of relative step 1e-7: the convergence stays
    ~1e-7 per iteration), from the one-step solution, until the correction is at rounding level or stops
    shrinking (at most 50 iterations).  ``F0``, ``Fj``, ``rhs``, ``dh``, ``duh``, ``hw``, ``he`` [n], ``x`` [k],
    ``M``, ``lu`` [n, n] and ``ws`` (:func:`path_scratch`) are scratch.
    """
    n = h.shape[0]
    k = du.shape[0]
    prev = np.inf
    for it in range(50):
        if it == 0:
            big = 0.0
            for i in range(n):
                acc = 0.0
                for j in range(k):
                    acc += p.P[i, j] * du[j]
                if abs(acc) > big:
                    big = abs(acc)
            if path_weight(sigma, big) < 0.0:
                return
        _comp_residual(p, sigma, h, r, du, F0, dh, duh, hw, he, ws)
        size = 0.0
        for j in range(k):
            size = max(size, abs(du[j]))
        eps = 1e-7 * size
        if not eps > 0.0:
            return
        for j in range(k):
            dj = du[j]
            du[j] = dj + eps
            e = du[j] - dj
            _comp_residual(p, sigma, h, r, du, Fj, dh, duh, hw, he, ws)
            du[j] = dj
            for i in range(n):
                M[i, j] = (Fj[i] - F0[i]) / e
        for i in range(n):
            Fj[i] = -F0[i]
        if not solve_small(M, Fj, x, lu, rhs):
            return
        step = 0.0
        size = 0.0
        for j in range(k):
            du[j] += x[j]
            step = max(step, abs(x[j]))
            size = max(size, abs(du[j]))
        if not step > 4e-16 * size:
            return
        if it >= 3 and not step < 0.5 * prev:
            return   # rounding level: the corrections no longer shrink
        prev = step


@njit
def bw_comp_run(p: BoucWenParams, Dp_pinv: np.ndarray, st: CompState, opt: CompOptions, yh: np.ndarray,
                u: np.ndarray, counters: np.ndarray) -> None:  # pragma: no cover - compiled
    """The inverse ``U = Dp⁻¹(Y_H + h)`` over a block ``yh [N, n]`` → ``u [N, k]`` (paper Eq. 6).

    Exact loop: given the signs of ``dÛ`` the increment of h is linear in dU, so each sign pattern gives a linear
    system ``(Dp − A + W·P)·dU = Y_H − Dp·U_prev + h``; the previous pattern is tried first, then all 2ⁿ, and the
    first consistent solution is kept (else the delayed formula, counted in ``counters[FALLBACKS]``).  A step that
    the model does not take in one explicit step (:func:`bw_path_increment`) is then refined by Newton on the path
    increment (:func:`bw_refine`), so that the model's output is again ``Y_H``.  The voltage then goes through :func:`~.limits.limit_step` (counted in ``counters[SATURATED]``).
    """
    h, u_prev, started, signs = st.h, st.u_prev, st.started, st.signs
    N = yh.shape[0]
    n = h.shape[0]
    k = u_prev.shape[0]
    r = np.zeros(n)
    du = np.zeros(k)
    dh = np.zeros(n)
    M = np.zeros((n, n))
    W = np.zeros((n, n))
    s = np.zeros(n)
    duh = np.zeros(n)
    lu = np.zeros((n, n))
    rhs = np.zeros(n)
    hw = np.zeros(n)
    he = np.zeros(n)
    F0 = np.zeros(n)
    Fj = np.zeros(n)
    x = np.zeros(k)
    ws = path_scratch(n)
    npat = 1 << n
    sigma = bw_sigma(p)
    for t in range(N):
        if not started[0]:
            # first sample: h = 0 and dU = 0 by definition, U = Dp⁻¹·Y_H (clamped only: no previous voltage)
            for j in range(k):
                acc = 0.0
                for i in range(n):
                    acc += Dp_pinv[j, i] * yh[t, i]
                v, f = limit_step(0.0, acc, opt.ulim, np.inf)
                if not abs(v) < np.inf:
                    v = 0.0   # no finite voltage: the rest voltage of the definition
                    f = CLAMPED
                if f & CLAMPED:
                    counters[SATURATED] += 1
                u_prev[j] = v
                u[t, j] = v
            started[0] = True
            continue
        solved = False
        if opt.exact:
            # r = Y_H − Dp·u_prev + h_prev
            for i in range(n):
                acc = yh[t, i] + h[i]
                for j in range(k):
                    acc -= p.Dp[i, j] * u_prev[j]
                r[i] = acc
            for q in range(npat + 1):
                if q == 0:
                    for i in range(n):
                        s[i] = signs[i]
                else:
                    for i in range(n):
                        s[i] = 1.0 if ((q - 1) >> i) & 1 else -1.0
                # W[i, l] = s_l φ_il + ψ_il (φ, ψ of bw_increment);  (Dp − A + W·P)·dU = r
                for i in range(n):
                    for l in range(n):
                        ah = abs(h[l])
                        W[i, l] = s[l] * (p.B[i, l] * h[l] + p.D2[i, l] * ah) + (p.G[i, l] * ah + p.D1[i, l] * h[l])
                for i in range(n):
                    for j in range(k):
                        acc = p.Dp[i, j] - p.A[i, j]
                        for l in range(n):
                            acc += W[i, l] * p.P[l, j]
                        M[i, j] = acc
                if not solve_small(M, r, du, lu, rhs):
                    continue
                ok = True
                for l in range(n):
                    d = 0.0
                    for j in range(k):
                        d += p.P[l, j] * du[j]
                    if d * s[l] < 0.0:
                        ok = False
                        break
                if ok:
                    solved = True
                    for i in range(n):
                        signs[i] = s[i]
                    break
            if not solved:
                counters[FALLBACKS] += 1
            else:
                bw_refine(p, sigma, h, r, du, F0, Fj, x, M, lu, rhs, dh, duh, hw, he, ws)
                for j in range(k):
                    if not abs(du[j]) < np.inf:
                        # beyond double precision (a reference of ~1e300 m): the delayed formula's direction
                        solved = False
                if not solved:
                    counters[FALLBACKS] += 1
        if not solved:
            for j in range(k):
                acc = 0.0
                for i in range(n):
                    acc += Dp_pinv[j, i] * (yh[t, i] + h[i])
                du[j] = acc - u_prev[j]
        for j in range(k):
            v, f = limit_step(u_prev[j], u_prev[j] + du[j], opt.ulim, opt.dulim)
            if not abs(v) < np.inf:
                # no finite voltage (no limit and an overflowing reference, or inf − inf): hold the last one
                v = u_prev[j]
                f = CLAMPED
            counters[SATURATED] += (1 if f & CLAMPED else 0) + (1 if f & SLEWED else 0)
            du[j] = v - u_prev[j]  # the step actually made: h follows the voltage output
            u_prev[j] = v
            u[t, j] = v
        bw_path_increment(p, sigma, h, du, dh, duh, hw, he, ws)
        for i in range(n):
            h[i] += dh[i]


# ------------------------------------------------------------------------------------------------ two axes (n = k = 2)

#: the coefficients of a 2×2 model as the step functions hold them (in registers): Dp, A, B, G, D1, D2, P
#: row-major (4 each: 28 numbers), for the compensator followed by Dp⁻¹ and Dp − A (36 numbers)
Coeffs2 = tuple[float, ...]


def coeffs_2x2(p: BoucWenParams) -> np.ndarray:
    """The 2×2 parameters as one flat array (Dp, A, B, G, D1, D2, P, row-major: 28 numbers).

    Parameters
    ----------
    p : BoucWenParams
        Two-axis parameters.

    Returns
    -------
    ndarray
        ``[28]``, read by :func:`bw_model_run_2x2` and the fused kernels.
    """
    return np.ascontiguousarray(np.concatenate([np.asarray(m, float).reshape(4) for m in p]))


def comp_coeffs_2x2(p: BoucWenParams, Dp_pinv: np.ndarray) -> np.ndarray:
    """:func:`coeffs_2x2` followed by ``Dp⁻¹`` and ``Dp − A`` (row-major): 36 numbers.

    Parameters
    ----------
    p : BoucWenParams
        Two-axis parameters.
    Dp_pinv : ndarray
        The (pseudo-)inverse of ``Dp``.

    Returns
    -------
    ndarray
        ``[36]``, read by :func:`bw_comp_run_2x2` and the fused kernels.
    """
    return np.ascontiguousarray(np.concatenate([coeffs_2x2(p), np.asarray(Dp_pinv, float).reshape(4),
                                                (p.Dp - p.A).reshape(4)]))


@njit(inline="always")
def coeff_tuple(c: np.ndarray) -> Coeffs2:  # pragma: no cover - compiled
    """The 36 numbers of :func:`comp_coeffs_2x2` as a tuple (registers)."""
    return (c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12], c[13], c[14], c[15],
            c[16], c[17], c[18], c[19], c[20], c[21], c[22], c[23], c[24], c[25], c[26], c[27], c[28], c[29], c[30],
            c[31], c[32], c[33], c[34], c[35])


@njit(inline="always")
def model_coeff_tuple(c: np.ndarray) -> Coeffs2:  # pragma: no cover - compiled
    """The 28 numbers of :func:`coeffs_2x2` as a tuple (registers)."""
    return (c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12], c[13], c[14], c[15],
            c[16], c[17], c[18], c[19], c[20], c[21], c[22], c[23], c[24], c[25], c[26], c[27])


@njit(inline="always")
def bw2_factors(c: Coeffs2, h0: float, h1: float) -> tuple[float, float, float, float, float, float, float,
                                                           float]:  # pragma: no cover - compiled
    """The h-only factors of the increment for two axes: ``(φ00, φ01, φ10, φ11, ψ00, ψ01, ψ10, ψ11)``,
    ``φ_ij = B_ij h_j + Δ2_ij |h_j|`` and ``ψ_ij = Γ_ij |h_j| + Δ1_ij h_j`` (as :func:`bw_increment`)."""
    ah0 = abs(h0)
    ah1 = abs(h1)
    return (c[8] * h0 + c[20] * ah0, c[9] * h1 + c[21] * ah1, c[10] * h0 + c[22] * ah0, c[11] * h1 + c[23] * ah1,
            c[12] * ah0 + c[16] * h0, c[13] * ah1 + c[17] * h1, c[14] * ah0 + c[18] * h0, c[15] * ah1 + c[19] * h1)


@njit(inline="always")
def bw2_increment(c: Coeffs2, h0: float, h1: float, du0: float,
                  du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`bw_increment` for two axes (same order of operations): ``(dh0, dh1)``."""
    a00, a01, a10, a11 = c[4], c[5], c[6], c[7]
    p00, p01, p10, p11 = c[24], c[25], c[26], c[27]
    duh0 = 0.0 + p00 * du0 + p01 * du1
    duh1 = 0.0 + p10 * du0 + p11 * du1
    phi00, phi01, phi10, phi11, psi00, psi01, psi10, psi11 = bw2_factors(c, h0, h1)
    dh0 = 0.0 + a00 * du0 + a01 * du1
    dh0 -= abs(duh0) * phi00 + duh0 * psi00
    dh0 -= abs(duh1) * phi01 + duh1 * psi01
    dh1 = 0.0 + a10 * du0 + a11 * du1
    dh1 -= abs(duh0) * phi10 + duh0 * psi10
    dh1 -= abs(duh1) * phi11 + duh1 * psi11
    return dh0, dh1


@njit(inline="always")
def bw2_sigma(c: Coeffs2) -> float:  # pragma: no cover - compiled
    """:func:`bw_sigma` for two axes (same order of operations)."""
    s0 = 0.0 + abs(c[8]) + abs(c[12]) + abs(c[16]) + abs(c[20])
    s0 = s0 + abs(c[9]) + abs(c[13]) + abs(c[17]) + abs(c[21])
    s1 = 0.0 + abs(c[10]) + abs(c[14]) + abs(c[18]) + abs(c[22])
    s1 = s1 + abs(c[11]) + abs(c[15]) + abs(c[19]) + abs(c[23])
    sigma = 0.0
    if s0 > sigma:
        sigma = s0
    if s1 > sigma:
        sigma = s1
    return sigma


@njit(inline="always")
def bw2_path_weight(c: Coeffs2, sigma: float, du0: float, du1: float) -> float:  # pragma: no cover - compiled
    """:func:`path_weight` of the step ``du`` for two axes."""
    duh0 = 0.0 + c[24] * du0 + c[25] * du1
    duh1 = 0.0 + c[26] * du0 + c[27] * du1
    big = 0.0
    if abs(duh0) > big:
        big = abs(duh0)
    if abs(duh1) > big:
        big = abs(duh1)
    return path_weight(sigma, big)


@njit(inline="always")
def _bw2_orthant(c: Coeffs2, q0: float, q1: float, s0: float,
                 s1: float) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """:func:`_orthant_matrix` for two axes: ``(M00, M01, M10, M11)``."""
    m00 = -(abs(q0) * (c[8] + c[20] * s0) + q0 * (c[12] * s0 + c[16]))
    m01 = -(abs(q1) * (c[9] + c[21] * s1) + q1 * (c[13] * s1 + c[17]))
    m10 = -(abs(q0) * (c[10] + c[22] * s0) + q0 * (c[14] * s0 + c[18]))
    m11 = -(abs(q1) * (c[11] + c[23] * s1) + q1 * (c[15] * s1 + c[19]))
    return m00, m01, m10, m11


@njit(inline="always")
def _bw2_flow(m00: float, m01: float, m10: float, m11: float, a0: float, a1: float, h0: float, h1: float,
              t: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`_flow` for two axes (same numbers)."""
    acc = a0
    acc += m00 * h0
    acc += m01 * h1
    t0 = t * acc
    o0 = h0 + t0
    acc = a1
    acc += m10 * h0
    acc += m11 * h1
    t1 = t * acc
    o1 = h1 + t1
    for kk in range(2, SERIES_TERMS + 1):
        f = t * _INV[kk]
        acc = 0.0
        acc += m00 * t0
        acc += m01 * t1
        x0 = f * acc
        acc = 0.0
        acc += m10 * t0
        acc += m11 * t1
        x1 = f * acc
        big = 0.0
        scale = 0.0
        t0 = x0
        o0 += x0
        if abs(x0) > big:
            big = abs(x0)
        if abs(o0) > scale:
            scale = abs(o0)
        t1 = x1
        o1 += x1
        if abs(x1) > big:
            big = abs(x1)
        if abs(o1) > scale:
            scale = abs(o1)
        if not big > 1e-17 * scale:
            break
    return o0, o1


@njit
def _bw2_crossing(m00: float, m01: float, m10: float, m11: float, a0: float, a1: float, h0: float, h1: float,
                  j: int, sj: float, tau: float, fhi: float) -> float:  # pragma: no cover - compiled
    """:func:`_crossing` for two axes (same numbers)."""
    lo = 0.0
    hi = tau
    flo = sj * (h0 if j == 0 else h1)
    t = tau * flo / (flo - fhi)
    if not (t > lo and t < hi):
        t = 0.5 * (lo + hi)
    for _ in range(100):
        r0, r1 = _bw2_flow(m00, m01, m10, m11, a0, a1, h0, h1, t)
        f = sj * (r0 if j == 0 else r1)
        if f > 0.0:
            lo = t
        elif f < 0.0:
            hi = t
        else:
            return t
        if j == 0:
            acc = a0
            acc += m00 * r0
            acc += m01 * r1
        else:
            acc = a1
            acc += m10 * r0
            acc += m11 * r1
        d = sj * acc
        tn = 0.5 * (lo + hi)
        if d != 0.0:
            tn = t - f / d
            if not (tn > lo and tn < hi):
                tn = 0.5 * (lo + hi)
        if not abs(tn - t) > 4e-16 * tau or not hi - lo > 4e-16 * tau:
            return tn
        t = tn
    return t


@njit
def _bw2_long_path(c: Coeffs2, q0: float, q1: float, a0: float, a1: float, tau0: float, e0: float, e1: float,
                   lam: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`_long_path` for two axes (the generic one on the same numbers, out of line: a long path is rare)."""
    B = np.empty((2, 2))
    G = np.empty((2, 2))
    D1 = np.empty((2, 2))
    D2 = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            B[i, j] = c[8 + 2 * i + j]
            G[i, j] = c[12 + 2 * i + j]
            D1[i, j] = c[16 + 2 * i + j]
            D2[i, j] = c[20 + 2 * i + j]
    q = np.empty(2)
    q[0] = q0
    q[1] = q1
    a = np.empty(2)
    a[0] = a0
    a[1] = a1
    he = np.empty(2)
    he[0] = e0
    he[1] = e1
    _long_path(B, G, D1, D2, q, a, tau0, he, lam)
    return he[0], he[1]


@njit(inline="always")
def bw2_exact_path(c: Coeffs2, sigma: float, h0: float, h1: float, du0: float,
                   du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`bw_exact_path` for two axes (same numbers): h at the end of the path."""
    q0 = 0.0 + c[24] * du0 + c[25] * du1
    q1 = 0.0 + c[26] * du0 + c[27] * du1
    big = 0.0
    if abs(q0) > big:
        big = abs(q0)
    if abs(q1) > big:
        big = abs(q1)
    a0 = 0.0 + c[4] * du0 + c[5] * du1
    a1 = 0.0 + c[6] * du0 + c[7] * du1
    kap = sigma * big
    if not kap < np.inf:
        dh0, dh1 = bw2_increment(c, h0, h1, du0, du1)
        return h0 + dh0, h1 + dh1
    tau_max = 1.0
    if kap > PIECE_KAPPA:
        tau_max = PIECE_KAPPA / kap
    e0 = h0
    e1 = h1
    if kap > PIECE_KAPPA * LONG_PIECES:
        return _bw2_long_path(c, q0, q1, a0, a1, tau_max, e0, e1, 0.0)
    lam = 0.0
    for piece in range(MAX_PIECES):
        rem = 1.0 - lam
        if not rem > 0.0:
            break
        if piece == LONG_PIECES:
            return _bw2_long_path(c, q0, q1, a0, a1, tau_max, e0, e1, lam)
        s0 = 1.0 if e0 > 0.0 else (-1.0 if e0 < 0.0 else 0.0)
        s1 = 1.0 if e1 > 0.0 else (-1.0 if e1 < 0.0 else 0.0)
        m00, m01, m10, m11 = _bw2_orthant(c, q0, q1, s0, s1)
        if s0 == 0.0 or s1 == 0.0:
            d0 = a0
            d0 += m00 * e0
            d0 += m01 * e1
            d1 = a1
            d1 += m10 * e0
            d1 += m11 * e1
            if s0 == 0.0:
                s0 = -1.0 if d0 < 0.0 else 1.0
            if s1 == 0.0:
                s1 = -1.0 if d1 < 0.0 else 1.0
            m00, m01, m10, m11 = _bw2_orthant(c, q0, q1, s0, s1)
        tau = rem if rem < tau_max else tau_max
        x0, x1 = _bw2_flow(m00, m01, m10, m11, a0, a1, e0, e1, tau)
        tc = tau
        jc = -1
        if s0 * x0 < 0.0:
            t = _bw2_crossing(m00, m01, m10, m11, a0, a1, e0, e1, 0, s0, tau, s0 * x0)
            if t < tc:
                tc = t
                jc = 0
        if s1 * x1 < 0.0:
            t = _bw2_crossing(m00, m01, m10, m11, a0, a1, e0, e1, 1, s1, tau, s1 * x1)
            if t < tc:
                tc = t
                jc = 1
        if jc >= 0:
            x0, x1 = _bw2_flow(m00, m01, m10, m11, a0, a1, e0, e1, tc)
            if jc == 0:
                x0 = 0.0
            else:
                x1 = 0.0
            lam += tc
        else:
            lam += tau
        e0 = x0
        e1 = x1
        if jc < 0 and tau == rem:
            break
    return e0, e1


@njit
def _bw2_large_step(c: Coeffs2, sigma: float, w: float, h0: float, h1: float, du0: float,
                    du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """The increment ``dh`` of a step beyond one explicit step (``w ≥ 0``), as :func:`bw_path_increment`
    computes it (out of line: the per-sample loop keeps its one-step body small)."""
    e0, e1 = bw2_exact_path(c, sigma, h0, h1, du0, du1)
    if w < 1.0:
        i0, i1 = bw2_increment(c, h0, h1, du0, du1)
        hw0 = h0 + i0
        hw1 = h1 + i1
        return (hw0 + w * (e0 - hw0)) - h0, (hw1 + w * (e1 - hw1)) - h1
    return e0 - h0, e1 - h1


@njit(inline="always")
def bw2_path_increment(c: Coeffs2, sigma: float, h0: float, h1: float, du0: float,
                       du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """h after the step ``du`` along its straight path (:func:`bw_path_increment` for two axes, same numbers)."""
    w = bw2_path_weight(c, sigma, du0, du1)
    if w < 0.0:
        dh0, dh1 = bw2_increment(c, h0, h1, du0, du1)
        return h0 + dh0, h1 + dh1
    dh0, dh1 = _bw2_large_step(c, sigma, w, h0, h1, du0, du1)
    return h0 + dh0, h1 + dh1


@njit(inline="always")
def _bw2_path_dh(c: Coeffs2, sigma: float, h0: float, h1: float, du0: float,
                 du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """The increment ``dh`` of :func:`bw_path_increment` for two axes (same numbers)."""
    w = bw2_path_weight(c, sigma, du0, du1)
    if w < 0.0:
        return bw2_increment(c, h0, h1, du0, du1)
    return _bw2_large_step(c, sigma, w, h0, h1, du0, du1)


@njit
def _bw2_residual(c: Coeffs2, sigma: float, h0: float, h1: float, r0: float, r1: float, du0: float,
                  du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`_comp_residual` for two axes (same numbers)."""
    dh0, dh1 = _bw2_path_dh(c, sigma, h0, h1, du0, du1)
    f0 = -r0 - dh0
    f0 += c[0] * du0
    f0 += c[1] * du1
    f1 = -r1 - dh1
    f1 += c[2] * du0
    f1 += c[3] * du1
    return f0, f1


@njit
def bw2_refine(c: Coeffs2, sigma: float, h0: float, h1: float, r0: float, r1: float, du0: float,
               du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`bw_refine` for two axes (same numbers): the refined ``(du0, du1)``."""
    prev = np.inf
    for it in range(50):
        if it == 0 and bw2_path_weight(c, sigma, du0, du1) < 0.0:
            return du0, du1
        f0, f1 = _bw2_residual(c, sigma, h0, h1, r0, r1, du0, du1)
        size = max(max(0.0, abs(du0)), abs(du1))
        eps = 1e-7 * size
        if not eps > 0.0:
            return du0, du1
        v = du0 + eps
        e = v - du0
        g0, g1 = _bw2_residual(c, sigma, h0, h1, r0, r1, v, du1)
        m00 = (g0 - f0) / e
        m10 = (g1 - f1) / e
        v = du1 + eps
        e = v - du1
        g0, g1 = _bw2_residual(c, sigma, h0, h1, r0, r1, du0, v)
        m01 = (g0 - f0) / e
        m11 = (g1 - f1) / e
        b0 = -f0
        b1 = -f1
        # Cramer's rule (as solve_small for n = 2)
        det = m00 * m11 - m01 * m10
        if abs(det) < 1e-300:
            return du0, du1
        x0 = (b0 * m11 - m01 * b1) / det
        x1 = (m00 * b1 - m10 * b0) / det
        du0 += x0
        du1 += x1
        step = max(max(0.0, abs(x0)), abs(x1))
        size = max(max(0.0, abs(du0)), abs(du1))
        if not step > 4e-16 * size:
            return du0, du1
        if it >= 3 and not step < 0.5 * prev:
            return du0, du1
        prev = step
    return du0, du1


@njit(inline="always")
def bw2_model_step(c: Coeffs2, sigma: float, h0: float, h1: float, up0: float, up1: float, u0: float,
                   u1: float) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """One sample of the 2-axis model from the previous voltage ``up``: ``(h0, h1, y0, y1)`` after it (``sigma``
    from :func:`bw2_sigma`: the increment along the path, :func:`bw2_path_increment`)."""
    h0, h1 = bw2_path_increment(c, sigma, h0, h1, u0 - up0, u1 - up1)
    y0 = 0.0 + c[0] * u0 + c[1] * u1 - h0
    y1 = 0.0 + c[2] * u0 + c[3] * u1 - h1
    return h0, h1, y0, y1


@njit
def bw_model_run_2x2(coeffs: np.ndarray, h: np.ndarray, u_prev: np.ndarray, started: np.ndarray, u: np.ndarray,
                     y: np.ndarray, hs: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`bw_model_run` for two voltages and two outputs, state in registers (``coeffs`` from
    :func:`coeffs_2x2`)."""
    N = u.shape[0]
    if N == 0:
        return
    c = model_coeff_tuple(coeffs)
    sigma = bw2_sigma(c)
    if not started[0]:
        u_prev[0] = u[0, 0]
        u_prev[1] = u[0, 1]
        started[0] = True
    h0 = h[0]
    h1 = h[1]
    up0 = u_prev[0]
    up1 = u_prev[1]
    for t in range(N):
        u0 = u[t, 0]
        u1 = u[t, 1]
        h0, h1, y0, y1 = bw2_model_step(c, sigma, h0, h1, up0, up1, u0, u1)
        up0 = u0
        up1 = u1
        y[t, 0] = y0
        y[t, 1] = y1
        hs[t, 0] = h0
        hs[t, 1] = h1
    h[0] = h0
    h[1] = h1
    u_prev[0] = up0
    u_prev[1] = up1


@njit(inline="always")
def bw2_comp_step(c: Coeffs2, sigma: float, exact: bool, ulim: float, dulim: float, h0: float, h1: float, up0: float,
                  up1: float, sg0: float, sg1: float, y0: float,
                  y1: float) -> tuple[float, float, float, float, float, float, int, int]:  # pragma: no cover - compiled
    """One sample of :func:`bw_comp_run` for two axes after the first (``c`` from :func:`comp_coeffs_2x2`).

    Returns ``(h0, h1, up0, up1, sg0, sg1, fallbacks, saturated)``: the new state (``up`` is the output voltage)
    and this sample's counts.
    """
    dp00, dp01, dp10, dp11 = c[0], c[1], c[2], c[3]
    p00, p01, p10, p11 = c[24], c[25], c[26], c[27]
    q00, q01, q10, q11 = c[28], c[29], c[30], c[31]
    c00, c01, c10, c11 = c[32], c[33], c[34], c[35]
    n_fallback = 0
    n_saturated = 0
    du0 = 0.0
    du1 = 0.0
    solved = False
    if exact:
        r0 = y0 + h0 - dp00 * up0 - dp01 * up1
        r1 = y1 + h1 - dp10 * up0 - dp11 * up1
        phi00, phi01, phi10, phi11, psi00, psi01, psi10, psi11 = bw2_factors(c, h0, h1)
        for q in range(5):
            if q == 0:
                s0 = sg0
                s1 = sg1
            else:
                s0 = 1.0 if (q - 1) & 1 else -1.0
                s1 = 1.0 if ((q - 1) >> 1) & 1 else -1.0
            w00 = s0 * phi00 + psi00
            w01 = s1 * phi01 + psi01
            w10 = s0 * phi10 + psi10
            w11 = s1 * phi11 + psi11
            m00 = c00 + w00 * p00 + w01 * p10
            m01 = c01 + w00 * p01 + w01 * p11
            m10 = c10 + w10 * p00 + w11 * p10
            m11 = c11 + w10 * p01 + w11 * p11
            # Cramer's rule (as solve_small for n = 2)
            det = m00 * m11 - m01 * m10
            if abs(det) < 1e-300:
                continue
            du0 = (r0 * m11 - m01 * r1) / det
            du1 = (m00 * r1 - m10 * r0) / det
            if (0.0 + p00 * du0 + p01 * du1) * s0 < 0.0:
                continue
            if (0.0 + p10 * du0 + p11 * du1) * s1 < 0.0:
                continue
            solved = True
            sg0 = s0
            sg1 = s1
            break
        if not solved:
            n_fallback = 1
        elif bw2_path_weight(c, sigma, du0, du1) >= 0.0:
            du0, du1 = bw2_refine(c, sigma, h0, h1, r0, r1, du0, du1)
            if not (abs(du0) < np.inf and abs(du1) < np.inf):
                # beyond double precision (a reference of ~1e300 m): the delayed formula's direction
                solved = False
                n_fallback = 1
    if not solved:
        du0 = 0.0 + q00 * (y0 + h0) + q01 * (y1 + h1) - up0
        du1 = 0.0 + q10 * (y0 + h0) + q11 * (y1 + h1) - up1
    v0, fl0 = limit_step(up0, up0 + du0, ulim, dulim)
    v1, fl1 = limit_step(up1, up1 + du1, ulim, dulim)
    if not abs(v0) < np.inf:
        # no finite voltage (no limit and an overflowing reference, or inf − inf): hold the last one
        v0 = up0
        fl0 = CLAMPED
    if not abs(v1) < np.inf:
        v1 = up1
        fl1 = CLAMPED
    n_saturated = ((1 if fl0 & CLAMPED else 0) + (1 if fl0 & SLEWED else 0)
                   + (1 if fl1 & CLAMPED else 0) + (1 if fl1 & SLEWED else 0))
    h0, h1 = bw2_path_increment(c, sigma, h0, h1, v0 - up0, v1 - up1)
    return h0, h1, v0, v1, sg0, sg1, n_fallback, n_saturated


@njit(inline="always")
def bw2_comp_first(c: Coeffs2, ulim: float, y0: float, y1: float) -> tuple[float, float, int]:  # pragma: no cover - compiled
    """The compensator's first sample (h = 0, dU = 0 by definition: ``U = Dp⁻¹·Y_H``, clamped only):
    ``(u0, u1, saturated)``."""
    v0, f0 = limit_step(0.0, 0.0 + c[28] * y0 + c[29] * y1, ulim, np.inf)
    v1, f1 = limit_step(0.0, 0.0 + c[30] * y0 + c[31] * y1, ulim, np.inf)
    if not abs(v0) < np.inf:
        v0 = 0.0   # no finite voltage: the rest voltage of the definition
        f0 = CLAMPED
    if not abs(v1) < np.inf:
        v1 = 0.0
        f1 = CLAMPED
    return v0, v1, (1 if f0 & CLAMPED else 0) + (1 if f1 & CLAMPED else 0)


@njit
def bw_comp_run_2x2(coeffs: np.ndarray, st: CompState, opt: CompOptions, yh: np.ndarray, u: np.ndarray,
                    counters: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`bw_comp_run` for two axes, state and parameters in registers (``coeffs`` from
    :func:`comp_coeffs_2x2`)."""
    N = yh.shape[0]
    if N == 0:
        return
    c = coeff_tuple(coeffs)
    sigma = bw2_sigma(c)
    t0 = 0
    if not st.started[0]:
        v0, v1, nsat = bw2_comp_first(c, opt.ulim, yh[0, 0], yh[0, 1])
        counters[SATURATED] += nsat
        st.u_prev[0] = v0
        st.u_prev[1] = v1
        u[0, 0] = v0
        u[0, 1] = v1
        st.started[0] = True
        t0 = 1
    h0 = st.h[0]
    h1 = st.h[1]
    up0 = st.u_prev[0]
    up1 = st.u_prev[1]
    sg0 = st.signs[0]
    sg1 = st.signs[1]
    n_fallback = 0
    n_saturated = 0
    for t in range(t0, N):
        h0, h1, up0, up1, sg0, sg1, nf, ns = bw2_comp_step(c, sigma, opt.exact, opt.ulim, opt.dulim, h0, h1, up0, up1,
                                                           sg0, sg1, yh[t, 0], yh[t, 1])
        n_fallback += nf
        n_saturated += ns
        u[t, 0] = up0
        u[t, 1] = up1
    st.h[0] = h0
    st.h[1] = h1
    st.u_prev[0] = up0
    st.u_prev[1] = up1
    st.signs[0] = sg0
    st.signs[1] = sg1
    counters[FALLBACKS] += n_fallback
    counters[SATURATED] += n_saturated
