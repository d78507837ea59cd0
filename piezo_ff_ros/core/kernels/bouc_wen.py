"""Bouc-Wen kernels (paper Eq. 1–6): one generic increment, the model and the compensator loops (compiled, pure).

The increment of h for a voltage step dU (``dÛ = P·dU``)::

    dh = A·dU − B(|dÛ|∘h) − Γ(dÛ∘|h|) − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)
       = A·dU − Σ_j (|dÛ_j|·φ_ij + dÛ_j·ψ_ij),   φ_ij = B_ij h_j + Δ2_ij |h_j|,   ψ_ij = Γ_ij |h_j| + Δ1_ij h_j

(the grouped form is the one computed: φ and ψ depend on h only) is written once for any size (:func:`bw_increment`) and once for two axes with the parameters in registers
(:func:`bw2_increment`, 2.5–8× faster on the 2-axis tube).

Bouc-Wen is rate independent: h depends on the voltage path, not on how fast it is followed.  One explicit step per
sample is accurate only while the step is small: its relative error grows with ``κ = σ·max_j |dÛ_j|``, σ the largest
row sum of ``|B| + |Γ| + |Δ1| + |Δ2|`` (42 % off on 100 V steps, ~0.1 % of the output with 1 V steps on the paper's
tube).  So a sample's increment is integrated along the straight voltage path (:func:`substep_split`,
:func:`bw_path_increment`, :func:`bw2_path_increment`): one explicit step while ``κ ≤`` :data:`KAPPA_MAX` (0.11 V per
sample on the paper's tube: its 0.1 Hz hysteresis sines and open-loop circles at 20 kHz), with exactly the numbers of
the single-step form; beyond, the blend ``(1 − θ)·H_m + θ·H_{m+1}`` of m and m + 1 equal explicit sub-steps,
``m + θ = κ / KAPPA_MAX`` (continuous in the step, so that it can be inverted).  The sub-steps have ``κ`` of about
:data:`KAPPA_MAX` whatever the sample rate: the model follows the continuous Bouc-Wen equally well at 100 Hz and at
20 kHz.  The compensator inverts the same path increment (Newton on the sub-step chains when one step is not
enough, :func:`bw_refine`, :func:`bw2_refine`), so the model and its inverse stay exact inverses and share h bit for
bit.

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
           "KAPPA_MAX", "MAX_SUBSTEPS", "substep_split", "bw_sigma", "bw_path_increment", "bw_path_jacobian",
           "bw_refine", "bw2_sigma", "bw2_substeps", "bw2_path_increment", "bw2_path_jacobian", "bw2_refine",
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
#: cap on the sub-steps of one sample (a 400 V step on the paper's tube needs ~3 700)
MAX_SUBSTEPS = 1 << 20


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
def substep_split(sigma: float, duh_max: float) -> tuple[int, float]:  # pragma: no cover - compiled
    """How a sample whose largest ``|dÛ_j|`` is ``duh_max`` is integrated: ``(m, θ)``.

    ``θ < 0``: one explicit step (``κ = σ·duh_max ≤ KAPPA_MAX``).  Else ``x = κ / KAPPA_MAX > 1``, ``m = ⌊x⌋`` and
    ``θ = x − m``: the increment is ``(1 − θ)·H_m + θ·H_{m+1}``, ``H_m`` the result of m equal explicit sub-steps.
    The blend makes h a continuous function of the step (plain ``⌈x⌉`` sub-steps jump where m changes, so the
    compensator could not invert the model there); at ``x → 1`` it is the one step.  Non-finite steps take one step
    (the result is non-finite anyway); at most :data:`MAX_SUBSTEPS`.
    """
    x = sigma * duh_max
    if x <= KAPPA_MAX:
        return 1, -1.0
    if x < MAX_SUBSTEPS * KAPPA_MAX:
        xr = x / KAPPA_MAX
        m = int(math.floor(xr))
        if m < 1:
            m = 1
        return m, xr - m
    if x != x:
        return 1, -1.0
    return MAX_SUBSTEPS, 0.0


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
def _bw_chain(p: BoucWenParams, m: int, h: np.ndarray, du: np.ndarray, hw: np.ndarray, dh: np.ndarray,
              duh: np.ndarray, ds: np.ndarray) -> None:  # pragma: no cover - compiled
    """``hw`` ← h after ``m`` equal explicit steps of ``du / m``."""
    n = h.shape[0]
    k = du.shape[0]
    for j in range(k):
        ds[j] = du[j] / m
    for i in range(n):
        hw[i] = h[i]
    for _ in range(m):
        bw_increment(p, hw, ds, dh, duh)
        for i in range(n):
            hw[i] += dh[i]


@njit
def bw_path_increment(p: BoucWenParams, sigma: float, h: np.ndarray, du: np.ndarray, dh: np.ndarray,
                      duh: np.ndarray, ds: np.ndarray, hw: np.ndarray,
                      hv: np.ndarray) -> None:  # pragma: no cover - compiled
    """``dh`` ← the increment of h along the straight voltage path ``du`` (:func:`substep_split`): exactly
    :func:`bw_increment` when one step is enough, else the blend of m and m + 1 equal explicit sub-steps.

    ``duh`` [n], ``ds`` [k], ``hw``, ``hv`` [n] are scratch; nothing is allocated.
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
    m, theta = substep_split(sigma, big)
    if theta < 0.0:
        bw_increment(p, h, du, dh, duh)
        return
    _bw_chain(p, m, h, du, hw, dh, duh, ds)
    _bw_chain(p, m + 1, h, du, hv, dh, duh, ds)
    for i in range(n):
        dh[i] = (hw[i] + theta * (hv[i] - hw[i])) - h[i]


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
    ds = np.zeros(k)
    dh = np.zeros(n)
    duh = np.zeros(n)
    hw = np.zeros(n)
    hv = np.zeros(n)
    sigma = bw_sigma(p)
    for t in range(N):
        if not started[0]:
            for j in range(k):
                u_prev[j] = u[t, j]
            started[0] = True
        for j in range(k):
            du[j] = u[t, j] - u_prev[j]
        bw_path_increment(p, sigma, h, du, dh, duh, ds, hw, hv)
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
def bw_path_jacobian(p: BoucWenParams, m: int, h: np.ndarray, du: np.ndarray, hw: np.ndarray, J: np.ndarray,
                     Jn: np.ndarray, ds: np.ndarray, dh: np.ndarray,
                     duh: np.ndarray) -> None:  # pragma: no cover - compiled
    """``hw`` ← h after ``m`` equal explicit sub-steps of ``du`` (as :func:`bw_path_increment`), ``J`` [n, k] ←
    ∂hw/∂du (forward differentiation through the sub-steps; ``Jn``, ``ds``, ``dh``, ``duh`` scratch)."""
    n = h.shape[0]
    k = du.shape[0]
    for j in range(k):
        ds[j] = du[j] / m
    for i in range(n):
        hw[i] = h[i]
        for j in range(k):
            J[i, j] = 0.0
    for _ in range(m):
        for l in range(n):
            acc = 0.0
            for j in range(k):
                acc += p.P[l, j] * ds[j]
            duh[l] = acc
        for i in range(n):
            for j in range(k):
                # direct term: (A − Σ_l (sgn(dÛ_l)·φ_il + ψ_il)·P_l) / m
                acc = p.A[i, j]
                for l in range(n):
                    ah = abs(hw[l])
                    sgn = 1.0 if duh[l] > 0.0 else (-1.0 if duh[l] < 0.0 else 0.0)
                    acc -= (sgn * (p.B[i, l] * hw[l] + p.D2[i, l] * ah) + (p.G[i, l] * ah + p.D1[i, l] * hw[l])) \
                        * p.P[l, j]
                acc /= m
                # through h: J + Σ_l ∂dh_i/∂h_l · J_lj
                g = J[i, j]
                for l in range(n):
                    sh = 1.0 if hw[l] > 0.0 else (-1.0 if hw[l] < 0.0 else 0.0)
                    dd = abs(duh[l]) * (p.B[i, l] + p.D2[i, l] * sh) + duh[l] * (p.G[i, l] * sh + p.D1[i, l])
                    g -= dd * J[l, j]
                Jn[i, j] = g + acc
        bw_increment(p, hw, ds, dh, duh)
        for i in range(n):
            hw[i] += dh[i]
            for j in range(k):
                J[i, j] = Jn[i, j]


