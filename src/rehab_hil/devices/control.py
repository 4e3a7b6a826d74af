"""The control channel every simulated device serves on stdin: one command per line, one reply.

The knobs all devices share (the e-stop button, its wire, a plant input, and ``load CHANNEL VALUE``:
a known load on an ADC sensor in its unit, e.g. a calibration weight in N) live here; each device adds
its own in ``_control`` (fault knobs, reboot, status). Replies: ``ok <command>``, ``ok <details>``
or ``error <why>``.
"""

from __future__ import annotations

from rehab_hil.devices.plant_io import PlantIO

__all__ = ["UNKNOWN", "ControlChannel"]

UNKNOWN = object()  # returned by ``_control`` for a command the device does not have


class ControlChannel:
    """Mixin: ``control(line) -> reply``. Needs ``plant`` (PlantIO) and ``estop_pin`` (bool: the
    button pressed); ``estop_wire_broken`` is the e-stop loop's wire cut."""

    plant: PlantIO
    estop_pin: bool
    estop_wire_broken: bool = False

    def control(self, line: str) -> str:
        """Apply one control command; returns the reply line."""
        parts = line.split()
        if not parts:
            return "error empty command"
        cmd, args = parts[0], parts[1:]
        try:
            if cmd == "estop" and len(args) == 1 and args[0] in ("0", "1"):
                self.estop_pin = args[0] == "1"
                reply = None
            elif cmd == "estop_wire" and len(args) == 1 and args[0] in ("ok", "broken"):
                self.estop_wire_broken = args[0] == "broken"
                reply = None
            elif cmd == "input" and len(args) == 2:
                self.plant.set_input(args[0], float(args[1]))
                reply = None
            elif cmd == "load" and len(args) == 2:  # a known weight on a sensor: calibrate force
                self.plant.set_sensor_load(int(args[0]), float(args[1]))
                reply = None
            else:
                reply = self._control(cmd, args)
        except (ValueError, KeyError) as e:
            return f"error {e}"
        if reply is UNKNOWN:
            return f"error unknown or malformed command {line.strip()!r} ({type(self).__name__})"
        return "ok " + line.strip() if reply is None else reply

    def _control(self, cmd: str, args: list[str]) -> str | object | None:
        """A device's own knobs: a reply line, None for plain ``ok``, or ``UNKNOWN``."""
        return UNKNOWN
