"""Multivariable hysteresis compensator, inverse multiplicative structure (paper Eq. 5–6, Fig. 5).

``U = Dp⁻¹(Y_H + h)`` with ``h = H(U)`` the Bouc-Wen state driven by the compensator's own output: no inversion
of the nonlinear operator, the compensator's parameters are the model's.

In discrete time ``h[k]`` depends on ``U[k]`` (through ``dU = U[k] − U[k−1]``), so Eq. 6 is implicit at every
sample.  ``loop='exact'`` solves it: given the signs of ``dÛ`` the increment of h is linear in dU, so each of the
2ⁿ sign patterns gives a linear system and the consistent one is kept (n = 2 → at most four 2×2 solves; the
previous pattern is tried first).  The compensator is then the exact inverse of the discrete model
(``model ∘ compensator = identity`` to rounding).  ``loop='delayed'`` uses ``h[k−1]``, i.e. a unit delay in the
loop as a Simulink implementation would have; its error is one sample's increment of h.
"""
from __future__ import annotations

import numpy as np

from .._jit import njit
from ..config import BoucWenConfig
from ..models.bouc_wen import BoucWenState, _bw_increment, _bw_model_run, _bw_model_run_2x2
from ..stage import StageState

__all__ = ["HysteresisCompensator"]


