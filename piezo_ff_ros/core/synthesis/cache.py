"""An on-disk cache of H∞ designs, so that a compensator restarted on the same stage does not synthesise again.

The synthesis of the paper's C(s) costs seconds of CPU (SLICOT SB10AD, the frequency-grid verification, the
balanced truncation) and gives the same matrices every time for the same plant, weights and code.  A compensator
node (re)started on an unchanged configuration, or a live change that comes back to a configuration already built,
loads the design it made before instead.

The key is a SHA-256 over everything the result depends on: the plant ``G_L`` and the weights (every field, floats
by their exact bits), the ``reduce``/``verify`` flags, the source of the synthesis code (this package's
``core/synthesis`` and ``core/transfer.py``) and the versions of numpy, scipy, python-control and slycot.  Any
change of one of them is a miss.  Entries are ``.npz`` files read without pickle; an unreadable or inconsistent entry
is ignored and written again.

``PIEZO_FF_HINF_CACHE`` names the directory (default ``$XDG_CACHE_HOME/piezo_ff_ros/hinf``, else
``~/.cache/piezo_ff_ros/hinf``); ``off`` disables the cache.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
import zipfile
from importlib import metadata
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..config import HinfConfig
from ..transfer import TFMatrix
from .hinf import HinfDesign, synthesize_hinf

#: environment variable: the cache directory, or ``off``
CACHE_ENV = "PIEZO_FF_HINF_CACHE"
#: bump when the entry layout changes
_LAYOUT = "hinf-design-1"
_LIBRARIES = ("numpy", "scipy", "control", "slycot")
_SCALARS = ("gamma", "gamma_full_achieved", "gamma_reduced_achieved", "order_full", "order_reduced",
            "generalized_plant_order", "synthesis_s", "gamma_lower_bound", "verify_s")
_code_digest: str | None = None


def cache_dir() -> Path | None:
    """The cache directory from :data:`CACHE_ENV` (None when the cache is off)."""
    value = os.environ.get(CACHE_ENV, "")
    if value.strip().lower() == "off":
        return None
    if value:
        return Path(value)
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root) / "piezo_ff_ros" / "hinf"


def design_key(G_L: TFMatrix, cfg: HinfConfig, reduce: bool = True, verify: bool = True) -> str:
    """The cache key of a synthesis: SHA-256 hex of its inputs, the synthesis code and the libraries' versions."""
    h = hashlib.sha256(_LAYOUT.encode())
    h.update(_code_and_libraries().encode())
    _feed(h, (G_L, dataclasses.replace(cfg, controller=None), bool(reduce), bool(verify)))
    return h.hexdigest()


def cached_synthesis(G_L: TFMatrix, cfg: HinfConfig) -> HinfDesign:
    """:func:`~.hinf.synthesize_hinf` (reduced, verified), loaded from the cache when it was made before.

    Parameters
    ----------
    G_L : TFMatrix
        Square, stable plant ``Y_L → Y``.
    cfg : HinfConfig
        Weights, reduction order and γ_max.

    Returns
    -------
    HinfDesign
        The same design as a fresh synthesis (the matrices to the last bit; ``synthesis_s`` is the original
        synthesis's time).

    Raises
    ------
    HinfSynthesisError
        As :func:`~.hinf.synthesize_hinf` (a failed synthesis is not cached).
    """
    folder = cache_dir()
    if folder is None:
        return synthesize_hinf(G_L, cfg)
    path = folder / f"{design_key(G_L, cfg)}.npz"
    design = _load(path)
    if design is None:
        design = synthesize_hinf(G_L, cfg)
        _save(path, design)
    return design


def _code_and_libraries() -> str:
    global _code_digest
    if _code_digest is None:
        h = hashlib.sha256()
        here = Path(__file__).resolve().parent
        for src in [*sorted(here.glob("*.py")), here.parent / "transfer.py"]:
            h.update(src.name.encode())
            h.update(src.read_bytes())
        for lib in _LIBRARIES:
            try:
                version = metadata.version(lib)
            except metadata.PackageNotFoundError:
                version = "absent"
            h.update(f"{lib}={version};".encode())
        _code_digest = h.hexdigest()
    return _code_digest


