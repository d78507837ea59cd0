"""The backend interface of the driver (no ROS here)."""
from __future__ import annotations

import abc

import numpy as np


class BackendError(RuntimeError):
    """The backend cannot do what was asked (open failed, hardware fault…); the message says why."""


class Backend(abc.ABC):
    """One positioner's amplifier (and sensor, if any).

    Life cycle: ``open()`` → ``start()`` → ``write(block)`` … → ``safe_state()`` → ``close()``.
    The driver only ever passes blocks that are already clamped and slew-limited.
    """

    name = "abstract"

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the device (or build the model)."""

    @abc.abstractmethod
    def start(self) -> None:
        """Start output at the safe voltage."""

    @abc.abstractmethod
    def write(self, voltage: np.ndarray) -> np.ndarray | None:
        """Apply a ``[N, axes]`` voltage block [V]; return the displacement block [m] for the same samples,
        or None when the backend has no sensor."""

    @abc.abstractmethod
    def safe_state(self) -> None:
        """Put the output at the safe voltage now (the driver has already ramped down to it)."""

    @abc.abstractmethod
    def status(self) -> dict:
        """Key/value status for ``/diagnostics``."""

    def reset(self) -> bool:
        """Return to the initial state if the backend can (a simulator can, hardware cannot); True if done."""
        return False

    def close(self) -> None:
        """Release the device."""
