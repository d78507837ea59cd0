"""Hysteresis-side effects: the replacement of the nominal Bouc-Wen and the loop-shape terms that go with it.

:class:`HysteresisStage` is the generalized (asymmetric ``Δ1``, ``Δ2``) and rate-dependent Bouc-Wen that replaces
the nominal hysteresis (``hysteresis_rate_dependence``, ``hysteresis_asymmetry``); :class:`RelaxedHysteresisStage`
lets its hysteretic state reach the output through a relaxation (``relaxation``).  :class:`BranchEvenTerm` (an even,
branch-dependent bend) and :class:`PlayWidthTerm` (a play-operator loop-width correction) are displacement-side
stages of ``hysteresis_asymmetry``; :func:`asymmetric_hysteresis_config` adds its ``Δ`` terms to a config.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from ..._jit import njit
from ...lti import static_gain
from ...config import BoucWenConfig
from ...kernels.bouc_wen import bw_model_rate_run, params_of  # the model loop (one source)
from .common import DIRECTION_TAU, LEVEL_REF, RATE_REF, RATE_SMOOTHING, _block, _per_axis

__all__ = ["HysteresisStage", "RelaxedHysteresisStage", "VelocityTerm", "LoopShapeTerm", "RatePlayTerm",
           "RelayPlaneTerm", "BranchEvenTerm",
           "PlayWidthTerm",
           "asymmetric_hysteresis_config"]


@njit
def _velocity_run(u: np.ndarray, gains: np.ndarray, exponent: float, rate_ref: float, a: float, dt: float,
                  u_prev: np.ndarray, rate: np.ndarray, started: np.ndarray,
                  out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[t, j] = gains[j]·sgn(r_j)·|r_j/rate_ref|^exponent``, r the voltage rate ``ΔU/dt`` low-passed by
    ``r ← a·r + (1 − a)·ΔU/dt`` (states ``u_prev``, ``rate``); started at rest at the first input."""
    N, n = u.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                u_prev[j] = u[t, j]
                rate[j] = 0.0
            rate[j] = a * rate[j] + (1.0 - a) * (u[t, j] - u_prev[j]) / dt
            u_prev[j] = u[t, j]
            x = rate[j] / rate_ref
            out[t, j] = gains[j] * math.copysign(abs(x) ** exponent, x) if x != 0.0 else 0.0
        started[0] = True


class VelocityTerm:
    """A velocity-damping term of the hysteresis output: ``Y_H,i += Dp_ii·c_i·sgn(r_i)·|r_i/r_ref|^m``, r_i the
    rate of voltage i (``ΔU/dt`` low-passed over ``smoothing`` [s]), r_ref = :data:`RATE_REF`.  A loop that widens
    with the rate, absent at rest and — for m < 1 — *not* linear in the rate (which is how it differs from a delay,
    whose error is linear in the derivative at every frequency).  ``gains`` c_i in volts (the equivalent input
    voltage at r_ref), ``exponent`` m in (0, 2].  Part of ``hysteresis_rate_dependence`` (``velocity_gain``,
    ``velocity_exponent``, ``velocity_smoothing``)."""

    def __init__(self, dp_diag: ArrayLike, gains: ArrayLike, exponent: float, smoothing: float, dt: float) -> None:
        self.dp = np.asarray(dp_diag, float).reshape(-1)
        n = self.dp.size
        self.gains = _per_axis(gains, n, "hysteresis_rate_dependence.velocity_gain")
        if not (math.isfinite(exponent) and 0.0 < exponent <= 2.0):
            raise ValueError(f"hysteresis_rate_dependence.velocity_exponent: must be in (0, 2], got {exponent!r}")
        if not (math.isfinite(smoothing) and smoothing >= 0.0):
            raise ValueError(f"hysteresis_rate_dependence.velocity_smoothing: must be >= 0 s, got {smoothing!r}")
        self.exponent, self.smoothing, self.dt, self.n = float(exponent), float(smoothing), float(dt), n
        self._a = math.exp(-self.dt / self.smoothing) if self.smoothing > 0 else 0.0
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._u_prev = np.zeros(self.n)
        self._rate = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """The term for one voltage block ``[N, n]`` (displacement [m]); the state moves on by N samples."""
        u = _block(u, self.n)
        out = np.empty((len(u), self.n))
        _velocity_run(u, self.gains * self.dp, self.exponent, RATE_REF, self._a, self.dt, self._u_prev,
                      self._rate, self._started, out)
        return out


