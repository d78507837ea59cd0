"""numba's ``njit`` when available (the Bouc-Wen recursion needs a compiled loop to be fast), else a no-op.

numba earns its place: per-sample loops are the heart of every stage, and plain Python runs them at ~1× real time.
The fallback keeps the core importable (and correct, only slow) where numba is missing.
"""
from __future__ import annotations

try:  # pragma: no cover - import guard
    from numba import njit as _njit

    def njit(*args, **kwargs):
        kwargs.setdefault("cache", True)
        return _njit(*args, **kwargs)

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    HAVE_NUMBA = False

    def njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f
