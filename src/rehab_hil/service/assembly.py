"""From a validated plant config to the loop's parts: controller, estimator, supervisor and the
CONFIGURE for the firmware. The firmware gets the ``[rig.limits]`` as they are; the host trips a
margin (``[rig.host]``) inside them, so it acts first and the firmware is the backstop.
"""

from __future__ import annotations

import dataclasses
import math

from rehab_hil.calibration import force_limit_counts
from rehab_hil.config import ConfigError
from rehab_hil.controllers import ControllerError, Reference, offline_session
from rehab_hil.controllers import build_controller as build
from rehab_hil.controllers.build import Sources
from rehab_hil.hardware.interface import configure_from_config
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loop.controllers import ControllerRuntime
from rehab_hil.loop.estimation import Estimator
from rehab_hil.loop.supervisor import Supervisor, SupervisorLimits
from rehab_hil.plants.registry import get_plant
from rehab_hil.plants.sections import PlantConfig
from rehab_hil.plants.thermal import safety_thermal
from rehab_hil.protocol import Configure
from rehab_hil.session_metrics import SessionMeter

__all__ = ["REFERENCES", "ServiceSetupError", "build_controller", "build_estimator", "build_meter", "build_supervisor",
           "firmware_configure", "force_channels", "period_s"]

REFERENCES = ("session", "step")  # what the controller tracks: the session's cycles, or a step to step_deg


class ServiceSetupError(ValueError):
    """The config lacks what the chosen controller or the loop needs."""


def period_s(cfg: PlantConfig) -> float:
    return 1.0 / cfg.rig.sample_rate_hz


def force_channels(binding: DeviceBinding) -> tuple[str, ...]:
    """ADC channels whose state interface is a force: the force limit applies to them."""
    return tuple(ch.signal for ch in binding.adc if ch.kind == "force")


def build_controller(cfg: PlantConfig, name: str | None = None, reference: str = "session",
                     source: str = "<config>", sources: Sources | None = None) -> ControllerRuntime:
    """The controller ``name`` (default: ``[rig.session] controller``) built for the config's
    plant (``rehab_hil.controllers``: refused in one line if it does not apply) and ready for the
    loop; ``reference`` is the session's cycles or a step to ``[rig.session] step_deg``."""
    if cfg.rig.session is None:
        raise ServiceSetupError("the config has no [rig.session] table (what `rehab-hil run` does)")
    if reference not in REFERENCES:
        raise ServiceSetupError(f"unknown reference {reference!r}; choose from {list(REFERENCES)}")
    ref = Reference.session(cfg) if reference == "session" else Reference.step(cfg)
    try:
        return ControllerRuntime(build(cfg, name, ref, source=source, sources=sources))
    except (ControllerError, ConfigError) as e:
        raise ServiceSetupError(str(e)) from None


def build_meter(cfg: PlantConfig, controller: ControllerRuntime, duration_s: float) -> SessionMeter | None:
    """Per-cycle session figures (``session_metrics``) for a controller tracking open-close cycles;
    None for a step. Energy from the plant's own actuator power (``Plant.actuator_power_w``)."""
    ref = controller.reference
    if ref.kind != "session":
        return None
    plant = get_plant(cfg.plant)
    return SessionMeter(round(duration_s / period_s(cfg)) + 1, ref.period_s, ref.move_s, ref.first_open_s,
                        ref.closed_deg, ref.open_deg, lambda effort, vel: plant.actuator_power_w(cfg, effort, vel),
                        baseline_energy_j=passive_energy_j(controller), interaction=interaction_channel(cfg),
                        assisted=("open", "close") if controller.controller.ctx.signed else ("open",),
                        count_deg=controller.controller.ctx.binding.encoder_count_deg)