@njit
def bw_refine(p: BoucWenParams, sigma: float, h: np.ndarray, r: np.ndarray, du: np.ndarray, ds: np.ndarray,
              hw: np.ndarray, hv: np.ndarray, J: np.ndarray, Jv: np.ndarray, Jn: np.ndarray, M: np.ndarray,
              G: np.ndarray, dh: np.ndarray, duh: np.ndarray, lu: np.ndarray,
              rhs: np.ndarray) -> None:  # pragma: no cover - compiled
    """Refine the one-step solution ``du`` of ``Dp·du − (h' − h) = r`` for the path increment (Newton).

    Nothing to do (``du`` untouched) when ``du`` takes one step; else Newton's iterations on the blend of the
    sub-step chains (:func:`bw_path_increment`, m and θ re-chosen from each iterate; θ's own, tiny, derivative is
    left out), from the one-step solution, until the correction is at rounding level (at most 50 iterations).
    """
    n = h.shape[0]
    k = du.shape[0]
    for it in range(50):
        big = 0.0
        for l in range(n):
            acc = 0.0
            for j in range(k):
                acc += p.P[l, j] * du[j]
            if abs(acc) > big:
                big = abs(acc)
        m, theta = substep_split(sigma, big)
        if theta < 0.0:
            if it == 0:
                return
            bw_path_jacobian(p, 1, h, du, hw, J, Jn, ds, dh, duh)
        else:
            bw_path_jacobian(p, m, h, du, hw, J, Jn, ds, dh, duh)
            bw_path_jacobian(p, m + 1, h, du, hv, Jv, Jn, ds, dh, duh)
            for i in range(n):
                hw[i] = hw[i] + theta * (hv[i] - hw[i])
                for j in range(k):
                    J[i, j] = J[i, j] + theta * (Jv[i, j] - J[i, j])
        for i in range(n):
            acc = -r[i] - (hw[i] - h[i])
            for j in range(k):
                acc += p.Dp[i, j] * du[j]
                M[i, j] = p.Dp[i, j] - J[i, j]
            G[i] = -acc
        if not solve_small(M, G, ds, lu, rhs):
            return
        step = 0.0
        size = 0.0
        for j in range(k):
            du[j] += ds[j]
            step = max(step, abs(ds[j]))
            size = max(size, abs(du[j]))
        if not step > 4e-16 * size:
            return


