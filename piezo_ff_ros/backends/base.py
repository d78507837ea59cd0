"""What a driver backend plug-in declares (no ROS here): its name, its parameters (defaults, descriptions,
checks) and a factory that returns a :class:`~piezo_ff_ros.core.hardware.contract.StreamingBackend`.

The driver declares every parameter of the selected backend as ``<backend>.<name>`` (typed by its default),
validates it with the plug-in's check and refuses to start with a one-line error naming the parameter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from ..core.config import ConfigError


class BackendError(RuntimeError):
    """The backend cannot do what was asked (unknown name, open failed, vendor package missing…)."""


@dataclass(frozen=True)
class Param:
    """One backend parameter: default (its type is the parameter's type), description, optional check
    ``check(value) -> error text | None``."""

    default: Any
    description: str
    check: Callable[[Any], str | None] | None = None


@dataclass(frozen=True)
class BackendSpec:
    """A backend plug-in: register it in the ``piezo_ff_ros.backends`` entry-point group (``name = module:SPEC``)."""

    name: str
    description: str
    parameters: Mapping[str, Param]
    create: Callable[[Any, dict], Any]   #: ``create(cfg: PiezoConfig, params: dict) -> StreamingBackend``

    def validate(self, values: Mapping[str, Any]) -> dict:
        """Defaults filled in, every value checked; ConfigError naming ``<backend>.<param>`` otherwise."""
        unknown = sorted(set(values) - set(self.parameters))
        if unknown:
            raise ConfigError(f"{self.name}.{unknown[0]}", f"unknown parameter of backend {self.name!r}; known: "
                                                           f"{sorted(self.parameters)}")
        out = {}
        for name, p in self.parameters.items():
            v = values.get(name, p.default)
            if isinstance(p.default, float) and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if isinstance(p.default, list) and not isinstance(v, (str, bytes)) and hasattr(v, "__iter__"):
                v = list(v)   # ROS gives array('d') for double arrays
            if type(v) is not type(p.default) and not (isinstance(p.default, list) and isinstance(v, (list, tuple))):
                raise ConfigError(f"{self.name}.{name}", f"expected {type(p.default).__name__}, got {v!r}")
            err = p.check(v) if p.check is not None else None
            if err:
                raise ConfigError(f"{self.name}.{name}", err)
            out[name] = v
        return out


# -- checks ---------------------------------------------------------------------------------------------------------
def int_range(lo: int, hi: int) -> Callable[[Any], str | None]:
    return lambda v: None if lo <= v <= hi else f"must be an integer in [{lo}, {hi}], got {v!r}"


def float_range(lo: float, hi: float) -> Callable[[Any], str | None]:
    return lambda v: (None if (math.isfinite(v) and lo <= v <= hi)
                      else f"must be a number in [{lo:g}, {hi:g}], got {v!r}")


def one_of(*choices: Any) -> Callable[[Any], str | None]:
    """A check: the value is one of ``choices``."""
    return lambda v: None if v in choices else f"must be one of {list(choices)}, got {v!r}"


def non_empty(v: Any) -> str | None:
    """A check: the value is not empty text."""
    return None if str(v).strip() else "must not be empty"
