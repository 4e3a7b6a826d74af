"""What tests and benchmarks share: a free loopback port and an in-process rig.

The in-process rig is ``InProcessHardware`` (the firmware's logic and the config's plant in this
process, one SAMPLE per COMMAND): deterministic and without a pty or a subprocess, so the loop
service, the recorder and the telemetry publisher can run inside a unit test or a benchmark.
"""

from __future__ import annotations

import socket
from collections.abc import Mapping
from pathlib import Path

from rehab_hil.hardware.inprocess import InProcessHardware
from rehab_hil.hardware.open import inprocess_hardware

__all__ = ["CONFIGS", "InProcessHardware", "free_port", "inprocess_rig"]

CONFIGS = Path(__file__).resolve().parents[2] / "configs"  # the repository's plant configs


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (another process may still take it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def inprocess_rig(config_path: str | Path = CONFIGS / "finger_extensor.toml", *, configured: bool = True,
                  hello: Mapping[str, int] | None = None) -> InProcessHardware:
    """An in-process rig on the plant of ``config_path``, connected and, when ``configured``, given
    the config's CONFIGURE (ACTIVE: each ``write_command`` returns the next sample at once).
    ``hello`` overrides fields of the device's HELLO (a different firmware version, fewer channels)."""
    from rehab_hil.plants import get_plant, load_config
    from rehab_hil.service import assembly

    cfg = load_config(config_path)
    binding = get_plant(cfg.plant).device(cfg)
    hw = inprocess_hardware(binding, hello=hello)
    hw.connect()
    if configured:
        hw.configure(assembly.firmware_configure(cfg, binding))
    return hw
