"""The streaming backend contract: what a hardware-timed output device (DAQ, digital amplifier) looks like to the
driver.  No ROS here.

A device runs on **its own sample clock** at ``info.sample_rate_hz``; its *sample index* ``k`` counts samples
output since :meth:`StreamingBackend.start`.  The host writes voltages **ahead** of that clock into a FIFO of
``info.fifo_depth`` samples, and reads the sensor samples (if any) **later**, tagged with the index of the output
sample they answer:

- ``start(safe, prefill)`` queues ``prefill`` samples of the safe voltage, then starts the clock (a DAQ task with
  regeneration off must be written before it starts); returns the first writable index;
- ``clock()`` is the index of the next sample the device will output (samples output so far);
- ``write_index`` is the next index the host may write (writes are contiguous: ``write(write_index, block)``);
  ``write_space()`` how many samples fit in the FIFO now.  ``write_index - clock()`` is the write-ahead margin;
- ``read()`` returns acquired ``(k0, displacement[N, axes])`` blocks, in order, each sample exactly once;
- ``take_applied()`` returns ``(k0, voltage[N, axes])`` of what the device *actually output* (holds during an
  underrun included), in order, each sample exactly once — the driver publishes it as ``voltage_applied``;
- ``latency_samples``: the input→output latency the device measured or was configured with (samples);
- faults are typed (:class:`Underrun`, :class:`Overrun`, :class:`Disconnect`, :class:`LimitFault`,
  :class:`ControllerFault`; their ``kind`` is one of :data:`FAULT_KINDS`, the one vocabulary of backends, driver and
  rig-check), raised from any call (``write``, ``write_space``, ``clock``, ``poll``, ``read``, ``take_applied``);
  the driver turns every one into its fault path (counted, ``/diagnostics`` with the device's own code and text,
  the safe ramp — from the voltage the output holds, ``held``, when the device knows it — while a stream runs; a
  disconnect stops writing);
- ``close()`` releases the device, after bringing the output to the safe voltage **by a ramp, in time**, where it
  can (the driver core ramps first and waits until the device has output it; a backend closed on its own, e.g.
  after a crash, ramps from what its output holds).

Misuse of the contract (a write not at ``write_index``, more than ``write_space()``) raises :class:`ContractError`:
that is a bug in the caller, not a device fault.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["DeviceInfo", "StreamingBackend", "WriteCursorClock", "ContractError", "DeviceFault", "Underrun", "Overrun", "Disconnect",
           "LimitFault", "ControllerFault", "FAULT_KINDS"]


class ContractError(ValueError):
    """The caller broke the contract (write out of order, beyond the FIFO, before start): a bug, not a fault."""


class DeviceFault(RuntimeError):
    """A device fault; ``kind`` names it (one of :data:`FAULT_KINDS`).

    Parameters
    ----------
    message : str
        One line for the log and ``/diagnostics`` (a controller's own code and text included).
    k : int, optional
        Device sample index where it happened, if known.
    code : int, optional
        The device's own error code (e.g. a GCS error number), if it gave one.
    held : array, optional
        The voltage the output holds after the fault [V per axis], when the device knows it (a set-and-hold
        controller: its last accepted set point): the driver's safe ramp starts from there, not from what it had
        committed.
    """

    kind = "fault"

    def __init__(self, message: str, k: int | None = None, *, code: int | None = None,
                 held: "np.ndarray | None" = None):
        super().__init__(message)
        self.k = k  #: device sample index where it happened, if known
        self.code = code
        self.held = None if held is None else np.array(held, dtype=float)


class Underrun(DeviceFault):
    """The output FIFO ran dry: the device held its last value for samples the host had not written."""

    kind = "underrun"


class Overrun(DeviceFault):
    """The input (sensor) buffer overflowed: acquired samples were lost because the host read too late."""

    kind = "overrun"


class Disconnect(DeviceFault):
    """The device is gone (cable, power, driver): nothing can be written any more."""

    kind = "disconnect"


class LimitFault(DeviceFault):
    """The device refused or clipped a value (its own voltage/current limit tripped)."""

    kind = "limit"


class ControllerFault(DeviceFault):
    """The device's controller reported an error of its own (``code`` and its text in the message) that is neither a
    refused value (:class:`LimitFault`) nor a lost link: the link still works, the command was not applied."""

    kind = "controller"


#: every fault kind a backend may raise (``DeviceFault.kind``): the driver counts each (``<kind>_faults`` in its
#: status) and rig-check reports each
FAULT_KINDS = ("underrun", "overrun", "disconnect", "limit", "controller")


@dataclass(frozen=True)
class DeviceInfo:
    """What the driver needs to know about a device."""

    name: str
    sample_rate_hz: float
    n_axes: int
    fifo_depth: int              #: output FIFO [samples]: the most that can be written ahead of the clock
    has_sensor: bool
    clocked: bool                #: True: runs on its own clock (real hardware, clocked sim); False: lockstep
    #: True only for a simulator whose time advances with the samples written (the lockstep sim): while a lockstep
    #: stream paces it, no time passes between blocks, so a host stall is not stale input.  A real non-clocked
    #: device (set-and-hold, e.g. a PI controller) holds its voltage in wall time: False.
    time_follows_samples: bool = False
    #: True for a set-and-hold device (a PI controller in set-point mode): each written value is applied at once and
    #: held, and ``write`` plays a block in wall time (it returns when the block's time has passed).  Its output
    #: moves as a paced staircase: the safety invariant is judged per elapsed time between set points, not per
    #: sample, and a block's input is "fresh" until its write returns.
    holds_setpoints: bool = False


class StreamingBackend(abc.ABC):
    """A hardware-timed output device (and its sensor).  See the module docstring for the contract."""

    info: DeviceInfo

    @abc.abstractmethod
    def start(self, safe_voltage: np.ndarray, prefill: int = 0) -> int:
        """Queue ``prefill`` samples of ``safe_voltage`` [V per axis], start the sample clock; return the first
        writable index."""

    @abc.abstractmethod
    def clock(self) -> int:
        """Index of the next sample the device outputs (= samples output since start)."""

    @property
    @abc.abstractmethod
    def write_index(self) -> int:
        """Next sample index the host may write."""

    @abc.abstractmethod
    def write_space(self) -> int:
        """Samples that can be written now without exceeding the FIFO."""

    @abc.abstractmethod
    def write(self, k0: int, block: np.ndarray) -> None:
        """Queue ``block [N, axes]`` [V] for samples ``k0 … k0+N-1``; ``k0`` must be :attr:`write_index`."""

    @abc.abstractmethod
    def read(self) -> list[tuple[int, np.ndarray]]:
        """Sensor samples acquired since the last call, ``[(k0, displacement [N, axes] m)]`` (empty: no sensor)."""

    @abc.abstractmethod
    def take_applied(self) -> list[tuple[int, np.ndarray]]:
        """Voltage actually output since the last call, ``[(k0, voltage [N, axes] V)]`` (holds included)."""

    @property
    @abc.abstractmethod
    def latency_samples(self) -> int:
        """Input→output latency: a sensor sample for output index k becomes readable at clock ≥ k + latency."""

    def poll(self) -> None:
        """Let the device catch up with its clock (transfers, fault detection); raises pending faults."""

    def reset(self) -> bool:
        """Back to the initial state if the device can (a simulator can, hardware cannot); True if done."""
        return False

    def status(self) -> dict[str, Any]:
        """Key/value status for ``/diagnostics``."""
        return {"backend": self.info.name}

    def close(self) -> None:
        """Stop the clock and release the device (output left at the safe voltage where the device allows)."""


class WriteCursorClock:
    """The clock of a device without a sample clock of its own (a set-and-hold controller, the lockstep simulator):
    what is written is output at once, so the write cursor ``_k`` *is* the clock and the FIFO never fills.

    Mix it in before :class:`StreamingBackend`; the backend advances ``self._k`` in ``write``.
    """

    _k: int
    info: DeviceInfo

    def clock(self) -> int:
        """Index of the next sample: the write cursor."""
        return self._k

    @property
    def write_index(self) -> int:
        """Next index to write: the write cursor."""
        return self._k

    def write_space(self) -> int:
        """Always the whole (nominal) FIFO: nothing waits in it."""
        return self.info.fifo_depth
