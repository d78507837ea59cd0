"""Identification excitations: :class:`PRBS` (maximal-length LFSR), :class:`Multisine` (Schroeder phases) and
:class:`Chirp`."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..config import ConfigError
from .base import Trajectory, _axis_index, _duration, _finite

__all__ = ["PRBS", "Multisine", "Chirp"]


# maximal-length LFSR feedback taps (Fibonacci form, bit positions 1-based), orders 5 … 16
_LFSR_TAPS = {5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4), 9: (9, 5), 10: (10, 7), 11: (11, 9),
              12: (12, 11, 10, 4), 13: (13, 12, 11, 8), 14: (14, 13, 12, 2), 15: (15, 14), 16: (16, 15, 13, 4)}


def _m_sequence(order: int) -> np.ndarray:
    """One period (2^order − 1 chips) of the maximal-length sequence, as 0/1."""
    taps = _LFSR_TAPS[order]
    state = [1] * order
    n = 2 ** order - 1
    out = np.empty(n, dtype=np.int8)
    for i in range(n):
        out[i] = state[-1]
        fb = 0
        for tp in taps:
            fb ^= state[tp - 1]
        state = [fb] + state[:-1]
    return out


@dataclass(frozen=True)
class PRBS(Trajectory):
    """Pseudo-random binary sequence: ``offset ± amplitude``, one chip per ``1/clock_rate`` seconds.

    A maximal-length LFSR sequence of ``order`` (period 2^order − 1 chips, flat spectrum up to ≈ clock_rate/2.3);
    ``seed`` picks the starting chip.  On ``axis='all'`` each axis uses the same sequence shifted by
    period/n_axes chips (mutually uncorrelated inputs for MIMO identification).
    """

    amplitude: float = 1e-6
    clock_rate: float = 1000.0
    seed: int = 0
    axis: Any = "x"
    offset: float = 0.0
    order: int = 11
    duration: float = math.inf

    kind = "prbs"
    length_fields = ("amplitude", "offset")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "amplitude", _finite(self.amplitude, "amplitude"))
        object.__setattr__(self, "offset", _finite(self.offset, "offset"))
        object.__setattr__(self, "clock_rate", _finite(self.clock_rate, "clock_rate", positive=True))
        if int(self.order) not in _LFSR_TAPS or int(self.order) != self.order:
            raise ConfigError("order", f"must be an integer in {min(_LFSR_TAPS)}…{max(_LFSR_TAPS)}, got {self.order!r}")
        object.__setattr__(self, "order", int(self.order))
        try:
            object.__setattr__(self, "seed", int(self.seed))
        except (TypeError, ValueError):
            raise ConfigError("seed", f"expected an integer, got {self.seed!r}") from None
        object.__setattr__(self, "duration", _duration(self.duration))
        _axis_index(self.axes, self.axis)
        self._chips: np.ndarray   # not a dataclass field: the ±1 chip sequence, set once here
        object.__setattr__(self, "_chips", 2.0 * _m_sequence(self.order) - 1.0)

    @property
    def period(self) -> float:
        """Sequence period [s]."""
        return float((2 ** self.order - 1) / self.clock_rate)

    def bound(self) -> tuple[float, ...]:
        return self._axis_bound(abs(self.offset) + abs(self.amplitude), self.axis, abs(self.offset))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        chips = self._chips
        n = len(chips)
        chip_index = np.floor(k * (self.clock_rate / fs) + 1e-9).astype(np.int64) + self.seed
        idx = _axis_index(self.axes, self.axis)
        if idx is not None:
            return self._on_axis(self.amplitude * chips[chip_index % n], self.axis, self.offset)
        cols = [chips[(chip_index + j * (n // self.n_axes)) % n] for j in range(self.n_axes)]
        return self.offset + self.amplitude * np.column_stack(cols)


@dataclass(frozen=True)
class Multisine(Trajectory):
    """Sum of ``n_tones`` sines between ``f_min`` and ``f_max`` (linearly spaced), RMS value ``amplitude``.

    Phases: ``'schroeder'`` (φ_i = −π·i(i−1)/n, low crest factor) or ``'random'`` (uniform, from ``seed``).
    Each tone has amplitude ``amplitude·√(2/n)`` so the long-run RMS is exactly ``amplitude``.
    """

    amplitude: float = 1e-6
    f_min: float = 1.0
    f_max: float = 100.0
    n_tones: int = 20
    phases: str = "schroeder"
    seed: int = 0
    axis: Any = "x"
    offset: float = 0.0
    duration: float = math.inf

    kind = "multisine"
    length_fields = ("amplitude", "offset")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "amplitude", _finite(self.amplitude, "amplitude", nonneg=True))
        object.__setattr__(self, "offset", _finite(self.offset, "offset"))
        f0 = _finite(self.f_min, "f_min", positive=True)
        f1 = _finite(self.f_max, "f_max", positive=True)
        if f1 < f0:
            raise ConfigError("f_max", f"must be >= f_min ({f0}), got {f1}")
        object.__setattr__(self, "f_min", f0)
        object.__setattr__(self, "f_max", f1)
        if int(self.n_tones) != self.n_tones or int(self.n_tones) < 1:
            raise ConfigError("n_tones", f"must be a positive integer, got {self.n_tones!r}")
        object.__setattr__(self, "n_tones", int(self.n_tones))
        if self.phases not in ("schroeder", "random"):
            raise ConfigError("phases", f"must be 'schroeder' or 'random', got {self.phases!r}")
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "duration", _duration(self.duration))
        _axis_index(self.axes, self.axis)

    @property
    def frequencies(self) -> np.ndarray:
        """Tone frequencies [Hz]: ``n_tones`` evenly spaced from ``f_min`` to ``f_max``."""
        return np.linspace(self.f_min, self.f_max, self.n_tones)

    @property
    def tone_phases(self) -> np.ndarray:
        """Phase [rad] of each tone (Schroeder phases for a low crest factor, else uniform random ones from ``seed``)."""
        n = self.n_tones
        if self.phases == "schroeder":
            i = np.arange(1, n + 1)
            return -np.pi * i * (i - 1) / n
        return np.random.default_rng(self.seed).uniform(0, 2 * np.pi, n)

    def bound(self) -> tuple[float, ...]:
        peak = abs(self.offset) + self.amplitude * math.sqrt(2.0 / self.n_tones) * self.n_tones
        return self._axis_bound(peak, self.axis, abs(self.offset))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        t = self._t(k, fs)
        a = self.amplitude * math.sqrt(2.0 / self.n_tones)
        v = np.zeros(len(t))
        for f, p in zip(self.frequencies, self.tone_phases):
            v += np.sin(2 * np.pi * f * t + p)
        return self._on_axis(a * v, self.axis, self.offset)


@dataclass(frozen=True)
class Chirp(Trajectory):
    """Swept sine ``offset + amplitude·sin(phase(t))`` from ``f0`` to ``f1`` over ``duration`` seconds.

    ``method``: ``'linear'`` (instantaneous frequency f0 + (f1−f0)·t/T) or ``'logarithmic'`` (geometric sweep).
    """

    amplitude: float = 1e-6
    f0: float = 1.0
    f1: float = 1000.0
    duration: float = 10.0
    method: str = "linear"
    axis: Any = "x"
    offset: float = 0.0

    kind = "chirp"
    length_fields = ("amplitude", "offset")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "amplitude", _finite(self.amplitude, "amplitude"))
        object.__setattr__(self, "offset", _finite(self.offset, "offset"))
        object.__setattr__(self, "f0", _finite(self.f0, "f0", positive=True))
        object.__setattr__(self, "f1", _finite(self.f1, "f1", positive=True))
        d = _duration(self.duration)
        if math.isinf(d):
            raise ConfigError("duration", "a chirp needs a finite duration")
        object.__setattr__(self, "duration", d)
        if self.method not in ("linear", "logarithmic"):
            raise ConfigError("method", f"must be 'linear' or 'logarithmic', got {self.method!r}")
        _axis_index(self.axes, self.axis)

    def instantaneous_frequency(self, t: ArrayLike) -> np.ndarray:
        """The sweep's frequency [Hz] at times ``t`` [s]."""
        t = np.asarray(t, float)
        if self.method == "linear":
            return self.f0 + (self.f1 - self.f0) * t / self.duration
        return self.f0 * (self.f1 / self.f0) ** (t / self.duration)

    def bound(self) -> tuple[float, ...]:
        return self._axis_bound(abs(self.offset) + abs(self.amplitude), self.axis, abs(self.offset))

    def _values(self, k: np.ndarray, fs: float) -> np.ndarray:
        t = self._t(k, fs)
        T = self.duration
        if self.method == "linear":
            phase = 2 * np.pi * (self.f0 * t + 0.5 * (self.f1 - self.f0) * t * t / T)
        elif self.f1 == self.f0:
            phase = 2 * np.pi * self.f0 * t
        else:
            r = self.f1 / self.f0
            phase = 2 * np.pi * self.f0 * T / math.log(r) * (r ** (t / T) - 1.0)
        return self._on_axis(self.amplitude * np.sin(phase), self.axis, self.offset)
