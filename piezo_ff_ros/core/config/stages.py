"""One frozen, validated configuration per stage: hysteresis, creep, dynamics, H∞ design, cascade, limits.

:class:`BoucWenConfig` (multivariable, generalized Bouc-Wen), :class:`CreepConfig`, :class:`DynamicsConfig`,
:class:`HinfConfig` (model-matching weights or a ready controller), :class:`CascadeConfig` (which stages run, in
which order) and :class:`LimitsConfig` (what the driver enforces).  SI units inside; each ``validate()`` returns the
config or raises :class:`~.validation.ConfigError` naming the field.  :class:`~.piezo.PiezoConfig` holds one of each.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping, Sequence

import numpy as np

from ..transfer import TFMatrix
from .tf_entries import _check_tf_matrix
from .validation import (MAX_GAIN_M_PER_V, MAX_HYSTERESIS_RATE, MAX_LIMIT_SLEW, MAX_LIMIT_VOLTAGE, MAX_STALE_TIMEOUT,
                         ConfigError, Matrix, _arr, _bounded, _matrix, _unknown_keys)

__all__ = ["BoucWenConfig", "CreepConfig", "DynamicsConfig", "HinfConfig", "CascadeConfig", "LimitsConfig"]


@dataclass(frozen=True)
class BoucWenConfig:
    """Multivariable Bouc-Wen (Eq. 1–3), SI units.

    ``Y = Dp·U − h``;  ``ḣ = A·U̇ − B(|Û̇|∘h) − Γ(Û̇∘|h|) − Δ1(Û̇∘h) − Δ2(|Û̇|∘|h|)``.

    ``Dp`` and ``A`` are n×k [m/V]; ``B``, ``Gamma``, ``Delta1``, ``Delta2`` n×n [1/V].  ``Û = P·U`` with the
    input map ``P`` (n×k, identity for the square case the paper treats; the paper does not spell Û out for
    rectangular systems, so the map is explicit here).  ``Delta1``/``Delta2`` are the generalized (asymmetric)
    terms: both break the odd symmetry ``(U, h) → (−U, −h)`` of the classical model; zero gives the classical one.
    """

    Dp: Matrix
    A: Matrix
    B: Matrix
    Gamma: Matrix
    Delta1: Matrix | None = None
    Delta2: Matrix | None = None
    input_map: Matrix | None = None

    @property
    def n_out(self) -> int:
        """Number of outputs (displacements)."""
        return len(self.Dp)

    @property
    def n_in(self) -> int:
        """Number of inputs (voltages)."""
        return len(self.Dp[0])

    @property
    def generalized(self) -> bool:
        """True when Delta1 or Delta2 is non-zero (the asymmetric model)."""
        return any(m is not None and bool(np.any(_arr(m))) for m in (self.Delta1, self.Delta2))

    def arrays(self) -> dict[str, np.ndarray]:
        """``Dp``, ``A``, ``B``, ``Gamma``, ``Delta1``, ``Delta2`` (zero when absent) and ``P`` as float arrays."""
        n, k = self.n_out, self.n_in
        z = np.zeros((n, n))
        P = _arr(self.input_map) if self.input_map is not None else np.eye(n, k)
        return {"Dp": _arr(self.Dp), "A": _arr(self.A), "B": _arr(self.B), "Gamma": _arr(self.Gamma),
                "Delta1": _arr(self.Delta1) if self.Delta1 is not None else z,
                "Delta2": _arr(self.Delta2) if self.Delta2 is not None else z.copy(), "P": P}

    def validate(self, prefix: str = "hysteresis") -> "BoucWenConfig":
        """``self`` if every matrix has its shape, is finite and plausible, and Dp is invertible; else ConfigError."""
        n, k = self.n_out, self.n_in
        _matrix(self.Dp, f"{prefix}.Dp", (n, k))
        _matrix(self.A, f"{prefix}.A", (n, k))
        for name in ("B", "Gamma", "Delta1", "Delta2"):
            v = getattr(self, name)
            if v is not None:
                _matrix(v, f"{prefix}.{name}", (n, n))
        if self.input_map is not None:
            _matrix(self.input_map, f"{prefix}.input_map", (n, k))
        _bounded(self.Dp, f"{prefix}.Dp", MAX_GAIN_M_PER_V, "m/V")
        _bounded(self.A, f"{prefix}.A", MAX_GAIN_M_PER_V, "m/V")
        for name in ("B", "Gamma", "Delta1", "Delta2"):
            if getattr(self, name) is not None:
                _bounded(getattr(self, name), f"{prefix}.{name}", MAX_HYSTERESIS_RATE, "1/V")
        Dp = _arr(self.Dp)
        sv = np.linalg.svd(Dp, compute_uv=False)
        if sv[-1] <= 1e-9 * max(sv[0], 1e-300):
            raise ConfigError(f"{prefix}.Dp", f"not invertible (singular values {sv.tolist()}); the compensator "
                                              "U = Dp⁻¹(Y_H + h) needs a full-rank Dp")
        return self

    @staticmethod
    def from_dict(d: Mapping[str, Any], length: float = 1.0, prefix: str = "hysteresis") -> "BoucWenConfig":
        """From the YAML form; ``length`` [m] per length unit scales Dp and A.  Validated."""
        _unknown_keys(d, [f.name for f in fields(BoucWenConfig)], prefix)

        def get(name: str, scale: float = 1.0, required: bool = True) -> Matrix | None:
            if name not in d or d[name] is None:
                if required:
                    raise ConfigError(f"{prefix}.{name}", "missing")
                return None
            m = _matrix(d[name], f"{prefix}.{name}")
            return tuple(tuple(v * scale for v in row) for row in m)

        def need(name: str, scale: float = 1.0) -> Matrix:
            m = get(name, scale)
            assert m is not None   # required: get raised otherwise
            return m

        cfg = BoucWenConfig(Dp=need("Dp", length), A=need("A", length), B=need("B"), Gamma=need("Gamma"),
                            Delta1=get("Delta1", required=False), Delta2=get("Delta2", required=False),
                            input_map=get("input_map", required=False))
        return cfg.validate(prefix)

    def to_dict(self, length: float = 1.0) -> dict[str, Any]:
        """The YAML form, Dp and A divided by ``length`` [m per unit]."""
        out = {"Dp": (_arr(self.Dp) / length).tolist(), "A": (_arr(self.A) / length).tolist(),
               "B": _arr(self.B).tolist(), "Gamma": _arr(self.Gamma).tolist()}
        for name in ("Delta1", "Delta2", "input_map"):
            if getattr(self, name) is not None:
                out[name] = _arr(getattr(self, name)).tolist()
        return out


@dataclass(frozen=True)
class CreepConfig:
    """Multivariable creep ``Y = [K + Cr(s)]·Y_H`` (Eq. 8–11); K and Cr dimensionless."""

    K: Matrix
    Cr: TFMatrix

    def validate(self, axes: Sequence[str], prefix: str = "creep") -> "CreepConfig":
        """``self`` if K is n×n and invertible and Cr n×n, strictly proper and stable; else ConfigError."""
        n = len(axes)
        K = _arr(_matrix(self.K, f"{prefix}.K", (n, n)))
        if abs(np.linalg.det(K)) < 1e-9 or np.linalg.cond(K) > 1e9:
            raise ConfigError(f"{prefix}.K", f"not invertible (det={np.linalg.det(K):.3g}); the compensator "
                                             "Y_H = K⁻¹[Y_L − Cr·Y_H] needs an invertible K")
        if self.Cr.shape != (n, n):
            raise ConfigError(f"{prefix}.Cr", f"expected {n}x{n}")
        _check_tf_matrix(self.Cr, f"{prefix}.Cr", axes, strictly_proper=True)
        return self


@dataclass(frozen=True)
class DynamicsConfig:
    """MIMO dynamics ``G_L(s)`` of the system left by the hysteresis and creep compensators (Eq. 13–14)."""

    G_L: TFMatrix

    def validate(self, axes: Sequence[str], prefix: str = "dynamics") -> "DynamicsConfig":
        """``self`` if G_L is n×n, strictly proper, stable, with an invertible DC gain; else ConfigError."""
        n = len(axes)
        if self.G_L.shape != (n, n):
            raise ConfigError(f"{prefix}.G_L", f"expected {n}x{n}")
        _check_tf_matrix(self.G_L, f"{prefix}.G_L", axes, strictly_proper=True)
        G0 = self.G_L.dc_gain()
        if abs(np.linalg.det(G0)) < 1e-12:
            raise ConfigError(f"{prefix}.G_L", "singular DC gain: no feedforward can reach a static reference")
        return self


@dataclass(frozen=True)
class HinfConfig:
    """H∞ model-matching weights (Eq. 15–19) and the reduction order; or a ready controller.

    ``Wr = 1/(t_r/3·s + 1)``, ``W1 = (s + 3/t_r)/(k_o·s + 3·eps_s/t_r)``, ``W2`` constant per axis.
    ``controller`` (optional) is a continuous state space ``{A, B, C, D}`` used as is, skipping synthesis.
    """

    t_r: float = 0.025
    eps_s: float = 0.01
    k_o: float = 1.0
    W2: tuple[float, ...] = (1.0, 1.0)
    order: int = 12
    gamma_max: float = 1.0
    controller: Mapping[str, Any] | None = None

    def validate(self, axes: Sequence[object], prefix: str = "vibration") -> "HinfConfig":
        """``self`` if the weights are positive and finite and a given controller is stable; else ConfigError."""
        n = len(axes)
        for name, lo in (("t_r", 0.0), ("eps_s", 0.0), ("k_o", 0.0), ("gamma_max", 0.0)):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= lo:
                raise ConfigError(f"{prefix}.{name}", f"must be a finite number > {lo}, got {v!r}")
        if not self.eps_s < 1.0:
            raise ConfigError(f"{prefix}.eps_s", "a static error bound must be < 1")
        if len(self.W2) != n or not all(math.isfinite(w) and w > 0 for w in self.W2):
            raise ConfigError(f"{prefix}.W2", f"expected {n} positive finite weights, got {list(self.W2)}")
        if not isinstance(self.order, int) or self.order < 1:
            raise ConfigError(f"{prefix}.order", f"must be an integer ≥ 1, got {self.order!r}")
        if self.controller is not None:
            c = self.controller
            for key in ("A", "B", "C", "D"):
                if key not in c:
                    raise ConfigError(f"{prefix}.controller.{key}", "missing")
            A = np.atleast_2d(np.array(c["A"], float))
            if A.size and np.any(np.linalg.eigvals(A).real >= 0):
                raise ConfigError(f"{prefix}.controller.A", "unstable controller")
        return self


@dataclass(frozen=True)
class CascadeConfig:
    """Which stages run, in which order, and how the hysteresis compensator closes its implicit loop.

    ``order``: ``paper`` (Fig. 3: C(s) → creep⁻¹ → hysteresis⁻¹ → plant) or ``commuted`` (Fig. 16: hysteresis⁻¹ →
    C(s) → creep⁻¹ → plant).  ``hysteresis_loop``: ``exact`` solves ``Y_H = Dp·U − h(U)`` at every sample (the
    compensator is then the exact inverse of the discrete model), ``delayed`` uses h of the previous sample (a
    Simulink unit delay).
    """

    hysteresis: bool = True
    creep: bool = True
    vibration: bool = True
    order: str = "paper"
    hysteresis_loop: str = "exact"
    #: clamp and slew-limit the output exactly as the driver will (``limits``), so that the hysteresis
    #: compensator's internal state stays the plant's when a reference asks for more than the amplifier gives
    respect_limits: bool = True

    def validate(self, prefix: str = "cascade") -> "CascadeConfig":
        """``self`` if ``order`` and ``hysteresis_loop`` are known and the switches booleans; else ConfigError."""
        if self.order not in ("paper", "commuted"):
            raise ConfigError(f"{prefix}.order", f"must be 'paper' or 'commuted', got {self.order!r}")
        if self.hysteresis_loop not in ("exact", "delayed"):
            raise ConfigError(f"{prefix}.hysteresis_loop", f"must be 'exact' or 'delayed', got {self.hysteresis_loop!r}")
        for name in ("hysteresis", "creep", "vibration", "respect_limits"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{prefix}.{name}", "must be true or false")
        return self


@dataclass(frozen=True)
class LimitsConfig:
    """Driver safety limits: what the driver enforces whatever it is sent."""

    voltage: float = 200.0          #: |U| ≤ voltage [V]
    slew: float = 2.0e5             #: |dU/dt| ≤ slew [V/s]
    stale_timeout: float = 0.2      #: no block for this long → ramp to the safe state [s]
    safe_voltage: float = 0.0       #: the safe state [V]
    #: reference limits per axis, ((min, max), …) [m] (YAML: in the config's length unit); None = unlimited
    workspace: tuple[tuple[float, float], ...] | None = None

    def validate(self, prefix: str = "limits") -> "LimitsConfig":
        """``self`` if every limit is finite and plausible for a piezo drive; else ConfigError."""
        for name in ("voltage", "slew", "stale_timeout"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"{prefix}.{name}", f"must be a finite number > 0, got {v!r}")
        v = self.safe_voltage
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{prefix}.safe_voltage", f"must be a finite number, got {v!r}")
        for name, bound, unit in (("voltage", MAX_LIMIT_VOLTAGE, "V"), ("slew", MAX_LIMIT_SLEW, "V/s"),
                                  ("stale_timeout", MAX_STALE_TIMEOUT, "s")):
            if getattr(self, name) > bound:
                raise ConfigError(f"{prefix}.{name}", f"{getattr(self, name):g} {unit} is not plausible for a piezo "
                                                      f"drive (≤ {bound:g} {unit})")
        if abs(self.safe_voltage) > self.voltage:
            raise ConfigError(f"{prefix}.safe_voltage", "outside the voltage limit")
        for i, pair in enumerate(self.workspace or ()):
            if len(pair) != 2 or not all(math.isfinite(v) for v in pair) or not pair[0] < pair[1]:
                raise ConfigError(f"{prefix}.workspace", f"axis {i}: expected [min, max] with min < max, got {pair!r}")
        return self
