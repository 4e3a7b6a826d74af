"""Host-side hardware interface: the rig behind a lifecycle (connect, configure, read, write, estop)."""

from rehab_hil.hardware.interface import (
    HardwareError,
    HardwareInterface,
    LinkStats,
    configure_from_config,
    duty_units,
)
from rehab_hil.hardware.serial_hw import SerialHardware

__all__ = ["HardwareError", "HardwareInterface", "LinkStats", "SerialHardware", "configure_from_config",
           "duty_units"]
