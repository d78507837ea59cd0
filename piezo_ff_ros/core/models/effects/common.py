"""What the effect stages share: the reference scales of the effects and the check of a block's shape.

The constants are the physical reference scales of the effects (a voltage rate, creep decades, a displacement
level, the time over which the direction of motion is judged); the stages of :mod:`.voltage`, :mod:`.displacement`,
:mod:`.modes` and :mod:`.hysteresis` use them and the registry (:mod:`.registry`) quotes them in its descriptions.
``_block`` refuses a block that is not ``[N, axes]``; ``_per_axis`` turns a scalar or a list into one finite value
per axis.  Units are SI: volts, metres, seconds, hertz.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ...stage import as_block

__all__ = ["RATE_REF", "RATE_SMOOTHING", "CREEP_TAUS", "CREEP_YREF", "LEVEL_TAU", "LEVEL_REF", "DIRECTION_TAU"]


#: reference voltage rate of the rate-dependent hysteresis [V/s]: A grows by ``alpha·tanh(|dU/dt|/RATE_REF)``
RATE_REF = 1.0e4
#: time constant of the smoothing of |dU/dt| in the rate-dependent hysteresis [s] (measured voltages are noisy)
RATE_SMOOTHING = 1.0e-3
#: relaxation times of the extra (logarithmic) creep, one per decade [s]
CREEP_TAUS = (0.1, 1.0, 10.0, 100.0)
#: reference displacement of the amplitude-dependent creep term [m]
CREEP_YREF = 10e-6
#: level of the amplitude-dependent dynamics: |Y| low-passed over LEVEL_TAU [s], in units of LEVEL_REF [m]
LEVEL_TAU = 0.05
LEVEL_REF = 10e-6
#: direction of motion of the asymmetric loop's even term: sign of Y minus Y low-passed over this [s]
DIRECTION_TAU = 2e-3


def _block(x: ArrayLike, n: int | None = None) -> np.ndarray:
    return as_block(x, n)


def _per_axis(value: Any, n: int, name: str) -> np.ndarray:
    a = np.atleast_1d(np.asarray(value, dtype=float))
    if a.size == 1:
        a = np.full(n, float(a[0]))
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected {n} finite value(s), got {value!r}")
    return a
