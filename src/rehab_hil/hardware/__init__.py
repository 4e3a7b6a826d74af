"""Host-side hardware interface: the rig behind a lifecycle (connect, configure, read, write, estop),
its implementations, the typed rig contract checked before a run, and ``open_rig``."""

from rehab_hil.hardware.contract import Claims, CommandInterface, ContractError, StateInterface, on_configure
from rehab_hil.hardware.inprocess import InProcessHardware
from rehab_hil.hardware.interface import (
    Arrival,
    HardwareError,
    HardwareInterface,
    LifecycleState,
    LinkStats,
    configure_from_config,
    duty_units,
)
from rehab_hil.hardware.open import RIG_KINDS, inprocess_hardware, open_rig
from rehab_hil.hardware.serial_hw import SerialHardware

__all__ = ["RIG_KINDS", "Arrival", "Claims", "CommandInterface", "ContractError", "HardwareError", "HardwareInterface",
           "InProcessHardware", "LifecycleState", "LinkStats", "SerialHardware", "StateInterface",
           "configure_from_config", "duty_units", "inprocess_hardware", "on_configure", "open_rig"]
