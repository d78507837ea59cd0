"""Truth simulator of the independent diagnosis benchmark — written apart from the code it judges.

Nothing here imports ``piezo_ff_ros.core.models`` or ``piezo_ff_ros.core.diagnosis``: the nominal plant is read
only through the public config (:func:`piezo_ff_ros.core.config.load_config`) and simulated by this module's own
code, from the model's definition (paper Eq. 3, 10, 14; ``Y = G_L(s)·[K + Cr(s)]·(Dp·U − h)``):

* Bouc-Wen in its explicit discrete form ``h[k] = h[k−1] + A·dU − B(|dU|∘h) − Γ(dU∘|h|)`` (a compiled loop here);
* every SISO transfer function of ``Cr`` and ``G_L`` discretised by exact zero-order hold on its own, through a
  partial-fraction (modal) expansion computed from the *factored* form (no polynomial expansion, so the 9th-order
  entries stay well conditioned), pairing conjugate poles on the continuous poles; cross-checked against
  ``scipy.signal.cont2discrete`` and against the package's own plant in ``test/test_diagnosis_benchmark.py``.

The withheld effects are stages inserted in that chain (voltage side, inside the hysteresis, on the displacement, or
in the hold of the DAC), each in functional forms that differ from the diagnosis candidates' parameterisations
(see ``cases.py`` for the list and the verdict each one should get).  Sensor noise: white, coloured (first-order
low-pass) and quantised.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import signal

__all__ = ["Modal", "modal_zoh", "lti_siso", "lti_mimo", "tf_from_poly", "simulate", "add_noise", "excitation",
           "nominal_matrices"]


# ----------------------------------------------------------------------------------------------------------------
# Linear parts: exact ZOH of a factored transfer function, modal form
# ----------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Modal:
    """``G(s) = D + Σ r_i/(s − p_i)`` with one representative per conjugate pair (weight 2, real part taken)."""

    poles: np.ndarray      # complex [M]
    residues: np.ndarray   # complex [M]
    weights: np.ndarray    # 1.0 (real pole) or 2.0 (pair)
    direct: float


def _factor_roots(factors) -> np.ndarray:
    out = []
    for f in factors:
        f = np.asarray(f, float)
        if len(f) == 2:
            out.append(np.array([-f[1] / f[0]], complex))
        elif len(f) == 3:
            a, b, c = f
            disc = complex(b * b - 4 * a * c)
            sq = np.sqrt(disc)
            # the numerically stable pair of formulas (no cancellation for real roots)
            q = -0.5 * (b + (sq if b >= 0 else -sq))
            r1 = q / a
            r2 = c / q if q != 0 else -b / (2 * a)
            if disc.real < 0:  # exact conjugates
                re = -b / (2 * a)
                im = math.sqrt(-disc.real) / (2 * abs(a))
                r1, r2 = complex(re, im), complex(re, -im)
            out.append(np.array([r1, r2], complex))
        elif len(f) > 3:
            out.append(np.roots(f).astype(complex))
    return np.concatenate(out) if out else np.zeros(0, complex)


def modal_from_factors(gain: float, num, den) -> Modal:
    """Partial fractions of ``gain·Πnum/Πden`` (factors: polynomial coefficients, highest power first)."""
    num = [np.asarray(f, float) for f in num]
    den = [np.asarray(f, float) for f in den]
    lead_n = float(np.prod([f[0] for f in num])) if num else 1.0
    lead_d = float(np.prod([f[0] for f in den]))
    k = gain * lead_n / lead_d
    p = _factor_roots(den)
    deg_n = sum(len(f) - 1 for f in num)
    if deg_n > len(p):
        raise ValueError("improper transfer function")
    direct = k if deg_n == len(p) else 0.0

    def monic_num(s):
        v = 1.0 + 0j
        for f in num:
            v *= np.polyval(f / f[0], s)
        return v

    keep, w = [], []
    for i, pi in enumerate(p):
        if pi.imag < -1e-12 * max(abs(pi), 1e-300):
            continue  # the conjugate representative is kept
        keep.append(i)
        w.append(2.0 if pi.imag > 1e-12 * max(abs(pi), 1e-300) else 1.0)
    res = []
    for i in keep:
        d = 1.0 + 0j
        for j in range(len(p)):
            if j != i:
                d *= p[i] - p[j]
        res.append(k * monic_num(p[i]) / d)
    poles = p[keep]
    res = np.array(res, complex)
    real = np.array(w) == 1.0
    res[real] = res[real].real
    poles = np.where(real, poles.real + 0j, poles)
    return Modal(poles, res, np.array(w, float), float(direct))


def tf_from_poly(num, den) -> Modal:
    """Modal form of a transfer function given as two polynomials (low order only: the effect filters)."""
    num = np.trim_zeros(np.atleast_1d(np.asarray(num, float)), "f")
    if len(num) == 1:
        return modal_from_factors(float(num[0]), [], [np.asarray(den, float)])
    return modal_from_factors(1.0, [num], [np.asarray(den, float)])


def modal_zoh(m: Modal, dt: float, frac_delay: float = 0.0):
    """Exact ZOH of each mode for an input held over each sample and delayed by ``frac_delay`` ∈ [0, 1) samples.

    ``x[k+1] = a·x[k] + b0·u[k] + b1·u[k−1]`` with ``a = e^{pT}``; without delay ``b0 = (e^{pT} − 1)/p``, ``b1 = 0``;
    delayed by fT the held value u[k−1] still acts during the first fT of the interval.
    """
    p = m.poles
    T = dt
    f = float(frac_delay)
    a = np.exp(p * T)
    with np.errstate(divide="ignore", invalid="ignore"):
        b0 = np.where(p != 0, np.expm1(p * (1 - f) * T) / np.where(p != 0, p, 1), (1 - f) * T)
        b1 = np.where(p != 0, np.exp(p * (1 - f) * T) * np.expm1(p * f * T) / np.where(p != 0, p, 1), f * T)
    return a.astype(complex), b0.astype(complex), b1.astype(complex)


@njit(cache=True)
def _modal_run(a, b0, b1, r, w, d, d_delayed, u, c1, c2, average):  # pragma: no cover - compiled
    N = u.shape[0]
    M = a.shape[0]
    y = np.empty(N)
    x = np.zeros(M, np.complex128)
    u_prev = 0.0
    for k in range(N):
        uk = u[k]
        acc = d * (u_prev if d_delayed else uk)
        for i in range(M):
            if average:
                acc += w[i] * (r[i] * (c1[i] * x[i] + c2[i] * uk)).real
            else:
                acc += w[i] * (r[i] * x[i]).real
        y[k] = acc
        for i in range(M):
            x[i] = a[i] * x[i] + b0[i] * uk + b1[i] * u_prev
        u_prev = uk
    return y


def lti_siso(m: Modal, dt: float, u: np.ndarray, delay_samples: float = 0.0, average: bool = False) -> np.ndarray:
    """Response of ``m`` (exact ZOH, from rest) to the held samples ``u`` delayed by ``delay_samples`` ≥ 0.

    ``average=True`` returns the mean of the continuous output over each sample interval instead of its value at
    the sample instant: the held value a continuous voltage-side filter (an amplifier) is equivalent to for the
    stages after it (a filter far faster than the sample rate is then the identity, not a one-sample delay).
    """
    u = np.ascontiguousarray(u, float)
    whole = int(math.floor(delay_samples + 1e-12))
    frac = float(delay_samples - whole)
    if frac < 1e-12:
        frac = 0.0
    if whole:
        u = np.concatenate([np.zeros(whole), u[:-whole]]) if whole < len(u) else np.zeros_like(u)
    if len(m.poles) == 0:
        return m.direct * u
    a, b0, b1 = modal_zoh(m, dt, frac)
    p = m.poles
    pT = p * dt
    small = np.abs(pT) < 1e-3
    with np.errstate(divide="ignore", invalid="ignore"):
        c1 = np.where(small, dt * (1 + pT / 2 + pT ** 2 / 6), np.expm1(pT) / np.where(small, 1, p))
        c2 = np.where(small, dt ** 2 / 2 * (1 + pT / 3 + pT ** 2 / 12),
                      (np.expm1(pT) / np.where(small, 1, p) - dt) / np.where(small, 1, p))
    return _modal_run(a, b0, b1, m.residues.astype(complex), m.weights, m.direct, frac > 0, u,
                      (c1 / dt).astype(complex), (c2 / dt).astype(complex), bool(average))


def lti_mimo(entries, dt: float, u: np.ndarray, delay_samples: float = 0.0) -> np.ndarray:
    """``y_i = Σ_j G_ij u_j``; ``entries[i][j]`` a :class:`Modal` or None (zero)."""
    n_out = len(entries)
    y = np.zeros((u.shape[0], n_out))
    for i in range(n_out):
        for j, m in enumerate(entries[i]):
            if m is not None:
                y[:, i] += lti_siso(m, dt, u[:, j], delay_samples)
    return y


def _modal_matrix(tfm, n: int):
    out = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(n):
            tf = tfm[i, j]
            if not tf.is_zero():
                out[i][j] = modal_from_factors(tf.gain, tf.num, tf.den)
    return out


def nominal_matrices(cfg) -> dict:
    """The nominal model's numbers, read from the public config (SI units)."""
    h = cfg.hysteresis
    arr = lambda m: np.array(m, float) if m is not None else None  # noqa: E731
    return {"Dp": arr(h.Dp), "A": arr(h.A), "B": arr(h.B), "Gamma": arr(h.Gamma),
            "Delta1": arr(h.Delta1), "Delta2": arr(h.Delta2),
            "K": np.array(cfg.creep.K, float), "Cr": _modal_matrix(cfg.creep.Cr, cfg.n_axes),
            "G_L": _modal_matrix(cfg.dynamics.G_L, cfg.n_axes), "dt": cfg.dt, "n": cfg.n_axes,
            "G_L_tf": cfg.dynamics.G_L}


