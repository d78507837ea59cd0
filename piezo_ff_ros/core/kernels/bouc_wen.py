"""Bouc-Wen kernels (paper Eq. 1–6): one generic increment, the model and the compensator loops (compiled, pure).

The increment of h for a voltage step dU (``dÛ = P·dU``)::

    dh = A·dU − B(|dÛ|∘h) − Γ(dÛ∘|h|) − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)
       = A·dU − Σ_j (|dÛ_j|·φ_ij + dÛ_j·ψ_ij),   φ_ij = B_ij h_j + Δ2_ij |h_j|,   ψ_ij = Γ_ij |h_j| + Δ1_ij h_j

(the grouped form is the one computed: φ and ψ depend on h only) is written once for any size (:func:`bw_increment`) and once for two axes with the parameters in registers
(:func:`bw2_increment`, 2.5–8× faster on the 2-axis tube).  Every ``*_2x2`` kernel is built from the per-sample
step functions below (:func:`bw2_model_step`, :func:`bw2_comp_step`) — which the fused chain kernels
(:mod:`.fused`) call too — and keeps the generic kernel's order of operations (``0.0 + …`` where a sum starts from
zero), so it gives the generic kernel's numbers; ``test/test_kernels.py`` checks that on random parameters.

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
           "bw_increment", "bw_model_run", "bw_model_rate_run", "bw_model_run_2x2", "bw_comp_run", "bw_comp_run_2x2", "solve_small",
           "coeffs_2x2", "bw2_factors", "bw2_increment", "bw2_model_step", "bw2_comp_step", "bw2_comp_first", "comp_coeffs_2x2",
           "coeff_tuple", "model_coeff_tuple"]

#: index in the compensator's counters: samples where no sign pattern was consistent (delayed formula used)
FALLBACKS = 0
#: index in the compensator's counters: axis-samples clamped to ±limit, plus axis-samples held back by the slew limit
SATURATED = 1
#: length of the compensator's counters array
N_COUNTERS = 2


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
    ``r ← a_smooth·r + (1 − a_smooth)·|dU|/dt`` (state ``rate`` [k]); B/Γ/Δ still see the true dU.  Used by the
    hysteresis-replacement effect (:class:`~piezo_ff_ros.core.models.effects.HysteresisStage`).
    """
    N = u.shape[0]
    k = u.shape[1]
    n = h.shape[0]
    du = np.zeros(k)
    dus = np.zeros(k)
    dh = np.zeros(n)
    duh = np.zeros(n)
    for t in range(N):
        if not started[0]:
            for j in range(k):
                u_prev[j] = u[t, j]
            started[0] = True
        for j in range(k):
            du[j] = u[t, j] - u_prev[j]
        bw_increment(p, h, du, dh, duh)
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
def bw_comp_run(p: BoucWenParams, Dp_pinv: np.ndarray, st: CompState, opt: CompOptions, yh: np.ndarray,
                u: np.ndarray, counters: np.ndarray) -> None:  # pragma: no cover - compiled
    """The inverse ``U = Dp⁻¹(Y_H + h)`` over a block ``yh [N, n]`` → ``u [N, k]`` (paper Eq. 6).

    Exact loop: given the signs of ``dÛ`` the increment of h is linear in dU, so each sign pattern gives a linear
    system ``(Dp − A + W·P)·dU = Y_H − Dp·U_prev + h``; the previous pattern is tried first, then all 2ⁿ, and the
    first consistent solution is kept (else the delayed formula, counted in ``counters[FALLBACKS]``).  The
    voltage then goes through :func:`~.limits.limit_step` (counted in ``counters[SATURATED]``).
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
    npat = 1 << n
    for t in range(N):
        if not started[0]:
            # first sample: h = 0 and dU = 0 by definition, U = Dp⁻¹·Y_H (clamped only: no previous voltage)
            for j in range(k):
                acc = 0.0
                for i in range(n):
                    acc += Dp_pinv[j, i] * yh[t, i]
                v, f = limit_step(0.0, acc, opt.ulim, np.inf)
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
        if not solved:
            for j in range(k):
                acc = 0.0
                for i in range(n):
                    acc += Dp_pinv[j, i] * (yh[t, i] + h[i])
                du[j] = acc - u_prev[j]
        for j in range(k):
            v, f = limit_step(u_prev[j], u_prev[j] + du[j], opt.ulim, opt.dulim)
            counters[SATURATED] += (1 if f & CLAMPED else 0) + (1 if f & SLEWED else 0)
            du[j] = v - u_prev[j]  # the step actually made: h follows the voltage output
            u_prev[j] = v
            u[t, j] = v
        bw_increment(p, h, du, dh, duh)
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
def bw2_model_step(c: Coeffs2, h0: float, h1: float, up0: float, up1: float, u0: float,
                   u1: float) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """One sample of the 2-axis model from the previous voltage ``up``: ``(h0, h1, y0, y1)`` after it."""
    dh0, dh1 = bw2_increment(c, h0, h1, u0 - up0, u1 - up1)
    h0 += dh0
    h1 += dh1
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
        h0, h1, y0, y1 = bw2_model_step(c, h0, h1, up0, up1, u0, u1)
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
def bw2_comp_step(c: Coeffs2, exact: bool, ulim: float, dulim: float, h0: float, h1: float, up0: float,
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
    if not solved:
        du0 = 0.0 + q00 * (y0 + h0) + q01 * (y1 + h1) - up0
        du1 = 0.0 + q10 * (y0 + h0) + q11 * (y1 + h1) - up1
    v0, fl0 = limit_step(up0, up0 + du0, ulim, dulim)
    v1, fl1 = limit_step(up1, up1 + du1, ulim, dulim)
    n_saturated = ((1 if fl0 & CLAMPED else 0) + (1 if fl0 & SLEWED else 0)
                   + (1 if fl1 & CLAMPED else 0) + (1 if fl1 & SLEWED else 0))
    dh0, dh1 = bw2_increment(c, h0, h1, v0 - up0, v1 - up1)
    return h0 + dh0, h1 + dh1, v0, v1, sg0, sg1, n_fallback, n_saturated


@njit(inline="always")
def bw2_comp_first(c: Coeffs2, ulim: float, y0: float, y1: float) -> tuple[float, float, int]:  # pragma: no cover - compiled
    """The compensator's first sample (h = 0, dU = 0 by definition: ``U = Dp⁻¹·Y_H``, clamped only):
    ``(u0, u1, saturated)``."""
    v0, f0 = limit_step(0.0, 0.0 + c[28] * y0 + c[29] * y1, ulim, np.inf)
    v1, f1 = limit_step(0.0, 0.0 + c[30] * y0 + c[31] * y1, ulim, np.inf)
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
        h0, h1, up0, up1, sg0, sg1, nf, ns = bw2_comp_step(c, opt.exact, opt.ulim, opt.dulim, h0, h1, up0, up1,
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
