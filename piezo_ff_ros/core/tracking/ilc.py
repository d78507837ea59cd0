"""Iterative learning control for repeated trajectories: learn a feedforward correction, store it, replay it.

Update law (Bristow, Tharayil & Alleyne's survey, inversion-based ILC; all applied offline, zero phase, on a whole
trial)::

    Δ_{j+1} = Q · (Δ_j + γ · L · e_j),      e_j = r − y_j (measured),   L = T̂⁻¹ (the model's compensated stage)

Δ is added to the (preview-shaped) reference in front of the cascade, so the learning acts on ``T = G_L·C`` of the
*true* actuator.  For long trials the iteration contracts monotonically when (frequency-domain condition)::

    ρ = sup_ω σ_max( Q(ω) · (I − γ · L(ω) · T(ω)) ) < 1

With the model exact, ``L·T = I`` and ρ = sup |Q|·|1 − γ| < 1 for 0 < γ < 2; the mismatch ``T̂⁻¹T − I`` is what
eats the margin, and it grows with frequency (phase errors of the resonances, delays), so Q — a zero-phase low-pass
``|Q| = 1/(1 + (f/q_bandwidth)^(2·q_order))`` — cuts the learning where the model is no longer trusted.  The
error then converges to ``(I − Q)`` of what the plant cannot be taught, not to zero.  :func:`convergence_factor`
evaluates ρ for a model/truth pair; :meth:`IterativeLearning.learn` also guards the iteration: when the measured
error exceeds the best trial's by more than ``tolerance`` for ``patience`` consecutive trials it restores the best correction and halves the Q bandwidth (so a
condition violated on purpose cannot make the learned feedforward diverge).

The correction is stored per trajectory (:func:`save_correction`, an ``.npz`` with the trajectory's spec and sample
rate) and played without a sensor by :class:`LearnedCorrection`, a streaming stage indexed by the absolute sample.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..stage import as_block
from ..config import ConfigError, dataclass_from_mapping
from .linear import CompensatedModel

__all__ = ["ILCConfig", "IterativeLearning", "LearningResult", "convergence_factor", "q_filter_response",
           "LearnedCorrection", "save_correction", "load_correction"]


@dataclass(frozen=True)
class ILCConfig:
    """Learning settings (validated; errors name ``learning.<field>``)."""

    gain: float = 1.0               #: γ, learning gain (0 < γ < 2 for the nominal condition)
    q_bandwidth_hz: float = 150.0   #: Q-filter cut-off [Hz]
    q_order: int = 2                #: Q-filter order (|Q| falls as f^(−2·order))
    iterations: int = 10            #: trials
    patience: int = 2               #: trials of growing error before the guard steps in
    tolerance: float = 0.1          #: "growing" = more than this fraction above the best trial's error
    pad_s: float = 0.25             #: zero padding of each trial for the offline FFT filtering [s]

    def __post_init__(self) -> None:
        for name in ("gain", "q_bandwidth_hz", "pad_s", "tolerance"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"learning.{name}", f"must be a finite number > 0, got {v!r}")
        for name, lo in (("q_order", 1), ("iterations", 0), ("patience", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or int(v) != v or v < lo:
                raise ConfigError(f"learning.{name}", f"must be an integer >= {lo}, got {v!r}")
            object.__setattr__(self, name, int(v))

    @staticmethod
    def from_dict(d: Mapping[str, Any] | None) -> "ILCConfig":
        """From a mapping of the field names (unknown keys refused, naming them and the closest known one)."""
        return dataclass_from_mapping(ILCConfig, d, "learning")


def q_filter_response(f: np.ndarray, bandwidth_hz: float, order: int) -> np.ndarray:
    """Zero-phase Q: ``1/(1 + (f/bandwidth)^(2·order))``."""
    out: np.ndarray = 1.0 / (1.0 + (np.abs(f) / bandwidth_hz) ** (2 * order))
    return out


def convergence_factor(model_T: np.ndarray, true_T: np.ndarray, f: np.ndarray, cfg: ILCConfig) -> dict[str, Any]:
    """ρ = sup_ω σ_max(Q (I − γ T̂⁻¹ T)) on a frequency grid, and where it peaks.

    Parameters
    ----------
    model_T, true_T : ndarray [len(f), axes, axes]
        Frequency responses of the model's and the true compensated stage.
    f : ndarray
        Frequencies [Hz].
    cfg : ILCConfig
        Gain and Q filter.

    Returns
    -------
    dict
        ``rho`` (the factor; < 1: monotonic convergence), ``f_peak_hz``, ``rho_without_q`` (the same with Q = 1)
        and ``f_violation_hz`` (lowest frequency where ``σ_max(I − γ T̂⁻¹ T) ≥ 1``, None if nowhere).
    """
    na = model_T.shape[1]
    E = np.eye(na)[None] - cfg.gain * np.linalg.solve(model_T, true_T)
    sv = np.linalg.svd(E, compute_uv=False)[:, 0]
    q = q_filter_response(f, cfg.q_bandwidth_hz, cfg.q_order)
    rho_f = q * sv
    k = int(np.argmax(rho_f))
    viol = np.nonzero(sv >= 1.0)[0]
    return {"rho": float(rho_f[k]), "f_peak_hz": float(f[k]), "rho_without_q": float(sv.max()),
            "f_violation_hz": float(f[viol[0]]) if len(viol) else None}


@dataclass
class LearningResult:
    """What :meth:`IterativeLearning.learn` returns."""

    correction: np.ndarray                    #: [N, axes] learned Δ (the best trial's)
    rms_history_m: list[float] = field(default_factory=list)   #: measured RMS error per trial (trial 0: no correction)
    q_bandwidth_hz: list[float] = field(default_factory=list)  #: Q bandwidth used for each update
    guard_events: int = 0                     #: times the guard restored the best correction and halved Q

    def to_json(self) -> dict[str, Any]:
        """The history as JSON-ready values (RMS in µm)."""
        return {"rms_history_um": [1e6 * v for v in self.rms_history_m], "q_bandwidth_hz": self.q_bandwidth_hz,
                "guard_events": self.guard_events}


class IterativeLearning:
    """Offline ILC updates with the model's inverse as learning operator (see the module docstring)."""

    def __init__(self, model: CompensatedModel, cfg: ILCConfig | None = None) -> None:
        self.model = model
        self.cfg = cfg or ILCConfig()
        self.fs = 1.0 / model.dt

    def _filtered(self, x: np.ndarray, weight: Callable[[np.ndarray, int], np.ndarray]) -> np.ndarray:
        """Apply ``weight(f) [nf, axes, axes]`` (or [nf]) to a trial on a zero-padded FFT grid (no wrap-around)."""
        n = x.shape[0]
        pad = int(round(self.cfg.pad_s * self.fs))
        n_fft = 1 << int(math.ceil(math.log2(n + 2 * pad)))
        f = np.fft.rfftfreq(n_fft, self.model.dt)
        X = np.fft.rfft(np.vstack([x, np.zeros((n_fft - n, x.shape[1]))]), axis=0)
        W = weight(f, n_fft)
        Y = np.einsum("fij,fj->fi", W, X) if W.ndim == 3 else W[:, None] * X
        out: np.ndarray = np.fft.irfft(Y, n=n_fft, axis=0)[:n]
        return out

    def update(self, correction: np.ndarray, error: np.ndarray, q_bandwidth_hz: float | None = None) -> np.ndarray:
        """One learning step ``Q·(Δ + γ·T̂⁻¹·e)`` on whole trials ``[N, axes]``."""
        bw = q_bandwidth_hz or self.cfg.q_bandwidth_hz
        model = self.model

        def inverse(f: np.ndarray, n_fft: int) -> np.ndarray:
            Tf = model.frequency_response(n_fft)[1]
            w: np.ndarray = np.linalg.inv(Tf) * q_filter_response(f, bw, self.cfg.q_order)[:, None, None]
            return w

        step = self._filtered(np.asarray(error, float), inverse)
        kept = self._filtered(np.asarray(correction, float), lambda f, n: q_filter_response(f, bw, self.cfg.q_order))
        out: np.ndarray = kept + self.cfg.gain * step
        return out

    def learn(self, run_trial: Callable[[np.ndarray], np.ndarray], reference: np.ndarray,
              correction: np.ndarray | None = None, iterations: int | None = None,
              weight: np.ndarray | None = None) -> LearningResult:
        """Iterate trials: ``run_trial(Δ) -> measured y [N, axes]``; returns the best correction found.

        ``weight`` (optional, [N] of 0/1) selects the samples the RMS of the guard is read on (all by default).
        """
        r = np.asarray(reference, float)
        delta = np.zeros_like(r) if correction is None else np.array(correction, float)
        w = np.ones(len(r), bool) if weight is None else np.asarray(weight, bool)
        bw = self.cfg.q_bandwidth_hz
        res = LearningResult(delta.copy())
        best = np.inf
        worse = 0
        n_iter = self.cfg.iterations if iterations is None else int(iterations)
        for j in range(n_iter + 1):
            e = r - run_trial(delta)
            rms = float(np.sqrt(np.mean(np.sum(e[w] ** 2, axis=1))))
            res.rms_history_m.append(rms)
            if rms < best:
                best, res.correction = rms, delta.copy()
            if rms <= best * (1 + self.cfg.tolerance):
                worse = 0
            else:
                worse += 1
                if worse >= self.cfg.patience:      # guard: back to the best, learn more slowly from there
                    res.guard_events += 1
                    bw *= 0.5
                    delta, worse = res.correction.copy(), 0
                    e = None
            if j == n_iter:
                break
            if e is None:
                e = r - run_trial(delta)
            delta = self.update(delta, e, bw)
            res.q_bandwidth_hz.append(bw)
        return res


