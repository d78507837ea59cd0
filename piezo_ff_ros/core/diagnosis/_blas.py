"""Run the diagnosis with single-threaded BLAS (the matrices it multiplies are tall and thin).

The diagnosis multiplies many small Gram matrices and tall-thin products; multi-threaded OpenBLAS gains nothing on
them and its worker threads busy-wait between calls, which on a 2-core machine cost ~7 s of CPU time (user and
system) on a 10-minute 20 kHz record.  :func:`single_threaded_blas` sets every OpenBLAS already loaded
in the process (numpy's and scipy's bundled copies) to one thread for the duration and restores the previous
count; where the libraries cannot be found (another BLAS, another OS) it does nothing.  What threadpoolctl does,
in the few lines this package needs.
"""
from __future__ import annotations

import ctypes
import os
from contextlib import contextmanager
from typing import Any, Iterator

__all__ = ["single_threaded_blas"]

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
            "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_",
            "openblas_get_num_threads")


def _loaded_openblas() -> list[tuple[Any, Any]]:
    """(set, get) function pairs of every OpenBLAS mapped into this process (Linux: from /proc/self/maps)."""
    out: list[tuple[Any, Any]] = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and ".so" in line})
    except OSError:
        return out
    for path in paths:
        if not os.path.isfile(path):
            continue
        try:
            lib = ctypes.CDLL(path, mode=getattr(os, "RTLD_NOLOAD", 0) | ctypes.RTLD_GLOBAL)
        except OSError:
            continue
        setter = next((getattr(lib, s) for s in _SETTERS if hasattr(lib, s)), None)
        getter = next((getattr(lib, g) for g in _GETTERS if hasattr(lib, g)), None)
        if setter is not None and getter is not None:
            setter.argtypes, getter.restype = [ctypes.c_int], ctypes.c_int
            out.append((setter, getter))
    return out


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context manager: every loaded OpenBLAS runs single-threaded inside, as before outside."""
    libs = []
    try:
        for setter, getter in _loaded_openblas():
            libs.append((setter, int(getter())))
            setter(1)
    except (OSError, AttributeError, ValueError):  # pragma: no cover - an unusual BLAS: leave it alone
        pass
    try:
        yield
    finally:
        for setter, n in libs:
            try:
                setter(max(int(n), 1))
            except (OSError, ValueError):  # pragma: no cover
                pass
