"""A generic one-axis electromechanical drive: a DC motor (through its amplifier) moving a load,
rotary or linear (docs/models.md, "Generic motor axis").

    M q'' = g sat(u) - Fv q' - Fc sgn(q') - offset          (Janot, Gautier and Brunot 2019, EMPS eq 1, 3, 7)

q is the load's position [m] (linear) or angle [rad] (rotary), u the drive input [V], g the drive's
force constant at the load [N/V] (or torque constant [N m/V]; with a transmission of ratio r motor
rad per load unit, g = r x the motor-side constant and M = M_load + r^2 J_rotor), sat the drive's
input range, Fv and Fc viscous and Coulomb friction (Karnopp stiction band, ``models.mechanics``),
offset a constant load. A drive commanded in torque or current (``drive.command``) takes its
command as the input instead of a voltage: ``drive_torque_nm`` (``drive_force_n`` on a linear axis
without a transmission; g = 1, or the ratio with one) or ``drive_current_a`` (g = the torque or force
constant per ampere). The measured velocity (``velocity_m_s`` / ``velocity_rad_s``) is an output a
record may carry beside the position. ``configs/emps.toml`` is the EMPS benchmark's reference model of its
prismatic axis, ``configs/emps_nominal.toml`` the same without Coulomb friction and offset.

On a linear axis the framework's rotary signal names carry linear quantities (``models/axis_parts``):
the axis port's torque sum is a force [N]; the effects' ``*_nm`` parameters are then newtons, and
their bounds scale with the drive's peak force (``AxisPort.force_scale``).
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Literal

import numpy as np

from rehab_hil.config import Field, Section, model_validator
from rehab_hil.control.cascade import RecordedControllerSection, loop_parts
from rehab_hil.models.axis_parts import ConstantLoad, Saturation
from rehab_hil.models.mechanics import CoulombFriction, RotaryInertia, ViscousFriction
from rehab_hil.models.ports import ActuatorPort, AxisPort, MeasuredPort, Ports, Wire
from rehab_hil.models.sensors import Gain
from rehab_hil.models.system import Part, SimulationResult
from rehab_hil.plants.experiments import FitParameter, Scenario
from rehab_hil.plants.registry import Plant
from rehab_hil.plants.sections import PlantConfig

__all__ = ["MotorAxis", "MotorAxisConfig", "axis_values", "build", "drive_signal", "ports"]

INPUTS = ("drive_input_v",)  # a voltage-commanded drive (the default); ``drive_signal`` gives the config's
COMMAND_INPUTS = ("drive_torque_nm", "drive_force_n", "drive_current_a")
# a linear axis gives position_m (and velocity_m_s), a rotary one angle_deg (and velocity_rad_s)
OUTPUTS = ("position_m", "angle_deg", "velocity_m_s", "velocity_rad_s")


class LoadSection(Section):
    """The moving load: a linear axis takes the ``*_kg``, ``*_n*`` keys, a rotary one ``*_kg_m2``, ``*_nm*``."""

    kind: Literal["linear", "rotary"] = Field(description="linear: position in m, forces in N; rotary: rad, N m")
    mass_kg: float | None = Field(None, gt=0.0, le=1e5, description="moving mass at the load (linear; EMPS: M)")
    inertia_kg_m2: float | None = Field(None, gt=0.0, le=1e4, description="inertia at the load (rotary)")
    viscous_n_s_per_m: float | None = Field(None, ge=0.0, le=1e6, description="viscous friction Fv (linear)")
    viscous_nm_s_per_rad: float | None = Field(None, ge=0.0, le=1e5, description="viscous friction (rotary)")
    coulomb_n: float | None = Field(None, ge=0.0, le=1e5, description="Coulomb friction Fc (linear)")
    coulomb_nm: float | None = Field(None, ge=0.0, le=1e4, description="Coulomb friction (rotary)")
    offset_n: float | None = Field(None, ge=-1e5, le=1e5, description="constant load against the axis (linear; "
                                   "EMPS eq 1: offset)")
    offset_nm: float | None = Field(None, ge=-1e4, le=1e4, description="constant load torque (rotary)")
    stick_velocity: float = Field(1e-4, gt=0.0, le=1.0, description="stiction band of the Coulomb law [m/s or rad/s]")
    stick_damping: float = Field(1e4, ge=0.0, le=1e8, description="brings motion inside the band to rest "
                                 "[N s/m or N m s/rad]")

    @model_validator(mode="after")
    def _one_kind(self) -> LoadSection:
        lin = ("mass_kg", "viscous_n_s_per_m", "coulomb_n", "offset_n")
        rot = ("inertia_kg_m2", "viscous_nm_s_per_rad", "coulomb_nm", "offset_nm")
        want, other = (lin, rot) if self.kind == "linear" else (rot, lin)
        wrong = [k for k in other if getattr(self, k) is not None]
        if wrong:
            raise ValueError(f"a {self.kind} load takes {', '.join(want)}, not {', '.join(wrong)}")
        if getattr(self, want[0]) is None:
            raise ValueError(f"a {self.kind} load needs {want[0]}")
        return self


class DriveSection(Section):
    """The motor and its amplifier: what commands it (a voltage, a torque or a current), the force (or
    torque) per unit of command, and the command's range."""

    command: Literal["voltage", "torque", "current"] = Field("voltage", description="what the record's drive "
                                                             "input is: drive_input_v, drive_torque_nm (drive_force_n "
                                                             "on a linear direct drive) or drive_current_a")
    force_constant_n_per_v: float | None = Field(None, gt=0.0, le=1e5, description="force at a linear load per "
                                                 "drive volt (EMPS: gtau = 35.15 N/V, the description's drive gain)")
    torque_constant_nm_per_v: float | None = Field(None, gt=0.0, le=1e4, description="torque per drive volt: at "
                                                   "a rotary load, or at the motor shaft with a transmission")
    force_constant_n_per_a: float | None = Field(None, gt=0.0, le=1e5, description="force per ampere (a linear "
                                                 "motor commanded in current)")
    torque_constant_nm_per_a: float | None = Field(None, gt=0.0, le=1e3, description="k_t: torque per ampere "
                                                   "(commanded in current; at the motor shaft with a transmission)")
    saturation_v: float | None = Field(None, gt=0.0, le=1e3, description="drive input range +- [V] (EMPS: viradm = "
                                       "10 V)")
    saturation_nm: float | None = Field(None, gt=0.0, le=1e4, description="torque command range +- [N m]")
    saturation_n: float | None = Field(None, gt=0.0, le=1e6, description="force command range +- [N]")
    saturation_a: float | None = Field(None, gt=0.0, le=1e3, description="current command range +- [A]")