@njit
def bw_comp_run(p: BoucWenParams, Dp_pinv: np.ndarray, st: CompState, opt: CompOptions, yh: np.ndarray,
                u: np.ndarray, counters: np.ndarray) -> None:  # pragma: no cover - compiled
    """The inverse ``U = Dp⁻¹(Y_H + h)`` over a block ``yh [N, n]`` → ``u [N, k]`` (paper Eq. 6).

    Exact loop: given the signs of ``dÛ`` the increment of h is linear in dU, so each sign pattern gives a linear
    system ``(Dp − A + W·P)·dU = Y_H − Dp·U_prev + h``; the previous pattern is tried first, then all 2ⁿ, and the
    first consistent solution is kept (else the delayed formula, counted in ``counters[FALLBACKS]``).  A step that
    the model integrates in several sub-steps (:func:`bw_path_increment`) is then refined by Newton on the sub-step
    chain (:func:`bw_refine`), so that the model's output is again ``Y_H``.  The voltage then goes through :func:`~.limits.limit_step` (counted in ``counters[SATURATED]``).
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
    ds = np.zeros(k)
    hw = np.zeros(n)
    hv = np.zeros(n)
    J = np.zeros((n, k))
    Jv = np.zeros((n, k))
    Jn = np.zeros((n, k))
    G = np.zeros(n)
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
                bw_refine(p, sigma, h, r, du, ds, hw, hv, J, Jv, Jn, M, G, dh, duh, lu, rhs)
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
        bw_path_increment(p, sigma, h, du, dh, duh, ds, hw, hv)
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
def bw2_substeps(c: Coeffs2, sigma: float, du0: float, du1: float) -> tuple[int, float]:  # pragma: no cover - compiled
    """:func:`substep_split` of the step ``du`` for two axes."""
    duh0 = 0.0 + c[24] * du0 + c[25] * du1
    duh1 = 0.0 + c[26] * du0 + c[27] * du1
    big = 0.0
    if abs(duh0) > big:
        big = abs(duh0)
    if abs(duh1) > big:
        big = abs(duh1)
    return substep_split(sigma, big)


@njit(inline="always")
def bw2_path_increment(c: Coeffs2, sigma: float, h0: float, h1: float, du0: float,
                       du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """h after the step ``du`` along its straight path (:func:`bw_path_increment` for two axes, same numbers)."""
    m, theta = bw2_substeps(c, sigma, du0, du1)
    if theta < 0.0:
        dh0, dh1 = bw2_increment(c, h0, h1, du0, du1)
        return h0 + dh0, h1 + dh1
    return _bw2_blend(c, m, theta, h0, h1, du0, du1)


@njit
def _bw2_chain(c: Coeffs2, m: int, h0: float, h1: float, du0: float,
               du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """h after ``m`` equal explicit steps of ``du / m``."""
    d0 = du0 / m
    d1 = du1 / m
    for _ in range(m):
        dh0, dh1 = bw2_increment(c, h0, h1, d0, d1)
        h0 += dh0
        h1 += dh1
    return h0, h1


@njit
def _bw2_blend(c: Coeffs2, m: int, theta: float, h0: float, h1: float, du0: float,
               du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """``(1 − θ)·H_m + θ·H_{m+1}`` as :func:`bw_path_increment` computes it (out of line: the per-sample loop keeps
    its one-step body small)."""
    w0, w1 = _bw2_chain(c, m, h0, h1, du0, du1)
    v0, v1 = _bw2_chain(c, m + 1, h0, h1, du0, du1)
    dh0 = (w0 + theta * (v0 - w0)) - h0
    dh1 = (w1 + theta * (v1 - w1)) - h1
    return h0 + dh0, h1 + dh1


@njit(inline="always")
def _sgn(x: float) -> float:  # pragma: no cover - compiled
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


@njit
def bw2_path_jacobian(c: Coeffs2, m: int, h0: float, h1: float, du0: float,
                      du1: float) -> tuple[float, float, float, float, float, float]:  # pragma: no cover - compiled
    """:func:`bw_path_jacobian` for two axes (same numbers): ``(hw0, hw1, J00, J01, J10, J11)``."""
    a = (c[4], c[5], c[6], c[7])
    b = (c[8], c[9], c[10], c[11])
    g = (c[12], c[13], c[14], c[15])
    e1 = (c[16], c[17], c[18], c[19])
    e2 = (c[20], c[21], c[22], c[23])
    pp = (c[24], c[25], c[26], c[27])
    d0 = du0 / m
    d1 = du1 / m
    j00 = 0.0
    j01 = 0.0
    j10 = 0.0
    j11 = 0.0
    for _ in range(m):
        q0 = 0.0 + pp[0] * d0 + pp[1] * d1
        q1 = 0.0 + pp[2] * d0 + pp[3] * d1
        ah0 = abs(h0)
        ah1 = abs(h1)
        s0 = _sgn(q0)
        s1 = _sgn(q1)
        sh0 = _sgn(h0)
        sh1 = _sgn(h1)
        n00 = 0.0
        n01 = 0.0
        n10 = 0.0
        n11 = 0.0
        for i in range(2):
            # w_il = sgn(dÛ_l)·φ_il + ψ_il;  dd_il = ∂dh_i/∂h_l (as the generic loop)
            w0 = s0 * (b[2 * i] * h0 + e2[2 * i] * ah0) + (g[2 * i] * ah0 + e1[2 * i] * h0)
            w1 = s1 * (b[2 * i + 1] * h1 + e2[2 * i + 1] * ah1) + (g[2 * i + 1] * ah1 + e1[2 * i + 1] * h1)
            dd0 = abs(q0) * (b[2 * i] + e2[2 * i] * sh0) + q0 * (g[2 * i] * sh0 + e1[2 * i])
            dd1 = abs(q1) * (b[2 * i + 1] + e2[2 * i + 1] * sh1) + q1 * (g[2 * i + 1] * sh1 + e1[2 * i + 1])
            for j in range(2):
                acc = a[2 * i + j]
                acc -= w0 * pp[j]
                acc -= w1 * pp[2 + j]
                acc /= m
                if j == 0:
                    gj = j00 if i == 0 else j10
                    gj -= dd0 * j00
                    gj -= dd1 * j10
                else:
                    gj = j01 if i == 0 else j11
                    gj -= dd0 * j01
                    gj -= dd1 * j11
                if i == 0 and j == 0:
                    n00 = gj + acc
                elif i == 0:
                    n01 = gj + acc
                elif j == 0:
                    n10 = gj + acc
                else:
                    n11 = gj + acc
        dh0, dh1 = bw2_increment(c, h0, h1, d0, d1)
        h0 += dh0
        h1 += dh1
        j00, j01, j10, j11 = n00, n01, n10, n11
    return h0, h1, j00, j01, j10, j11


@njit
def bw2_refine(c: Coeffs2, sigma: float, h0: float, h1: float, r0: float, r1: float, du0: float,
               du1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`bw_refine` for two axes (same numbers): the refined ``(du0, du1)``."""
    for it in range(50):
        m, theta = bw2_substeps(c, sigma, du0, du1)
        if theta < 0.0:
            if it == 0:
                return du0, du1
            hw0, hw1, j00, j01, j10, j11 = bw2_path_jacobian(c, 1, h0, h1, du0, du1)
        else:
            hw0, hw1, j00, j01, j10, j11 = bw2_path_jacobian(c, m, h0, h1, du0, du1)
            hv0, hv1, v00, v01, v10, v11 = bw2_path_jacobian(c, m + 1, h0, h1, du0, du1)
            hw0 = hw0 + theta * (hv0 - hw0)
            j00 = j00 + theta * (v00 - j00)
            j01 = j01 + theta * (v01 - j01)
            hw1 = hw1 + theta * (hv1 - hw1)
            j10 = j10 + theta * (v10 - j10)
            j11 = j11 + theta * (v11 - j11)
        acc0 = -r0 - (hw0 - h0)
        acc0 += c[0] * du0
        acc0 += c[1] * du1
        acc1 = -r1 - (hw1 - h1)
        acc1 += c[2] * du0
        acc1 += c[3] * du1
        m00 = c[0] - j00
        m01 = c[1] - j01
        m10 = c[2] - j10
        m11 = c[3] - j11
        g0 = -acc0
        g1 = -acc1
        det = m00 * m11 - m01 * m10
        if abs(det) < 1e-300:
            return du0, du1
        x0 = (g0 * m11 - m01 * g1) / det
        x1 = (m00 * g1 - m10 * g0) / det
        du0 += x0
        du1 += x1
        step = max(max(0.0, abs(x0)), abs(x1))
        size = max(max(0.0, abs(du0)), abs(du1))
        if not step > 4e-16 * size:
            return du0, du1
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
        elif bw2_substeps(c, sigma, du0, du1)[1] >= 0.0:
            du0, du1 = bw2_refine(c, sigma, h0, h1, r0, r1, du0, du1)
    if not solved:
        du0 = 0.0 + q00 * (y0 + h0) + q01 * (y1 + h1) - up0
        du1 = 0.0 + q10 * (y0 + h0) + q11 * (y1 + h1) - up1
    v0, fl0 = limit_step(up0, up0 + du0, ulim, dulim)
    v1, fl1 = limit_step(up1, up1 + du1, ulim, dulim)
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