# ----------------------------------------------------------------------------------------------------------------
# Hysteresis: the nominal Bouc-Wen and this benchmark's own variants (biased gain, rate law, lagged state)
# ----------------------------------------------------------------------------------------------------------------

#: the largest voltage sub-step [V] of the Bouc-Wen integration (error ≈ 1e-5 of the loop on the paper's tube)
BW_SUBSTEP_V = 0.01


@njit(cache=True)
def _bouc_wen(Dp, A, B, G, D1, D2, u, kappa, u_bias, u_scale, rate_alpha, rate_ref, rate_exp, rate_tau, dt,
              lag_tau):  # pragma: no cover - compiled
    """Bouc-Wen integrated along the straight voltage path of each sample in explicit sub-steps of at most
    :data:`BW_SUBSTEP_V` volts (the continuous, rate-independent model; one explicit step per sample is a
    discretisation that depends on the sample rate); the extras are off at kappa = rate_alpha = lag_tau = 0.

    kappa: A's column j scaled by 1 + kappa_j·tanh((U_j − u_bias_j)/u_scale) (a voltage-biased piezo coefficient:
    the loop widens on one side of the bias, an asymmetric loop).  rate_alpha: A scaled by
    1 + alpha·(r/rate_ref)^rate_exp, r = |dU/dt| smoothed over rate_tau (a power-law rate dependence).
    lag_tau: the hysteretic state seen at the output lags h by a first-order relaxation (a viscous loop that
    widens and turns with frequency).
    """
    N, k = u.shape
    n = Dp.shape[0]
    y = np.empty((N, n))
    h = np.zeros(n)
    hl = np.zeros(n)
    rate = np.zeros(k)
    du = np.zeros(k)
    dus = np.zeros(k)
    us = np.zeros(k)
    dh = np.zeros(n)
    up = u[0].copy()
    c_rate = 1.0 - math.exp(-dt / rate_tau) if rate_tau > 0 else 1.0
    c_lag = 1.0 - math.exp(-dt / lag_tau) if lag_tau > 0 else 1.0
    for t in range(N):
        dmax = 0.0
        for j in range(k):
            du[j] = u[t, j] - up[j]
            rate[j] += c_rate * (abs(du[j]) / dt - rate[j])
            dmax = max(dmax, abs(du[j]))
        n_sub = max(1, int(math.ceil(dmax / BW_SUBSTEP_V))) if dmax == dmax else 1
        for j in range(k):
            dus[j] = du[j] / n_sub
        for sub in range(n_sub):
            for j in range(k):
                us[j] = up[j] + (sub + 1) * dus[j]
            for i in range(n):
                acc = 0.0
                for j in range(k):
                    s = 1.0
                    if kappa[j] != 0.0:
                        s += kappa[j] * math.tanh((us[j] - u_bias[j]) / u_scale)
                    if rate_alpha != 0.0:
                        xr = (rate[j] / rate_ref) ** rate_exp
                        s *= 1.0 + rate_alpha * xr / (1.0 + xr)
                    acc += A[i, j] * s * dus[j]
                for j in range(n):
                    ad = abs(dus[j])
                    ah = abs(h[j])
                    acc -= B[i, j] * ad * h[j] + G[i, j] * dus[j] * ah + D1[i, j] * dus[j] * h[j] + D2[i, j] * ad * ah
                dh[i] = acc
            for i in range(n):
                h[i] += dh[i]
        for i in range(n):
            if lag_tau > 0:
                hl[i] += c_lag * (h[i] - hl[i])
            else:
                hl[i] = h[i]
        for j in range(k):
            up[j] = u[t, j]
        for i in range(n):
            acc = 0.0
            for j in range(k):
                acc += Dp[i, j] * u[t, j]
            y[t, i] = acc - hl[i]
    return y


