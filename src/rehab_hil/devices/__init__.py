"""Simulated rig devices: the firmware's behaviour (``core``), a plant behind the rig's I/O
(``plant_io``), the Python device process (``sim_device``) and spawners for tests and tools."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["DEVICE_KINDS", "spawn_device"]

DEVICE_KINDS = ("sim", "avr")  # the names ``rehab-hil run --device`` and ``open_rig`` take
_ALIASES = {"python": "sim"}  # the Python device's former name (device-conformance and fault tests use it)


def spawn_device(kind: str, config_path: str | Path, clock: str = "realtime", **kwargs: Any) -> Any:
    """Start a simulated device process of ``kind`` ("sim": the Python device, "avr": the firmware in
    simavr); the result has ``.port``, ``.control()`` and ``.close()``."""
    kind = _ALIASES.get(kind, kind)
    if kind == "sim":
        from rehab_hil.devices.spawn import spawn_sim_device

        return spawn_sim_device(config_path, clock=clock, **kwargs)
    if kind == "avr":
        from rehab_hil.devices import avr_device

        return avr_device.spawn_avr_device(config_path, clock=clock, **kwargs)
    raise ValueError(f"unknown device kind {kind!r}; known: {list(DEVICE_KINDS)}")