class TransmissionSection(Section):
    """Optional gearing between the motor and the load (a ball screw, a gearbox)."""

    ratio: float = Field(gt=0.0, le=1e6, description="motor rad per load unit (m or rad): 2 pi / lead of a screw")
    rotor_inertia_kg_m2: float = Field(0.0, ge=0.0, le=10.0, description="motor rotor inertia, reflected x ratio^2")


class MotorAxisConfig(PlantConfig):
    load: LoadSection
    drive: DriveSection
    transmission: TransmissionSection | None = None
    step_reference: float = Field(0.1, ge=-1e3, le=1e3, description="the step scenario's target [m or rad]")

    @model_validator(mode="after")
    def _drive_fits(self) -> MotorAxisConfig:
        d = self.drive
        direct_linear = self.transmission is None and self.load.kind == "linear"
        if d.command == "voltage":
            need = "force_constant_n_per_v" if direct_linear else "torque_constant_nm_per_v"
        elif d.command == "current":
            need = "force_constant_n_per_a" if direct_linear else "torque_constant_nm_per_a"
        else:
            need = ""
        if need and getattr(d, need) is None:
            what = "a linear load without a transmission" if direct_linear else "a rotary load or a transmission"
            raise ValueError(f"drive.{need} is needed for {what} commanded in {d.command}")
        signal, _, sat_key = _command(self)
        if getattr(d, sat_key) is None:
            raise ValueError(f"drive.{sat_key} is needed: the range of the {d.command} command ({signal})")
        return self


