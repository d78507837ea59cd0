"""Voltage-side effects (``pre`` stages): the amplifier and timing between the commanded and the acting voltage.

:class:`InputDelay` (a pure, fractional delay), :class:`AmplifierSlewLimit`, :class:`AmplifierSaturation` (and
:class:`AsymmetricSaturation`, rails that differ by sign) and :class:`AmplifierBandwidth` (a 1st- or 2nd-order
roll-off), each with its compiled per-sample loop.  A stage maps a voltage block ``[N, axes]`` [V] to a voltage
block, carries its state between blocks and gives the same output whatever the block split.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from ..._jit import njit
from ...kernels.limits import limit_run  # the driver guard's limiter (one source)
from .common import _block, _per_axis

__all__ = ["InputDelay", "AllPassDelay", "AmplifierSlewLimit", "AmplifierSaturation", "AsymmetricSaturation",
           "AmplifierBandwidth", "allpass_steps_per_sample"]


class InputDelay:
    """Pure (fractional) delay of the voltage: ``U_out(t) = U(t − delay)`` by linear interpolation between samples.

    Before the first sample the voltage is held at its first value (the actuator was at rest there).
    """

    def __init__(self, delay: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(delay) and delay >= 0):
            raise ValueError(f"input_delay.delay: must be >= 0 s, got {delay!r}")
        self.delay, self.dt, self.n = float(delay), float(dt), n_axes
        d = self.delay / self.dt
        self._m = int(math.floor(d))
        self._frac = d - self._m
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._hist: np.ndarray | None = None  # last m + 1 input samples, oldest first

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.n)
        m = self._m
        if self._hist is None:
            if len(u) == 0:
                return u.copy()
            self._hist = np.repeat(u[:1], m + 1, axis=0)
        out = np.empty_like(u)
        self._hist = _frac_delay_run(self._hist, u, self._frac, out)
        return out


@njit
def _frac_delay_run(hist: np.ndarray, u: np.ndarray, frac: float, out: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """:class:`InputDelay` on one block without the temporaries: output k = (1 − frac)·ext[k+1] + frac·ext[k] of
    ``ext = [hist; u]`` (``hist`` = the last m + 1 inputs); returns the new history."""
    h = hist.shape[0]
    N, n = u.shape
    for k in range(N):
        for j in range(n):
            i1 = k + 1
            a = hist[i1, j] if i1 < h else u[i1 - h, j]
            if frac > 0:
                b = hist[k, j] if k < h else u[k - h, j]
                out[k, j] = (1.0 - frac) * a + frac * b
            else:
                out[k, j] = a
    new = np.empty_like(hist)
    for r in range(h):
        i = N + r  # ext index of the kept sample: the last h of ext (length h + N)
        for j in range(n):
            new[r, j] = hist[i, j] if i < h else u[i - h, j]
    return new


class AmplifierSlewLimit:
    """Amplifier slew-rate limit: the voltage changes by at most ``rate·dt`` per sample [V/s]."""

    def __init__(self, rate: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"amplifier_slew_limit.rate: must be > 0 V/s, got {rate!r}")
        self.rate, self.dt, self.n = float(rate), float(dt), n_axes
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._prev = np.zeros(self.n)
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.n)
        out = np.empty_like(u)
        limit_run(u, self._prev, self._started, np.inf, self.rate * self.dt, out, np.zeros(2, np.int64))
        return out


class AmplifierSaturation:
    """Amplifier output rails: the voltage is clipped to ``[−limit, +limit]`` [V] (memoryless)."""

    def __init__(self, limit: float, n_axes: int = 2):
        if not (math.isfinite(limit) and limit > 0):
            raise ValueError(f"amplifier_saturation.limit: must be > 0 V, got {limit!r}")
        self.limit, self.n = float(limit), n_axes

    def reset(self) -> None:
        """All states back to rest."""
        pass

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        res: np.ndarray = np.clip(_block(u, self.n), -self.limit, self.limit)
        return res


class AsymmetricSaturation:
    """Amplifier rails that differ by sign: the voltage is clipped to ``[−lower_limit, +limit]`` [V]
    (``amplifier_saturation`` with ``lower_limit`` given; memoryless)."""

    def __init__(self, limit: float, lower_limit: float, n_axes: int = 2):
        for v, what in ((limit, "limit"), (lower_limit, "lower_limit")):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"amplifier_saturation.{what}: must be > 0 V, got {v!r}")
        self.limit, self.lower_limit, self.n = float(limit), float(lower_limit), n_axes

    def reset(self) -> None:
        """All states back to rest."""
        pass

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``."""
        res: np.ndarray = np.clip(_block(u, self.n), -self.lower_limit, self.limit)
        return res


