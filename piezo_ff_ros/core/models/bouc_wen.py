"""Multivariable Bouc-Wen hysteresis (paper Eq. 1–3), classical and generalized, in explicit discrete form.

``h[k+1] = h[k] + A·dU − B(|dÛ|∘h[k]) − Γ(dÛ∘|h[k]|) − Δ1(dÛ∘h[k]) − Δ2(|dÛ|∘|h[k]|)``,
``dU = U[k+1] − U[k]``, ``dÛ = P·dU``, ``h[0] = 0``, ``Y = Dp·U − h``.

The first sample a fresh model sees defines its starting voltage (dU = 0 there), so ``h`` is exactly the state the
definition ``h[0] = 0`` gives.  The recursion runs in a compiled loop with the state carried between blocks:
results are bit-identical whatever the block split.
"""
from __future__ import annotations

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
        return self.cfg.n_in

    @property
    def n_out(self) -> int:
        return self.cfg.n_out

    def reset(self) -> None:
        self.state = BoucWenState(self.cfg.n_out, self.cfg.n_in)

    def process(self, u: np.ndarray, return_h: bool = False):
        u = np.ascontiguousarray(u, dtype=float)
        if u.ndim != 2 or u.shape[1] != self.n_in:
            raise ValueError(f"expected a block of shape [N, {self.n_in}], got {u.shape}")
        y = np.empty((u.shape[0], self.n_out))
        hs = np.empty((u.shape[0], self.n_out))
        s = self.state
        _bw_model_run(self._Dp, self._A, self._B, self._G, self._D1, self._D2, self._P,
                      s.h, s.u_prev, s.started, u, y, hs)
        return (y, hs) if return_h else y


@njit
def _bw_increment(A, B, G, D1, D2, P, h, du, dh):  # pragma: no cover - compiled
    n = h.shape[0]
    k = du.shape[0]
    duh = np.zeros(n)
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
def _bw_model_run(Dp, A, B, G, D1, D2, P, h, u_prev, started, u, y, hs):  # pragma: no cover - compiled
    N = u.shape[0]
    k = u.shape[1]
    n = h.shape[0]
    du = np.zeros(k)
    dh = np.zeros(n)
    for t in range(N):
        if not started[0]:
            for j in range(k):
                u_prev[j] = u[t, j]
            started[0] = True
        for j in range(k):
            du[j] = u[t, j] - u_prev[j]
        _bw_increment(A, B, G, D1, D2, P, h, du, dh)
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
