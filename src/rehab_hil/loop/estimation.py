"""State estimation on the host: joint angle and filtered velocity from encoder counts, and
calibrated SI values from ADC counts, using the plant's ``DeviceBinding`` calibration.

Counters from the device wrap (32-bit encoder count and microsecond clock); the estimator unwraps
them so a long session never sees a jump.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rehab_hil.interfaces import AdcChannel, DeviceBinding

__all__ = ["Estimator", "State", "adc_to_si", "unwrap_delta"]

WRAP32 = 1 << 32
HALF32 = 1 << 31


def unwrap_delta(new: int, old: int, modulus: int = WRAP32) -> int:
    """Smallest signed difference new - old of a counter that wraps at ``modulus``."""
    d = (int(new) - int(old)) % modulus
    return d - modulus if d >= modulus // 2 else d


def adc_to_si(counts: float, channel: AdcChannel) -> float:
    """Invert the binding's ``counts = offset + per_unit * signal``."""
    return (float(counts) - channel.offset_counts) / channel.counts_per_unit


@dataclass
class State:
    """What the controllers and the supervisor see each cycle (SI units)."""

    t_s: float  # device time since the first sample (unwrapped) [s]
    angle_rad: float
    velocity_rad_s: float
    analog: dict[str, float]  # plant signal name -> calibrated value

    @property
    def angle_deg(self) -> float:
        return math.degrees(self.angle_rad)


class Estimator:
    """Turns raw sample fields into a ``State``.

    Velocity is the finite difference of the angle over the device's own sample interval, through
    a first-order low-pass of cutoff ``velocity_cutoff_hz`` (a 2000-count encoder at 1 kHz
    quantises raw velocity to 3.1 rad/s steps, so it must be filtered)."""

    def __init__(self, binding: DeviceBinding, velocity_cutoff_hz: float = 30.0) -> None:
        if not velocity_cutoff_hz > 0:
            raise ValueError(f"velocity cutoff must be positive, got {velocity_cutoff_hz}")
        self.binding = binding
        # the config's encoder direction: a rig wired backwards (-1) still reads positive flexion
        self.rad_per_count = binding.encoder_direction * 2.0 * math.pi / binding.encoder_counts_per_rev
        self.tau_s = 1.0 / (2.0 * math.pi * velocity_cutoff_hz)
        # (index, signal, offset, counts per unit) per ADC channel: adc_to_si without attribute lookups
        self._channels = tuple((i, ch.signal, ch.offset_counts, ch.counts_per_unit) for i, ch in enumerate(binding.adc))
        self.reset()

    def reset(self) -> None:
        """Forget history (after a device reboot the counters restart)."""
        self._count0: int | None = None
        self._count = 0
        self._time0: int | None = None
        self._time_us = 0
        self._raw_count = 0
        self._raw_time = 0
        self._angle = 0.0
        self._velocity = 0.0

    def update(self, encoder_count: int, device_time_us: int, adc: tuple[int, ...]) -> State:
        if self._count0 is None:
            self._count0, self._time0 = int(encoder_count), int(device_time_us)
            self._raw_count, self._raw_time = int(encoder_count), int(device_time_us)
            self._count = int(encoder_count)
            self._time_us = 0
            self._angle = self._count * self.rad_per_count
            self._velocity = 0.0
        else:  # unwrap_delta of both counters, inline (once per sample)
            d = (encoder_count - self._raw_count) % WRAP32
            self._count += d - WRAP32 if d >= HALF32 else d
            dt_us = (device_time_us - self._raw_time) % WRAP32
            if dt_us >= HALF32:
                dt_us -= WRAP32
            self._raw_count, self._raw_time = int(encoder_count), int(device_time_us)
            angle = self._count * self.rad_per_count
            if dt_us > 0:
                dt = dt_us * 1e-6
                raw_v = (angle - self._angle) / dt
                self._velocity += dt / (self.tau_s + dt) * (raw_v - self._velocity)
                self._time_us += dt_us
            self._angle = angle
        n = len(adc)
        analog = {name: (float(adc[i]) - offset) / per_unit for i, name, offset, per_unit in self._channels if i < n}
        return State(self._time_us * 1e-6, self._angle, self._velocity, analog)