def _command(cfg: MotorAxisConfig) -> tuple[str, str, str]:
    """(input signal, unit, range key) of the drive's command."""
    d = cfg.drive
    if d.command == "voltage":
        return "drive_input_v", "v", "saturation_v"
    if d.command == "current":
        return "drive_current_a", "a", "saturation_a"
    if cfg.transmission is None and cfg.load.kind == "linear":
        return "drive_force_n", "n", "saturation_n"
    return "drive_torque_nm", "nm", "saturation_nm"


def drive_signal(cfg: MotorAxisConfig) -> str:
    """The record's drive input under ``cfg``: drive_input_v, drive_torque_nm, drive_force_n or drive_current_a."""
    return _command(cfg)[0]


def _drive_gain(cfg: MotorAxisConfig) -> float:
    """Force (or torque) at the load per unit of drive command."""
    d, tr = cfg.drive, cfg.transmission
    lin = cfg.load.kind == "linear" and tr is None
    per_unit = {"voltage": d.force_constant_n_per_v if lin else d.torque_constant_nm_per_v,
                "current": d.force_constant_n_per_a if lin else d.torque_constant_nm_per_a,
                "torque": 1.0}[d.command]
    return float(per_unit) * (tr.ratio if tr is not None else 1.0)  # type: ignore[arg-type]


def axis_values(cfg: MotorAxisConfig) -> dict[str, float]:
    """The axis in one unit system (load side): inertia, viscous, Coulomb, offset, drive gain, peak force."""
    ld, tr = cfg.load, cfg.transmission
    lin = ld.kind == "linear"
    gain = _drive_gain(cfg)
    inertia = (ld.mass_kg if lin else ld.inertia_kg_m2) or 0.0
    if tr is not None:
        inertia += tr.rotor_inertia_kg_m2 * tr.ratio**2
    return {"inertia": inertia, "viscous": (ld.viscous_n_s_per_m if lin else ld.viscous_nm_s_per_rad) or 0.0,
            "coulomb": (ld.coulomb_n if lin else ld.coulomb_nm) or 0.0,
            "offset": (ld.offset_n if lin else ld.offset_nm) or 0.0,
            "gain": gain, "peak_force": gain * float(getattr(cfg.drive, _command(cfg)[2]))}


def build(cfg: MotorAxisConfig) -> list[Part]:
    """The axis as parts; external input the drive's command (``drive_signal``). Every force on the load
    is summed on ``axis_force`` except Coulomb friction, which reads that sum (stick or slip)."""
    v = axis_values(cfg)
    lin = cfg.load.kind == "linear"
    signal, _, sat_key = _command(cfg)
    return [
        RotaryInertia("load", connect={"torque_nm": ["axis_force", "friction_force"]},
                      rename={"angle_rad": "load_position", "velocity_rad_s": "load_velocity"},
                      inertia_kg_m2=v["inertia"]),
        Saturation("drive_limit", connect={"u": signal}, rename={"y": "drive_command_limited"},
                   limit=float(getattr(cfg.drive, sat_key))),
        Gain("drive", connect={"u": "drive_command_limited"}, rename={"y": "axis_force"}, gain=v["gain"]),
        ViscousFriction("viscous", connect={"velocity_rad_s": "load_velocity"}, rename={"torque_nm": "axis_force"},
                        damping_nm_s_per_rad=v["viscous"]),
        ConstantLoad("offset", rename={"torque_nm": "axis_force"}, level_nm=v["offset"]),
        CoulombFriction("coulomb", connect={"velocity_rad_s": "load_velocity", "other_torque_nm": "axis_force"},
                        rename={"torque_nm": "friction_force"}, level_nm=v["coulomb"],
                        stick_velocity_rad_s=cfg.load.stick_velocity,
                        stick_damping_nm_s_per_rad=cfg.load.stick_damping),
        Gain("sensor", connect={"u": "load_position"}, rename={"y": "position_m" if lin else "angle_deg"},
             gain=1.0 if lin else float(np.degrees(1.0))),
        Gain("tachometer", connect={"u": "load_velocity"}, rename={"y": "velocity_m_s" if lin else "velocity_rad_s"},
             gain=1.0),
    ]


