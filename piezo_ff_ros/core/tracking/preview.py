"""Preview stage: shape a known reference so that the compensated stage reproduces the reference itself.

The paper's cascade makes the stage follow the reference model, ``Y ≈ T·Y_R`` with ``T = G_L·C ≈ W_r`` (settling
≈ 33 ms), not ``Y_R``.  Given the reference ahead, this stage sends ``Y_R' = T⁻¹·F·r`` instead of r:

- **stable inversion** (Devasia–Chen–Paden, in discrete time): ``T(e^{jω})⁻¹`` evaluated on a dense frequency grid
  is the transfer function of the *two-sided* stable inverse — its causal part carries the inverse's stable poles,
  its anticausal part the ones coming from the non-minimum-phase zeros of T (G_L has right-half-plane zeros).  Its
  impulse response, truncated to ``horizon_s`` before and ``tail_s`` after the current sample (cosine-tapered
  ends), is run as an FIR filter on the reference stream, which arrives ``horizon_s`` ahead.  ``F`` is a zero-phase
  low-pass (``bandwidth_hz``) that keeps the inverse finite where T vanishes (above the resonances).
- **constrained receding horizon**: when the candidate above would ask more than the voltage or slew limit
  (predicted exactly by a replica of the cascade, model = plant), the next ``qp_step_s`` of output is chosen by a
  least-squares over ``qp_horizon_s`` — tracking error, subject to ``|U| ≤ voltage − voltage_margin`` and the slew
  limit — instead of letting the amplifier clamp.  Moves are parametrised by knots every ``qp_knot_s`` (linear
  interpolation), the voltage linearised around the candidate (the hysteresis slope is left out; a second pass
  re-linearises).

Stream convention: the stage's input at stream index i is the reference at ``i + preview_samples`` (the trajectory
node's ``preview_s``); its output at i is the shaped reference for sample i.  Before the stream the reference is 0
(at rest, as the cascade after a reset); the first ``preview_samples`` reference values, never received, are taken
equal to the first one received.  Everything is aligned on absolute sample indices (the constrained chunks too), so
the output is bit-identical whatever the block split.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..stage import as_block
from .._jit import njit
from ..config import ConfigError, PiezoConfig, dataclass_from_mapping
from .linear import CascadeReplica, CompensatedModel, ControllerABCD
from .qp import QPSolver

__all__ = ["PreviewConfig", "InverseKernel", "design_inverse", "PreviewStage"]


def _positive(value: Any, name: str, allow_zero: bool = False) -> float:
    if isinstance(value, bool):
        raise ConfigError(name, f"expected a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(name, f"expected a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ConfigError(name, f"must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return v


@dataclass(frozen=True)
class PreviewConfig:
    """Settings of the preview stage (validated on construction; errors name the field as ``preview.<name>``)."""

    horizon_s: float = 0.02          #: anticausal extent of the inverse = reference needed ahead [s]
    tail_s: float = 0.1              #: causal extent of the inverse [s]
    bandwidth_hz: float = 500.0      #: cut-off of the zero-phase low-pass F
    filter_order: int = 4            #: |F| = 1/(1 + (f/bandwidth)^(2·order))
    constrained: bool = False        #: receding-horizon constrained least-squares where the limits bind (slow)
    qp_horizon_s: float = 0.02       #: length of the constrained problem [s]
    qp_step_s: float = 0.005         #: output decided per constrained problem [s]
    qp_knot_s: float = 0.0005        #: spacing of the move knots [s]
    voltage_margin: float = 2.0      #: V kept below the voltage limit (hysteresis slope, linearisation)

    def __post_init__(self) -> None:
        for name in ("horizon_s", "tail_s", "bandwidth_hz", "qp_horizon_s", "qp_step_s", "qp_knot_s"):
            object.__setattr__(self, name, _positive(getattr(self, name), f"preview.{name}"))
        object.__setattr__(self, "voltage_margin", _positive(self.voltage_margin, "preview.voltage_margin", True))
        o = self.filter_order
        if isinstance(o, bool) or not isinstance(o, (int, float)) or int(o) != o or not 1 <= int(o) <= 10:
            raise ConfigError("preview.filter_order", f"must be an integer in 1…10, got {o!r}")
        object.__setattr__(self, "filter_order", int(o))
        if not isinstance(self.constrained, bool):
            raise ConfigError("preview.constrained", f"must be true or false, got {self.constrained!r}")
        if self.qp_step_s > self.qp_horizon_s:
            raise ConfigError("preview.qp_step_s", f"must be <= qp_horizon_s ({self.qp_horizon_s}), got {self.qp_step_s}")
        for name, top in (("horizon_s", 1.0), ("tail_s", 2.0), ("qp_horizon_s", 0.2)):
            if getattr(self, name) > top:
                raise ConfigError(f"preview.{name}", f"must be <= {top:g} s, got {getattr(self, name)}")

    @staticmethod
    def from_dict(d: Mapping[str, Any] | None) -> "PreviewConfig":
        """From a mapping of the field names (unknown keys refused, naming them and the closest known one)."""
        return dataclass_from_mapping(PreviewConfig, d, "preview")

    def to_dict(self) -> dict[str, Any]:
        """The settings as a plain mapping (the inverse of :meth:`from_dict`)."""
        return dataclasses.asdict(self)

    def samples(self, fs: float) -> dict[str, int]:
        """The durations as sample counts at rate ``fs``."""
        q = max(1, int(round(self.qp_knot_s * fs)))
        h = max(q, int(round(self.qp_horizon_s * fs)) // q * q)
        return {"horizon": int(round(self.horizon_s * fs)), "tail": int(round(self.tail_s * fs)),
                "qp_horizon": h, "qp_step": min(h, max(1, int(round(self.qp_step_s * fs)))), "qp_knot": q}

    def preview_samples(self, fs: float) -> int:
        """How far ahead the reference must arrive (samples): the inverse's horizon, plus the constrained one."""
        s = self.samples(fs)
        return int(s["horizon"] + (s["qp_horizon"] if self.constrained else 0))


