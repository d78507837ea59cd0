"""Modal-bank kernels: block-diagonal state space ``x ← A x + B u``, ``y = C x + D u`` (compiled, pure).

One generic loop for any size and block shape (:func:`bank_run`, and :func:`inverse_affine_run` for the creep
compensator's ``Y_H = K⁻¹(Y_L − C x)`` loop), and a two-axis form where every block is stored as 2×2
(:func:`pad_to_2x2`: a 1×1 block gets a second state that stays exactly 0) and the per-sample work is in the step
functions :func:`bank2_step`, :func:`bank2_output`, :func:`bank2_update` — used by the block kernels here and by the
fused chain kernels (:mod:`.fused`).  Every sum runs in the generic kernel's order (state by state, then the
inputs), and the terms the padding and ``feeds`` leave out are exact zeros, so the two-axis kernels give the
generic kernels' numbers (``test/test_kernels.py``).
"""
from __future__ import annotations

import numpy as np

from .._jit import njit

__all__ = ["pad_to_2x2", "bank_run", "bank_run_2x2", "inverse_affine_run", "inverse_affine_run_2x2", "bank2_step",
           "bank2_output", "bank2_update", "inverse2_step", "gather_2x2", "scatter_2x2"]


def pad_to_2x2(Ablk: np.ndarray, io: np.ndarray, offsets: np.ndarray,
               sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block b's A and io rows at 2b, 2b+1; a 1×1 block gets a second state with all-zero coefficients.

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
    A_pad, io_pad : ndarray
        ``[2·blocks, 2]`` and ``[2·blocks, 4]``.
    feeds : ndarray
        ``feeds[b]``: bit 0 set if block b reaches output 0 (a non-zero in its C row), bit 1 for output 1 — a block
        from a SISO entry reaches only one.
    """
    nb = len(sizes)
    A_pad = np.zeros((2 * nb, 2))
    io_pad = np.zeros((2 * nb, io.shape[1]))
    for b, (off, s) in enumerate(zip(offsets, sizes)):
        A_pad[2 * b:2 * b + s, :s] = Ablk[off:off + s, :s]
        io_pad[2 * b:2 * b + s] = io[off:off + s]
    reach = io_pad[:, 2:4].reshape(nb, 2, 2) != 0.0  # [block, state, output]
    feeds = (np.any(reach[:, :, 0], axis=1) * 1 + np.any(reach[:, :, 1], axis=1) * 2).astype(np.int64)
    return A_pad, io_pad, feeds


# ------------------------------------------------------------------------------------------------ generic

@njit
def bank_run(Ablk: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray,
             x: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:  # pragma: no cover - compiled
    """``y = C x + D u; x ← A x + B u`` over a block ``u [N, n_in]`` (A block-diagonal, stored by
    :meth:`~piezo_ff_ros.core.lti.DiscreteModalSS.packed`)."""
    N = u.shape[0]
    n_in = u.shape[1]
    n_out = y.shape[1]
    ns = x.shape[0]
    nb = sizes.shape[0]
    xn = np.empty(ns)
    for k in range(N):
        for o in range(n_out):
            acc = 0.0
            for i in range(ns):
                acc += C[o, i] * x[i]
            for j in range(n_in):
                acc += D[o, j] * u[k, j]
            y[k, o] = acc
        for b in range(nb):
            off = offsets[b]
            s = sizes[b]
            for r in range(s):
                acc = 0.0
                for c in range(s):
                    acc += Ablk[off + r, c] * x[off + c]
                for j in range(n_in):
                    acc += B[off + r, j] * u[k, j]
                xn[off + r] = acc
        for i in range(ns):
            x[i] = xn[i]


@njit
def inverse_affine_run(Kinv: np.ndarray, Ablk: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, B: np.ndarray,
                       C: np.ndarray, x: np.ndarray, yl: np.ndarray, yh: np.ndarray) -> None:  # pragma: no cover - compiled
    """The creep compensator loop (paper Eq. 12): ``Y_H = K⁻¹(Y_L − C x)``, ``x ← A x + B Y_H`` (C strictly proper)."""
    N = yl.shape[0]
    n = yl.shape[1]
    ns = x.shape[0]
    nb = sizes.shape[0]
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
        for b in range(nb):
            off = offsets[b]
            s = sizes[b]
            for r in range(s):
                acc = 0.0
                for cc in range(s):
                    acc += Ablk[off + r, cc] * x[off + cc]
                for j in range(n):
                    acc += B[off + r, j] * yh[k, j]
                xn[off + r] = acc
        for i in range(ns):
            x[i] = xn[i]


# ------------------------------------------------------------------------------------------------ two axes, padded

@njit(inline="always")
def bank2_step(A: np.ndarray, io: np.ndarray, feeds: np.ndarray, xp: np.ndarray, u0: float,
               u1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """One sample of a padded two-axis bank: returns ``C x`` (old state) and steps ``xp`` with ``(u0, u1)``.

    One pass over the blocks: each block adds its old state to the outputs it reaches, then steps in place.
    """
    y0 = 0.0
    y1 = 0.0
    for b in range(feeds.shape[0]):
        i = 2 * b
        x0 = xp[i]
        x1 = xp[i + 1]
        f = feeds[b]
        if f & 1:
            y0 += io[i, 2] * x0
            y0 += io[i + 1, 2] * x1
        if f & 2:
            y1 += io[i, 3] * x0
            y1 += io[i + 1, 3] * x1
        xp[i] = A[i, 0] * x0 + A[i, 1] * x1 + io[i, 0] * u0 + io[i, 1] * u1
        xp[i + 1] = A[i + 1, 0] * x0 + A[i + 1, 1] * x1 + io[i + 1, 0] * u0 + io[i + 1, 1] * u1
    return y0, y1


@njit(inline="always")
def bank2_output(io: np.ndarray, feeds: np.ndarray, xp: np.ndarray) -> tuple[float, float]:  # pragma: no cover - compiled
    """``C x`` of a padded two-axis bank (the state is not changed)."""
    y0 = 0.0
    y1 = 0.0
    for b in range(feeds.shape[0]):
        i = 2 * b
        f = feeds[b]
        if f & 1:
            y0 += io[i, 2] * xp[i]
            y0 += io[i + 1, 2] * xp[i + 1]
        if f & 2:
            y1 += io[i, 3] * xp[i]
            y1 += io[i + 1, 3] * xp[i + 1]
    return y0, y1


@njit(inline="always")
def bank2_update(A: np.ndarray, io: np.ndarray, xp: np.ndarray, u0: float,
                 u1: float) -> None:  # pragma: no cover - compiled
    """``x ← A x + B u`` of a padded two-axis bank."""
    for i in range(0, xp.shape[0], 2):
        x0 = xp[i]
        x1 = xp[i + 1]
        xp[i] = A[i, 0] * x0 + A[i, 1] * x1 + io[i, 0] * u0 + io[i, 1] * u1
        xp[i + 1] = A[i + 1, 0] * x0 + A[i + 1, 1] * x1 + io[i + 1, 0] * u0 + io[i + 1, 1] * u1


@njit(inline="always")
def gather_2x2(offsets: np.ndarray, sizes: np.ndarray, x: np.ndarray, xp: np.ndarray) -> None:  # pragma: no cover - compiled
    """The public state ``x`` into the padded layout ``xp`` (padding states 0)."""
    for i in range(xp.shape[0]):
        xp[i] = 0.0
    for b in range(sizes.shape[0]):
        for r in range(sizes[b]):
            xp[2 * b + r] = x[offsets[b] + r]


@njit(inline="always")
def scatter_2x2(offsets: np.ndarray, sizes: np.ndarray, xp: np.ndarray, x: np.ndarray) -> None:  # pragma: no cover - compiled
    """The padded state ``xp`` back into the public layout ``x``."""
    for b in range(sizes.shape[0]):
        for r in range(sizes[b]):
            x[offsets[b] + r] = xp[2 * b + r]


@njit
def bank_run_2x2(A_pad: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, io_pad: np.ndarray, feeds: np.ndarray,
                 D: np.ndarray, x: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`bank_run` for two inputs, two outputs and 1×1 / 2×2 blocks (padded by :func:`pad_to_2x2`)."""
    N = u.shape[0]
    xp = np.empty(2 * sizes.shape[0])
    gather_2x2(offsets, sizes, x, xp)
    d00 = D[0, 0]
    d01 = D[0, 1]
    d10 = D[1, 0]
    d11 = D[1, 1]
    for k in range(N):
        u0 = u[k, 0]
        u1 = u[k, 1]
        y0, y1 = bank2_step(A_pad, io_pad, feeds, xp, u0, u1)
        y[k, 0] = y0 + d00 * u0 + d01 * u1
        y[k, 1] = y1 + d10 * u0 + d11 * u1
    scatter_2x2(offsets, sizes, xp, x)


@njit(inline="always")
def inverse2_step(Kinv: np.ndarray, A_pad: np.ndarray, io_pad: np.ndarray, feeds: np.ndarray, xp: np.ndarray,
                  yl0: float, yl1: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """One sample of :func:`inverse_affine_run` on a padded two-axis bank: returns ``Y_H`` and steps ``xp``."""
    s0, s1 = bank2_output(io_pad, feeds, xp)
    c0 = yl0 - s0
    c1 = yl1 - s1
    v0 = 0.0 + Kinv[0, 0] * c0 + Kinv[0, 1] * c1
    v1 = 0.0 + Kinv[1, 0] * c0 + Kinv[1, 1] * c1
    bank2_update(A_pad, io_pad, xp, v0, v1)
    return v0, v1


@njit
def inverse_affine_run_2x2(Kinv: np.ndarray, A_pad: np.ndarray, offsets: np.ndarray, sizes: np.ndarray,
                           io_pad: np.ndarray, feeds: np.ndarray, x: np.ndarray, yl: np.ndarray,
                           yh: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`inverse_affine_run` for two axes on a padded bank (:func:`pad_to_2x2`)."""
    N = yl.shape[0]
    xp = np.empty(2 * sizes.shape[0])
    gather_2x2(offsets, sizes, x, xp)
    for k in range(N):
        v0, v1 = inverse2_step(Kinv, A_pad, io_pad, feeds, xp, yl[k, 0], yl[k, 1])
        yh[k, 0] = v0
        yh[k, 1] = v1
    scatter_2x2(offsets, sizes, xp, x)
