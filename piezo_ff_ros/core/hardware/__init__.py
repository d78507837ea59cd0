"""Hardware layer without ROS: the streaming backend contract, the simulator behind it (lockstep and clocked),
the driver's stream bookkeeping and the driver core the node wires to topics."""
from .contract import (ContractError, DeviceFault, DeviceInfo, Disconnect, LimitFault, Overrun, StreamingBackend,
                       Underrun)
from .driver_core import DriverCore, DriverSettings, DriverOutput
from .simulated_device import ClockedSim, LockstepSim
from .stream import StreamBook

__all__ = ["ContractError", "DeviceFault", "DeviceInfo", "Disconnect", "LimitFault", "Overrun", "StreamingBackend",
           "Underrun", "DriverCore", "DriverSettings", "DriverOutput", "ClockedSim", "LockstepSim", "StreamBook"]