@njit(cache=True)
def _generalized_play(u, radii, weights, c_up, c_down, u_ref):  # pragma: no cover - compiled
    """Asymmetric Prandtl–Ishlinskii: Σ_k w_k·(z_k − u), generalized play operators whose ascending and
    descending envelopes bend differently (γ_up(u) = u + c_up·u²/u_ref, γ_down(u) = u + c_down·u²/u_ref)."""
    N = u.shape[0]
    K = radii.shape[0]
    z = np.empty(K)
    out = np.empty(N)
    for m in range(K):
        z[m] = u[0] + 0.5 * (c_up + c_down) * u[0] * u[0] / u_ref
    for t in range(N):
        v = u[t]
        gu = v + c_up * v * v / u_ref
        gd = v + c_down * v * v / u_ref
        acc = 0.0
        for m in range(K):
            lo = gu - radii[m]
            hi = gd + radii[m]
            if lo > hi:
                lo = hi = 0.5 * (lo + hi)
            zm = z[m]
            if zm < lo:
                zm = lo
            elif zm > hi:
                zm = hi
            z[m] = zm
            acc += weights[m] * (zm - v)
        out[t] = acc
    return out


# ----------------------------------------------------------------------------------------------------------------
# Voltage-side stages
# ----------------------------------------------------------------------------------------------------------------