class LearnedCorrection:
    """Streaming stage adding a stored correction ``Δ[k]`` (k counted from reset; held at its last row after)."""

    def __init__(self, correction: np.ndarray):
        c = np.ascontiguousarray(correction, float)
        if c.ndim != 2 or len(c) == 0 or not np.all(np.isfinite(c)):
            raise ValueError("learning correction: expected a finite non-empty array [N, axes]")
        self.table = c
        self.k = 0

    @property
    def n_axes(self) -> int:
        """Number of axes of the correction."""
        return int(self.table.shape[1])

    def reset(self) -> None:
        """Back to the correction's first row."""
        self.k = 0

    def process(self, block: np.ndarray) -> np.ndarray:
        """``block + Δ[k … k + N)`` (Δ held at its last row past its end)."""
        x = as_block(block, self.n_axes)
        idx = np.minimum(np.arange(self.k, self.k + len(x)), len(self.table) - 1)
        self.k += len(x)
        out: np.ndarray = x + self.table[idx]
        return out


def save_correction(path: str | Path, correction: np.ndarray, sample_rate: float, trajectory: Mapping[str, Any],
                    meta: Mapping[str, Any] | None = None) -> Path:
    """Store a learned correction with the trajectory spec it belongs to (``.npz``)."""
    p = Path(path)
    if p.suffix != ".npz":
        p = p.with_name(p.name + ".npz")
    np.savez(p, correction=np.asarray(correction, float), sample_rate=float(sample_rate),
             trajectory=json.dumps(dict(trajectory), sort_keys=True), meta=json.dumps(dict(meta or {}), default=str))
    return p


