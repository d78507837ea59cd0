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
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping, Sequence, TypeVar

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


#: a matrix as a config holds it: rows of floats (hashable, immutable)
Matrix = tuple[tuple[float, ...], ...]


class ConfigError(ValueError):
    """A configuration value is invalid; ``field`` is its dotted name."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.reason = message


def _matrix(value: Any, name: str, shape: tuple[int, int] | None = None) -> Matrix:
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


def _arr(m: Matrix) -> np.ndarray:
    return np.array(m, dtype=float)


# Plausibility bounds of a piezoelectric positioner (SI).  Values outside are unit mistakes (µm/V entered as m/V,
# kV, ms …), not actuators: refused with the field's name.
#: |Dp|, |A| entries [m/V]: piezo stacks and tubes give 1e-10…1e-6 m/V; amplified (flexure) stages up to ~2e-5 m/V
MAX_GAIN_M_PER_V = 1e-4
#: |B|, |Gamma|, |Delta1|, |Delta2| entries [1/V]: fitted values are 1e-4…1e-1 1/V (the paper: 0.0073); above this
#: the hysteresis would saturate within a fraction of a volt
MAX_HYSTERESIS_RATE = 10.0
#: |limits.voltage| [V]: piezo amplifiers stay under 1.5 kV
MAX_LIMIT_VOLTAGE = 2000.0
#: limits.slew [V/s]: 1e7 V/s already needs ~50 mA into a few nF
MAX_LIMIT_SLEW = 1e10
#: limits.stale_timeout [s]: longer than this and a dead stream is never noticed
MAX_STALE_TIMEOUT = 60.0
#: sample rates a piezo drive runs at [Hz] (the same range the importers accept for recorded data)
MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 100.0, 10.0e6
#: the only voltage unit of a config file (gains per volt, limits in volts)
VOLTAGE_UNITS = ("V",)


_T = TypeVar("_T")


def _unknown_keys(d: Mapping[Any, Any], allowed: Sequence[Any], prefix: str) -> None:
    """Refuse keys not in ``allowed`` (a misspelling must not be silently ignored), suggesting the closest one."""
    import difflib

    for key in d:
        if key not in allowed:
            name = f"{prefix}.{key}" if prefix else str(key)
            close = difflib.get_close_matches(str(key), [str(a) for a in allowed], n=1, cutoff=0.6)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ConfigError(name, f"unknown key; {hint}(allowed: {', '.join(sorted(map(str, allowed)))})")


def dataclass_from_mapping(cls: type[_T], d: Mapping[str, Any] | None, prefix: str) -> _T:
    """``cls(**d)`` for a config dataclass, refusing unknown keys (named ``prefix.key``, with the closest known one).

    Parameters
    ----------
    cls : type
        A dataclass whose fields are the allowed keys (its ``__post_init__`` validates the values).
    d : mapping or None
        The section as read from YAML or parameters (None: all defaults).
    prefix : str
        The section's name in error messages (``learning``, ``preview`` …).

    Returns
    -------
    An instance of ``cls``.
    """
    import dataclasses

    values = dict(d or {})
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]  # _T is any config dataclass
    _unknown_keys(values, names, prefix)
    return cls(**values)


def _section(d: Mapping[str, Any], key: str, prefix: str = "", required: bool = False) -> dict[str, Any]:
    """``d[key]`` as a dict (``{}`` when absent or null); ``ConfigError`` naming it if it is not a mapping."""
    name = f"{prefix}.{key}" if prefix else key
    v = d.get(key)
    if v is None:
        if required:
            raise ConfigError(name, "missing section")
        return {}
    if not isinstance(v, Mapping):
        raise ConfigError(name, f"expected a mapping of keys to values, got {type(v).__name__} {v!r}"[:200])
    return dict(v)


def _number(value: Any, name: str) -> float:
    """A real number (numeric strings such as YAML's ``1e-3`` included, booleans not)."""
    if isinstance(value, bool) or value is None:
        raise ConfigError(name, f"expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(name, f"expected a number, got {value!r}"[:200]) from None


def _integer(value: Any, name: str) -> int:
    """An integer; a float is accepted only when it is integral (``12.0``), never rounded (``12.5``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(name, f"expected an integer, got {value!r}")
    if isinstance(value, float) and not value.is_integer():
        raise ConfigError(name, f"expected an integer, got {value!r} (not rounded: say what you mean)")
    return int(value)


def _bounded(m: Matrix, name: str, bound: float, unit: str) -> None:
    a = np.abs(_arr(m))
    if a.size and a.max() > bound:
        i, j = np.unravel_index(int(np.argmax(a)), a.shape)
        raise ConfigError(name, f"entry ({i + 1},{j + 1}) = {_arr(m)[i, j]:.6g} {unit} is not plausible for a "
                                f"piezo actuator (|entry| ≤ {bound:g} {unit}); check the units "
                                "(units.length, SI at runtime)")


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


def _tf_matrix_from_dict(d: Any, axes: tuple[str, ...], prefix: str) -> TFMatrix:
    n = len(axes)
    rows = [[FactoredTF(0.0) for _ in range(n)] for _ in range(n)]
    if isinstance(d, (list, tuple)):
        if len(d) != n or any(len(r) != n for r in d):
            raise ConfigError(prefix, f"expected a {n}x{n} nested list of transfer functions")
        items: dict[tuple[int, int], Any] = {(i, j): d[i][j] for i in range(n) for j in range(n)}
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
        if not isinstance(val, Mapping):
            raise ConfigError(name, "expected {k: gain, num: [[…], …], den: [[…], …]}")
        _unknown_keys(val, ("k", "gain", "num", "den"), name)
        if "den" not in val:
            raise ConfigError(f"{name}.den", "missing (a non-zero entry needs a denominator)")
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


def _axis_pair(key: str, axes: tuple[str, ...]) -> tuple[int, int] | None:
    for i, a in enumerate(axes):
        for j, b in enumerate(axes):
            if key in (a + b, f"{a},{b}", f"{a}_{b}"):
                return i, j
    return None


def _tf_matrix_to_dict(tfm: TFMatrix, axes: tuple[str, ...]) -> dict[str, Any]:
    out = {}
    for i, a in enumerate(axes):
        for j, b in enumerate(axes):
            tf = tfm[i, j]
            if not tf.is_zero():
                out[f"{a}{b}"] = tf.to_dict()
    return out


def _check_tf_matrix(tfm: TFMatrix, prefix: str, axes: Sequence[str], strictly_proper: bool) -> None:
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


@dataclass(frozen=True)
class PiezoConfig:
    """Everything about one positioner: axes, sample rate, the three models, H∞ weights, cascade, limits."""

    name: str
    axes: tuple[str, ...]
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
        """Sample period [s]."""
        return 1.0 / self.sample_rate

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return len(self.axes)

    def validate(self) -> "PiezoConfig":
        """``self`` if every section is valid and consistent with the axes; else ConfigError naming the field."""
        if not self.axes or len(set(self.axes)) != len(self.axes):
            raise ConfigError("axes", f"need distinct axis names, got {list(self.axes)}")
        if isinstance(self.sample_rate, bool) or not (isinstance(self.sample_rate, (int, float))
                                                       and math.isfinite(self.sample_rate) and self.sample_rate > 0):
            raise ConfigError("sample_rate", f"must be > 0 Hz, got {self.sample_rate!r}")
        if not MIN_SAMPLE_RATE <= self.sample_rate <= MAX_SAMPLE_RATE:
            raise ConfigError("sample_rate", f"{self.sample_rate:g} Hz is outside {MIN_SAMPLE_RATE:g} Hz … "
                                             f"{MAX_SAMPLE_RATE:g} Hz (a unit mistake?)")
        from .recording.blocks import sample_period_ns

        try:  # the topic contract stamps samples on a whole-nanosecond grid (docs/topics.md)
            sample_period_ns(self.sample_rate)
        except ValueError as exc:
            raise ConfigError("sample_rate", f"{self.sample_rate:g} Hz: {str(exc).split(': ', 1)[-1]} "
                                             "(docs/topics.md: 20 kHz, 10 kHz, 25 kHz … but not 30 kHz)") from None
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
        """The same configuration at sample rate ``fs`` [Hz] (validated)."""
        return replace(self, sample_rate=float(fs)).validate()

    # -- dict / YAML ----------------------------------------------------------------------------------------------
    @staticmethod
    def from_dict(d: Mapping[str, Any], variant: str | None = None) -> "PiezoConfig":
        """From the YAML form (any length unit, ``variants`` applied); validated, SI inside.

        Parameters
        ----------
        d : mapping
            The parsed YAML.
        variant : str, optional
            A name in ``variants`` (default: the file's ``variant`` key, else ``printed``).

        Returns
        -------
        PiezoConfig

        Raises
        ------
        ConfigError
            Naming the first invalid field.
        """
        if not isinstance(d, Mapping):
            raise ConfigError("config", f"top level must be a mapping, got {type(d).__name__}")
        data: dict[str, Any] = copy.deepcopy(dict(d))
        _unknown_keys(data, [f.name for f in fields(PiezoConfig)] + ["units", "variants", "description"], "")
        variants = _section(data, "variants")
        data.pop("variants", None)
        chosen = variant or data.pop("variant", None) or "printed"
        data.pop("variant", None)
        for vname, v in variants.items():
            if not isinstance(v, Mapping):
                raise ConfigError(f"variants.{vname}", "expected a mapping {description, set}")
            _unknown_keys(v, ("description", "set"), f"variants.{vname}")
            for path in _section(v, "set", f"variants.{vname}"):  # every variant, selected or not: a typo shows now
                cur: Any = data
                for k in str(path).split(".")[:-1]:
                    cur = cur.get(k) if isinstance(cur, dict) else None
                if not isinstance(cur, dict):
                    raise ConfigError(f"variants.{vname}.set", f"path {path!r} does not exist in the config")
        if chosen != "printed":
            if chosen not in variants:
                raise ConfigError("variant", f"unknown variant {chosen!r}; available: {['printed', *variants]}")
            for path, value in _section(variants[chosen], "set", f"variants.{chosen}").items():
                _set_path(data, path, value)
        units = _section(data, "units")
        _unknown_keys(units, ("length", "voltage"), "units")
        try:
            L = length_scale(units.get("length", "m"))
        except (TypeError, ValueError) as exc:
            raise ConfigError("units.length", str(exc)) from None
        if units.get("voltage", "V") not in VOLTAGE_UNITS:
            raise ConfigError("units.voltage", f"{units['voltage']!r} is not supported: give voltages in V (Dp, A "
                                               "in <length>/V, B, Gamma in 1/V, limits in V)")
        raw_axes = data.get("axes", ["x", "y"])
        if not isinstance(raw_axes, (list, tuple)) or not all(isinstance(a, str) and a for a in raw_axes):
            raise ConfigError("axes", f"expected a list of axis names like [x, y], got {raw_axes!r}")
        axes = tuple(raw_axes)
        if not axes or len(set(axes)) != len(axes):
            raise ConfigError("axes", f"need at least one axis and distinct names, got {list(axes)}")
        for key in ("name", "source"):
            if key in data and not isinstance(data[key], str):
                raise ConfigError(key, f"expected a string, got {data[key]!r}")
        hyst = BoucWenConfig.from_dict(_section(data, "hysteresis", required=True), L)
        cr = _section(data, "creep", required=True)
        _unknown_keys(cr, ("K", "Cr"), "creep")
        if "K" not in cr:
            raise ConfigError("creep.K", "missing")
        creep = CreepConfig(K=_matrix(cr["K"], "creep.K", (len(axes), len(axes))),
                            Cr=_tf_matrix_from_dict(cr.get("Cr", {}), axes, "creep.Cr"))
        dyn = _section(data, "dynamics", required=True)
        _unknown_keys(dyn, ("G_L",), "dynamics")
        if "G_L" not in dyn:
            raise ConfigError("dynamics.G_L", "missing")
        dynamics = DynamicsConfig(_tf_matrix_from_dict(dyn["G_L"], axes, "dynamics.G_L"))
        vib = _section(data, "vibration")
        _unknown_keys(vib, [f.name for f in fields(HinfConfig)], "vibration")
        W2 = vib.get("W2", 1.0)
        W2 = tuple(_number(w, "vibration.W2") for w in (W2 if isinstance(W2, (list, tuple)) else [W2] * len(axes)))
        ctrl = vib.get("controller")
        if ctrl is not None and not isinstance(ctrl, Mapping):
            raise ConfigError("vibration.controller", "expected a mapping {A, B, C, D}")
        vibration = HinfConfig(t_r=_number(vib.get("t_r", 0.025), "vibration.t_r"),
                               eps_s=_number(vib.get("eps_s", 0.01), "vibration.eps_s"),
                               k_o=_number(vib.get("k_o", 1.0), "vibration.k_o"), W2=W2,
                               order=_integer(vib.get("order", 12), "vibration.order"),
                               gamma_max=_number(vib.get("gamma_max", 1.0), "vibration.gamma_max"), controller=ctrl)
        casc = _section(data, "cascade")
        _unknown_keys(casc, [f.name for f in fields(CascadeConfig)], "cascade")
        cascade = CascadeConfig(**casc)
        lim = dict(_section(data, "limits"))
        _unknown_keys(lim, [f.name for f in fields(LimitsConfig)], "limits")
        ws = lim.pop("workspace", None)
        if ws is not None:
            try:
                ws = tuple((float(lo) * L, float(hi) * L) for lo, hi in ws)
            except (TypeError, ValueError) as exc:
                raise ConfigError("limits.workspace", f"expected [[min, max], …] per axis ({exc})") from None
            if len(ws) != len(axes):
                raise ConfigError("limits.workspace", f"{len(ws)} ranges for {len(axes)} axes")
        limits = LimitsConfig(**{k: _number(v, f"limits.{k}") for k, v in lim.items()}, workspace=ws)
        cfg = PiezoConfig(name=str(data.get("name", "piezo")), axes=axes,
                          sample_rate=_number(data.get("sample_rate", 20000.0), "sample_rate"), hysteresis=hyst,
                          creep=creep, dynamics=dynamics, vibration=vibration, cascade=cascade, limits=limits,
                          source=str(data.get("source", "")), variant=chosen)
        return cfg.validate()

    def to_dict(self, length_unit: str = "um") -> dict[str, Any]:
        """The YAML form with lengths in ``length_unit`` (:meth:`from_dict` reads it back)."""
        L = length_scale(length_unit)
        vib: dict[str, Any] = {"t_r": self.vibration.t_r, "eps_s": self.vibration.eps_s, "k_o": self.vibration.k_o,
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
                       "stale_timeout": self.limits.stale_timeout, "safe_voltage": self.limits.safe_voltage,
                       **({"workspace": [[lo / L, hi / L] for lo, hi in self.limits.workspace]}
                          if self.limits.workspace is not None else {})},
        }

    def to_yaml(self, path: str | Path | None = None, length_unit: str = "um") -> str:
        """:meth:`to_dict` as YAML text, also written to ``path`` when given."""
        text = yaml.safe_dump(self.to_dict(length_unit), sort_keys=False, default_flow_style=None, width=120)
        if path is not None:
            Path(path).write_text(text)
        return text


def _set_path(d: dict[str, Any], path: str, value: Any) -> None:
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


class DuplicateKeyError(ValueError):
    """A YAML mapping holds the same key twice (``line`` is 1-based)."""

    def __init__(self, key: Any, line: int) -> None:
        super().__init__(f"line {line}: duplicate key {key!r}")
        self.key, self.line = key, line


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys (the plain loader keeps the last value, silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        """The mapping of ``node``; :class:`DuplicateKeyError` on a repeated key."""
        self.flatten_mapping(node)
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                dup = key in seen
            except TypeError:  # an unhashable key: let the base class report it
                break
            if dup:
                raise DuplicateKeyError(key, key_node.start_mark.line + 1)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def load_config(path: str | Path | None = None, variant: str | None = None) -> PiezoConfig:
    """Load and validate a positioner config (default: the paper's PT230.94 values as printed)."""
    p = Path(path) if path is not None else default_config_path()
    if p.is_dir():
        raise ConfigError(str(p), "is a directory, not a YAML config file")
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such config file")
    try:
        data = yaml.load(p.read_text(), Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except DuplicateKeyError as exc:
        raise ConfigError(str(p), f"line {exc.line}: duplicate key {exc.key!r} (YAML would silently keep the "
                                  "last value)") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(str(p), f"not a text (YAML) file ({exc.reason} at byte {exc.start})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(str(p), f"not valid YAML ({exc})") from None
    if not isinstance(data, Mapping):
        raise ConfigError(str(p), "top level must be a mapping")
    return PiezoConfig.from_dict(data, variant=variant)


def flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{'a': {'b': 1}}`` → ``{'a.b': 1}`` (lists are leaves)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            out.update(flatten(v, key))
        else:
            out[key] = v
    return out


def unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """``{'a.b': 1}`` → ``{'a': {'b': 1}}`` (the inverse of :func:`flatten`)."""
    out: dict[str, Any] = {}
    for key, v in flat.items():
        cur = out
        parts = key.split(".")
        for p in parts[:-1]:
            cur = cur.setdefault(p, {})
        cur[parts[-1]] = v
    return out
