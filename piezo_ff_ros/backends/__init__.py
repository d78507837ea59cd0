"""Driver backends as plug-ins: ``sim`` (built in), ``nidaqmx`` and ``pi_gcs`` (optional extras), and any backend a
lab registers in the ``piezo_ff_ros.backends`` entry-point group (``mybackend = mypkg.module:SPEC``, a
:class:`BackendSpec`) — no fork needed.  The driver node does the safety before anything reaches a backend.
"""
from __future__ import annotations

from importlib import import_module
from importlib.metadata import entry_points

from .base import BackendError, BackendSpec, Param

ENTRY_POINT_GROUP = "piezo_ff_ros.backends"

#: built-in backends (also registered as entry points by setup.py; listed here so that a source checkout works)
BUILTIN = {"sim": "piezo_ff_ros.backends.sim:SPEC",
           "nidaqmx": "piezo_ff_ros.backends.nidaqmx_backend:SPEC",
           "pi_gcs": "piezo_ff_ros.backends.pi_gcs:SPEC"}


def _load(ref: str) -> BackendSpec:
    mod, _, attr = ref.partition(":")
    return getattr(import_module(mod), attr)


def available() -> dict[str, str]:
    """Backend name → ``module:attr`` of its spec (built-ins and entry points)."""
    found = dict(BUILTIN)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(ep.name, ep.value)
    return found


def get_spec(name: str) -> BackendSpec:
    """The spec of backend ``name``; BackendError (one line) if unknown or broken."""
    refs = available()
    if name not in refs:
        raise BackendError(f"backend: unknown backend {name!r}; available: {sorted(refs)}")
    try:
        spec = _load(refs[name])
    except Exception as exc:  # noqa: BLE001 - a broken plug-in: say which and why
        raise BackendError(f"backend: plug-in {name!r} ({refs[name]}) failed to load: {exc}") from None
    if not isinstance(spec, BackendSpec):
        raise BackendError(f"backend: plug-in {name!r} ({refs[name]}) is not a BackendSpec")
    return spec


__all__ = ["BackendError", "BackendSpec", "Param", "ENTRY_POINT_GROUP", "available", "get_spec"]
