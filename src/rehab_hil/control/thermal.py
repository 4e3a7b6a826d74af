"""Actuator temperature estimated from the PWM history, for the safety supervisor.

A sum of first-order modes: T = T_ambient + sum_i x_i, tau_i dx_i/dt = rise_i * duty - x_i. One
mode is the lumped wire of seed 000 eq 12 linearised: the Joule power is duty * U^2 / R and
convection h A (T - T0) removes it, so at a fixed convection coefficient the equilibrium rise is
proportional to the duty and tau = m c / (h A). A second mode writes an identified second-order
transfer function exactly (seed 001's TF_TP002 for a TCP coil: a slow mode and a fast one whose
rise is negative). The parameters come from the config's ``[rig.thermal]`` table.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["FirstOrderThermal", "ModalThermal", "thermal_from_config"]


class ModalThermal:
    """Temperature [C] of an actuator heated in proportion to the PWM duty, as first-order modes
    ``(rise at full duty [C], time constant [s])``."""

    def __init__(self, ambient_c: float, modes: Sequence[tuple[float, float]]) -> None:
        if not modes:
            raise ValueError("a thermal estimate needs at least one mode")
        for _, tau in modes:
            if not tau > 0:
                raise ValueError(f"time constant must be positive, got {tau}")
        self.ambient_c = ambient_c
        self.modes = tuple((float(r), float(t)) for r, t in modes)
        self.reset()

    def reset(self) -> None:
        self._x = [0.0] * len(self.modes)
        self.temperature_c = self.ambient_c

    def step(self, duty: float, dt_s: float) -> float:
        """Advance ``dt_s`` with ``duty`` held (exact solution over the step); return T."""
        d = min(max(duty, 0.0), 1.0)
        total = self.ambient_c
        for i, (rise, tau) in enumerate(self.modes):
            target = rise * d
            self._x[i] = target + (self._x[i] - target) * math.exp(-dt_s / tau)
            total += self._x[i]
        self.temperature_c = total
        return total


class FirstOrderThermal(ModalThermal):
    """One mode: tau dT/dt = T_ambient + rise * duty - T."""

    def __init__(self, ambient_c: float, rise_at_full_duty_c: float, time_constant_s: float) -> None:
        super().__init__(ambient_c, [(rise_at_full_duty_c, time_constant_s)])
        self.rise_c, self.tau_s = rise_at_full_duty_c, time_constant_s


def thermal_from_config(th: object) -> ModalThermal:
    """The estimate a ``[rig.thermal]`` table describes (one mode, or two with ``second_*``)."""
    modes = [(th.rise_at_full_duty_c, th.time_constant_s)]  # type: ignore[attr-defined]
    if getattr(th, "second_time_constant_s", None) is not None:
        modes.append((th.second_rise_at_full_duty_c, th.second_time_constant_s))  # type: ignore[attr-defined]
    return ModalThermal(th.ambient_c, modes)  # type: ignore[attr-defined]
