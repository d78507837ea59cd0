"""The whole positioner's configuration, :class:`PiezoConfig`, and its YAML form (units, variants) both ways.

:meth:`PiezoConfig.from_dict` reads the parsed YAML: it refuses unknown keys, applies the selected ``variant`` (every
variant's paths are checked, selected or not), converts lengths from the file's ``units`` to SI (here and nowhere
else) and builds and validates every stage config of :mod:`.stages`.  :meth:`PiezoConfig.to_dict` and
:meth:`PiezoConfig.to_yaml` write it back in a chosen length unit.  Reading files is :mod:`.loader`'s.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from ..units import length_scale, sample_period_ns
from .stages import BoucWenConfig, CascadeConfig, CreepConfig, DynamicsConfig, HinfConfig, LimitsConfig
from .tf_entries import _tf_matrix_from_dict, _tf_matrix_to_dict
from .validation import (MAX_SAMPLE_RATE, MIN_SAMPLE_RATE, VOLTAGE_UNITS, ConfigError, _arr, _integer, _matrix,
                         _number, _section, _unknown_keys)

__all__ = ["PiezoConfig"]


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