class HysteresisStage:
    """Bouc-Wen hysteresis with the generalized (asymmetric) terms and an optional rate dependence.

    Replaces the nominal hysteresis part: ``Y_H = Dp·U − h``, ``dh = A·(1 + α·tanh(r/r_ref))∘dU − B(|dÛ|∘h) − Γ(dÛ∘|h|)
    − Δ1(dÛ∘h) − Δ2(|dÛ|∘|h|)`` where r is |dU/dt| smoothed over :data:`RATE_SMOOTHING` and r_ref =
    :data:`RATE_REF`.  ``alpha = 0`` and zero Δ give exactly the nominal :class:`BoucWenModel`.
    """

    def __init__(self, cfg: BoucWenConfig, alpha: float = 0.0, dt: float = 5e-5,
                 extras: "tuple[VelocityTerm | LoopShapeTerm | RatePlayTerm | RelayPlaneTerm, ...]" = ()):
        self.cfg = cfg
        self._p = params_of(cfg.arrays())
        if not math.isfinite(alpha):
            raise ValueError(f"hysteresis_rate_dependence.alpha: must be finite, got {alpha!r}")
        self.alpha, self.dt = float(alpha), float(dt)
        self._a_smooth = math.exp(-self.dt / RATE_SMOOTHING)
        for x in extras:
            if cfg.n_in != cfg.n_out or x.n != cfg.n_in:
                raise ValueError(f"{type(x).__name__}: one value per axis of a square hysteresis")
        self.extras = tuple(extras)
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._h = np.zeros(self.cfg.n_out)
        self._u_prev = np.zeros(self.cfg.n_in)
        self._rate = np.zeros(self.cfg.n_in)
        self._started = np.zeros(1, np.bool_)
        for x in self.extras:
            x.reset()

    def _loop(self, u: np.ndarray) -> np.ndarray:
        """The (generalized, rate-widened) Bouc-Wen output of one block."""
        y = np.empty((len(u), self.cfg.n_out))
        bw_model_rate_run(self._p, self.alpha, RATE_REF, self._a_smooth, self.dt, self._rate, self._h,
                          self._u_prev, self._started, u, y, np.empty_like(y))
        return y

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.cfg.n_in)
        y = self._loop(u)
        for x in self.extras:
            y = y + x.process(u)
        return y


