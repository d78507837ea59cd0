"""The one voltage limiter: clamp to ``±limit``, then move at most ``step`` volts per sample (compiled, pure).

:func:`limit_step` is the per-sample, per-axis rule used by every caller — the driver's guard
(:class:`~piezo_ff_ros.core.safety.VoltageGuard`), the amplifier slew-limit effect
(:class:`~piezo_ff_ros.core.models.effects.AmplifierSlewLimit`) and the hysteresis compensators' kernels (which
saturate their own output exactly as the driver will) — so that they agree to the last bit.  A target that is
reachable (within ``±limit`` and within ``step`` of the previous value) is returned exactly, not as
``prev + (target − prev)``.
"""
from __future__ import annotations

import numpy as np

from .._jit import njit

__all__ = ["CLAMPED", "SLEWED", "limit_step", "limit_run"]

#: bit of :func:`limit_step`'s flags: the target was outside ±limit
CLAMPED = 1
#: bit of :func:`limit_step`'s flags: the clamped target was more than ``step`` away from the previous value
SLEWED = 2


@njit(inline="always")
def limit_step(prev: float, target: float, limit: float, step: float) -> tuple[float, int]:  # pragma: no cover - compiled
    """The next value from ``prev`` towards ``target``: clamped to ``±limit``, then at most ``step`` away.

    Parameters
    ----------
    prev : float
        The previous output (already within the limits).
    target : float
        The requested value.
    limit : float
        Bound of the output magnitude (``inf`` = none).
    step : float
        Largest change per sample (``inf`` = none).

    Returns
    -------
    value : float
        The output.
    flags : int
        :data:`CLAMPED` | :data:`SLEWED` for what was limited (0 when ``target`` was reachable).
    """
    flags = 0
    v = target
    if v > limit or v < -limit:
        v = limit if v > 0 else -limit
        flags |= CLAMPED
    d = v - prev
    if d > step:
        v = prev + step
        flags |= SLEWED
    elif d < -step:
        v = prev - step
        flags |= SLEWED
    return v, flags


@njit
def limit_run(target: np.ndarray, prev: np.ndarray, started: np.ndarray, limit: float, step: float,
              out: np.ndarray, counts: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`limit_step` over a block ``target [N, axes]``; ``prev`` (per axis) is updated in place.

    While ``started[0]`` is False the first sample only clamps (there is no previous value) and sets it.
    ``counts[0]`` += samples with an axis clamped, ``counts[1]`` += samples with an axis slew-limited.
    """
    N = target.shape[0]
    n = target.shape[1]
    for k in range(N):
        any_flags = 0
        for a in range(n):
            if started[0]:
                v, f = limit_step(prev[a], target[k, a], limit, step)
            else:  # no previous value: clamp only
                v, f = limit_step(0.0, target[k, a], limit, np.inf)
            any_flags |= f
            prev[a] = v
            out[k, a] = v
        started[0] = True
        if any_flags & CLAMPED:
            counts[0] += 1
        if any_flags & SLEWED:
            counts[1] += 1