class HysteresisCompensator:
    """Streaming ``Y_H [m] → U [V]``; ``process(block[N, n]) -> block[N, k]``."""

    def __init__(self, cfg: BoucWenConfig, loop: str = "exact", voltage_limit: float | None = None,
                 slew_per_sample: float | None = None):
        if loop not in ("exact", "delayed"):
            raise ValueError("loop must be 'exact' or 'delayed'")
        if loop == "exact" and cfg.n_in != cfg.n_out:
            loop = "delayed"  # the exact per-sample solve needs a square system
        self.cfg = cfg
        self.loop = loop
        p = cfg.arrays()
        self._Dp, self._A, self._B, self._G = p["Dp"], p["A"], p["B"], p["Gamma"]
        self._D1, self._D2, self._P = p["Delta1"], p["Delta2"], p["P"]
        self._Dp_pinv = np.linalg.pinv(self._Dp)
        self.bw_state = BoucWenState(cfg.n_out, cfg.n_in)
        self._signs = np.ones(cfg.n_out)
        self.fallbacks = 0  #: samples where no sign pattern was consistent (delayed formula used instead)
        # Saturating here (as the amplifier will) keeps the internal h equal to the plant's even when a reference
        # asks for more than the actuator can give.
        self.voltage_limit = float(voltage_limit) if voltage_limit is not None else np.inf
        self.saturated = 0  #: samples clamped to the voltage limit or held back by the slew limit
        # Same order as the driver's guard (core/safety.py): clamp to ±limit, then at most this many volts per sample.
        self.slew_per_sample = float(slew_per_sample) if slew_per_sample is not None else np.inf

    @property
    def n_in(self) -> int:
        """Number of input columns."""
        return self.cfg.n_out

    @property
    def n_out(self) -> int:
        """Number of output columns."""
        return self.cfg.n_in

    def reset(self) -> None:
        """All states back to rest."""
        self.bw_state = BoucWenState(self.cfg.n_out, self.cfg.n_in)
        self._signs[:] = 1.0
        self.fallbacks = 0
        self.saturated = 0

    def process(self, yh: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        yh = np.ascontiguousarray(yh, dtype=float)
        if yh.ndim != 2 or yh.shape[1] != self.n_in:
            raise ValueError(f"expected a block of shape [N, {self.n_in}], got {yh.shape}")
        u = np.empty((yh.shape[0], self.n_out))
        s = self.bw_state
        fb = np.zeros(2, np.int64)
        run = _bw_comp_run_2x2 if self.n_in == 2 and self.n_out == 2 else _bw_comp_run
        run(self._Dp, self._Dp_pinv, self._A, self._B, self._G, self._D1, self._D2, self._P,
            s.h, s.u_prev, s.started, self._signs, self.loop == "exact", self.voltage_limit, self.slew_per_sample, yh, u, fb)
        self.fallbacks += int(fb[0])
        self.saturated += int(fb[1])
        return u

    @property
    def h(self) -> np.ndarray:
        return self.bw_state.h.copy()

    # ``state`` is the Stage method; the Bouc-Wen state object itself is ``bw_state``
    def state(self) -> dict[str, np.ndarray]:
        """``h``, the last output voltage, whether a sample was seen, and the last sign pattern (copies)."""
        s = self.bw_state
        return {"h": s.h.copy(), "u_prev": s.u_prev.copy(), "started": s.started.copy(), "signs": self._signs.copy()}

    def load_state(self, state: StageState) -> None:
        """Copy ``state`` (as returned by :meth:`state`) into this stage."""
        s = self.bw_state
        s.h[:] = state["h"]
        s.u_prev[:] = state["u_prev"]
        s.started[:] = state["started"]
        self._signs[:] = state["signs"]

    def continue_from(self, old: "HysteresisCompensator") -> None:
        """Take over ``old``'s state: h and the last voltage describe the plant, whatever the new parameters."""
        self.load_state(old.state())

    def follow(self, u: np.ndarray) -> np.ndarray:
        """Advance the state as if this stage had output the voltages ``u`` (e.g. what the driver applied);
        returns ``Y_H = Dp·U − h`` consistent with them (the input the creep stage before it should have seen)."""
        u = np.ascontiguousarray(u, dtype=float)
        y = np.empty((u.shape[0], self.n_in))
        hs = np.empty((u.shape[0], self.n_in))
        s = self.bw_state
        run = _bw_model_run_2x2 if self.n_in == 2 and self.n_out == 2 else _bw_model_run
        run(self._Dp, self._A, self._B, self._G, self._D1, self._D2, self._P, s.h, s.u_prev, s.started, u, y, hs)
        return y


@njit
def _solve_small(M: np.ndarray, r: np.ndarray, x: np.ndarray, a: np.ndarray,
                 b: np.ndarray) -> bool:  # pragma: no cover - compiled
    """Gaussian elimination with partial pivoting for a small dense system; False if singular.

    ``a`` (n×n) and ``b`` (n) are scratch for the factorisation: nothing is allocated per call.
    """
    n = r.shape[0]
    for i in range(n):
        b[i] = r[i]
        for j in range(n):
            a[i, j] = M[i, j]
    for c in range(n):
        p = c
        for i in range(c + 1, n):
            if abs(a[i, c]) > abs(a[p, c]):
                p = i
        if abs(a[p, c]) < 1e-300:
            return False
        if p != c:
            for j in range(n):
                tmp = a[c, j]
                a[c, j] = a[p, j]
                a[p, j] = tmp
            tmp = b[c]
            b[c] = b[p]
            b[p] = tmp
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
def _bw_comp_run(Dp: np.ndarray, Dp_pinv: np.ndarray, A: np.ndarray, B: np.ndarray, G: np.ndarray, D1: np.ndarray,
                 D2: np.ndarray, P: np.ndarray, h: np.ndarray, u_prev: np.ndarray, started: np.ndarray,
                 signs: np.ndarray, exact: bool, ulim: float, dulim: float, yh: np.ndarray, u: np.ndarray,
                 counters: np.ndarray) -> None:  # pragma: no cover
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
            # first sample: h = 0 and dU = 0 by definition, U = Dp⁻¹·Y_H
            for j in range(k):
                acc = 0.0
                for i in range(n):
                    acc += Dp_pinv[j, i] * yh[t, i]
                if acc > ulim or acc < -ulim:
                    acc = ulim if acc > 0 else -ulim
                    counters[1] += 1
                u_prev[j] = acc
                u[t, j] = acc
            started[0] = True
            continue
        solved = False
        if exact:
            # r = Y_H − Dp·u_prev + h_prev
            for i in range(n):
                acc = yh[t, i] + h[i]
                for j in range(k):
                    acc -= Dp[i, j] * u_prev[j]
                r[i] = acc
            # try the previous sign pattern first, then the others
            for q in range(npat + 1):
                if q == 0:
                    for i in range(n):
                        s[i] = signs[i]
                else:
                    for i in range(n):
                        s[i] = 1.0 if ((q - 1) >> i) & 1 else -1.0
                # W[i, l] = B s_l h_l + G |h_l| + D1 h_l + D2 s_l |h_l|;  (Dp − A + W·P)·dU = r
                for i in range(n):
                    for l in range(n):
                        ah = abs(h[l])
                        W[i, l] = B[i, l] * s[l] * h[l] + G[i, l] * ah + D1[i, l] * h[l] + D2[i, l] * s[l] * ah
                for i in range(n):
                    for j in range(k):
                        acc = Dp[i, j] - A[i, j]
                        for l in range(n):
                            acc += W[i, l] * P[l, j]
                        M[i, j] = acc
                if not _solve_small(M, r, du, lu, rhs):
                    continue
                ok = True
                for l in range(n):
                    d = 0.0
                    for j in range(k):
                        d += P[l, j] * du[j]
                    if d * s[l] < 0.0:
                        ok = False
                        break
                if ok:
                    solved = True
                    for i in range(n):
                        signs[i] = s[i]
                    break
            if not solved:
                counters[0] += 1
        if not solved:
            for j in range(k):
                acc = 0.0
                for i in range(n):
                    acc += Dp_pinv[j, i] * (yh[t, i] + h[i])
                du[j] = acc - u_prev[j]
        for j in range(k):
            un = u_prev[j] + du[j]
            if un > ulim or un < -ulim:
                du[j] = (ulim if un > 0 else -ulim) - u_prev[j]
                counters[1] += 1
            if du[j] > dulim or du[j] < -dulim:
                du[j] = dulim if du[j] > 0 else -dulim
                counters[1] += 1
        _bw_increment(A, B, G, D1, D2, P, h, du, dh, duh)
        for i in range(n):
            h[i] += dh[i]
        for j in range(k):
            u_prev[j] = u_prev[j] + du[j]
            u[t, j] = u_prev[j]


@njit
def _bw_comp_run_2x2(Dp: np.ndarray, Dp_pinv: np.ndarray, A: np.ndarray, B: np.ndarray, G: np.ndarray, D1: np.ndarray,
                     D2: np.ndarray, P: np.ndarray, h: np.ndarray, u_prev: np.ndarray, started: np.ndarray,
                     signs: np.ndarray, exact: bool, ulim: float, dulim: float, yh: np.ndarray, u: np.ndarray,
                     counters: np.ndarray) -> None:  # pragma: no cover - compiled
    """``_bw_comp_run`` unrolled for two axes: parameters, state and the 2×2 solves in registers.

    Same algorithm step by step (previous sign pattern first, Gaussian elimination with partial pivoting, same
    fallbacks and clamping) and the same order of operations in every expression, so the results are the same
    numbers as the generic kernel's.
    """
    N = yh.shape[0]
    if N == 0:
        return
    dp00, dp01, dp10, dp11 = Dp[0, 0], Dp[0, 1], Dp[1, 0], Dp[1, 1]
    q00, q01, q10, q11 = Dp_pinv[0, 0], Dp_pinv[0, 1], Dp_pinv[1, 0], Dp_pinv[1, 1]
    a00, a01, a10, a11 = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    b00, b01, b10, b11 = B[0, 0], B[0, 1], B[1, 0], B[1, 1]
    g00, g01, g10, g11 = G[0, 0], G[0, 1], G[1, 0], G[1, 1]
    e00, e01, e10, e11 = D1[0, 0], D1[0, 1], D1[1, 0], D1[1, 1]
    f00, f01, f10, f11 = D2[0, 0], D2[0, 1], D2[1, 0], D2[1, 1]
    p00, p01, p10, p11 = P[0, 0], P[0, 1], P[1, 0], P[1, 1]
    # Dp − A, the constant part of the per-pattern matrix
    c00 = dp00 - a00
    c01 = dp01 - a01
    c10 = dp10 - a10
    c11 = dp11 - a11
    n_fallback = 0
    n_saturated = 0
    t0 = 0
    if not started[0]:
        # first sample: h = 0 and dU = 0 by definition, U = Dp⁻¹·Y_H
        v0 = 0.0 + q00 * yh[0, 0] + q01 * yh[0, 1]
        if v0 > ulim or v0 < -ulim:
            v0 = ulim if v0 > 0 else -ulim
            n_saturated += 1
        v1 = 0.0 + q10 * yh[0, 0] + q11 * yh[0, 1]
        if v1 > ulim or v1 < -ulim:
            v1 = ulim if v1 > 0 else -ulim
            n_saturated += 1
        u_prev[0] = v0
        u_prev[1] = v1
        u[0, 0] = v0
        u[0, 1] = v1
        started[0] = True
        t0 = 1
    h0 = h[0]
    h1 = h[1]
    up0 = u_prev[0]
    up1 = u_prev[1]
    sg0 = signs[0]
    sg1 = signs[1]
    du0 = 0.0
    du1 = 0.0
    for t in range(t0, N):
        y0 = yh[t, 0]
        y1 = yh[t, 1]
        solved = False
        if exact:
            r0 = y0 + h0 - dp00 * up0 - dp01 * up1
            r1 = y1 + h1 - dp10 * up0 - dp11 * up1
            ah0 = abs(h0)
            ah1 = abs(h1)
            for q in range(5):
                if q == 0:
                    s0 = sg0
                    s1 = sg1
                else:
                    s0 = 1.0 if (q - 1) & 1 else -1.0
                    s1 = 1.0 if ((q - 1) >> 1) & 1 else -1.0
                # W[i, l] = B s_l h_l + G |h_l| + D1 h_l + D2 s_l |h_l|;  (Dp − A + W·P)·dU = r
                w00 = b00 * s0 * h0 + g00 * ah0 + e00 * h0 + f00 * s0 * ah0
                w01 = b01 * s1 * h1 + g01 * ah1 + e01 * h1 + f01 * s1 * ah1
                w10 = b10 * s0 * h0 + g10 * ah0 + e10 * h0 + f10 * s0 * ah0
                w11 = b11 * s1 * h1 + g11 * ah1 + e11 * h1 + f11 * s1 * ah1
                m00 = c00 + w00 * p00 + w01 * p10
                m01 = c01 + w00 * p01 + w01 * p11
                m10 = c10 + w10 * p00 + w11 * p10
                m11 = c11 + w10 * p01 + w11 * p11
                rr0 = r0
                rr1 = r1
                # Gaussian elimination with partial pivoting (as _solve_small)
                if abs(m10) > abs(m00):
                    m00, m10 = m10, m00
                    m01, m11 = m11, m01
                    rr0, rr1 = rr1, rr0
                if abs(m00) < 1e-300:
                    continue
                fct = m10 / m00
                m11 -= fct * m01
                rr1 -= fct * rr0
                if abs(m11) < 1e-300:
                    continue
                du1 = rr1 / m11
                du0 = (rr0 - m01 * du1) / m00
                if (0.0 + p00 * du0 + p01 * du1) * s0 < 0.0:
                    continue
                if (0.0 + p10 * du0 + p11 * du1) * s1 < 0.0:
                    continue
                solved = True
                sg0 = s0
                sg1 = s1
                break
            if not solved:
                n_fallback += 1
        if not solved:
            du0 = 0.0 + q00 * (y0 + h0) + q01 * (y1 + h1) - up0
            du1 = 0.0 + q10 * (y0 + h0) + q11 * (y1 + h1) - up1
        un = up0 + du0
        if un > ulim or un < -ulim:
            du0 = (ulim if un > 0 else -ulim) - up0
            n_saturated += 1
        if du0 > dulim or du0 < -dulim:
            du0 = dulim if du0 > 0 else -dulim
            n_saturated += 1
        un = up1 + du1
        if un > ulim or un < -ulim:
            du1 = (ulim if un > 0 else -ulim) - up1
            n_saturated += 1
        if du1 > dulim or du1 < -dulim:
            du1 = dulim if du1 > 0 else -dulim
            n_saturated += 1
        # the model's increment (as _bw_increment)
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
        up0 = up0 + du0
        up1 = up1 + du1
        u[t, 0] = up0
        u[t, 1] = up1
    h[0] = h0
    h[1] = h1
    u_prev[0] = up0
    u_prev[1] = up1
    signs[0] = sg0
    signs[1] = sg1
    counters[0] += n_fallback
    counters[1] += n_saturated