def ports(cfg: MotorAxisConfig) -> Ports:
    """The drive input on PWM channel 0 (signed, full scale = the drive's range); the load axis; the
    position as measured (a lab's logger, no rig encoder on this plant)."""
    lin = cfg.load.kind == "linear"
    out = "position_m" if lin else "angle_deg"
    signal, unit, sat_key = _command(cfg)
    return Ports(
        actuators=(ActuatorPort(Wire(signal, (("drive_limit", "u"),)), unit, duty_channel=0,
                                duty_scale=float(getattr(cfg.drive, sat_key)), signed=True),),
        axes=(AxisPort("load", "load_position", "load_velocity", "axis_force", ("load", "torque_nm"),
                       stick_velocity_rad_s=cfg.load.stick_velocity, stick_damping_nm_s_per_rad=cfg.load.stick_damping,
                       force_scale=axis_values(cfg)["peak_force"], linear=lin),),
        measured=(MeasuredPort(out, "position" if lin else "angle", "m" if lin else "deg"),
                  MeasuredPort("velocity_m_s" if lin else "velocity_rad_s", "velocity", "m/s" if lin else "rad/s")),
        sums=("axis_force",),
    )


def step_scenario(cfg: MotorAxisConfig, duration_s: float | None = None) -> Scenario:
    """A step of ``step_reference`` under the ``[recorded_controller]`` (open loop: 10 % of the drive
    range for half the time, then nothing, when the config declares none)."""
    n = MotorAxis.n_steps(cfg, duration_s or 2.0)
    rc = cfg.recorded_controller
    lin = cfg.load.kind == "linear"
    out = "position_m" if lin else "angle_deg"

    def score(res: SimulationResult) -> dict[str, float]:
        y = res[out]
        return {"final": float(y[-1]), "peak": float(np.max(np.abs(y)))}

    if rc is None:
        signal, _, sat_key = _command(cfg)
        u = np.where(np.arange(n) < n // 2, 0.1 * float(getattr(cfg.drive, sat_key)), 0.0)
        return Scenario("step", n, inputs={signal: u}, metrics=score)
    ref = np.full(n, cfg.step_reference)
    return Scenario("step", n, parts=loop_parts(rc, 0.0), inputs={rc.reference: ref,
                    **{d: np.zeros(n) for d in rc.disturbances}}, extra_outputs=(rc.effort,), metrics=score,
                    sums=(rc.effort,))


class MotorAxis(Plant):
    """A DC motor axis driving a rotary or linear load (EMPS benchmark)."""

    name = "motor_axis"
    config = MotorAxisConfig
    inputs = INPUTS
    optional_inputs = COMMAND_INPUTS  # the drive's command when it is not a voltage (``input_signals``)
    vocabulary = MappingProxyType({"thing": "drive", "axis": "axis", "actuator": "drive amplifier",
                                   "sources": "general"})
    outputs = OUTPUTS
    build = staticmethod(build)
    ports = staticmethod(ports)
    scenarios = MappingProxyType({"step": step_scenario})
    fit_parameters = (  # EMPS eq 1: M, Fv, Fc, offset; eq 7: the drive gain
        FitParameter("load.mass_kg", diagram=("load.inertia_kg_m2",)),
        FitParameter("load.inertia_kg_m2", diagram=("load.inertia_kg_m2",)),
        FitParameter("load.viscous_n_s_per_m", diagram=("viscous.damping_nm_s_per_rad",)),
        FitParameter("load.viscous_nm_s_per_rad", diagram=("viscous.damping_nm_s_per_rad",)),
        FitParameter("load.coulomb_n", diagram=("coulomb.level_nm",)),
        FitParameter("load.coulomb_nm", diagram=("coulomb.level_nm",)),
        FitParameter("load.offset_n", diagram=("offset.level_nm",)),
        FitParameter("load.offset_nm", diagram=("offset.level_nm",)),
        FitParameter("drive.force_constant_n_per_v", diagram=("drive.gain",)),
        FitParameter("drive.torque_constant_nm_per_v", diagram=("drive.gain",)),
        FitParameter("drive.force_constant_n_per_a", diagram=("drive.gain",)),
        FitParameter("drive.torque_constant_nm_per_a", diagram=("drive.gain",)),
    )

    @classmethod
    def input_signals(cls, cfg: PlantConfig) -> tuple[str, ...]:
        """The drive's command under ``cfg`` (a voltage, torque, force or current column)."""
        return (drive_signal(cfg),)  # type: ignore[arg-type]


__all__ += ["RecordedControllerSection"]
