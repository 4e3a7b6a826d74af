"""From a validated plant config to the loop's parts: controller, estimator, supervisor and the
CONFIGURE for the firmware. The firmware gets the ``[rig.limits]`` as they are; the host trips a
margin (``[rig.host]``) inside them, so it acts first and the firmware is the backstop.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from rehab_hil.calibration import force_limit_counts
from rehab_hil.hardware.interface import configure_from_config
from rehab_hil.plants.base import DeviceBinding, get_plant
from rehab_hil.protocol import Configure
from rehab_hil.service.controllers import (
    Actuator,
    Controller,
    OpenLoopPWM,
    PIDPosition,
    PWMRatio,
    constant_reference,
    cycle_reference,
)
from rehab_hil.service.estimation import Estimator
from rehab_hil.service.supervisor import Supervisor, SupervisorLimits
from rehab_hil.service.thermal import FirstOrderThermal

__all__ = ["CONTROLLERS", "ServiceSetupError", "build_controller", "build_estimator", "build_supervisor",
           "firmware_configure", "force_channels", "period_s"]

CONTROLLERS = ("session", "pid", "pwm", "open-loop")


class ServiceSetupError(ValueError):
    """The config lacks what the chosen controller or the loop needs."""


def period_s(cfg: Any) -> float:
    return 1.0 / cfg.rig.sample_rate_hz


def force_channels(binding: DeviceBinding) -> tuple[str, ...]:
    """ADC channels whose state interface is a force: the force limit applies to them."""
    return tuple(ch.signal for ch in binding.adc if ch.kind == "force")


def _pid_gains(cfg: Any) -> tuple[float, float, float, float]:
    gains = get_plant(cfg.plant).pid_gains(cfg)
    if gains is None:
        raise ServiceSetupError(f"plant {cfg.plant!r} declares no position PID (no [pid] table of gains per "
                                "degree of encoder angle)")
    return gains


def build_controller(cfg: Any, binding: DeviceBinding, name: str) -> Controller:
    """``session`` (open-close cycles), ``pid`` (step to ``step_deg``), ``pwm`` (PWM ratio for
    ``step_deg``) or ``open-loop`` (duty profile), from ``[rig.session]``."""
    ses = cfg.rig.session
    if ses is None:
        raise ServiceSetupError("the config has no [rig.session] table (what `rehab-hil run` does)")
    act = Actuator(binding)

    def pid(reference: Any) -> PIDPosition:
        kp, ki, kd, tf = _pid_gains(cfg)
        return PIDPosition(act, reference, kp, ki, kd, tf, period_s(cfg))

    def pwm(reference: Any) -> PWMRatio:
        return PWMRatio(act, reference, ses.pwm_duty_min, ses.pwm_duty_max, ses.pwm_angle_at_duty_min_deg,
                        ses.pwm_angle_at_duty_max_deg)

    if name == "session" and ses.tracking == "pulsed":
        return OpenLoopPWM(act, ses.open_loop_duty, ses.open_loop_on_s, ses.open_loop_off_s)
    if name == "session":
        ref = cycle_reference(ses.closed_deg, ses.open_deg, ses.cycles_per_minute, ses.move_fraction)
        return pid(ref) if ses.tracking == "pid" else pwm(ref)
    if name == "pid":
        return pid(constant_reference(ses.step_deg))
    if name == "pwm":
        return pwm(constant_reference(ses.step_deg))
    if name == "open-loop":
        return OpenLoopPWM(act, ses.open_loop_duty, ses.open_loop_on_s, ses.open_loop_off_s)
    raise ServiceSetupError(f"unknown controller {name!r}; choose from {list(CONTROLLERS)}")


def build_estimator(cfg: Any, binding: DeviceBinding) -> Estimator:
    host = cfg.rig.host
    return Estimator(binding, host.velocity_filter_hz if host else 30.0)


def temperature_channel(binding: DeviceBinding) -> str | None:
    """The ADC channel of a wired thermistor (a temperature signal, ``*_c``), or None."""
    return next((ch.signal for ch in binding.adc if ch.kind == "temperature" or ch.signal.endswith("_c")), None)


def estop_enabled(cfg: Any) -> bool:
    """``[rig.estop] enabled``; without the table: on for a real serial port, off for simulated rigs."""
    es = cfg.rig.estop
    return es.enabled if es is not None else cfg.rig.port.startswith("/")


def build_supervisor(cfg: Any, binding: DeviceBinding) -> Supervisor:
    """Host limits = ``[rig.limits]`` tightened by the ``[rig.host]`` margins."""
    lim, host, th = cfg.rig.limits, cfg.rig.host, cfg.rig.thermal
    am = host.angle_margin_deg if host else 0.0
    fm = host.force_margin_n if host else 0.0
    hm = host.heating_margin_s if host else 0.0
    limits = SupervisorLimits(
        min_angle_deg=lim.min_angle_deg + am, max_angle_deg=lim.max_angle_deg - am,
        max_force_n=max(lim.max_force_n - fm, 0.0), max_heating_s=max(lim.max_heating_s - hm, period_s(cfg)),
        max_temperature_c=lim.max_temperature_c, link_loss_periods=lim.link_loss_periods, max_duty=lim.max_duty,
        stuck_sensor_s=lim.stuck_sensor_s, stuck_min_duty=lim.stuck_min_duty,
        stuck_min_error_deg=lim.stuck_min_error_deg, stuck_min_motion_deg=lim.stuck_min_motion_deg,
        force_debounce_s=lim.force_debounce_ms / 1000.0,
        max_disagreement_c=th.max_disagreement_c if th else 25.0, disagreement_s=th.disagreement_s if th else 1.0,
    )
    thermal = FirstOrderThermal(th.ambient_c, th.rise_at_full_duty_c, th.time_constant_s) if th else None
    return Supervisor(limits, period_s(cfg), force_channels(binding), thermal, estop_input=estop_enabled(cfg),
                      temperature_signal=temperature_channel(binding))


def firmware_configure(cfg: Any, binding: DeviceBinding) -> Configure:
    """The firmware's copy of the limits: range of motion, heating time, max duty, the e-stop input
    (enabled, wiring) and, when A0 is a contact force, its limit in ADC counts and debounce (the
    firmware checks A0 only)."""
    limit_counts = force_limit_counts(cfg, binding)  # 1023 (off) unless A0 is a force; unrepresentable: refused
    msg = configure_from_config(cfg, binding.encoder_counts_per_rev, force_limit_counts=limit_counts,
                                estop_input=estop_enabled(cfg), encoder_direction=binding.encoder_direction)
    es = cfg.rig.estop
    nc = Configure.FLAG_ESTOP_NORMALLY_CLOSED if es is not None and es.normally_closed else 0
    return dataclasses.replace(msg, flags=msg.flags | nc, force_debounce_ms=cfg.rig.limits.force_debounce_ms)
