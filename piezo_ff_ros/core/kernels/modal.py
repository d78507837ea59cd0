"""Modal-bank kernels: block-diagonal state space ``x ← A x + B u``, ``y = C x + D u`` (compiled, pure).

One generic loop for any size and block shape (:func:`bank_run`, and :func:`inverse_affine_run` for the creep
compensator's ``Y_H = K⁻¹(Y_L − C x)`` loop), and a two-axis form where every block is stored as 2×2
(:func:`pad_to_2x2`: a table of per-block coefficients, a 1×1 block getting a second state that stays exactly 0) and
the per-sample work is in the step
functions :func:`bank2_step`, :func:`bank2_output`, :func:`bank2_update` — used by the block kernels here and by the
fused chain kernels (:mod:`.fused`).  Every sum runs in the generic kernel's order (state by state, then the
inputs), and the terms the padding and ``feeds`` leave out are exact zeros, so the two-axis kernels give the
generic kernels' numbers (``test/test_kernels.py``).
"""
from __future__ import annotations

import numpy as np

from .._jit import njit

__all__ = ["A_PP", "A_PQ", "A_QP", "A_QQ", "B_P0", "B_P1", "B_Q0", "B_Q1", "C_0P", "C_0Q", "C_1P", "C_1Q", "pad_to_2x2", "bank_run", "bank_run_2x2", "inverse_affine_run", "inverse_affine_run_2x2", "bank2_step",
           "bank2_output", "bank2_update", "inverse2_step", "gather_2x2", "scatter_2x2",
           "bank2_loop", "inverse2_loop"]


#: rows of a two-axis bank's coefficient table ``W [12, blocks]`` (block b's states are p = ``x[off]``,
#: q = ``x[off + 1]``; a 1×1 block has q ≡ 0 and zero coefficients on it)
A_PP, A_PQ, A_QP, A_QQ, B_P0, B_P1, B_Q0, B_Q1, C_0P, C_0Q, C_1P, C_1Q = range(12)


