"""The telemetry tests' rig: the shared in-process hardware (``rehab_hil.testing``) on the Finger
Extensor, every COMMAND producing the next SAMPLE at once, and a controller that keeps it moving.

Deterministic and without a subprocess or a pty, so the loop service can run with a recorder and a
zenoh publisher inside a unit test.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from rehab_hil.hardware import Claims, InProcessHardware
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.service import assembly
from rehab_hil.testing import inprocess_rig

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "finger_extensor.toml"
FIRMWARE = {"fw_major": 1, "fw_minor": 2, "fw_patch": 3}  # what the monitor test expects to see


def LockstepRig() -> InProcessHardware:  # the tests' name for it
    """The in-process Finger Extensor rig, connected and configured with its firmware limits
    widened (tests drive it open loop; the loop service reconfigures it with the real ones)."""
    hw = inprocess_rig(CONFIG, configured=False, hello=FIRMWARE)
    cfg = load_config(CONFIG)
    conf = assembly.firmware_configure(cfg, get_plant(cfg.plant).device(cfg))
    hw.configure(dataclasses.replace(conf, enc_min=-10**6, enc_max=10**6))
    return hw


class RampController:
    """The angle follows a sine between 20 and 50 deg through a proportional law on the signed
    motor input: enough variety for every column, inside the range of motion."""

    claims = Claims(command=("motor_voltage_v",), state=("iris_angle_rad",))

    def reset(self) -> None:
        pass

    def __call__(self, t_s: float, state: object) -> object:
        from rehab_hil.loop.controllers import Command

        ref = 35.0 + 15.0 * math.sin(8 * t_s)
        effort = 0.02 * (ref - state.angle_deg)  # type: ignore[attr-defined]
        return Command((min(abs(effort), 0.6), 0.0), 1 if effort < 0 else 0, True, ref)
