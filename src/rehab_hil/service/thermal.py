"""Actuator temperature estimated from the PWM history, for the safety supervisor.

A first-order lumped model: tau dT/dt = T_ambient + rise * duty - T. For an SMA wire (seed 000
eq 12) the Joule power is duty * U^2 / R and convection h A (T - T0) removes it, so at a fixed
convection coefficient the equilibrium rise is proportional to the duty and tau = m c / (h A).
The parameters come from the config's ``[rig.thermal]`` table.
"""

from __future__ import annotations

import math

__all__ = ["FirstOrderThermal"]


class FirstOrderThermal:
    """Temperature [C] of a lumped actuator heated in proportion to the PWM duty."""

    def __init__(self, ambient_c: float, rise_at_full_duty_c: float, time_constant_s: float) -> None:
        if not time_constant_s > 0:
            raise ValueError(f"time constant must be positive, got {time_constant_s}")
        self.ambient_c, self.rise_c, self.tau_s = ambient_c, rise_at_full_duty_c, time_constant_s
        self.temperature_c = ambient_c

    def reset(self) -> None:
        self.temperature_c = self.ambient_c

    def step(self, duty: float, dt_s: float) -> float:
        """Advance ``dt_s`` with ``duty`` held (exact solution over the step); return T."""
        target = self.ambient_c + self.rise_c * min(max(duty, 0.0), 1.0)
        self.temperature_c = target + (self.temperature_c - target) * math.exp(-dt_s / self.tau_s)
        return self.temperature_c
