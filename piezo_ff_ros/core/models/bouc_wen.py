"""Multivariable Bouc-Wen hysteresis (paper Eq. 1–3), classical and generalized, in explicit discrete form.

``h[k+1] = h[k] + A·dU − B(|dÛ|∘h[k]) − Γ(dÛ∘|h[k]|) − Δ1(dÛ∘h[k]) − Δ2(|dÛ|∘|h[k]|)``,
``dU = U[k+1] − U[k]``, ``dÛ = P·dU``, ``h[0] = 0``, ``Y = Dp·U − h``.

The first sample a fresh model sees defines its starting voltage (dU = 0 there), so ``h`` is exactly the state the
definition ``h[0] = 0`` gives.  The recursion runs in a compiled loop with the state carried between blocks:
results are bit-identical whatever the block split.
"""
from __future__ import annotations

from typing import Literal, overload

import numpy as np

from .._jit import njit
from ..config import BoucWenConfig

__all__ = ["BoucWenModel", "BoucWenState"]


class BoucWenState:
    """Carried state: the hysteresis vector ``h``, the previous voltage and whether a sample was seen."""

    __slots__ = ("h", "u_prev", "started")

    def __init__(self, n_out: int, n_in: int):
        self.h = np.zeros(n_out)
        self.u_prev = np.zeros(n_in)
        self.started = np.zeros(1, np.bool_)

    def copy(self) -> "BoucWenState":
        s = BoucWenState(len(self.h), len(self.u_prev))
        s.h[:] = self.h
        s.u_prev[:] = self.u_prev
        s.started[:] = self.started
        return s


