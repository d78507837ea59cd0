"""Driver backends: what turns a voltage block into applied voltage (and, for the simulator, a displacement).

A backend for real hardware (DAQ/amplifier + optional sensor) implements :class:`Backend` and registers itself in
:data:`BACKENDS`; the driver node does the safety (limits, slew, stale input) before anything reaches it.
"""
from __future__ import annotations

from .base import Backend, BackendError
from .sim import SimBackend

#: backend name (driver parameter ``backend``) → factory ``(cfg, params: dict) -> Backend``
BACKENDS = {"sim": SimBackend.from_params}


def make_backend(name: str, cfg, params: dict) -> Backend:
    try:
        factory = BACKENDS[name]
    except KeyError:
        raise BackendError(f"backend: unknown backend {name!r}; available: {sorted(BACKENDS)}") from None
    return factory(cfg, params)


__all__ = ["Backend", "BackendError", "SimBackend", "BACKENDS", "make_backend"]