@dataclass(frozen=True)
class InverseKernel:
    """Truncated two-sided inverse ``g[lag]``, lag = −horizon … tail, as taps ``G[j] = g[j − horizon]``."""

    taps: np.ndarray        #: [horizon + tail + 1, axes, axes]
    horizon: int
    tail: int
    truncation: dict[str, Any]  #: kernel envelope beyond the kept range and the lags holding 1-1e-3 / 1-1e-6 of it

    @property
    def dc_gain(self) -> np.ndarray:
        """Sum of the taps ``[axes, axes]`` (the inverse's static gain)."""
        g: np.ndarray = self.taps.sum(axis=0)
        return g


def lowpass_response(f: np.ndarray, bandwidth_hz: float, order: int) -> np.ndarray:
    """Zero-phase ``|F| = 1/(1 + (f/bandwidth)^(2·order))``."""
    out: np.ndarray = 1.0 / (1.0 + (np.abs(f) / bandwidth_hz) ** (2 * order))
    return out


def design_inverse(model: CompensatedModel, cfg: PreviewConfig) -> InverseKernel:
    """The stable two-sided inverse of ``model.T`` times F, truncated and tapered (see the module docstring)."""
    fs = 1.0 / model.dt
    s = cfg.samples(fs)
    La, M = s["horizon"], s["tail"]
    n_fft = max(len(model.T), 1 << int(math.ceil(math.log2(4 * (La + M + 1)))))
    f, Tf = model.frequency_response(n_fft)
    F = lowpass_response(f, cfg.bandwidth_hz, cfg.filter_order)
    G = np.linalg.inv(Tf) * F[:, None, None]
    g = np.fft.irfft(G, n=n_fft, axis=0)             # g[n] for lag n mod n_fft
    lags = np.arange(-La, M + 1)
    taps = g[lags % n_fft].copy()
    env = np.abs(g).max(axis=(1, 2))
    total = env.max()
    all_lags = np.fft.fftfreq(n_fft, 1.0 / n_fft).astype(int)
    outside = (all_lags < -La) | (all_lags > M)
    trunc = {"envelope_outside_relative": float(env[outside].max() / total) if outside.any() else 0.0}
    for label, thr in (("1e-3", 1e-3), ("1e-6", 1e-6)):
        sig = all_lags[env > thr * total]
        trunc[f"anticausal_lags_{label}"] = int(max(0, -sig.min()))
        trunc[f"causal_lags_{label}"] = int(max(0, sig.max()))
    # cosine tapers over the outer 10 % of each side (a hard cut rings in frequency)
    w = np.ones(len(lags))
    for side, n_side in ((lags < 0, La), (lags > 0, M)):
        nt = max(1, n_side // 10)
        pos = np.abs(lags[side])
        ramp = np.clip((n_side - pos) / nt, 0.0, 1.0)
        w[side] = 0.5 - 0.5 * np.cos(np.pi * ramp)
    taps *= w[:, None, None]
    # keep the static gain exact: put the truncated sum's defect on lag 0
    T0 = model.T.sum(axis=0)
    taps[La] += np.linalg.inv(T0) - taps.sum(axis=0)
    return InverseKernel(np.ascontiguousarray(taps), La, M, trunc)


@njit
def _fir_run(taps: np.ndarray, r: np.ndarray, start: int, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[k] = Σ_j taps[j] · r[start + k − j]`` (MIMO; fixed summation order → split-invariant)."""
    nt, na, nb = taps.shape
    for k in range(out.shape[0]):
        for i in range(na):
            acc = 0.0
            for j in range(nt):
                p = start + k - j
                for b in range(nb):
                    acc += taps[j, i, b] * r[p, b]
            out[k, i] = acc


class PreviewStage:
    """Streaming ``reference (preview_samples ahead) [m] → shaped reference [m]`` for the cascade.

    Parameters
    ----------
    cfg : PiezoConfig
        The model the cascade compensates (its limits bound the constrained mode).
    controller : tuple (A, B, C, D) or None
        The cascade's C(s) (``cascade.vibration.continuous``); None when the vibration stage is off.
    preview : PreviewConfig
        Settings.
    model : CompensatedModel, optional
        Precomputed impulse responses (else computed here, ~0.1 s).
    """

    PASSES = 5   #: re-linearisations at most (the hysteresis slope is not in the linear voltage map)

    def __init__(self, cfg: PiezoConfig, controller: ControllerABCD | None, preview: PreviewConfig | None = None,
                 model: CompensatedModel | None = None) -> None:
        self.cfg = cfg
        self.settings = preview or PreviewConfig()
        self.model = model or CompensatedModel.from_config(cfg, controller)
        self.kernel = design_inverse(self.model, self.settings)
        self.fs = cfg.sample_rate
        s = self.settings.samples(self.fs)
        self._La, self._M = s["horizon"], s["tail"]
        self.preview_samples = self.settings.preview_samples(self.fs)
        self.n_axes = cfg.n_axes
        self.constrained = self.settings.constrained
        self.replica = CascadeReplica(cfg, controller) if self.constrained else None
        if self.constrained:
            self._setup_qp(s)
        self.qp_solves = 0           #: constrained problems solved since reset
        self.qp_unconverged = 0
        self.reset()

    # -- constrained problem (P, A fixed; q, bounds per chunk) ------------------------------------------------------
    def _setup_qp(self, s: dict[str, int]) -> None:
        H, q, na = s["qp_horizon"], s["qp_knot"], self.n_axes
        self._H, self._B = H, s["qp_step"]
        knots = np.arange(0, H, q)
        if knots[-1] != H - 1:
            knots = np.append(knots, H - 1)
        Phi1 = np.zeros((H, len(knots)))
        for i in range(len(knots) - 1):
            a, b = knots[i], knots[i + 1]
            t = (np.arange(a, b + 1) - a) / (b - a)
            Phi1[a:b + 1, i] = np.maximum(Phi1[a:b + 1, i], 1 - t)
            Phi1[a:b + 1, i + 1] = np.maximum(Phi1[a:b + 1, i + 1], t)
        self._Phi = np.kron(Phi1, np.eye(na))                      # sample-major rows, knot-major columns
        um = 1e6                                                   # the problem in µm and V (well scaled)
        self._TPhi = self.model.lifted("T", H) @ self._Phi         # µm → µm
        self._VPhi = self.model.lifted("V", H) @ self._Phi / um    # µm → V
        D = np.eye(H * na) - np.eye(H * na, k=-na)                 # sample-to-sample difference
        P = self._TPhi.T @ self._TPhi
        P += 1e-2 * np.trace(P) / len(P) * np.eye(len(P))   # moves T cannot see stay small
        A = np.vstack([self._VPhi, D @ self._VPhi])
        # rows no move can reach (C strictly proper: the first voltage sample is already decided) are left out
        norms = np.linalg.norm(A, axis=1)
        self._rows = norms > 1e-9 * norms.max()
        self._qp = QPSolver(P, A[self._rows], eps_abs=1e-4, eps_rel=1e-5, max_iter=1000, rho_scale=10.0)
        lim = self.cfg.limits
        self._vmax = lim.voltage - self.settings.voltage_margin
        self._dvmax = lim.slew * self.cfg.dt

    def reset(self) -> None:
        """Forget the stream (history, caches, QP warm start and counters)."""
        self._r: np.ndarray | None = None  # known reference; _r[p] is the sample at absolute index p + _r0
        self._r0 = 0
        self._n_in = 0                  # stream samples received
        self._f = np.zeros((0, self.n_axes))
        self._f0 = 0                    # absolute index of _f[0] (FIR candidate cache)
        self._out = np.zeros((0, self.n_axes))
        self._out0 = 0                  # absolute index of _out[0] (decided output not yet emitted)
        self._x_prev: np.ndarray | None = None  # last QP solution (warm start)
        if self.replica is not None:
            self.replica.reset()
        self.qp_solves = 0
        self.qp_unconverged = 0

    # -- streaming -------------------------------------------------------------------------------------------------
    def process(self, block: np.ndarray) -> np.ndarray:
        """One reference block ``[N, axes]`` received ``preview_samples`` ahead; returns N shaped samples."""
        x = as_block(block, self.n_axes, "reference")
        n = x.shape[0]
        if n == 0:
            return np.zeros((0, self.n_axes))
        L = self.preview_samples
        if self._r is None:             # history at rest (0), the unreceived first L samples held at the first one
            self._r0 = -self._M
            self._r = np.vstack([np.zeros((self._M, self.n_axes)), np.repeat(x[:1], L, axis=0)])
        self._r = np.vstack([self._r, x])
        o = self._n_in
        self._n_in += n
        if self.constrained:
            out = self._constrained_until(o + n)[: n]
        else:
            out = self._fir(o, o + n)
        self._trim(o + n)
        return out

    def _fir(self, a: int, b: int) -> np.ndarray:
        """FIR candidate for absolute samples [a, b) (reference known up to a + La … b − 1 + La)."""
        out = np.empty((b - a, self.n_axes))
        assert self._r is not None      # set by the first process() call, before any candidate is asked
        _fir_run(self.kernel.taps, self._r, a + self._La - self._r0, out)
        return out

    def _candidate(self, a: int, b: int) -> np.ndarray:
        if b > self._f0 + len(self._f):
            start = self._f0 + len(self._f)
            self._f = np.vstack([self._f, self._fir(start, b)])
        return self._f[a - self._f0: b - self._f0]

    def _constrained_until(self, stop: int) -> np.ndarray:
        while self._out0 + len(self._out) < stop:
            c = self._out0 + len(self._out)
            self._out = np.vstack([self._out, self._chunk(c)])
        first = self._out0
        need = stop - first
        emitted, self._out, self._out0 = self._out[:need], self._out[need:], stop
        return emitted

    def _chunk(self, c: int) -> np.ndarray:
        H, B = self._H, self._B
        assert self.replica is not None and self._r is not None   # constrained mode, after the first block
        cand = self._candidate(c, c + H).copy()
        u, y = self.replica.predict(cand)
        if not self._violates(u):
            chunk = cand[:B]
        else:
            r = self._r[c - self._r0: c - self._r0 + H]
            for _ in range(self.PASSES):  # later passes re-linearise the voltage around the previous solution
                z = self._solve(cand, u, y, r)
                cand = cand + (self._Phi @ z).reshape(H, self.n_axes) * 1e-6
                u, y = self.replica.predict(cand)
                if not self._violates(u):
                    break
            chunk = cand[:B]
        self.replica.process(chunk)
        return chunk

    def _violates(self, u: np.ndarray) -> bool:
        assert self.replica is not None   # constrained mode only
        du = np.diff(np.vstack([self.replica.u_last[None, :], u]), axis=0)
        return bool(np.max(np.abs(u)) > self._vmax + 1e-9 or np.max(np.abs(du)) > self._dvmax + 1e-9)

    def _solve(self, cand: np.ndarray, u: np.ndarray, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Deviation knots z [µm] minimising the predicted error subject to the limits (linearised at cand)."""
        assert self.replica is not None   # constrained mode only
        e = ((y - r) * 1e6).ravel()
        q = self._TPhi.T @ e
        uf = u.ravel()
        du = np.diff(np.vstack([self.replica.u_last[None, :], u]), axis=0).ravel()
        lo = np.concatenate([-self._vmax - uf, -self._dvmax - du])
        hi = np.concatenate([self._vmax - uf, self._dvmax - du])
        res = self._qp.solve(q, lo[self._rows], hi[self._rows])
        self.qp_solves += 1
        self.qp_unconverged += int(not res.converged)
        return res.x

    def _trim(self, next_out: int) -> None:
        assert self._r is not None                   # called after a block was received
        keep_from = next_out - self._M - 1           # the FIR looks back tail samples
        cut = keep_from - self._r0
        if cut > 4096:
            self._r, self._r0 = self._r[cut:], self._r0 + cut
        cut_f = next_out - self._f0
        if cut_f > 4096:
            self._f, self._f0 = self._f[cut_f:], self._f0 + cut_f
