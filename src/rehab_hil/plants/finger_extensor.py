"""1-DOF Finger Extensor: iris mechanism driven by a geared 24 V DC motor (seed 002).

Model, derived anew from seed 002 eq 1-11 on the iris axis (angle theta, rad):

    (J2 + N^2 J_m) theta'' = k_t i - (b1 + N^2 B_v) theta' - k1 theta - T_f - T_e
    L di/dt = V - R i - k_v theta'

with J2 = m r^2 / 2 (solid cylinder, r = 0.055 m), T_f Coulomb friction F_c sgn(theta')
with stiction, and T_e the patient's torque (opposing opening, eq 3). States
[theta, theta', i] are equivalent to the paper's [theta, theta', theta''] (eq 13, 17).

Corrections to seed 002, section 3.2-3.3:
- the printed A_B has row 2 = [0 1 0]; for states [theta, theta', theta''] it must be
  [0 0 1] (theta'' is the derivative of theta'), and row 1 must be [0 1 0];
- a_32 reads (-k_v k_t + B_v R)/(J_m L); it is -(k_v k_t + B_v R)/(J_m L), likewise
  a_33 = -(B_v L + J_m R)/(J_m L): both damping terms must have the same sign;
- in eq 12 the gear ratio enters k_t and k_v; seed 002 measured k_t = 0.791 N m/A and
  k_v = 0.886 V s/rad from the motor's characteristic curves at the gearbox output
  (24 V / 0.886 = 27 rad/s no-load at the output is what a 32.5:1 gearmotor does), so here
  they act on the output axis directly; reflected motor inertia and viscous friction carry N^2.
Parameters seed 002 takes from its reference [20] (J_m, B_v, R, L, masses, friction levels) are
not given there: configs/finger_extensor.toml documents the physically plausible values chosen.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from rehab_hil import metrics
from rehab_hil.config import Field, Section
from rehab_hil.models.dc_motor import DCMotorArmature
from rehab_hil.models.mechanics import CoulombFriction, HardStop, RotaryInertia, TorsionSpring, ViscousFriction
from rehab_hil.models.ports import ActuatorPort, AxisPort, MeasuredPort, Ports, Wire
from rehab_hil.models.sensors import Gain, QuadratureEncoder
from rehab_hil.models.system import Part, SimulationResult
from rehab_hil.plants.experiments import Excitation, FitParameter, Scenario, multisine
from rehab_hil.plants.registry import Plant
from rehab_hil.plants.sections import EncoderSection, PlantConfig

if TYPE_CHECKING:  # python-control takes seconds to import: only where it is used
    import control

__all__ = ["FingerExtensor", "FingerExtensorConfig", "build", "iris_inertia_kg_m2", "linear_model", "ports"]

INPUTS = ("motor_voltage_v", "patient_torque_nm")
OUTPUTS = ("iris_angle_deg", "motor_current_a")


class IrisSection(Section):
    radius_m: float = Field(gt=0.0, le=1.0, description="iris radius, seed 002 sec 3.1: 0.055 m")
    mass_kg: float = Field(gt=0.0, le=20.0, description="mass of the rotating iris (chosen)")
    spring_nm_per_rad: float = Field(ge=0.0, le=100.0, description="k1, seed 002 eq 2")
    viscous_nm_s_per_rad: float = Field(ge=0.0, le=100.0, description="b1 / V_c, seed 002 eq 6")
    coulomb_nm: float = Field(ge=0.0, le=100.0, description="F_c, seed 002 eq 6")
    stick_velocity_rad_s: float = Field(gt=0.0, le=1.0, description="stiction band of the friction model")
    stick_damping_nm_s_per_rad: float = Field(ge=0.0, le=1000.0, description="settles motion inside the band")
    closed_stop_deg: float | None = Field(None, ge=-180.0, le=180.0, description="angle of the closed mechanical "
                                          "stop (a rig to home against); unset: the iris has none, only its spring")
    stop_stiffness_nm_per_rad: float = Field(50.0, gt=0.0, le=10_000.0, description="stiffness of that stop")
    stop_damping_nm_s_per_rad: float = Field(0.5, ge=0.0, le=100.0, description="damping of that stop")


class MotorSection(Section):
    supply_v: float = Field(gt=0.0, le=60.0, description="H-bridge supply, seed 002: 24 V")
    gear_ratio: float = Field(ge=1.0, le=1000.0, description="N, seed 002: 32.5:1 planetary")
    kt_nm_per_a: float = Field(gt=0.0, le=100.0, description="torque constant at the gearbox output")
    kv_v_s_per_rad: float = Field(gt=0.0, le=100.0, description="back-EMF constant at the gearbox output")
    resistance_ohm: float = Field(gt=0.0, le=1000.0)
    inductance_h: float = Field(gt=0.0, le=10.0)
    rotor_inertia_kg_m2: float = Field(ge=0.0, le=1.0, description="J_m at the motor shaft")
    rotor_viscous_nm_s_per_rad: float = Field(ge=0.0, le=10.0, description="B_v at the motor shaft")


class TorqueSensorSection(Section):
    counts_per_nm: float = Field(gt=0.0, le=10000.0, description="ADC counts per N m of patient torque")
    offset_counts: float = Field(ge=0.0, le=1023.0, description="ADC counts at zero torque")


class StepScenarioSection(Section):
    start_deg: float = Field(ge=-360.0, le=360.0)
    target_deg: float = Field(ge=-360.0, le=360.0, description="seed 002 Fig. 11: 59.58 deg")
    duration_s: float = Field(gt=0.0, le=3600.0)


class CycleScenarioSection(Section):
    closed_deg: float = Field(ge=-360.0, le=360.0, description="seed 002 Fig. 10: 7.89 deg")
    open_deg: float = Field(ge=-360.0, le=360.0, description="seed 002 Fig. 10: 121 deg")
    move_s: float = Field(gt=0.0, le=600.0)
    hold_open_s: float = Field(ge=0.0, le=600.0)
    hold_closed_s: float = Field(ge=0.0, le=600.0)
    duration_s: float = Field(gt=0.0, le=3600.0)


class ScenariosSection(Section):
    step: StepScenarioSection
    cycle: CycleScenarioSection


class FingerExtensorConfig(PlantConfig):
    iris: IrisSection
    motor: MotorSection
    encoder: EncoderSection
    torque_sensor: TorqueSensorSection
    scenarios: ScenariosSection


def iris_inertia_kg_m2(cfg: FingerExtensorConfig) -> float:
    """J2 of a solid cylinder (seed 002 sec 3.1)."""
    return 0.5 * cfg.iris.mass_kg * cfg.iris.radius_m**2


def total_inertia_kg_m2(cfg: FingerExtensorConfig) -> float:
    return iris_inertia_kg_m2(cfg) + cfg.motor.gear_ratio**2 * cfg.motor.rotor_inertia_kg_m2


def build(cfg: FingerExtensorConfig) -> list[Part]:
    """The plant as parts; external inputs motor_voltage_v, patient_torque_nm.

    Every torque on the iris axis is summed on ``drive_torque_nm`` (except Coulomb friction,
    which needs that sum to decide stick or slip)."""
    m, iris = cfg.motor, cfg.iris
    n2 = m.gear_ratio**2
    return [
        RotaryInertia(
            "iris",
            connect={"torque_nm": ["drive_torque_nm", "friction_torque_nm"]},
            rename={"angle_rad": "iris_angle_rad", "velocity_rad_s": "iris_velocity_rad_s"},
            inertia_kg_m2=total_inertia_kg_m2(cfg),
        ),
        DCMotorArmature(
            "motor",
            connect={"voltage_v": "motor_voltage_v", "velocity_rad_s": "iris_velocity_rad_s"},
            rename={"torque_nm": "drive_torque_nm", "current_a": "motor_current_a"},
            kt_nm_per_a=m.kt_nm_per_a, kv_v_s_per_rad=m.kv_v_s_per_rad,
            resistance_ohm=m.resistance_ohm, inductance_h=m.inductance_h,
        ),
        ViscousFriction(
            "rotor_viscous", connect={"velocity_rad_s": "iris_velocity_rad_s"},
            rename={"torque_nm": "drive_torque_nm"}, damping_nm_s_per_rad=n2 * m.rotor_viscous_nm_s_per_rad,
        ),
        ViscousFriction(
            "iris_viscous", connect={"velocity_rad_s": "iris_velocity_rad_s"},
            rename={"torque_nm": "drive_torque_nm"}, damping_nm_s_per_rad=iris.viscous_nm_s_per_rad,
        ),
        TorsionSpring(
            "spring", connect={"angle_rad": "iris_angle_rad"}, rename={"torque_nm": "drive_torque_nm"},
            stiffness_nm_per_rad=iris.spring_nm_per_rad, rest_angle_rad=0.0,
        ),
        Gain("patient", connect={"u": "patient_torque_nm"}, rename={"y": "drive_torque_nm"}, gain=-1.0),
        CoulombFriction(
            "coulomb",
            connect={"velocity_rad_s": "iris_velocity_rad_s", "other_torque_nm": "drive_torque_nm"},
            rename={"torque_nm": "friction_torque_nm"},
            level_nm=iris.coulomb_nm, stick_velocity_rad_s=iris.stick_velocity_rad_s,
            stick_damping_nm_s_per_rad=iris.stick_damping_nm_s_per_rad,
        ),
        *([] if iris.closed_stop_deg is None else [HardStop(
            "closed_stop", connect={"angle_rad": "iris_angle_rad", "velocity_rad_s": "iris_velocity_rad_s"},
            rename={"torque_nm": "drive_torque_nm"}, stiffness_nm_per_rad=iris.stop_stiffness_nm_per_rad,
            damping_nm_s_per_rad=iris.stop_damping_nm_s_per_rad, stop_angle_rad=float(np.radians(iris.closed_stop_deg)),
        )]),
        QuadratureEncoder(
            "encoder", connect={"angle_rad": "iris_angle_rad"},
            rename={"counts": "encoder_counts", "angle_deg": "iris_angle_deg"},
            counts_per_rev=cfg.encoder.counts_per_rev,
        ),
    ]


def linear_model(cfg: FingerExtensorConfig) -> control.StateSpace:
    """The linear part (no Coulomb friction, no quantisation) as a python-control system.

    States [theta (rad), theta' (rad/s), i (A)]; inputs [V (V), T_e (N m)]; outputs [theta, i]."""
    import control

    m, iris = cfg.motor, cfg.iris
    J = total_inertia_kg_m2(cfg)
    b = iris.viscous_nm_s_per_rad + m.gear_ratio**2 * m.rotor_viscous_nm_s_per_rad
    A = np.array([
        [0.0, 1.0, 0.0],
        [-iris.spring_nm_per_rad / J, -b / J, m.kt_nm_per_a / J],
        [0.0, -m.kv_v_s_per_rad / m.inductance_h, -m.resistance_ohm / m.inductance_h],
    ])
    B = np.array([[0.0, 0.0], [0.0, -1.0 / J], [1.0 / m.inductance_h, 0.0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return control.ss(A, B, C, np.zeros((2, 2)), inputs=["motor_voltage_v", "patient_torque_nm"],
                      outputs=["iris_angle_rad", "motor_current_a"], states=["theta", "omega", "current"])


def _closed_loop(cfg: FingerExtensorConfig, name: str, n_steps: int, reference: object, patient_torque_nm: float,
                 score: object) -> Scenario:
    """The rig's controller ``name`` ([controllers.<name>], ``rehab_hil.controllers``) on the model."""
    from rehab_hil.controllers import build_controller  # controllers build on plants

    ctl = build_controller(cfg, name, reference, check=False)  # type: ignore[arg-type]
    return Scenario(name, n_steps, parts=ctl.parts, inputs={"patient_torque_nm": patient_torque_nm,
                                                            **ctl.offline_inputs(n_steps)},
                    extra_outputs=("iris_angle_reference_deg",), metrics=score, sums=ctl.sums)  # type: ignore[arg-type]


def step_scenario(cfg: FingerExtensorConfig, duration_s: float | None = None,
                  target_deg: float | None = None, patient_torque_nm: float = 0.0,
                  controller: str = "pid") -> Scenario:
    """Seed 002 Fig. 11: a step to 59.58 deg (~0.3 s, 2.86 deg overshoot) under the rig's PID."""
    from rehab_hil.controllers import Reference

    sc = cfg.scenarios.step
    target = sc.target_deg if target_deg is None else target_deg

    def score(res: SimulationResult) -> dict[str, float]:
        return metrics.step_metrics(res.t, res["iris_angle_deg"], sc.start_deg, target)

    n = FingerExtensor.n_steps(cfg, duration_s or sc.duration_s)
    return _closed_loop(cfg, controller, n, Reference.step(cfg, target, sc.start_deg), patient_torque_nm, score)


def cycle_scenario(cfg: FingerExtensorConfig, duration_s: float | None = None,
                   patient_torque_nm: float = 0.0, controller: str = "pid") -> Scenario:
    """Open-close cycling (seed 002 Fig. 10: 7.89 <-> 121 deg over 30 s) under the rig's PID."""
    from rehab_hil.controllers import Reference

    sc = cfg.scenarios.cycle

    def score(res: SimulationResult) -> dict[str, float]:
        return metrics.tracking_metrics(res["iris_angle_reference_deg"], res["iris_angle_deg"])

    ref = Reference("session", sc.closed_deg, sc.open_deg, sc.move_s, sc.hold_open_s, sc.hold_closed_s)
    n = FingerExtensor.n_steps(cfg, duration_s or sc.duration_s)
    return _closed_loop(cfg, controller, n, ref, patient_torque_nm, score)


def steady_angle_rad(cfg: FingerExtensorConfig, voltage_v: float) -> float:
    """Analytic rest angle under constant voltage with a spring and no friction: k_t V / (R k1)."""
    return cfg.motor.kt_nm_per_a * voltage_v / (cfg.motor.resistance_ohm * cfg.iris.spring_nm_per_rad)


def steady_speed_rad_s(cfg: FingerExtensorConfig, voltage_v: float) -> float:
    """Analytic steady speed with no spring and no Coulomb friction: k_t V / (k_t k_v + R b)."""
    m = cfg.motor
    b = cfg.iris.viscous_nm_s_per_rad + m.gear_ratio**2 * m.rotor_viscous_nm_s_per_rad
    return m.kt_nm_per_a * voltage_v / (m.kt_nm_per_a * m.kv_v_s_per_rad + m.resistance_ohm * b)


def ports(cfg: FingerExtensorConfig) -> Ports:
    """The rig's view: PWM channel 0 + direction pin drive the H-bridge (V = +-supply * duty);
    the encoder reads the iris angle; A0 is the torque sensor between the patient's finger and the
    iris (``torque_sensor`` table): it measures the model's input ``patient_torque_nm``."""
    ts = cfg.torque_sensor
    return Ports(
        actuators=(ActuatorPort(Wire("motor_voltage_v", (("motor", "voltage_v"),)), "v",
                                duty_channel=0, duty_scale=cfg.motor.supply_v, signed=True),),
        axes=(AxisPort("iris", "iris_angle_rad", "iris_velocity_rad_s", "drive_torque_nm", ("iris", "torque_nm"),
                       stick_velocity_rad_s=cfg.iris.stick_velocity_rad_s,
                       stick_damping_nm_s_per_rad=cfg.iris.stick_damping_nm_s_per_rad),),
        measured=(
            MeasuredPort("iris_angle_deg", "angle", "deg", "encoder",
                         Wire("iris_angle_rad", (("encoder", "angle_rad"),)),
                         counts_per_unit=cfg.encoder.counts_per_rev),
            MeasuredPort("patient_torque_nm", "torque", "nm", "adc", Wire("patient_torque_nm", ()),
                         counts_per_unit=ts.counts_per_nm, offset_counts=ts.offset_counts),
            MeasuredPort("motor_current_a", "current", "a"),
        ),
        constants={"patient_torque_nm": 0.0},
        sums=("drive_torque_nm",),  # motor, both viscous frictions, spring, patient (and a closed stop)
        interaction=("patient_torque_nm", -1.0),  # a simulated patient's torque enters where the sensor reads it
    )


class FingerExtensor(Plant):
    """Seed 002's 1-DOF Finger Extensor."""

    name = "finger_extensor"
    config = FingerExtensorConfig
    inputs = INPUTS
    outputs = OUTPUTS
    build = staticmethod(build)
    ports = staticmethod(ports)
    scenarios = MappingProxyType({"step": step_scenario, "cycle": cycle_scenario})
    fit_parameters = (  # seed 002 eq 8-11 (motor), eq 6 (spring, inertia): candidates of the discrepancy workflow
        FitParameter("motor.kt_nm_per_a", diagram=("motor.kt_nm_per_a",)),
        FitParameter("motor.kt_nm_per_a", diagram=("motor.kt_nm_per_a", "motor.kv_v_s_per_rad"),  # one magnet:
                     also=("motor.kv_v_s_per_rad",), label="motor.flux (kt_nm_per_a and kv_v_s_per_rad)"),  # eq 8-9
        FitParameter("motor.resistance_ohm", diagram=("motor.resistance_ohm",)),
        FitParameter("iris.spring_nm_per_rad", diagram=("spring.stiffness_nm_per_rad",)),
        FitParameter("motor.rotor_inertia_kg_m2", diagram=("iris.inertia_kg_m2",),  # the rotor dominates J
                     to_config=lambda cfg, f: (f * total_inertia_kg_m2(cfg) - iris_inertia_kg_m2(cfg))
                     / cfg.motor.gear_ratio**2),
    )

    @classmethod
    def actuator_power_w(cls, cfg: FingerExtensorConfig, effort: np.ndarray,
                         velocity_rad_s: np.ndarray) -> np.ndarray:
        """V i with the armature current quasi-static (L/R = 1 ms): i = (V - k_v w) / R (seed 002
        eq 9); a motor braking back into the bridge draws nothing from the supply (no regeneration)."""
        m = cfg.motor
        v = np.asarray(effort, float)
        return np.maximum(v * (v - m.kv_v_s_per_rad * np.asarray(velocity_rad_s, float)) / m.resistance_ohm, 0.0)

    excitation = Excitation(
        inputs=lambda t, rng: {"motor_voltage_v": multisine(t, rng, 2.5, (0.35, 0.8, 1.7), 0.2),
                               "patient_torque_nm": np.zeros_like(t)},
        mismatch=("iris.inertia_kg_m2", 1.05),
        noise={"motor_current_a": 0.01},
    )