def passive_energy_j(controller: ControllerRuntime) -> float:
    """The robot's electrical energy per cycle with a passive patient: the controller's ``baseline``
    (itself at full assistance) on the host's model, whose finger is passive; the second of two
    cycles (the first starts from rest). nan for a controller without one [J]."""
    baseline = getattr(controller.controller, "baseline", None)
    if baseline is None:
        return math.nan
    _, figures = offline_session(baseline, cycles=2)
    return figures.get("energy_per_cycle_j", math.nan)


def interaction_channel(cfg: PlantConfig) -> tuple[str, float] | None:
    """(the ADC channel of the torque sensor between patient and rig, its sign on the joint axis),
    from ``Ports.interaction`` (the Finger Extensor's); None: the rig has no such sensor."""
    ports = get_plant(cfg.plant).ports(cfg)
    if ports.interaction is None:
        return None
    signal, gain = ports.interaction
    sensed = any(m.signal == signal and m.sensor == "adc" for m in ports.measured)
    return (signal, 1.0 / gain) if sensed and gain else None


def build_estimator(cfg: PlantConfig, binding: DeviceBinding) -> Estimator:
    host = cfg.rig.host
    return Estimator(binding, host.velocity_filter_hz if host else 30.0)


def temperature_channel(binding: DeviceBinding) -> str | None:
    """The ADC channel of a wired thermistor (a temperature signal, ``*_c``), or None."""
    return next((ch.signal for ch in binding.adc if ch.kind == "temperature" or ch.signal.endswith("_c")), None)


def estop_enabled(cfg: PlantConfig) -> bool:
    """``[rig.estop] enabled``; without the table: on for a real serial port, off for simulated rigs."""
    es = cfg.rig.estop
    return es.enabled if es is not None else cfg.rig.port.startswith("/")


def build_supervisor(cfg: PlantConfig, binding: DeviceBinding) -> Supervisor:
    """Host limits = ``[rig.limits]`` tightened by the ``[rig.host]`` margins (``RigSection.host_limits``); the
    temperature estimate is the plant's own thermal model of its actuator (``plants.thermal.safety_thermal``)."""
    lim, th, host = cfg.rig.limits, cfg.rig.thermal, cfg.rig.host_limits()
    limits = SupervisorLimits(
        min_angle_deg=host.min_angle_deg, max_angle_deg=host.max_angle_deg,
        max_force_n=host.max_force_n, max_heating_s=host.max_heating_s,
        max_temperature_c=lim.max_temperature_c, link_loss_periods=lim.link_loss_periods, max_duty=lim.max_duty,
        stuck_sensor_s=lim.stuck_sensor_s, stuck_min_duty=lim.stuck_min_duty,
        stuck_min_error_deg=lim.stuck_min_error_deg, stuck_min_motion_deg=lim.stuck_min_motion_deg,
        force_debounce_s=lim.force_debounce_ms / 1000.0,
        max_disagreement_c=th.max_disagreement_c if th else 25.0, disagreement_s=th.disagreement_s if th else 1.0,
    )
    thermal = safety_thermal(cfg)
    return Supervisor(limits, period_s(cfg), force_channels(binding), thermal, estop_input=estop_enabled(cfg),
                      temperature_signal=temperature_channel(binding))


def firmware_configure(cfg: PlantConfig, binding: DeviceBinding) -> Configure:
    """The firmware's copy of the limits: range of motion, heating time, max duty, the e-stop input
    (enabled, wiring) and, when A0 is a contact force, its limit in ADC counts and debounce (the
    firmware checks A0 only)."""
    limit_counts = force_limit_counts(cfg, binding)  # 1023 (off) unless A0 is a force; unrepresentable: refused
    msg = configure_from_config(cfg, binding.encoder_counts_per_rev, force_limit_counts=limit_counts,
                                estop_input=estop_enabled(cfg), encoder_direction=binding.encoder_direction)
    es = cfg.rig.estop
    nc = Configure.FLAG_ESTOP_NORMALLY_CLOSED if es is not None and es.normally_closed else 0
    return dataclasses.replace(msg, flags=msg.flags | nc, force_debounce_ms=cfg.rig.limits.force_debounce_ms)