def load_correction(path: str | Path, sample_rate: float | None = None,
                    trajectory: Mapping[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Load ``(correction, info)``; refuses a file learned at another rate or for another trajectory."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError("learning.file", f"{p}: no such file")
    try:
        with np.load(p, allow_pickle=False) as z:
            corr = np.array(z["correction"], float)
            fs = float(z["sample_rate"])
            spec = json.loads(str(z["trajectory"]))
            meta = json.loads(str(z["meta"]))
    except (OSError, KeyError, ValueError) as exc:
        raise ConfigError("learning.file", f"{p}: not a learned correction ({exc})") from None
    if corr.ndim != 2 or not np.all(np.isfinite(corr)):
        raise ConfigError("learning.file", f"{p}: correction must be a finite array [N, axes]")
    if sample_rate is not None and abs(fs - float(sample_rate)) > 1e-9 * fs:
        raise ConfigError("learning.file", f"{p}: learned at {fs:g} Hz, played at {sample_rate:g} Hz")
    if trajectory is not None and json.loads(json.dumps(dict(trajectory), sort_keys=True)) != spec:
        raise ConfigError("learning.file", f"{p}: learned for another trajectory ({spec.get('type')})")
    return corr, {"sample_rate": fs, "trajectory": spec, "meta": meta}
