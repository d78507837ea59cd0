"""numba's ``njit`` when available (the Bouc-Wen recursion needs a compiled loop to be fast), else a no-op.

numba earns its place: per-sample loops are the heart of every stage, and plain Python runs them at ~1× real time.
The fallback keeps the core importable (and correct, only slow) where numba is missing.
"""
from __future__ import annotations

from typing import Any, Callable, TypeVar, overload

F = TypeVar("F", bound=Callable[..., Any])

_njit: Callable[..., Any] | None
try:  # pragma: no cover - import guard
    from numba import njit as _numba_njit

    _njit = _numba_njit
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    _njit = None
    HAVE_NUMBA = False


@overload
def njit(fn: F, /) -> F: ...
@overload
def njit(**kwargs: Any) -> Callable[[F], F]: ...


def njit(*args: Any, **kwargs: Any) -> Any:
    """Compile a function with numba (``cache=True`` unless given), or return it unchanged without numba.

    Used bare (``@njit``) or with numba's keyword options (``@njit(cache=True)``).  For the type checker, the
    compiled function has the signature of the Python one.

    Parameters
    ----------
    *args
        The function to compile (bare use) or nothing.
    **kwargs
        Options passed to ``numba.njit``.

    Returns
    -------
    callable
        The compiled function, or a decorator when no function is given.
    """
    if _njit is None:  # pragma: no cover - numba missing
        if args and callable(args[0]):
            return args[0]
        return lambda f: f
    kwargs.setdefault("cache", True)
    return _njit(*args, **kwargs)
