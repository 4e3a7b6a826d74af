"""``SafetyRules``: the firmware's safety rules, the part of ``DeviceCore`` that can switch the PWM off.

Each 1 kHz tick checks, in the firmware's order (``io::on_tick`` in rehab_fw.ino): the watchdog (no
valid COMMAND for ``watchdog_ms`` ticks once one armed it), the heating time (``max_heating_ms``
consecutive ticks driving), then the conditional causes (force above its limit for
``force_debounce_ms`` ticks, the encoder outside its range, the e-stop input). A trip switches every
output off at once and latches its fault bit, reported in one FAULT frame when new. Kept apart from
``DeviceCore`` (frames, time, samples) so the rules read in one place, next to the firmware's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rehab_hil.protocol import Configure, Fault, FaultReport, Message

if TYPE_CHECKING:
    from rehab_hil.devices.core import Readings

__all__ = ["CONDITIONAL", "SafetyRules"]

# faults CLEAR cannot remove while their cause is present
CONDITIONAL = Fault.FORCE_LIMIT | Fault.RANGE_OF_MOTION | Fault.ESTOP_INPUT


class SafetyRules:
    """The checks of a tick and the trip, mixed into ``DeviceCore``, whose state they read and write
    (declared below; ``DeviceCore.__init__`` sets it, as the firmware's globals)."""

    config: Configure | None
    readings: Readings
    estop_wiring_nc: bool | None  # the simulated rig's e-stop wiring (None: as CONFIGURE says)
    faults: int
    armed: bool
    since_cmd: int
    heating: int
    force_ticks: int
    duty: list[int]
    direction: int
    enabled: bool

    def _check_limits(self, c: Configure, watch_host: bool) -> list[Message]:
        """The safety checks of one tick of a device configured with ``c``, its ``readings`` taken: the
        FAULT frames of new trips. ``watch_host=False``: a tick that does not count towards the
        watchdog (``DeviceCore.tick``)."""
        out: list[Message] = []
        if self.armed and watch_host:
            self.since_cmd += 1
            if self.since_cmd >= c.watchdog_ms:
                self.armed = False
                out += self._trip(Fault.WATCHDOG)
        if self.enabled and (self.duty[0] > 0 or self.duty[1] > 0):
            self.heating += 1
            if self.heating >= c.max_heating_ms:
                out += self._trip(Fault.HEATING_TIME)
        else:
            self.heating = 0
        present = self._present_causes()
        if present & Fault.FORCE_LIMIT:  # debounced: N consecutive ticks above the limit
            self.force_ticks += 1
            if self.force_ticks < c.force_debounce_ms:
                present &= ~Fault.FORCE_LIMIT
        else:
            self.force_ticks = 0
        present &= ~self.faults
        if present:
            out += self._trip(present)
        return out

    @property
    def estop_active(self) -> bool:
        """The e-stop input per the configured polarity (before CONFIGURE: active low, as the firmware)."""
        nc = bool(self.config and self.config.flags & Configure.FLAG_ESTOP_NORMALLY_CLOSED)
        wiring = nc if self.estop_wiring_nc is None else self.estop_wiring_nc
        high = self.readings.pin_high(wiring)
        return high if nc else not high

    def _present_causes(self) -> int:
        """Conditional faults whose condition holds now."""
        c, r = self.config, self.readings
        bits = 0
        if c is None:
            return bits
        if r.adc0 > c.force_limit_counts:
            bits |= Fault.FORCE_LIMIT
        if r.encoder_count < c.enc_min or r.encoder_count > c.enc_max:
            bits |= Fault.RANGE_OF_MOTION
        if c.flags & Configure.FLAG_ESTOP_INPUT and self.estop_active:
            bits |= Fault.ESTOP_INPUT
        return bits & CONDITIONAL

    def _trip(self, bits: int) -> list[Message]:
        """PWM off at once; latch ``bits``; one FAULT frame if any bit is new."""
        self._outputs_off()
        self.heating = 0
        new = bits & ~self.faults
        self.faults |= bits
        return [FaultReport(new, self.faults)] if new else []

    def _outputs_off(self) -> None:
        self.duty = [0, 0]
        self.direction = 0
        self.enabled = False