@njit
def _relax2_run(x: np.ndarray, a: float, s1: np.ndarray, s2: np.ndarray, started: np.ndarray,
                out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Two cascaded unit-DC first-order relaxations (critically damped, pole ``a`` twice), per column; started
    settled at the first input."""
    N, n = x.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                s1[j] = x[t, j]
                s2[j] = x[t, j]
            s1[j] = a * s1[j] + (1.0 - a) * x[t, j]
            s2[j] = a * s2[j] + (1.0 - a) * s1[j]
            out[t, j] = s2[j]
        started[0] = True


class RelaxedHysteresisStage(HysteresisStage):
    """:class:`HysteresisStage` whose hysteretic state reaches the output through a critically damped relaxation
    ``1/(1 + s·τ)²`` (τ = ``relaxation`` [s]): ``Y_H = Dp·U − R_τ(h)``.  A viscous loop — it widens and turns with
    the frequency, unlike the ``alpha`` term, which widens it with the voltage rate.  Part of
    ``hysteresis_rate_dependence`` (parameter ``relaxation``)."""

    def __init__(self, cfg: BoucWenConfig, alpha: float = 0.0, dt: float = 5e-5, relaxation: float = 0.0,
                 extras: "tuple[VelocityTerm | LoopShapeTerm | RatePlayTerm | RelayPlaneTerm, ...]" = ()):
        if not (math.isfinite(relaxation) and relaxation > 0):
            raise ValueError(f"hysteresis_rate_dependence.relaxation: must be > 0 s, got {relaxation!r}")
        self.relaxation = float(relaxation)
        self._a_relax = math.exp(-dt / self.relaxation)
        super().__init__(cfg, alpha, dt, extras)

    def reset(self) -> None:
        """All states back to rest."""
        super().reset()
        self._r1 = np.zeros(self.cfg.n_out)
        self._r2 = np.zeros(self.cfg.n_out)
        self._r_started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.cfg.n_in)
        y = self._loop(u)
        lin = static_gain(u, self._p[0])  # Dp·U
        h = lin - y
        hr = np.empty_like(h)
        _relax2_run(h, self._a_relax, self._r1, self._r2, self._r_started, hr)
        res: np.ndarray = lin - hr
        for x in self.extras:
            res = res + x.process(u)
        return res


class BranchEvenTerm:
    """The even, branch-dependent part of an asymmetric loop: ``Y_i += (e_i + b_i·D_i(t))·Y_i²/LEVEL_REF`` with
    ``D_i = sign(Y_i − LP(Y_i))`` the direction of motion (LP over :data:`DIRECTION_TAU`): an ascending and a
    descending branch bent differently, which a point-symmetric loop cannot have.  Part of
    ``hysteresis_asymmetry`` (parameters ``even``, ``branch_even``)."""

    def __init__(self, even: ArrayLike, branch_even: ArrayLike, dt: float, n_axes: int = 2) -> None:
        self.n, self.dt = n_axes, float(dt)
        self.even = _per_axis(even, n_axes, "hysteresis_asymmetry.even")
        self.branch = _per_axis(branch_even, n_axes, "hysteresis_asymmetry.branch_even")
        self._a = math.exp(-self.dt / DIRECTION_TAU)
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._lp = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def terms(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, D·q) of every column, q = Y²/LEVEL_REF (advances the direction state)."""
        y = _block(y, self.n)
        lp = np.empty_like(y)
        _lp1_run(y, self._lp, self._started, self._a, lp)
        q = y * y / LEVEL_REF
        return q, np.sign(y - lp) * q

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        q, dq = self.terms(y)
        res: np.ndarray = y + q * self.even + dq * self.branch
        return res


@njit
def _lp1_run(u: np.ndarray, y_prev: np.ndarray, started: np.ndarray, a: float, out: np.ndarray) -> None:  # pragma: no cover - compiled
    N, n = u.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                y_prev[j] = u[t, j]
            y_prev[j] = a * y_prev[j] + (1.0 - a) * u[t, j]
            out[t, j] = y_prev[j]
        started[0] = True


@njit
def _play_run(y: np.ndarray, radii: np.ndarray, z: np.ndarray, started: np.ndarray,
              out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Classical (symmetric) play operators of every column: out[t, k, j] = z_kj − y_j, z_kj clipped to
    [y_j − r_k, y_j + r_k]; started at z = y."""
    N, n = y.shape
    K = radii.shape[0]
    for t in range(N):
        for j in range(n):
            v = y[t, j]
            for k in range(K):
                if not started[0]:
                    z[k, j] = v
                zk = z[k, j]
                if zk < v - radii[k]:
                    zk = v - radii[k]
                elif zk > v + radii[k]:
                    zk = v + radii[k]
                z[k, j] = zk
                out[t, k, j] = zk - v
        started[0] = True


class PlayWidthTerm:
    """Loop-width correction of the asymmetric hysteresis candidate: ``Y_i += Σ_k w_ki·(P_k(Y_i) − Y_i)``, with
    ``P_k`` the classical play operator of radius ``play_radii[k]`` [m] on the displacement (each term is ±r_k on
    the branches, and changes sides over a reversal of 2·r_k): a loop wider or narrower than the nominal
    Bouc-Wen's, by an amount that depends on how far the motion has gone since it last reversed.  ``play_gains``:
    [K][n] (or one value per radius, shared by the axes)."""

    def __init__(self, play_radii: ArrayLike, play_gains: ArrayLike, n_axes: int = 2) -> None:
        r = np.atleast_1d(np.asarray(play_radii, float)).reshape(-1)
        if r.size == 0 or not np.all(np.isfinite(r)) or np.any(r <= 0):
            raise ValueError(f"hysteresis_asymmetry.play_radii: expected positive radii [m], got {play_radii!r}")
        g = np.asarray(play_gains, float)
        if g.ndim <= 1:
            g = np.repeat(np.atleast_1d(g).reshape(-1, 1), n_axes, axis=1) if g.size == r.size else g
        if g.shape != (r.size, n_axes) or not np.all(np.isfinite(g)):
            raise ValueError(f"hysteresis_asymmetry.play_gains: expected [{r.size}][{n_axes}] finite values, got "
                             f"{play_gains!r}")
        self.radii, self.gains, self.n = r, g, n_axes
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._z = np.zeros((self.radii.size, self.n))
        self._started = np.zeros(1, np.bool_)

    def terms(self, y: np.ndarray) -> np.ndarray:
        """``P_k(Y) − Y`` as [N, K, n] (advances the operators' state)."""
        y = _block(y, self.n)
        out = np.empty((len(y), self.radii.size, self.n))
        _play_run(y, self.radii, self._z, self._started, out)
        return out

    def process(self, y: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        y = _block(y, self.n)
        res: np.ndarray = y + np.einsum("tkj,kj->tj", self.terms(y), self.gains)
        return res


@njit
def _rate_play_run(u: np.ndarray, radii: np.ndarray, rate_ref: float, a: float, dt: float, z: np.ndarray,
                   z0: np.ndarray, rate: np.ndarray, u_prev: np.ndarray, started: np.ndarray,
                   out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Per column j and radius k: ``P_{r_k·(1 + tanh(ρ_j/ρ_ref))}(U_j) − P_{r_k}(U_j)``, ρ = |ΔU|/dt low-passed by
    ``ρ ← a·ρ + (1 − a)·|ΔU|/dt``; the plays started at z = U."""
    N, n = u.shape
    K = radii.shape[0]
    for t in range(N):
        for j in range(n):
            v = u[t, j]
            if not started[0]:
                u_prev[j] = v
                rate[j] = 0.0
                for k in range(K):
                    z[k, j] = v
                    z0[k, j] = v
            rate[j] = a * rate[j] + (1.0 - a) * abs(v - u_prev[j]) / dt
            u_prev[j] = v
            g = 1.0 + math.tanh(rate[j] / rate_ref)
            for k in range(K):
                r = radii[k] * g
                if z[k, j] < v - r:
                    z[k, j] = v - r
                elif z[k, j] > v + r:
                    z[k, j] = v + r
                r = radii[k]
                if z0[k, j] < v - r:
                    z0[k, j] = v - r
                elif z0[k, j] > v + r:
                    z0[k, j] = v + r
                out[t, k, j] = z[k, j] - z0[k, j]
        started[0] = True


class RatePlayTerm:
    """Rate-dependent play widths at the hysteresis output: ``Y_H,i += Dp_ii·Σ_k w_ki·(P_{r_k·(1 + tanh(ρ_i/ρ_ref))}
    (U_i) − P_{r_k}(U_i))`` — Prandtl-Ishlinskii plays whose thresholds grow with the voltage rate ρ (|dU/dt|
    low-passed over ``smoothing`` [s]): a loop that widens with the rate and *keeps* its width at rest after a fast
    move (unlike a velocity term).  Radii [V], gains [K][n], ``rate_ref`` [V/s].  Part of
    ``hysteresis_rate_dependence`` (``rate_play_radii``, ``rate_play_gains``, ``rate_play_ref``,
    ``rate_play_smoothing``)."""

    def __init__(self, dp_diag: ArrayLike, radii: ArrayLike, gains: ArrayLike, rate_ref: float, smoothing: float,
                 dt: float) -> None:
        self.dp = np.asarray(dp_diag, float).reshape(-1)
        n = self.n = self.dp.size
        r = np.atleast_1d(np.asarray(radii, float)).reshape(-1)
        if r.size == 0 or not np.all(np.isfinite(r)) or np.any(r <= 0):
            raise ValueError(f"hysteresis_rate_dependence.rate_play_radii: expected positive radii [V], got {radii!r}")
        g = np.asarray(gains, float)
        if g.shape != (r.size, n) or not np.all(np.isfinite(g)):
            raise ValueError(f"hysteresis_rate_dependence.rate_play_gains: expected [{r.size}][{n}] finite values, "
                             f"got {gains!r}")
        if not (math.isfinite(rate_ref) and rate_ref > 0):
            raise ValueError(f"hysteresis_rate_dependence.rate_play_ref: must be > 0 V/s, got {rate_ref!r}")
        if not (math.isfinite(smoothing) and smoothing >= 0):
            raise ValueError(f"hysteresis_rate_dependence.rate_play_smoothing: must be >= 0 s, got {smoothing!r}")
        self.radii, self.gains, self.rate_ref, self.dt = r, g, float(rate_ref), float(dt)
        self._a = math.exp(-self.dt / smoothing) if smoothing > 0 else 0.0
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        K = self.radii.size
        self._z, self._z0 = np.zeros((K, self.n)), np.zeros((K, self.n))
        self._rate, self._u_prev = np.zeros(self.n), np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def terms(self, u: np.ndarray) -> np.ndarray:
        """The widened-minus-static plays × Dp_ii as [N, K, n] (advances the state)."""
        u = _block(u, self.n)
        out = np.empty((len(u), self.radii.size, self.n))
        _rate_play_run(u, self.radii, self.rate_ref, self._a, self.dt, self._z, self._z0, self._rate,
                       self._u_prev, self._started, out)
        out *= self.dp
        return out

    def process(self, u: np.ndarray) -> np.ndarray:
        """The term for one voltage block ``[N, n]`` (displacement [m]); the state moves on by N samples."""
        res: np.ndarray = np.einsum("tkj,kj->tj", self.terms(u), self.gains)
        return res


#: reference voltage of the loop-shape terms at the hysteresis output [V]
LOOP_SHAPE_UREF = 100.0


class LoopShapeTerm:
    """Loop-shape terms of the asymmetric hysteresis at the hysteresis output (before the creep and the dynamics,
    where the loop lives): ``Y_H,i += Dp_ii·[e_i·U_i²/U_ref + Σ_k (w_ki + v_ki·U_i/U_ref)·(P_k(U_i) − U_i)]``,
    ``P_k`` the classical play operator of radius ``radii[k]`` [V] on the voltage, U_ref = :data:`LOOP_SHAPE_UREF`.
    ``e``: a static even bend (branches not point-symmetric); ``w``: a loop wider or narrower than the Bouc-Wen's
    (a Prandtl-Ishlinskii correction); ``v``: a loop whose width changes with the level (wider at the top than at
    the bottom — what a Preisach density off the symmetric line gives).  Part of ``hysteresis_asymmetry``
    (``input_even``, ``input_play_radii``, ``input_play_gains``, ``input_play_level_gains``)."""

    def __init__(self, dp_diag: ArrayLike, even: ArrayLike, radii: ArrayLike, gains: ArrayLike,
                 level_gains: ArrayLike) -> None:
        self.dp = np.asarray(dp_diag, float).reshape(-1)
        n = self.n = self.dp.size
        self.even = _per_axis(even, n, "hysteresis_asymmetry.input_even")
        r = np.atleast_1d(np.asarray(radii, float)).reshape(-1)
        if r.size == 0 or not np.all(np.isfinite(r)) or np.any(r <= 0):
            raise ValueError(f"hysteresis_asymmetry.input_play_radii: expected positive radii [V], got {radii!r}")
        self.radii = r
        self.gains = self._matrix(gains, "input_play_gains")
        self.level_gains = self._matrix(level_gains, "input_play_level_gains")
        self.reset()

    def _matrix(self, g: ArrayLike, what: str) -> np.ndarray:
        a = np.asarray(g, float)
        if a.shape != (self.radii.size, self.n) or not np.all(np.isfinite(a)):
            raise ValueError(f"hysteresis_asymmetry.{what}: expected [{self.radii.size}][{self.n}] finite values, "
                             f"got {g!r}")
        return a

    def reset(self) -> None:
        """All states back to rest."""
        self._z = np.zeros((self.radii.size, self.n))
        self._started = np.zeros(1, np.bool_)

    def terms(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(U²/U_ref, P_k(U) − U, (P_k(U) − U)·U/U_ref)`` as [N, n], [N, K, n], [N, K, n], each × Dp_ii (advances
        the operators' state)."""
        u = _block(u, self.n)
        w = np.empty((len(u), self.radii.size, self.n))
        _play_run(u, self.radii, self._z, self._started, w)
        w *= self.dp
        return u * u / LOOP_SHAPE_UREF * self.dp, w, w * (u / LOOP_SHAPE_UREF)[:, None, :]

    def process(self, u: np.ndarray) -> np.ndarray:
        """The term for one voltage block ``[N, n]`` (displacement [m]); the state moves on by N samples."""
        q, w, wl = self.terms(u)
        res: np.ndarray = q * self.even + np.einsum("tkj,kj->tj", w, self.gains) + \
            np.einsum("tkj,kj->tj", wl, self.level_gains)
        return res


@njit
def _relay_run(u: np.ndarray, alpha: np.ndarray, beta: np.ndarray, state: np.ndarray, started: np.ndarray,
               out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Preisach relays of every column: out[t, r, j] = state_rj, switched to +1 where U_j ≥ α_r and to −1 where
    U_j ≤ β_r; at the first input a relay is up when U_j is above its centre (α_r + β_r)/2."""
    N, n = u.shape
    R = alpha.shape[0]
    for t in range(N):
        for j in range(n):
            v = u[t, j]
            for r in range(R):
                if not started[0]:
                    state[r, j] = 1.0 if v >= 0.5 * (alpha[r] + beta[r]) else -1.0
                if v >= alpha[r]:
                    state[r, j] = 1.0
                elif v <= beta[r]:
                    state[r, j] = -1.0
                out[t, r, j] = state[r, j]
        started[0] = True


class RelayPlaneTerm:
    """A hysteretic term with its own loop at the hysteresis output: a discretised Preisach plane on the voltage,
    ``Y_H,i += Dp_ii·Σ_r w_ri·γ_r(U_i)``, γ_r the relay that switches up at ``alpha[r]`` and down at ``beta[r]`` ≤
    ``alpha[r]`` [V] (state ±1).  Weights anywhere on the plane make loops of any shape — off the symmetric line
    (a density shifted to positive voltages: a loop that lives at the top of the stroke), narrow or wide, with
    minor loops that depend on the reversal history — which the Bouc-Wen's Δ terms and the loop-shape plays
    cannot.  The term is linear in the weights ``gains`` [R][n] (volts of equivalent input).  Part of
    ``hysteresis_asymmetry`` (``relay_alpha``, ``relay_beta``, ``relay_gains``)."""

    def __init__(self, dp_diag: ArrayLike, alpha: ArrayLike, beta: ArrayLike, gains: ArrayLike) -> None:
        self.dp = np.asarray(dp_diag, float).reshape(-1)
        n = self.n = self.dp.size
        a = np.atleast_1d(np.asarray(alpha, float)).reshape(-1)
        b = np.atleast_1d(np.asarray(beta, float)).reshape(-1)
        if a.size == 0 or a.shape != b.shape or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))) or \
                np.any(b > a):
            raise ValueError(f"hysteresis_asymmetry.relay_alpha/relay_beta: expected as many finite thresholds "
                             f"[V] with beta <= alpha, got {alpha!r}, {beta!r}")
        g = np.asarray(gains, float)
        if g.shape != (a.size, n) or not np.all(np.isfinite(g)):
            raise ValueError(f"hysteresis_asymmetry.relay_gains: expected [{a.size}][{n}] finite values, got "
                             f"{gains!r}")
        self.alpha, self.beta, self.gains = a, b, g
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._state = np.zeros((self.alpha.size, self.n))
        self._started = np.zeros(1, np.bool_)

    def terms(self, u: np.ndarray) -> np.ndarray:
        """The relays' states × Dp_ii as [N, R, n] (advances the relays)."""
        u = _block(u, self.n)
        out = np.empty((len(u), self.alpha.size, self.n))
        _relay_run(u, self.alpha, self.beta, self._state, self._started, out)
        out *= self.dp
        return out

    def process(self, u: np.ndarray) -> np.ndarray:
        """The term for one voltage block ``[N, n]`` (displacement [m]); the state moves on by N samples."""
        res: np.ndarray = np.einsum("tkj,kj->tj", self.terms(u), self.gains)
        return res


def asymmetric_hysteresis_config(hcfg: BoucWenConfig, delta1: ArrayLike, delta2: ArrayLike) -> BoucWenConfig:
    """The nominal Bouc-Wen with diagonal generalized terms ``Δ1 = diag(delta1)``, ``Δ2 = diag(delta2)`` added."""
    n = hcfg.n_out
    p = hcfg.arrays()
    D1 = p["Delta1"] + np.diag(_per_axis(delta1, n, "hysteresis_asymmetry.Delta1"))
    D2 = p["Delta2"] + np.diag(_per_axis(delta2, n, "hysteresis_asymmetry.Delta2"))
    return replace(hcfg, Delta1=tuple(map(tuple, D1)), Delta2=tuple(map(tuple, D2)))