def soft_clip(u: np.ndarray, upper: float, lower: float, knee: float) -> np.ndarray:
    """Identity up to ``limit − knee``, then a tanh knee that reaches ``+upper`` / ``−lower`` asymptotically."""
    out = u.copy()
    hi = upper - knee
    m = u > hi
    out[m] = hi + knee * np.tanh((u[m] - hi) / knee)
    lo = -(lower - knee)
    m = u < lo
    out[m] = lo - knee * np.tanh((lo - u[m]) / knee)
    return out


@njit(cache=True)
def _current_limited(u, dt, rate_up, rate_down, tau, n_sub):  # pragma: no cover - compiled
    """Amplifier with a finite output current: dv/dt = S·tanh((u − v)/(S·τ)), S = rate_up (rising) or rate_down,
    integrated with RK2 sub-steps over each held input sample; the mean over the interval is returned (the held
    value the stages after it see)."""
    N, k = u.shape
    v = u[0].copy()
    y = np.empty((N, k))
    h = dt / n_sub
    for t in range(N):
        for j in range(k):
            target = u[t, j]
            vj = v[j]
            acc = 0.0
            for _ in range(n_sub):
                acc += 0.5 * vj
                e = target - vj
                S = rate_up if e > 0 else rate_down
                k1 = S * math.tanh(e / (S * tau))
                e2 = target - (vj + 0.5 * h * k1)
                S2 = rate_up if e2 > 0 else rate_down
                k2 = S2 * math.tanh(e2 / (S2 * tau))
                vj += h * k2
                acc += 0.5 * vj
            v[j] = vj
            y[t, j] = acc / n_sub
    return y