def _feed(h: Any, x: Any) -> None:
    """Feed ``x`` to the hash ``h`` unambiguously (type tags, lengths, floats by their bits)."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        h.update(f"<{type(x).__qualname__}>".encode())
        for f in dataclasses.fields(x):
            h.update(f.name.encode())
            _feed(h, getattr(x, f.name))
    elif isinstance(x, np.ndarray):
        a = np.ascontiguousarray(x)
        h.update(f"<nd {a.dtype.str} {a.shape}>".encode())
        h.update(a.tobytes())
    elif isinstance(x, (bool, np.bool_)):
        h.update(b"<b1>" if x else b"<b0>")
    elif isinstance(x, (int, np.integer)):
        h.update(f"<i{int(x)}>".encode())
    elif isinstance(x, (float, np.floating)):
        h.update(f"<f{float(x).hex()}>".encode())
    elif isinstance(x, (complex, np.complexfloating)):
        h.update(f"<c{complex(x).real.hex()},{complex(x).imag.hex()}>".encode())
    elif isinstance(x, str):
        h.update(f"<s{len(x)}>".encode() + x.encode())
    elif x is None:
        h.update(b"<none>")
    elif isinstance(x, Mapping):
        h.update(f"<map {len(x)}>".encode())
        for k in sorted(x, key=str):
            _feed(h, str(k))
            _feed(h, x[k])
    elif isinstance(x, (list, tuple)):
        h.update(f"<seq {len(x)}>".encode())
        for v in x:
            _feed(h, v)
    else:   # a field of a type not handled here must never be left out of the key silently
        raise TypeError(f"H∞ cache key: cannot hash {type(x).__name__}")


def _save(path: Path, design: HinfDesign) -> None:
    arrays: dict[str, np.ndarray] = {}
    for name, ss in (("K", design.controller_full), ("Kr", design.controller)):
        for m in ("A", "B", "C", "D"):
            arrays[f"{name}_{m}"] = np.asarray(getattr(ss, m), float)
    arrays["hsv"] = np.asarray(design.hankel_singular_values, float)
    meta: dict[str, Any] = {k: float(getattr(design, k)) for k in _SCALARS}
    meta["notes"] = list(design.notes)
    arrays["meta"] = np.array(json.dumps(meta, allow_nan=True))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **arrays)   # type: ignore[arg-type]  # numpy's stub types allow_pickle as **kwds
            os.replace(tmp, path)   # atomic: a concurrent reader sees the whole entry or none
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError:
        pass   # a read-only or full disk: the design is still returned, only not kept


def _load(path: Path) -> HinfDesign | None:
    import control

    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            ss = {name: control.ss(*(np.array(z[f"{name}_{m}"]) for m in ("A", "B", "C", "D")))
                  for name in ("K", "Kr")}
            hsv = np.array(z["hsv"])
        scalars = {k: float(meta[k]) for k in _SCALARS}
        notes = tuple(str(n) for n in meta["notes"])
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile):
        return None   # absent, truncated or of another layout: synthesise again
    if ss["Kr"].nstates != scalars["order_reduced"] or ss["K"].nstates != scalars["order_full"] \
            or not math.isfinite(scalars["gamma"]):
        return None
    return HinfDesign(controller=ss["Kr"], controller_full=ss["K"], gamma=scalars["gamma"],
                      gamma_full_achieved=scalars["gamma_full_achieved"],
                      gamma_reduced_achieved=scalars["gamma_reduced_achieved"],
                      order_full=int(scalars["order_full"]), order_reduced=int(scalars["order_reduced"]),
                      generalized_plant_order=int(scalars["generalized_plant_order"]), hankel_singular_values=hsv,
                      synthesis_s=scalars["synthesis_s"], gamma_lower_bound=scalars["gamma_lower_bound"],
                      verify_s=scalars["verify_s"], notes=notes)
