"""One frozen, validated configuration object per stage, built from YAML (``config/``) or a plain dict.

Every ``validate()`` raises :class:`ConfigError` whose message starts with the dotted name of the offending field
(``hysteresis.Dp: singular matrix …``) so that a rejected runtime change says exactly why.

Units: the YAML may give lengths in µm (``units: {length: um}``, as the paper prints them); everything is converted
to SI here and nowhere else.  Only the Bouc-Wen ``Dp`` and ``A`` carry a length per volt; ``B``, ``Gamma``, the
creep and the dynamics are ratios and do not scale.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from .lti import FactoredTF, TFMatrix
from .units import length_scale

__all__ = [
    "ConfigError",
    "BoucWenConfig",
    "CreepConfig",
    "DynamicsConfig",
    "HinfConfig",
    "CascadeConfig",
    "LimitsConfig",
    "PiezoConfig",
    "load_config",
    "default_config_path",
    "flatten",
    "unflatten",
]


class ConfigError(ValueError):
    """A configuration value is invalid; ``field`` is its dotted name."""

    def __init__(self, field_name: str, message: str):
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.reason = message


def _matrix(value, name: str, shape: tuple[int, int] | None = None) -> tuple:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(name, f"not a numeric matrix ({exc})") from None
    if a.ndim == 1 and shape is not None and shape[0] == shape[1] == a.size:
        a = np.diag(a)
    if a.ndim == 0 and shape is not None:
        a = np.full(shape, float(a)) if shape[0] != shape[1] else np.eye(shape[0]) * float(a)
    if a.ndim != 2:
        raise ConfigError(name, f"expected a matrix, got an array of {a.ndim} dimension(s)")
    if shape is not None and a.shape != shape:
        raise ConfigError(name, f"expected shape {shape[0]}x{shape[1]}, got {a.shape[0]}x{a.shape[1]}")
    if not np.all(np.isfinite(a)):
        raise ConfigError(name, "contains NaN or Inf")
    return tuple(tuple(float(v) for v in row) for row in a)


def _arr(m: tuple) -> np.ndarray:
    return np.array(m, dtype=float)


# ----------------------------------------------------------------------------------------------------------------
# Stage configurations
# ----------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class BoucWenConfig:
    """Multivariable Bouc-Wen (Eq. 1–3), SI units.

    ``Y = Dp·U − h``;  ``ḣ = A·U̇ − B(|Û̇|∘h) − Γ(Û̇∘|h|) − Δ1(Û̇∘h) − Δ2(|Û̇|∘|h|)``.

    ``Dp`` and ``A`` are n×k [m/V]; ``B``, ``Gamma``, ``Delta1``, ``Delta2`` n×n [1/V].  ``Û = P·U`` with the
    input map ``P`` (n×k, identity for the square case the paper treats; the paper does not spell Û out for
    rectangular systems, so the map is explicit here).  ``Delta1``/``Delta2`` are the generalized (asymmetric)
    terms: both break the odd symmetry ``(U, h) → (−U, −h)`` of the classical model; zero gives the classical one.
    """

    Dp: tuple
    A: tuple
    B: tuple
    Gamma: tuple
    Delta1: tuple | None = None
    Delta2: tuple | None = None
    input_map: tuple | None = None

    @property
    def n_out(self) -> int:
        return len(self.Dp)

    @property
    def n_in(self) -> int:
        return len(self.Dp[0])

    @property
    def generalized(self) -> bool:
        return any(m is not None and np.any(_arr(m)) for m in (self.Delta1, self.Delta2))

    def arrays(self) -> dict[str, np.ndarray]:
        n, k = self.n_out, self.n_in
        z = np.zeros((n, n))
        P = _arr(self.input_map) if self.input_map is not None else np.eye(n, k)
        return {"Dp": _arr(self.Dp), "A": _arr(self.A), "B": _arr(self.B), "Gamma": _arr(self.Gamma),
                "Delta1": _arr(self.Delta1) if self.Delta1 is not None else z,
                "Delta2": _arr(self.Delta2) if self.Delta2 is not None else z.copy(), "P": P}

    def validate(self, prefix: str = "hysteresis") -> "BoucWenConfig":
        n, k = self.n_out, self.n_in
        _matrix(self.Dp, f"{prefix}.Dp", (n, k))
        _matrix(self.A, f"{prefix}.A", (n, k))
        for name in ("B", "Gamma", "Delta1", "Delta2"):
            v = getattr(self, name)
            if v is not None:
                _matrix(v, f"{prefix}.{name}", (n, n))
        if self.input_map is not None:
            _matrix(self.input_map, f"{prefix}.input_map", (n, k))
        Dp = _arr(self.Dp)
        sv = np.linalg.svd(Dp, compute_uv=False)
        if sv[-1] <= 1e-9 * max(sv[0], 1e-300):
            raise ConfigError(f"{prefix}.Dp", f"not invertible (singular values {sv.tolist()}); the compensator "
                                              "U = Dp⁻¹(Y_H + h) needs a full-rank Dp")
        return self

    @staticmethod
    def from_dict(d: Mapping, length: float = 1.0, prefix: str = "hysteresis") -> "BoucWenConfig":
        def get(name, scale=1.0, required=True):
            if name not in d or d[name] is None:
                if required:
                    raise ConfigError(f"{prefix}.{name}", "missing")
                return None
            m = _matrix(d[name], f"{prefix}.{name}")
            return tuple(tuple(v * scale for v in row) for row in m)

        cfg = BoucWenConfig(Dp=get("Dp", length), A=get("A", length), B=get("B"), Gamma=get("Gamma"),
                            Delta1=get("Delta1", required=False), Delta2=get("Delta2", required=False),
                            input_map=get("input_map", required=False))
        return cfg.validate(prefix)

    def to_dict(self, length: float = 1.0) -> dict:
        out = {"Dp": (_arr(self.Dp) / length).tolist(), "A": (_arr(self.A) / length).tolist(),
               "B": _arr(self.B).tolist(), "Gamma": _arr(self.Gamma).tolist()}
        for name in ("Delta1", "Delta2", "input_map"):
            if getattr(self, name) is not None:
                out[name] = _arr(getattr(self, name)).tolist()
        return out


def _tf_matrix_from_dict(d: Mapping | Any, axes: tuple[str, ...], prefix: str) -> TFMatrix:
    n = len(axes)
    rows = [[FactoredTF(0.0) for _ in range(n)] for _ in range(n)]
    if isinstance(d, (list, tuple)):
        if len(d) != n or any(len(r) != n for r in d):
            raise ConfigError(prefix, f"expected a {n}x{n} nested list of transfer functions")
        items = {(i, j): d[i][j] for i in range(n) for j in range(n)}
    elif isinstance(d, Mapping):
        items = {}
        for key, val in d.items():
            pair = _axis_pair(str(key), axes)
            if pair is None:
                raise ConfigError(f"{prefix}.{key}", f"unknown entry; use '<out><in>' with axes {list(axes)}")
            items[pair] = val
    else:
        raise ConfigError(prefix, "expected a mapping like {xx: {k:…, num:…, den:…}, …}")
    for (i, j), val in items.items():
        name = f"{prefix}.{axes[i]}{axes[j]}"
        if val is None or val == 0:
            continue
        if not isinstance(val, Mapping) or "den" not in val:
            raise ConfigError(name, "expected {k: gain, num: [[…], …], den: [[…], …]}")
        try:
            tf = FactoredTF.from_dict(val)
        except (TypeError, ValueError) as exc:
            raise ConfigError(name, f"malformed factors ({exc})") from None
        for part, factors in (("num", tf.num), ("den", tf.den)):
            for f in factors:
                if len(f) == 0 or not all(math.isfinite(c) for c in f):
                    raise ConfigError(f"{name}.{part}", "factors must be non-empty finite polynomials")
                if f[0] == 0.0:
                    raise ConfigError(f"{name}.{part}", f"factor {list(f)} has a zero leading coefficient")
        if not math.isfinite(tf.gain):
            raise ConfigError(f"{name}.k", "not finite")
        rows[i][j] = tf
    return TFMatrix.from_nested(rows)


def _axis_pair(key: str, axes: tuple[str, ...]):
    for i, a in enumerate(axes):
        for j, b in enumerate(axes):
            if key in (a + b, f"{a},{b}", f"{a}_{b}"):
                return i, j
    return None


def _tf_matrix_to_dict(tfm: TFMatrix, axes: tuple[str, ...]) -> dict:
    out = {}
    for i, a in enumerate(axes):
        for j, b in enumerate(axes):
            tf = tfm[i, j]
            if not tf.is_zero():
                out[f"{a}{b}"] = tf.to_dict()
    return out


def _check_tf_matrix(tfm: TFMatrix, prefix: str, axes, strictly_proper: bool) -> None:
    n = len(axes)
    for i in range(n):
        for j in range(n):
            tf = tfm[i, j]
            if tf.is_zero():
                continue
            name = f"{prefix}.{axes[i]}{axes[j]}"
            rd = tf.relative_degree
            if rd < 0:
                raise ConfigError(name, "improper (numerator degree above denominator degree)")
            if strictly_proper and rd < 1:
                raise ConfigError(name, "must be strictly proper")
            p = tf.cancelled().poles()
            if np.any(p.real >= 0):
                raise ConfigError(name, f"unstable pole(s) {[complex(x) for x in p[p.real >= 0]]}")
            try:
                tf.modes()
            except ValueError as exc:
                raise ConfigError(name, str(exc)) from None


@dataclass(frozen=True)
class CreepConfig:
    """Multivariable creep ``Y = [K + Cr(s)]·Y_H`` (Eq. 8–11); K and Cr dimensionless."""

    K: tuple
    Cr: TFMatrix

    def validate(self, axes, prefix: str = "creep") -> "CreepConfig":
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

    def validate(self, axes, prefix: str = "dynamics") -> "DynamicsConfig":
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
    W2: tuple = (1.0, 1.0)
    order: int = 12
    gamma_max: float = 1.0
    controller: Mapping | None = None

    def validate(self, axes, prefix: str = "vibration") -> "HinfConfig":
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

    def validate(self, prefix: str = "limits") -> "LimitsConfig":
        for name in ("voltage", "slew", "stale_timeout"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"{prefix}.{name}", f"must be a finite number > 0, got {v!r}")
        if abs(self.safe_voltage) > self.voltage:
            raise ConfigError(f"{prefix}.safe_voltage", "outside the voltage limit")
        return self


@dataclass(frozen=True)
class PiezoConfig:
    """Everything about one positioner: axes, sample rate, the three models, H∞ weights, cascade, limits."""

    name: str
    axes: tuple
    sample_rate: float
    hysteresis: BoucWenConfig
    creep: CreepConfig
    dynamics: DynamicsConfig
    vibration: HinfConfig = field(default_factory=HinfConfig)
    cascade: CascadeConfig = field(default_factory=CascadeConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    source: str = ""
    variant: str = "printed"

    @property
    def dt(self) -> float:
        return 1.0 / self.sample_rate

    @property
    def n_axes(self) -> int:
        return len(self.axes)

    def validate(self) -> "PiezoConfig":
        if not self.axes or len(set(self.axes)) != len(self.axes):
            raise ConfigError("axes", f"need distinct axis names, got {list(self.axes)}")
        if not (isinstance(self.sample_rate, (int, float)) and math.isfinite(self.sample_rate) and self.sample_rate > 0):
            raise ConfigError("sample_rate", f"must be > 0 Hz, got {self.sample_rate!r}")
        self.hysteresis.validate()
        if self.hysteresis.n_out != self.n_axes:
            raise ConfigError("hysteresis.Dp", f"{self.hysteresis.n_out} outputs for {self.n_axes} axes")
        self.creep.validate(self.axes)
        self.dynamics.validate(self.axes)
        self.vibration.validate(self.axes)
        self.cascade.validate()
        self.limits.validate()
        return self

    def with_sample_rate(self, fs: float) -> "PiezoConfig":
        return replace(self, sample_rate=float(fs)).validate()

    # -- dict / YAML ----------------------------------------------------------------------------------------------
    @staticmethod
    def from_dict(d: Mapping, variant: str | None = None) -> "PiezoConfig":
        d = copy.deepcopy(dict(d))
        variants = d.pop("variants", {}) or {}
        chosen = variant or d.pop("variant", None) or "printed"
        d.pop("variant", None)
        if chosen != "printed":
            if chosen not in variants:
                raise ConfigError("variant", f"unknown variant {chosen!r}; available: {['printed', *variants]}")
            for path, value in (variants[chosen].get("set") or {}).items():
                _set_path(d, path, value)
        units = d.get("units", {}) or {}
        try:
            L = length_scale(units.get("length", "m"))
        except ValueError as exc:
            raise ConfigError("units.length", str(exc)) from None
        axes = tuple(str(a) for a in d.get("axes", ("x", "y")))
        for key in ("hysteresis", "creep", "dynamics"):
            if key not in d:
                raise ConfigError(key, "missing section")
        hyst = BoucWenConfig.from_dict(d["hysteresis"], L)
        cr = d["creep"]
        if "K" not in cr:
            raise ConfigError("creep.K", "missing")
        creep = CreepConfig(K=_matrix(cr["K"], "creep.K", (len(axes), len(axes))),
                            Cr=_tf_matrix_from_dict(cr.get("Cr", {}), axes, "creep.Cr"))
        dyn = d["dynamics"]
        if "G_L" not in dyn:
            raise ConfigError("dynamics.G_L", "missing")
        dynamics = DynamicsConfig(_tf_matrix_from_dict(dyn["G_L"], axes, "dynamics.G_L"))
        vib = dict(d.get("vibration", {}) or {})
        W2 = vib.get("W2", 1.0)
        W2 = tuple(float(w) for w in (W2 if isinstance(W2, (list, tuple)) else [W2] * len(axes)))
        try:
            vibration = HinfConfig(t_r=float(vib.get("t_r", 0.025)), eps_s=float(vib.get("eps_s", 0.01)),
                                   k_o=float(vib.get("k_o", 1.0)), W2=W2, order=int(vib.get("order", 12)),
                                   gamma_max=float(vib.get("gamma_max", 1.0)), controller=vib.get("controller"))
        except (TypeError, ValueError) as exc:
            raise ConfigError("vibration", f"malformed ({exc})") from None
        cascade = CascadeConfig(**(d.get("cascade") or {}))
        limits = LimitsConfig(**{k: float(v) for k, v in (d.get("limits") or {}).items()})
        cfg = PiezoConfig(name=str(d.get("name", "piezo")), axes=axes,
                          sample_rate=float(d.get("sample_rate", 20000.0)), hysteresis=hyst, creep=creep,
                          dynamics=dynamics, vibration=vibration, cascade=cascade, limits=limits,
                          source=str(d.get("source", "")), variant=chosen)
        return cfg.validate()

    def to_dict(self, length_unit: str = "um") -> dict:
        L = length_scale(length_unit)
        vib = {"t_r": self.vibration.t_r, "eps_s": self.vibration.eps_s, "k_o": self.vibration.k_o,
               "W2": list(self.vibration.W2), "order": self.vibration.order, "gamma_max": self.vibration.gamma_max}
        if self.vibration.controller is not None:
            vib["controller"] = {k: np.asarray(v, float).tolist() for k, v in self.vibration.controller.items()}
        return {
            "name": self.name, "source": self.source, "variant": self.variant, "axes": list(self.axes),
            "sample_rate": self.sample_rate, "units": {"length": length_unit, "voltage": "V"},
            "hysteresis": self.hysteresis.to_dict(L),
            "creep": {"K": _arr(self.creep.K).tolist(), "Cr": _tf_matrix_to_dict(self.creep.Cr, self.axes)},
            "dynamics": {"G_L": _tf_matrix_to_dict(self.dynamics.G_L, self.axes)},
            "vibration": vib,
            "cascade": {"hysteresis": self.cascade.hysteresis, "creep": self.cascade.creep,
                        "vibration": self.cascade.vibration, "order": self.cascade.order,
                        "hysteresis_loop": self.cascade.hysteresis_loop,
                        "respect_limits": self.cascade.respect_limits},
            "limits": {"voltage": self.limits.voltage, "slew": self.limits.slew,
                       "stale_timeout": self.limits.stale_timeout, "safe_voltage": self.limits.safe_voltage},
        }

    def to_yaml(self, path: str | Path | None = None, length_unit: str = "um") -> str:
        text = yaml.safe_dump(self.to_dict(length_unit), sort_keys=False, default_flow_style=None, width=120)
        if path is not None:
            Path(path).write_text(text)
        return text


def _set_path(d: dict, path: str, value) -> None:
    keys = path.split(".")
    cur = d
    for k in keys[:-1]:
        if k not in cur or not isinstance(cur[k], dict):
            raise ConfigError(path, "variant sets a path that does not exist")
        cur = cur[k]
    cur[keys[-1]] = value


def default_config_path() -> Path:
    """``config/pt230_94.yaml``: in the source tree, or installed under ``share/piezo_ff_ros/config``."""
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / "config" / "pt230_94.yaml"]
    import sys

    candidates.append(Path(sys.prefix) / "share" / "piezo_ff_ros" / "config" / "pt230_94.yaml")
    try:  # a colcon/ROS install
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("piezo_ff_ros")) / "config" / "pt230_94.yaml")
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
        pass
    for c in candidates:
        if c.is_file():
            return c
    raise FileNotFoundError("config/pt230_94.yaml not found (looked in: " + ", ".join(map(str, candidates)) + ")")


def load_config(path: str | Path | None = None, variant: str | None = None) -> PiezoConfig:
    """Load and validate a positioner config (default: the paper's PT230.94 values as printed)."""
    p = Path(path) if path is not None else default_config_path()
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(str(p), f"not valid YAML ({exc})") from None
    if not isinstance(data, Mapping):
        raise ConfigError(str(p), "top level must be a mapping")
    return PiezoConfig.from_dict(data, variant=variant)


def flatten(d: Mapping, prefix: str = "") -> dict[str, Any]:
    """``{'a': {'b': 1}}`` → ``{'a.b': 1}`` (lists are leaves)."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            out.update(flatten(v, key))
        else:
            out[key] = v
    return out


def unflatten(flat: Mapping[str, Any]) -> dict:
    out: dict = {}
    for key, v in flat.items():
        cur = out
        parts = key.split(".")
        for p in parts[:-1]:
            cur = cur.setdefault(p, {})
        cur[parts[-1]] = v
    return out