def lagrange_delay(u: np.ndarray, delay_samples: float, order: int = 3) -> np.ndarray:
    """Fractional delay by a Lagrange-interpolating FIR (``order`` + 1 taps, centred on the delay; ≥ 1 sample)."""
    if delay_samples < (order - 1) // 2:
        raise ValueError(f"a centred order-{order} Lagrange delay needs >= {(order - 1) // 2} samples")
    D = float(delay_samples)
    start = max(0, int(math.floor(D)) - (order - 1) // 2)
    idx = np.arange(start, start + order + 1)
    h = np.ones(order + 1)
    for i, n in enumerate(idx):
        for m in idx:
            if m != n:
                h[i] *= (D - m) / (n - m)
    taps = np.zeros(idx[-1] + 1)
    taps[idx] = h
    # from rest at the first voltage (the rig's amplifier has been holding it)
    pad = np.repeat(u[:1], len(taps), axis=0)
    out = signal.lfilter(taps, [1.0], np.concatenate([pad, u]), axis=0)
    return out[len(taps):]


# ----------------------------------------------------------------------------------------------------------------
# Displacement-side stages
# ----------------------------------------------------------------------------------------------------------------

def creep_law(yh: np.ndarray, dt: float, law: str, gamma, tau0: float, level_coef: float, y_ref: float,
              alpha: float = 0.1) -> np.ndarray:
    """Extra creep by superposition of the increments of f(Y_H): Σ dF[k]·γ·L(t − t_k).

    law ``log``: L(t) = log10(1 + t/τ0) (the classical logarithmic creep law);
    law ``power``: L(t) = (1 + t/τ0)^α − 1 (fractional-order creep).
    f(y) = y·(1 + level_coef·y/y_ref) — creep that grows with the level, asymmetric in sign.
    """
    N = yh.shape[0]
    t = np.arange(N) * dt
    if law == "log":
        L = np.log10(1.0 + t / tau0)
    elif law == "power":
        L = (1.0 + t / tau0) ** alpha - 1.0
    else:
        raise ValueError(law)
    out = np.zeros_like(yh)
    for i in range(yh.shape[1]):
        F = yh[:, i] * (1.0 + level_coef * yh[:, i] / y_ref)
        dF = np.diff(F, prepend=F[0])
        out[:, i] = gamma[i] * signal.fftconvolve(dF, L)[:N]
    return out


@njit(cache=True)
def _amplitude_mode(y, dt, w0, z0, kw, kz, y_ref, env_tau, duffing, n_sub):  # pragma: no cover - compiled
    """One axis: the resonance (w0, z0) of the displacement replaced by an amplitude-dependent one.

    Series filter ``T = (ω²/ω0²)·(s² + 2ζ0ω0 s + ω0²)/(s² + 2ζωs + ω²)`` — identity when ω = ω0, ζ = ζ0, unity DC
    gain always.  ``duffing = 0``: ω = ω0(1 − kw·e), ζ = ζ0(1 + kz·e), e = RMS envelope of y (time constant
    env_tau) over y_ref (a resonance that softens and damps with level).  ``duffing ≠ 0``: ω² = ω0²(1 + duffing·
    (ω0²q/y_ref)²), instantaneous hardening stiffness of the mode.  RK4 with n_sub sub-steps per held sample.
    """
    N = y.shape[0]
    out = np.empty(N)
    q = y[0] / (w0 * w0)
    v = 0.0
    e2 = 0.0
    c_env = 1.0 - math.exp(-dt / env_tau)
    h = dt / n_sub
    for t in range(N):
        u = y[t]
        e2 += c_env * (u * u - e2)
        e = math.sqrt(e2) / y_ref
        if duffing == 0.0:
            w = w0 * (1.0 - kw * e)
            z = z0 * (1.0 + kz * e)
            w2 = w * w
        else:
            xq = w0 * w0 * q / y_ref
            w2 = w0 * w0 * (1.0 + duffing * xq * xq)
            z = z0
        wn = math.sqrt(w2)
        damp = 2.0 * (z0 * w0 - z * wn) * v if duffing == 0.0 else 0.0
        out[t] = (w2 / (w0 * w0)) * (u + damp + (w0 * w0 - w2) * q)
        for _ in range(n_sub):
            # q'' = u − 2ζω q' − ω² q   (RK4, ω and ζ frozen over the sample except the Duffing stiffness)
            if duffing == 0.0:
                a1 = u - 2 * z * wn * v - w2 * q
                q2 = q + 0.5 * h * v
                v2 = v + 0.5 * h * a1
                a2 = u - 2 * z * wn * v2 - w2 * q2
                q3 = q + 0.5 * h * v2
                v3 = v + 0.5 * h * a2
                a3 = u - 2 * z * wn * v3 - w2 * q3
                q4 = q + h * v3
                v4 = v + h * a3
                a4 = u - 2 * z * wn * v4 - w2 * q4
            else:
                def_k = w0 * w0 / (y_ref * y_ref) * duffing * w0 * w0 * w0 * w0
                a1 = u - 2 * z * w0 * v - w0 * w0 * q - def_k * q * q * q
                q2 = q + 0.5 * h * v
                v2 = v + 0.5 * h * a1
                a2 = u - 2 * z * w0 * v2 - w0 * w0 * q2 - def_k * q2 * q2 * q2
                q3 = q + 0.5 * h * v2
                v3 = v + 0.5 * h * a2
                a3 = u - 2 * z * w0 * v3 - w0 * w0 * q3 - def_k * q3 * q3 * q3
                q4 = q + h * v3
                v4 = v + h * a3
                a4 = u - 2 * z * w0 * v4 - w0 * w0 * q4 - def_k * q4 * q4 * q4
            q += h / 6.0 * (v + 2 * v2 + 2 * v3 + v4)
            v += h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
    return out


# ----------------------------------------------------------------------------------------------------------------
# The truth chain
# ----------------------------------------------------------------------------------------------------------------

def simulate(nom: dict, effects: list[dict], u: np.ndarray) -> np.ndarray:
    """Noise-free truth displacement [N, n] for voltages ``u`` [N, n]: the nominal chain + ``effects``.

    Each effect is ``{"kind": ..., **params}``; kinds are listed in the branches below.  With no effect this is the
    nominal model's definition (the null cases).
    """
    dt, n = nom["dt"], nom["n"]
    kinds = {e["kind"] for e in effects}
    unknown = kinds - _KINDS
    if unknown:
        raise ValueError(f"unknown truth effect kind(s) {sorted(unknown)}")
    E = {e["kind"]: e for e in effects}
    v = np.array(u, float)

    # -- voltage side (amplifier, DAC) --
    if "voltage_gain" in E:
        v = v @ np.asarray(E["voltage_gain"]["matrix"], float).T
    if "lagrange_delay" in E:
        v = lagrange_delay(v, E["lagrange_delay"]["samples"])
    if "rolloff" in E:
        e = E["rolloff"]
        wc = 2 * math.pi * e["cutoff"]
        if e["order"] == 1:
            m = tf_from_poly([wc], [1.0, wc])
        else:
            m = tf_from_poly([wc * wc], [1.0, 2 * e["zeta"] * wc, wc * wc])
        # the amplifier starts settled at the first voltage
        v = v[0] + np.column_stack([lti_siso(m, dt, v[:, j] - v[0, j], average=True) for j in range(n)])
    if "current_limit" in E:
        e = E["current_limit"]
        n_sub = max(4, int(math.ceil(dt / (e["tau"] / 2))))
        v = _current_limited(np.ascontiguousarray(v), dt, e["rate_up"], e["rate_down"], e["tau"], min(n_sub, 400))
    if "clip" in E:
        e = E["clip"]
        v = soft_clip(v, e["upper"], e["lower"], e["knee"])

    # -- hysteresis --
    z = np.zeros(n)
    D1 = nom["Delta1"] if nom["Delta1"] is not None else np.zeros((n, n))
    D2 = nom["Delta2"] if nom["Delta2"] is not None else np.zeros((n, n))
    bw = dict(kappa=z, u_bias=z, u_scale=1.0, rate_alpha=0.0, rate_ref=1.0, rate_exp=1.0, rate_tau=0.0, lag_tau=0.0)
    if "biased_bw" in E:
        e = E["biased_bw"]
        bw.update(kappa=np.asarray(e["kappa"], float), u_bias=np.asarray(e["u_bias"], float), u_scale=e["u_scale"])
    if "rate_law" in E:
        e = E["rate_law"]
        bw.update(rate_alpha=e["alpha"], rate_ref=e["rate_ref"], rate_exp=e["exponent"], rate_tau=e["smoothing"])
    if "lagged_hysteresis" in E:
        bw.update(lag_tau=E["lagged_hysteresis"]["tau"])
    yh = _bouc_wen(nom["Dp"], nom["A"], nom["B"], nom["Gamma"], D1, D2, np.ascontiguousarray(v),
                   bw["kappa"], bw["u_bias"], float(bw["u_scale"]), float(bw["rate_alpha"]), float(bw["rate_ref"]),
                   float(bw["rate_exp"]), float(bw["rate_tau"]), dt, float(bw["lag_tau"]))
    if "asym_pi" in E:
        e = E["asym_pi"]
        for i in range(n):
            yh[:, i] += nom["Dp"][i, i] * _generalized_play(np.ascontiguousarray(v[:, i]),
                                                            np.asarray(e["radii"], float),
                                                            np.asarray(e["weights"], float),
                                                            float(e["c_up"][i]), float(e["c_down"][i]),
                                                            float(e["u_ref"]))

    # -- creep --
    yl = yh @ nom["K"].T + lti_mimo(nom["Cr"], dt, yh)
    if "creep_law" in E:
        e = E["creep_law"]
        yl = yl + creep_law(yh, dt, e["law"], e["gamma"], e["tau0"], e["level_coef"], e["y_ref"],
                            e.get("alpha", 0.1))

    # -- dynamics (DAC latency: the held input acts fT late, exact modified-ZOH) --
    delay = E["dac_latency"]["samples"] if "dac_latency" in E else 0.0
    y = lti_mimo(nom["G_L"], dt, yl, delay_samples=delay)

    # -- displacement side --
    if "series_modes" in E:
        for i, modes in enumerate(E["series_modes"]["per_axis"]):
            for (fp, zp, fz, zz) in modes:
                wp, wz = 2 * math.pi * fp, 2 * math.pi * fz
                m = tf_from_poly(np.array([1.0, 2 * zz * wz, wz * wz]) * (wp * wp / (wz * wz)),
                                 [1.0, 2 * zp * wp, wp * wp])
                y[:, i] = lti_siso(m, dt, y[:, i])
    if "parallel_modes" in E:
        add = np.zeros_like(y)
        for (i, j, f, zeta, r) in E["parallel_modes"]["modes"]:
            w = 2 * math.pi * f
            # a mode with its static part removed: r·(ω²/(s²+2ζωs+ω²) − 1)
            m = tf_from_poly(np.array([-1.0, -2 * zeta * w, 0.0]) * r, [1.0, 2 * zeta * w, w * w])
            add[:, i] += lti_siso(m, dt, y[:, j])
        y = y + add
    if "amplitude_mode" in E:
        e = E["amplitude_mode"]
        for i, (f0, z0) in enumerate(e["modes"]):
            w0 = 2 * math.pi * f0
            n_sub = max(4, int(math.ceil(w0 * 1.3 * dt / 0.25)))
            y[:, i] = _amplitude_mode(np.ascontiguousarray(y[:, i]), dt, w0, z0, e["kw"][i], e["kz"][i],
                                      e["y_ref"], e["env_tau"], e["duffing"][i], n_sub)
    if "output_gain" in E:
        y = y @ np.asarray(E["output_gain"]["matrix"], float).T
    if "heating" in E:
        e = E["heating"]
        t = np.arange(len(y)) * dt
        # heating that ramps from switch-on and levels off: ρ = s − s²/2, s = min(t/T_h, 1) (a ramp rounded at T_h)
        rho = np.minimum(t / e["ramp_time"], 1.0)
        rho = rho - 0.5 * rho ** 2 if e.get("rounded", True) else rho
        y = y * (1.0 + np.outer(rho, e["gain_per_unit"])) + np.outer(rho, e["offset"])
    if "sensor_drift" in E:
        e = E["sensor_drift"]
        t = np.arange(len(y)) * dt
        y = y + np.outer(t, e["rate"]) + np.outer(t ** 2, e["curvature"]) + \
            np.outer(np.sin(2 * np.pi * t / e["period"]) * (t > 0), e["wobble"])
    return y


_KINDS = {"voltage_gain", "lagrange_delay", "rolloff", "current_limit", "clip", "biased_bw", "rate_law",
          "lagged_hysteresis", "asym_pi", "creep_law", "dac_latency", "series_modes", "parallel_modes",
          "amplitude_mode", "output_gain", "heating", "sensor_drift"}


def add_noise(y: np.ndarray, dt: float, spec: dict, rng: np.random.Generator) -> np.ndarray:
    """Sensor noise: ``white`` std [m], ``coloured`` std [m] of first-order low-passed noise at ``corner`` [Hz],
    then ``quantum`` [m] (the reading rounded to the ADC step)."""
    out = y + spec.get("white", 0.0) * rng.standard_normal(y.shape)
    c = spec.get("coloured", 0.0)
    if c > 0:
        a = math.exp(-2 * math.pi * spec["corner"] * dt)
        w = rng.standard_normal(y.shape) * math.sqrt(1 - a * a)
        lp = signal.lfilter([1.0], [1.0, -a], w, axis=0, zi=np.outer([a], rng.standard_normal(y.shape[1])))[0]
        out = out + c * lp
    q = spec.get("quantum", 0.0)
    if q > 0:
        out = np.round(out / q) * q
    return out


# ----------------------------------------------------------------------------------------------------------------
# Excitations (this benchmark's own; TRAIN and TEST differ in kind)
# ----------------------------------------------------------------------------------------------------------------

def _ramp_in(t: np.ndarray, T: float = 0.5) -> np.ndarray:
    return np.clip(t / T, 0.0, 1.0) ** 2 * (3 - 2 * np.clip(t / T, 0.0, 1.0))


def _periodic_multisine(N: int, fs: float, f_lo: float, f_hi: float, rms: float, rng, period_s: float):
    """Random-phase multisine on a log grid of the harmonics of 1/period_s, periodic in ``period_s``."""
    P = max(int(round(period_s * fs)), 8)
    k_lo = max(1, int(math.ceil(f_lo * P / fs)))
    k_hi = max(k_lo + 1, int(f_hi * P / fs))
    ks = np.unique(np.round(np.geomspace(k_lo, k_hi, 60)).astype(int))
    ph = rng.uniform(0, 2 * np.pi, len(ks))
    n = np.arange(P)
    x = np.zeros(P)
    for k, p in zip(ks, ph):
        x += np.cos(2 * np.pi * k * n / P + p)
    x *= rms / max(x.std(), 1e-12)
    return np.tile(x, N // P + 1)[:N]


def excitation(kind: str, fs: float, duration: float, rng: np.random.Generator, amplitude: float = 110.0):
    """Voltages [N, 2]; ``train``: loops of growing size at a slow rate, held steps, a periodic multisine;
    ``test``: triangles of two rates, a band-limited random drive, a swept sine and a staircase.  Frequencies scale
    with the sample rate (the fast content reaches past the main resonances when fs allows)."""
    N = int(round(duration * fs))
    t = np.arange(N) / fs
    T = duration
    f_top = min(0.2 * fs, 2500.0)
    f_slow = min(1.0, 20.0 / T) * rng.uniform(0.7, 1.4)
    u = np.zeros((N, 2))
    for ax in range(2):
        s = np.zeros(N)
        if kind == "train":
            a = t < 0.35 * T
            env = np.interp(t[a], [0, 0.35 * T], [0.3, 1.0])
            s[a] = amplitude * env * np.sin(2 * np.pi * f_slow * (1 + 0.37 * ax) * t[a])
            b = (t >= 0.35 * T) & (t < 0.6 * T)
            idx = np.flatnonzero(b)
            levels = rng.uniform(-0.85, 0.85, 6) * amplitude
            for j, lev in enumerate(levels):
                s[idx[j * len(idx) // 6:(j + 1) * len(idx) // 6]] = lev
            c = t >= 0.6 * T
            period = min(max(2.0, 0.05 * T), 0.1 * T)
            s[c] = _periodic_multisine(int(c.sum()), fs, 0.5 / period, f_top, 0.28 * amplitude, rng, period) + \
                0.35 * amplitude * np.sin(2 * np.pi * 3 * f_slow * t[c])
        elif kind == "test":
            tri = lambda f: 2 * np.abs(2 * ((t * f) % 1.0) - 1) - 1  # noqa: E731
            a = t < 0.3 * T
            s[a] = amplitude * (0.9 if ax == 0 else 0.75) * tri(1.3 * f_slow * (1 + 0.5 * ax))[a]
            b = (t >= 0.3 * T) & (t < 0.45 * T)
            s[b] = 0.55 * amplitude * tri(7 * f_slow)[b]
            c = (t >= 0.45 * T) & (t < 0.65 * T)
            w = rng.standard_normal(int(c.sum()))
            bb, aa = signal.butter(2, min(0.45 * f_top / (fs / 2), 0.95))
            w = signal.lfilter(bb, aa, w)
            s[c] = 0.3 * amplitude * w / max(w.std(), 1e-12)
            d = (t >= 0.65 * T) & (t < 0.85 * T)
            tc = t[d] - t[d][0]
            dur = 0.2 * T
            f0, f1 = 0.5 * f_slow, f_top
            kk = math.log(f1 / f0) / dur
            s[d] = 0.3 * amplitude * np.sin(2 * np.pi * f0 * (np.exp(kk * tc) - 1) / kk)
            e = t >= 0.85 * T
            idx = np.flatnonzero(e)
            levels = rng.uniform(-0.9, 0.9, 5) * amplitude
            for j, lev in enumerate(levels):
                s[idx[j * len(idx) // 5:(j + 1) * len(idx) // 5]] = lev
        else:
            raise ValueError(f"excitation kind must be 'train' or 'test', got {kind!r}")
        u[:, ax] = s
    return u * _ramp_in(t)[:, None]