class BoucWenModel:
    """Streaming Bouc-Wen model: ``process(U[N, k]) -> Y[N, n]`` with ``Y = Dp·U − h`` (metres, volts)."""

    def __init__(self, cfg: BoucWenConfig):
        self.cfg = cfg
        p = cfg.arrays()
        self._Dp, self._A, self._B, self._G = p["Dp"], p["A"], p["B"], p["Gamma"]
        self._D1, self._D2, self._P = p["Delta1"], p["Delta2"], p["P"]
        self.state = BoucWenState(cfg.n_out, cfg.n_in)

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.cfg.n_in

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.cfg.n_out

    def reset(self) -> None:
        """All states back to rest."""
        self.state = BoucWenState(self.cfg.n_out, self.cfg.n_in)

    @overload
    def process(self, u: np.ndarray, return_h: Literal[False] = ...) -> np.ndarray: ...
    @overload
    def process(self, u: np.ndarray, return_h: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...

    def process(self, u: np.ndarray, return_h: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Displacements ``y = Dp·u − h`` for the voltage block ``u`` [N, n_in] (state carried between blocks).

        Parameters
        ----------
        u : ndarray
            Voltages [V], shape [N, n_in].
        return_h : bool
            Also return the hysteresis term ``h`` [N, n_out].

        Returns
        -------
        y : ndarray
            [N, n_out] metres.
        h : ndarray
            Only with ``return_h``.
        """
        u = np.ascontiguousarray(u, dtype=float)
        if u.ndim != 2 or u.shape[1] != self.n_in:
            raise ValueError(f"expected a block of shape [N, {self.n_in}], got {u.shape}")
        y = np.empty((u.shape[0], self.n_out))
        hs = np.empty((u.shape[0], self.n_out))
        s = self.state
        run = _bw_model_run_2x2 if self.n_in == 2 and self.n_out == 2 else _bw_model_run
        run(self._Dp, self._A, self._B, self._G, self._D1, self._D2, self._P, s.h, s.u_prev, s.started, u, y, hs)
        return (y, hs) if return_h else y


@njit
def _bw_increment(A: np.ndarray, B: np.ndarray, G: np.ndarray, D1: np.ndarray, D2: np.ndarray, P: np.ndarray,
                  h: np.ndarray, du: np.ndarray, dh: np.ndarray, duh: np.ndarray) -> None:  # pragma: no cover - compiled
    """``dh`` ← the increment of h for the voltage step ``du``; ``duh`` is scratch (``P·du``), no allocation."""
    n = h.shape[0]
    k = du.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(k):
            acc += P[i, j] * du[j]
        duh[i] = acc
    for i in range(n):
        acc = 0.0
        for j in range(k):
            acc += A[i, j] * du[j]
        for j in range(n):
            ah = abs(h[j])
            ad = abs(duh[j])
            acc -= B[i, j] * ad * h[j] + G[i, j] * duh[j] * ah + D1[i, j] * duh[j] * h[j] + D2[i, j] * ad * ah
        dh[i] = acc


@njit
def _bw_model_run(Dp: np.ndarray, A: np.ndarray, B: np.ndarray, G: np.ndarray, D1: np.ndarray, D2: np.ndarray,
                  P: np.ndarray, h: np.ndarray, u_prev: np.ndarray, started: np.ndarray, u: np.ndarray, y: np.ndarray,
                  hs: np.ndarray) -> None:  # pragma: no cover - compiled
    N = u.shape[0]
    k = u.shape[1]
    n = h.shape[0]
    du = np.zeros(k)
    dh = np.zeros(n)
    duh = np.zeros(n)
    for t in range(N):
        if not started[0]:
            for j in range(k):
                u_prev[j] = u[t, j]
            started[0] = True
        for j in range(k):
            du[j] = u[t, j] - u_prev[j]
        _bw_increment(A, B, G, D1, D2, P, h, du, dh, duh)
        for i in range(n):
            h[i] += dh[i]
        for j in range(k):
            u_prev[j] = u[t, j]
        for i in range(n):
            acc = 0.0
            for j in range(k):
                acc += Dp[i, j] * u[t, j]
            y[t, i] = acc - h[i]
            hs[t, i] = h[i]


@njit
def _bw_model_run_2x2(Dp: np.ndarray, A: np.ndarray, B: np.ndarray, G: np.ndarray, D1: np.ndarray, D2: np.ndarray,
                      P: np.ndarray, h: np.ndarray, u_prev: np.ndarray, started: np.ndarray, u: np.ndarray,
                      y: np.ndarray, hs: np.ndarray) -> None:  # pragma: no cover - compiled
    """``_bw_model_run`` unrolled for two voltages and two outputs (the 2-axis tube): parameters and state in
    registers, ≈ 8× faster.  Every expression keeps the generic kernel's order of operations (``0.0 + …`` where
    it starts a sum from zero), so the results are the same numbers."""
    N = u.shape[0]
    if N == 0:
        return
    dp00, dp01, dp10, dp11 = Dp[0, 0], Dp[0, 1], Dp[1, 0], Dp[1, 1]
    a00, a01, a10, a11 = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    b00, b01, b10, b11 = B[0, 0], B[0, 1], B[1, 0], B[1, 1]
    g00, g01, g10, g11 = G[0, 0], G[0, 1], G[1, 0], G[1, 1]
    e00, e01, e10, e11 = D1[0, 0], D1[0, 1], D1[1, 0], D1[1, 1]
    f00, f01, f10, f11 = D2[0, 0], D2[0, 1], D2[1, 0], D2[1, 1]
    p00, p01, p10, p11 = P[0, 0], P[0, 1], P[1, 0], P[1, 1]
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
        du0 = u0 - up0
        du1 = u1 - up1
        duh0 = 0.0 + p00 * du0 + p01 * du1
        duh1 = 0.0 + p10 * du0 + p11 * du1
        ah0 = abs(h0)
        ah1 = abs(h1)
        ad0 = abs(duh0)
        ad1 = abs(duh1)
        dh0 = 0.0 + a00 * du0 + a01 * du1
        dh0 -= b00 * ad0 * h0 + g00 * duh0 * ah0 + e00 * duh0 * h0 + f00 * ad0 * ah0
        dh0 -= b01 * ad1 * h1 + g01 * duh1 * ah1 + e01 * duh1 * h1 + f01 * ad1 * ah1
        dh1 = 0.0 + a10 * du0 + a11 * du1
        dh1 -= b10 * ad0 * h0 + g10 * duh0 * ah0 + e10 * duh0 * h0 + f10 * ad0 * ah0
        dh1 -= b11 * ad1 * h1 + g11 * duh1 * ah1 + e11 * duh1 * h1 + f11 * ad1 * ah1
        h0 += dh0
        h1 += dh1
        up0 = u0
        up1 = u1
        y[t, 0] = 0.0 + dp00 * u0 + dp01 * u1 - h0
        y[t, 1] = 0.0 + dp10 * u0 + dp11 * u1 - h1
        hs[t, 0] = h0
        hs[t, 1] = h1
    h[0] = h0
    h[1] = h1
    u_prev[0] = up0
    u_prev[1] = up1
