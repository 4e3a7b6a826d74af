"""Simulated rig devices: the firmware's behaviour (``core``), a plant behind the rig's I/O
(``plant_io``), the Python device process (``sim_device``) and spawners for tests and tools."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["DEVICE_KINDS", "spawn_device"]

DEVICE_KINDS = ("python", "avr")


def spawn_device(kind: str, config_path: str | Path, clock: str = "realtime", **kwargs: Any) -> Any:
    """Start a simulated device of ``kind`` ("python" or "avr"); the result has ``.port`` and ``.close()``."""
    if kind == "python":
        from rehab_hil.devices.spawn import spawn_sim_device

        return spawn_sim_device(config_path, clock=clock, **kwargs)
    if kind == "avr":
        from rehab_hil.devices import avr_device  # part of the firmware work (issue 5 part B)

        return avr_device.spawn_avr_device(config_path, clock=clock, **kwargs)
    raise ValueError(f"unknown device kind {kind!r}; known: {list(DEVICE_KINDS)}")