@njit
def _ap2_run(u: np.ndarray, state: np.ndarray, started: np.ndarray, g: np.ndarray, a1: np.ndarray, a2: np.ndarray,
             out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Per column j: ``y[k] = g_j·u[k] − a1_j·y[k−1] − a2_j·y[k−2]``, started settled at the first input."""
    N, n = u.shape
    for t in range(N):
        for j in range(n):
            if not started[0]:
                state[0, j] = u[t, j]
                state[1, j] = u[t, j]
            y = g[j] * u[t, j] - a1[j] * state[0, j] - a2[j] * state[1, j]
            state[1, j] = state[0, j]
            state[0, j] = y
            out[t, j] = y
        started[0] = True


def _pole_matched(cutoff: float, order: int, damping: float, dt: float) -> tuple[float, float, float]:
    """Unit-DC-gain all-pole discretisation (poles ``e^{pT}``) of a 1st/2nd-order low-pass: (g, a1, a2).

    As the cutoff grows beyond the sample rate the poles go to 0 and the filter to the identity, so "no bandwidth
    limit" is a point of the parameter space (unlike a ZOH or bilinear discretisation)."""
    w = 2.0 * math.pi * cutoff
    if order == 1:
        a = math.exp(-w * dt)
        return 1.0 - a, -a, 0.0
    z = damping
    if z < 1.0:
        r = math.exp(-z * w * dt)
        a1 = -2.0 * r * math.cos(w * dt * math.sqrt(1.0 - z * z))
        a2 = r * r
    else:
        s = math.sqrt(z * z - 1.0)
        p1, p2 = -w * (z - s), -w * (z + s)
        a1 = -(math.exp(p1 * dt) + math.exp(p2 * dt))
        a2 = math.exp((p1 + p2) * dt)
    return 1.0 + a1 + a2, a1, a2


@njit
def _ss_run(u: np.ndarray, state: np.ndarray, started: np.ndarray, phi: np.ndarray, gam: np.ndarray,
            cpsi: np.ndarray, clam: np.ndarray, xss: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Per column j, a small state-space filter: ``y = cpsi_j·x + clam_j·u[k]``, ``x ← phi_j·x + gam_j·u[k]``; the
    state ``[ns, n]`` started settled at the first input (``x = xss·u[0]``)."""
    N, n = u.shape
    ns = xss.shape[0]
    tmp = np.empty(ns)
    for t in range(N):
        for j in range(n):
            v = u[t, j]
            if not started[0]:
                for i in range(ns):
                    state[i, j] = xss[i] * v
            y = clam[j] * v
            for i in range(ns):
                y += cpsi[j, i] * state[i, j]
            for i in range(ns):
                acc = gam[j, i] * v
                for q in range(ns):
                    acc += phi[j, i, q] * state[q, j]
                tmp[i] = acc
            for i in range(ns):
                state[i, j] = tmp[i]
            out[t, j] = y
        started[0] = True


def _lowpass_ss(cutoff: float, order: int, damping: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous state space ``(A, B, C)`` of the unit-DC-gain low-pass of order 1, 2 or 3 (3 = 1st × 2nd)."""
    w = 2.0 * math.pi * cutoff
    z = damping
    if order == 1:
        return np.array([[-w]]), np.array([w]), np.array([1.0])
    if order == 2:
        return np.array([[0.0, 1.0], [-w * w, -2 * z * w]]), np.array([0.0, w * w]), np.array([1.0, 0.0])
    A = np.array([[-w, 0.0, 0.0], [0.0, 0.0, 1.0], [w * w, -w * w, -2 * z * w]])
    return A, np.array([w, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


def _bessel_ss(cutoff: float, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous state space ``(A, B, C)`` of the Bessel (maximally flat group delay) low-pass of ``order``, −3 dB
    at ``cutoff`` [Hz], unit DC gain."""
    import scipy.signal

    b, a = scipy.signal.bessel(order, 2.0 * math.pi * cutoff, analog=True, norm="mag")
    A, B, C, _ = scipy.signal.tf2ss(b, a)
    return A, B[:, 0], C[0]


def _interval_averaged(cutoff: float, order: int, damping: float, dt: float,
                       form: str = "filter") -> tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray]:
    """:func:`_interval_averaged_ss` of the low-pass of :func:`_lowpass_ss` (``form='bessel'``: of
    :func:`_bessel_ss`)."""
    A, B, C = _bessel_ss(cutoff, order) if form == "bessel" else _lowpass_ss(cutoff, order, damping)
    return _interval_averaged_ss(A, B, C, 0.0, dt)


def _interval_averaged_ss(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: float,
                          dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray]:
    """The continuous low-pass driven by the DAC's staircase (the voltage held over each sample interval), its output
    averaged over each interval: ``(Φ, Γ, C·Ψ, C·Λ, x_ss)`` with ``x ← Φx + Γu`` and ``ȳ = CΨx + CΛu``.

    The average over the interval is the staircase that, held in turn, carries the same mean voltage into the
    plant's ZOH model: its DC group delay is the filter's own (a pole-matched or ZOH discretisation is half a sample
    early or late, which a delay candidate then takes for the effect).  Exact, by one matrix exponential (Van Loan):
    ``expm([[M, I], [0, 0]]·T)`` with ``M = [[A, B], [0, 0]]`` gives ``e^{MT}`` and ``∫₀ᵀ e^{Mσ} dσ``.  As the
    cutoff goes far above the sample rate the filter tends to the identity ("no bandwidth limit" is a point of the
    parameter space, not a disguised delay).
    """
    from scipy.linalg import expm

    ns = A.shape[0]
    M = np.zeros((ns + 1, ns + 1))
    M[:ns, :ns], M[:ns, ns] = A, B
    big = np.zeros((2 * (ns + 1), 2 * (ns + 1)))
    big[:ns + 1, :ns + 1] = M * dt
    big[:ns + 1, ns + 1:] = np.eye(ns + 1) * dt
    E = expm(big)
    phi, gam = E[:ns, :ns], E[:ns, ns]
    integ = E[:ns + 1, ns + 1:] / dt
    psi, lam = integ[:ns, :ns], integ[:ns, ns]
    xss = -np.linalg.solve(A, B)
    return phi, gam, C @ psi, float(C @ lam) + float(D), xss


class AmplifierBandwidth:
    """Amplifier roll-off on the voltage: first order ``1/(s/ωc + 1)``, second order ``ωc²/(s² + 2ζωc·s + ωc²)``
    (``order=2``, damping ``ζ``) or third order, the product of the two (``order=3``; ζ = 0.5 is Butterworth), with
    a cutoff per axis or shared.  ``form='bessel'``: the Bessel low-pass of that order instead (−3 dB at the cutoff,
    maximally flat group delay: in the band it is a delay, its magnitude falls near the cutoff; ``damping`` unused).

    The continuous filter driven by the DAC's staircase, its output averaged over each sample interval
    (:func:`_interval_averaged`): unit DC gain, the filter's own delay, the identity as the cutoff goes to
    infinity; started settled at the first voltage it sees.  Unlike a pure delay it attenuates (≈ (f/fc)²/2 at
    order 1) and rounds steps instead of shifting them.
    """

    def __init__(self, cutoff: ArrayLike, dt: float, n_axes: int = 2, order: int = 1,
                 damping: float = 1 / math.sqrt(2), form: str = "filter") -> None:
        c = _per_axis(cutoff, n_axes, "amplifier_bandwidth.cutoff")
        if form not in ("filter", "bessel"):
            raise ValueError(f"amplifier_bandwidth.form: must be 'filter' or 'bessel', got {form!r}")
        if not np.all(c > 0):
            raise ValueError(f"amplifier_bandwidth.cutoff: must be > 0 Hz, got {cutoff!r}")
        if int(order) not in (1, 2, 3):
            raise ValueError(f"amplifier_bandwidth.order: must be 1, 2 or 3, got {order!r}")
        if not (math.isfinite(damping) and damping > 0):
            raise ValueError(f"amplifier_bandwidth.damping: must be > 0, got {damping!r}")
        self.cutoff, self.dt, self.n = c, float(dt), n_axes
        self.order, self.damping, self.form = int(order), float(damping), form
        parts = [_interval_averaged(float(f), self.order, self.damping, self.dt, form) for f in c]
        self._phi = np.ascontiguousarray(np.stack([p[0] for p in parts]))
        self._gam = np.ascontiguousarray(np.stack([p[1] for p in parts]))
        self._cpsi = np.ascontiguousarray(np.stack([p[2] for p in parts]))
        self._clam = np.array([p[3] for p in parts])
        self._xss = np.ascontiguousarray(parts[0][4])
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._state = np.zeros((self.order, self.n))
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.n)
        out = np.empty_like(u)
        _ss_run(u, self._state, self._started, self._phi, self._gam, self._cpsi, self._clam, self._xss, out)
        return out



class AllPassDelay:
    """A delay of rational (all-pass) form: the second-order Padé approximant of ``e^{−s·delay}``,
    ``(1 − sT/2 + (sT)²/12)/(1 + sT/2 + (sT)²/12)`` (``input_delay`` with ``form='allpass'``).

    Unit gain at every frequency, a phase lag that follows the delay's up to ``ωT ≈ 2`` — the delay as an analogue
    stage, a lagging loop or a model written in transfer functions has it.  Unlike the interpolated
    :class:`InputDelay` it does not attenuate within the band, and its response to each DAC step jumps, undershoots
    and recovers within a few sample intervals: a rate-independent hysteresis behind it sees that excursion.  Driven
    by the DAC's staircase, the output averaged over each interval (:func:`_interval_averaged_ss`; exact), started
    settled at the first voltage; the replay runs it at a fine internal rate (:func:`allpass_steps_per_sample`).
    """

    def __init__(self, delay: float, dt: float, n_axes: int = 2):
        if not (math.isfinite(delay) and delay > 0):
            raise ValueError(f"input_delay.delay: must be > 0 s for form 'allpass', got {delay!r}")
        self.delay, self.dt, self.n = float(delay), float(dt), n_axes
        T = self.delay
        # H = 1 − (12/T)·s/(s² + (6/T)s + 12/T²)
        A = np.array([[0.0, 1.0], [-12.0 / T ** 2, -6.0 / T]])
        B = np.array([0.0, 1.0])
        C = np.array([0.0, -12.0 / T])
        phi, gam, cpsi, clam, xss = _interval_averaged_ss(A, B, C, 1.0, self.dt)
        self._phi = np.ascontiguousarray(np.repeat(phi[None], n_axes, axis=0))
        self._gam = np.ascontiguousarray(np.repeat(gam[None], n_axes, axis=0))
        self._cpsi = np.ascontiguousarray(np.repeat(cpsi[None], n_axes, axis=0))
        self._clam = np.full(n_axes, clam)
        self._xss = np.ascontiguousarray(xss)
        self.reset()

    def reset(self) -> None:
        """All states back to rest."""
        self._state = np.zeros((2, self.n))
        self._started = np.zeros(1, np.bool_)

    def process(self, u: np.ndarray) -> np.ndarray:
        """Run one block ``[N, n_in] → [N, n_out]``; the state moves on by N samples."""
        u = _block(u, self.n)
        out = np.empty_like(u)
        _ss_run(u, self._state, self._started, self._phi, self._gam, self._cpsi, self._clam, self._xss, out)
        return out


#: the replay resolves an all-pass delay's step response (time constant T/3) with at least this many internal steps
#: per time constant, and takes at most ALLPASS_MAX_STEPS internal steps per record sample
ALLPASS_STEPS_PER_TC = 8
ALLPASS_MAX_STEPS = 16


def allpass_steps_per_sample(delay: float, dt: float) -> int:
    """Internal steps per record sample for :class:`AllPassDelay`: ``dt/k ≤ (delay/3)/ALLPASS_STEPS_PER_TC``."""
    if not (delay > 0):
        return 1
    return int(min(ALLPASS_MAX_STEPS, max(1, math.ceil(3 * ALLPASS_STEPS_PER_TC * dt / delay))))