def pad_to_2x2(Ablk: np.ndarray, io: np.ndarray, offsets: np.ndarray,
               sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A two-axis bank as a table of per-block coefficients (structure of arrays, every block 2×2).

    Parameters
    ----------
    Ablk, offsets : ndarray
        From :meth:`~piezo_ff_ros.core.lti.DiscreteModalSS.packed`.
    io : ndarray
        From :meth:`~piezo_ff_ros.core.lti.DiscreteModalSS.packed_io` (two inputs, two outputs).
    sizes : ndarray
        The block sizes (1 or 2).

    Returns
    -------
    W : ndarray
        ``[12, blocks]``, rows :data:`A_PP` … :data:`C_1Q`; a 1×1 block gets a second state with all-zero
        coefficients (it stays exactly 0).
    feeds : ndarray
        ``feeds[b]``: bit 0 set if block b reaches output 0 (a non-zero in its C row), bit 1 for output 1 — a block
        from a SISO entry reaches only one.
    """
    nb = len(sizes)
    W = np.zeros((12, nb))
    for b, (off, s) in enumerate(zip(offsets, sizes)):
        W[A_PP, b] = Ablk[off, 0]
        W[B_P0, b], W[B_P1, b], W[C_0P, b], W[C_1P, b] = io[off]
        if s == 2:
            W[A_PQ, b] = Ablk[off, 1]
            W[A_QP, b], W[A_QQ, b] = Ablk[off + 1, 0], Ablk[off + 1, 1]
            W[B_Q0, b], W[B_Q1, b], W[C_0Q, b], W[C_1Q, b] = io[off + 1]
    reach0 = (W[C_0P] != 0.0) | (W[C_0Q] != 0.0)
    reach1 = (W[C_1P] != 0.0) | (W[C_1Q] != 0.0)
    feeds = (reach0 * 1 + reach1 * 2).astype(np.int64)
    return np.ascontiguousarray(W), feeds


# ------------------------------------------------------------------------------------------------ generic

@njit(inline="always")
def _advance(Ablk: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, B: np.ndarray, x: np.ndarray, xn: np.ndarray,
             u: np.ndarray) -> None:  # pragma: no cover - compiled
    """``x ← A x + B u`` block by block (``xn`` is scratch), each sum state by state then input by input."""
    for b in range(sizes.shape[0]):
        off = offsets[b]
        s = sizes[b]
        for r in range(s):
            acc = 0.0
            for c in range(s):
                acc += Ablk[off + r, c] * x[off + c]
            for j in range(u.shape[0]):
                acc += B[off + r, j] * u[j]
            xn[off + r] = acc
    for i in range(x.shape[0]):
        x[i] = xn[i]


@njit
def bank_run(Ablk: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray,
             x: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:  # pragma: no cover - compiled
    """``y = C x + D u; x ← A x + B u`` over a block ``u [N, n_in]`` (A block-diagonal, stored by
    :meth:`~piezo_ff_ros.core.lti.DiscreteModalSS.packed`)."""
    N = u.shape[0]
    n_in = u.shape[1]
    n_out = y.shape[1]
    ns = x.shape[0]
    xn = np.empty(ns)
    for k in range(N):
        for o in range(n_out):
            acc = 0.0
            for i in range(ns):
                acc += C[o, i] * x[i]
            for j in range(n_in):
                acc += D[o, j] * u[k, j]
            y[k, o] = acc
        _advance(Ablk, offsets, sizes, B, x, xn, u[k])


@njit
def inverse_affine_run(Kinv: np.ndarray, Ablk: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, B: np.ndarray,
                       C: np.ndarray, x: np.ndarray, yl: np.ndarray, yh: np.ndarray) -> None:  # pragma: no cover - compiled
    """The creep compensator loop (paper Eq. 12): ``Y_H = K⁻¹(Y_L − C x)``, ``x ← A x + B Y_H`` (C strictly proper)."""
    N = yl.shape[0]
    n = yl.shape[1]
    ns = x.shape[0]
    xn = np.empty(ns)
    c = np.empty(n)
    for k in range(N):
        for o in range(n):
            acc = 0.0
            for i in range(ns):
                acc += C[o, i] * x[i]
            c[o] = yl[k, o] - acc
        for o in range(n):
            acc = 0.0
            for j in range(n):
                acc += Kinv[o, j] * c[j]
            yh[k, o] = acc
        _advance(Ablk, offsets, sizes, B, x, xn, yh[k])


# ------------------------------------------------------------------------------------------------ two axes, padded

@njit(inline="always")
def bank2_output(W: np.ndarray, feeds: np.ndarray, xp: np.ndarray) -> tuple[float, float]:  # pragma: no cover - compiled
    """``C x`` of a two-axis bank (state ``xp [2, blocks]``: p then q), summed state by state as :func:`bank_run`."""
    y0 = 0.0
    y1 = 0.0
    for b in range(feeds.shape[0]):
        f = feeds[b]
        if f & 1:
            y0 += W[8, b] * xp[0, b]
            y0 += W[9, b] * xp[1, b]
        if f & 2:
            y1 += W[10, b] * xp[0, b]
            y1 += W[11, b] * xp[1, b]
    return y0, y1


@njit(inline="always")
def bank2_update(W: np.ndarray, xp: np.ndarray, u0: float, u1: float) -> None:  # pragma: no cover - compiled
    """``x ← A x + B u`` of a two-axis bank (independent blocks: one vectorisable loop)."""
    for b in range(xp.shape[1]):
        p = xp[0, b]
        q = xp[1, b]
        xp[0, b] = W[0, b] * p + W[1, b] * q + W[4, b] * u0 + W[5, b] * u1
        xp[1, b] = W[2, b] * p + W[3, b] * q + W[6, b] * u0 + W[7, b] * u1


@njit(inline="always")
def bank2_step(W: np.ndarray, feeds: np.ndarray, xp: np.ndarray, u0: float,
               u1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """One sample of a two-axis bank: returns ``C x`` (old state) and steps ``xp`` with ``(u0, u1)``.

    One pass over the blocks: each block adds its old state to the outputs it reaches, then steps in place.
    """
    y0 = 0.0
    y1 = 0.0
    for b in range(feeds.shape[0]):
        p = xp[0, b]
        q = xp[1, b]
        f = feeds[b]
        if f & 1:
            y0 += W[8, b] * p
            y0 += W[9, b] * q
        if f & 2:
            y1 += W[10, b] * p
            y1 += W[11, b] * q
        xp[0, b] = W[0, b] * p + W[1, b] * q + W[4, b] * u0 + W[5, b] * u1
        xp[1, b] = W[2, b] * p + W[3, b] * q + W[6, b] * u0 + W[7, b] * u1
    return y0, y1


@njit(inline="always")
def gather_2x2(offsets: np.ndarray, sizes: np.ndarray, x: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """The public state ``x`` in the two-axis layout ``[2, blocks]`` (the q of a 1×1 block is 0), a new array."""
    nb = sizes.shape[0]
    xp = np.zeros((2, nb))
    for b in range(nb):
        for r in range(sizes[b]):
            xp[r, b] = x[offsets[b] + r]
    return xp


@njit(inline="always")
def scatter_2x2(offsets: np.ndarray, sizes: np.ndarray, xp: np.ndarray, x: np.ndarray) -> None:  # pragma: no cover - compiled
    """The two-axis state ``xp`` back into the public layout ``x``."""
    for b in range(sizes.shape[0]):
        for r in range(sizes[b]):
            x[offsets[b] + r] = xp[r, b]


@njit
def bank2_loop(W: np.ndarray, feeds: np.ndarray, D: np.ndarray, xp: np.ndarray, src: np.ndarray, dst: np.ndarray,
               n: int) -> None:  # pragma: no cover - compiled
    """``n`` samples of a two-axis bank (state ``xp`` in the two-axis layout); ``dst`` may be ``src``."""
    d00 = D[0, 0]
    d01 = D[0, 1]
    d10 = D[1, 0]
    d11 = D[1, 1]
    for k in range(n):
        u0 = src[k, 0]
        u1 = src[k, 1]
        y0, y1 = bank2_step(W, feeds, xp, u0, u1)
        dst[k, 0] = y0 + d00 * u0 + d01 * u1
        dst[k, 1] = y1 + d10 * u0 + d11 * u1


@njit
def bank_run_2x2(Win: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, feeds: np.ndarray, D: np.ndarray,
                 x: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`bank_run` for two inputs, two outputs and 1×1 / 2×2 blocks (``Win``, ``feeds`` from
    :func:`pad_to_2x2`)."""
    W = Win.copy()  # local: the compiler then knows it cannot alias the state
    xp = gather_2x2(offsets, sizes, x)
    bank2_loop(W, feeds, D, xp, u, y, u.shape[0])
    scatter_2x2(offsets, sizes, xp, x)


@njit(inline="always")
def inverse2_step(Kinv: np.ndarray, W: np.ndarray, feeds: np.ndarray, xp: np.ndarray, yl0: float,
                  yl1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """One sample of :func:`inverse_affine_run` on a two-axis bank: returns ``Y_H`` and steps ``xp``."""
    s0, s1 = bank2_output(W, feeds, xp)
    c0 = yl0 - s0
    c1 = yl1 - s1
    v0 = 0.0 + Kinv[0, 0] * c0 + Kinv[0, 1] * c1
    v1 = 0.0 + Kinv[1, 0] * c0 + Kinv[1, 1] * c1
    bank2_update(W, xp, v0, v1)
    return v0, v1


@njit
def inverse2_loop(Kinv: np.ndarray, W: np.ndarray, feeds: np.ndarray, xp: np.ndarray, src: np.ndarray,
                  dst: np.ndarray, n: int) -> None:  # pragma: no cover - compiled
    """``n`` samples of the two-axis creep inverse (state ``xp`` in the two-axis layout); ``dst`` may be ``src``."""
    for k in range(n):
        v0, v1 = inverse2_step(Kinv, W, feeds, xp, src[k, 0], src[k, 1])
        dst[k, 0] = v0
        dst[k, 1] = v1


@njit
def inverse_affine_run_2x2(Kinv: np.ndarray, Win: np.ndarray, offsets: np.ndarray, sizes: np.ndarray,
                           feeds: np.ndarray, x: np.ndarray, yl: np.ndarray,
                           yh: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`inverse_affine_run` for two axes (``Win``, ``feeds`` from :func:`pad_to_2x2`)."""
    W = Win.copy()
    xp = gather_2x2(offsets, sizes, x)
    inverse2_loop(Kinv, W, feeds, xp, yl, yh, yl.shape[0])
    scatter_2x2(offsets, sizes, xp, x)
