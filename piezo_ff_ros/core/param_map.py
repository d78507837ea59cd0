"""PiezoConfig ⇄ flat ROS-parameter dictionary (pure; the compensator node declares exactly these names).

ROS parameters are scalars or flat arrays, so:

- matrices are flat ``double[]`` in row-major order with one row per axis (``hysteresis.Dp`` [m/V], ``hysteresis.A``
  [m/V], ``hysteresis.B``/``Gamma``/``Delta1``/``Delta2`` [1/V], ``hysteresis.input_map``, ``creep.K``); the column
  count follows from the length;
- every entry ``<out><in>`` of a transfer-function matrix (``creep.Cr``, ``dynamics.G_L``) is ``….k`` (gain),
  ``….num``/``….den`` (all factor coefficients concatenated, highest power first) and ``….num_deg``/``….den_deg``
  (the degree of each factor); ``k = 0`` is a zero entry;
- ``vibration.t_r|eps_s|k_o|gamma_max`` (double), ``vibration.W2`` (double[] per axis), ``vibration.order`` (int),
  ``vibration.controller.A|B|C|D`` (flat, empty = synthesise H∞ from the weights);
- ``cascade.hysteresis|creep|vibration`` (bool), ``cascade.order`` ('paper'|'commuted'),
  ``cascade.hysteresis_loop`` ('exact'|'delayed').

Lengths are SI (metres).  :func:`params_to_config` raises :class:`~piezo_ff_ros.core.config.ConfigError` whose text
starts with the parameter's name.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from .config import ConfigError, PiezoConfig

__all__ = ["config_to_params", "params_to_config", "STAGE_PREFIXES", "is_config_param", "needs_synthesis"]

STAGE_PREFIXES = ("hysteresis.", "creep.", "dynamics.", "vibration.", "cascade.")
_HYST = ("Dp", "A", "B", "Gamma", "Delta1", "Delta2", "input_map")
_TF_GROUPS = (("creep", "Cr"), ("dynamics", "G_L"))


def is_config_param(name: str) -> bool:
    """Whether a flat ROS parameter name belongs to the positioner config (one of the stage prefixes).

    Parameters
    ----------
    name : str
        Dotted parameter name.

    Returns
    -------
    bool
        True for ``hysteresis.*``, ``creep.*`` … (see ``STAGE_PREFIXES``).
    """
    return name.startswith(STAGE_PREFIXES)


def needs_synthesis(name: str) -> bool:
    """A change of this parameter requires a new H∞ design (slow: done off the hot path)."""
    return name.startswith(("vibration.", "dynamics.")) and not name.startswith("vibration.controller.")


def _flat(m: Any) -> list[float]:
    return [float(v) for v in np.asarray(m, float).ravel()]


def config_to_params(cfg: PiezoConfig) -> dict[str, Any]:
    """All stage parameters of ``cfg`` as ``{dotted_name: bool|int|float|str|list}`` (SI)."""
    d = cfg.to_dict(length_unit="m")
    n = cfg.n_axes
    out: dict[str, Any] = {}
    arr = cfg.hysteresis.arrays()
    for name in _HYST:
        key = "P" if name == "input_map" else name
        out[f"hysteresis.{name}"] = _flat(arr[key]) if name not in ("Dp", "A") else _flat(d["hysteresis"][name])
    out["creep.K"] = _flat(d["creep"]["K"])
    for section, group in _TF_GROUPS:
        entries = d[section][group]
        for a in cfg.axes:
            for b in cfg.axes:
                tf = entries.get(a + b, {"k": 0.0, "num": [], "den": []})
                base = f"{section}.{group}.{a}{b}"
                out[f"{base}.k"] = float(tf["k"])
                for part in ("num", "den"):
                    out[f"{base}.{part}"] = [float(c) for f in tf[part] for c in f]
                    out[f"{base}.{part}_deg"] = [len(f) - 1 for f in tf[part]]
    v = d["vibration"]
    for name in ("t_r", "eps_s", "k_o", "gamma_max"):
        out[f"vibration.{name}"] = float(v[name])
    out["vibration.W2"] = [float(w) for w in v["W2"]]
    out["vibration.order"] = int(v["order"])
    ctrl = v.get("controller") or {}
    for name in ("A", "B", "C", "D"):
        out[f"vibration.controller.{name}"] = _flat(ctrl[name]) if name in ctrl else []
    c = d["cascade"]
    for name in ("hysteresis", "creep", "vibration", "respect_limits"):
        out[f"cascade.{name}"] = bool(c[name])
    out["cascade.order"] = str(c["order"])
    out["cascade.hysteresis_loop"] = str(c["hysteresis_loop"])
    assert all(k.startswith(STAGE_PREFIXES) for k in out)
    _ = n
    return out


# -- parameters → config -------------------------------------------------------------------------------------------
def _as_float(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(name, f"expected a number, got {v!r}")
    return float(v)


def _as_float_list(name: str, v: Any) -> list[float]:
    if v is None:
        return []
    if isinstance(v, (str, bytes)) or not hasattr(v, "__len__"):
        raise ConfigError(name, f"expected an array of numbers, got {v!r}")
    out: list[float] = []
    for x in v:
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise ConfigError(name, f"expected an array of numbers, got element {x!r}")
        out.append(float(x))
    return out


def _as_matrix(name: str, v: Any, rows: int) -> list[list[float]]:
    flat = _as_float_list(name, v)
    if not flat or len(flat) % rows:
        raise ConfigError(name, f"{len(flat)} values do not make a matrix of {rows} rows (flat, row-major)")
    cols = len(flat) // rows
    return [flat[i * cols:(i + 1) * cols] for i in range(rows)]


def _as_factors(name: str, coeffs: Any, degrees: Any) -> list[list[float]]:
    flat = _as_float_list(name, coeffs)
    if degrees is None:
        degrees = []
    if isinstance(degrees, (str, bytes)) or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 1
                                                    for x in degrees):
        raise ConfigError(f"{name}_deg", f"expected factor degrees ≥ 1, got {degrees!r}")
    if sum(g + 1 for g in degrees) != len(flat):
        raise ConfigError(name, f"{len(flat)} coefficients but the degrees {list(degrees)} need "
                                f"{sum(g + 1 for g in degrees)}")
    out: list[list[float]] = []
    i = 0
    for g in degrees:
        out.append(flat[i:i + g + 1])
        i += g + 1
    return out


def params_to_config(params: Mapping[str, Any], base: PiezoConfig) -> PiezoConfig:
    """A validated config: ``base`` with every stage parameter present in ``params`` taking its value."""
    d = base.to_dict(length_unit="m")
    n = base.n_axes
    p = dict(params)
    known = config_to_params(base).keys()
    for name in p:
        if is_config_param(name) and name not in known:
            raise ConfigError(name, "unknown parameter")

    def get(k: str, default: Any = None) -> Any:
        return p.get(k, default)

    hyst = d["hysteresis"]
    base_arrays = base.hysteresis.arrays()
    for name in _HYST:
        key = f"hysteresis.{name}"
        if key in p:
            r, c = np.shape(base_arrays["P" if name == "input_map" else name])
            flat = _as_float_list(key, p[key])
            if len(flat) != r * c:   # the shape is the node's axes: it cannot change at runtime
                raise ConfigError(key, f"{len(flat)} values, expected {r}×{c} = {r * c} (flat, row-major)")
            hyst[name] = _as_matrix(key, flat, n)
    if "creep.K" in p:
        d["creep"]["K"] = _as_matrix("creep.K", p["creep.K"], n)
    for section, group in _TF_GROUPS:
        entries = d[section][group]
        for a in base.axes:
            for b in base.axes:
                base_key = f"{section}.{group}.{a}{b}"
                if not any(k.startswith(base_key + ".") for k in p):
                    continue
                cur = entries.get(a + b, {"k": 0.0, "num": [], "den": []})
                k = _as_float(f"{base_key}.k", get(f"{base_key}.k", cur["k"]))
                tf: dict[str, Any] = {"k": k}
                for part in ("num", "den"):
                    coeffs = get(f"{base_key}.{part}", [c for f in cur[part] for c in f])
                    degs = get(f"{base_key}.{part}_deg", [len(f) - 1 for f in cur[part]])
                    tf[part] = _as_factors(f"{base_key}.{part}", coeffs, list(degs) if degs is not None else [])
                if k == 0.0:
                    entries.pop(a + b, None)
                else:
                    if not tf["den"]:
                        raise ConfigError(f"{base_key}.den", "a non-zero entry needs a denominator")
                    entries[a + b] = tf
    vib = d["vibration"]
    for name in ("t_r", "eps_s", "k_o", "gamma_max"):
        key = f"vibration.{name}"
        if key in p:
            vib[name] = _as_float(key, p[key])
            if not math.isfinite(vib[name]):
                raise ConfigError(key, "not finite")
    if "vibration.W2" in p:
        vib["W2"] = _as_float_list("vibration.W2", p["vibration.W2"])
    if "vibration.order" in p:
        o = p["vibration.order"]
        if isinstance(o, bool) or not isinstance(o, int):
            raise ConfigError("vibration.order", f"expected an integer, got {o!r}")
        vib["order"] = int(o)
    ctrl_keys = [f"vibration.controller.{m}" for m in "ABCD"]
    if any(k in p for k in ctrl_keys):
        cur = vib.get("controller") or {}
        mats = {m: _as_float_list(k, p.get(k, np.asarray(cur.get(m, []), float).ravel().tolist()))
                for m, k in zip("ABCD", ctrl_keys)}
        if not any(mats.values()):
            vib.pop("controller", None)
        else:
            nc = int(round(math.sqrt(len(mats["A"]))))
            if nc * nc != len(mats["A"]) or nc == 0:
                raise ConfigError("vibration.controller.A", f"{len(mats['A'])} values are not a square matrix")
            shapes = {"A": (nc, nc), "B": (nc, n), "C": (n, nc), "D": (n, n)}
            ctrl = {}
            for m, (r, c) in shapes.items():
                if len(mats[m]) != r * c:
                    raise ConfigError(f"vibration.controller.{m}", f"{len(mats[m])} values, expected {r}x{c}")
                mat = np.array(mats[m], float).reshape(r, c)
                if not np.all(np.isfinite(mat)):
                    raise ConfigError(f"vibration.controller.{m}", "contains NaN or Inf")
                ctrl[m] = mat.tolist()
            vib["controller"] = ctrl
    casc = d["cascade"]
    for name in ("hysteresis", "creep", "vibration", "respect_limits"):
        key = f"cascade.{name}"
        if key in p:
            if not isinstance(p[key], bool):
                raise ConfigError(key, f"expected true or false, got {p[key]!r}")
            casc[name] = p[key]
    for name in ("order", "hysteresis_loop"):
        key = f"cascade.{name}"
        if key in p:
            if not isinstance(p[key], str):
                raise ConfigError(key, f"expected a string, got {p[key]!r}")
            casc[name] = p[key]
    for key, v in p.items():
        if key.startswith("hysteresis.") and not np.all(np.isfinite(np.asarray(_as_float_list(key, v)))):
            raise ConfigError(key, "contains NaN or Inf")
    try:
        cfg = PiezoConfig.from_dict(d)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError("config", str(exc)) from None
    return cfg
