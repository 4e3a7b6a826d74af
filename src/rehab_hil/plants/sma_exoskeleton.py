"""SMA-wire-driven soft finger exoskeleton on an index finger: the coupled model of seed 000.

Signal flow (every effect its own part; docs/sma_exoskeleton.md):

    pwm_duty, supply_voltage_v -> SMAThermal (eq 12-13) -> sma_temperature_c
    finger angles + pad bend -> TendonExcursion (eq 5, 11) -> both wires
    SMATanakaWire (eq 14-17) -> sma_tension_n;  PassiveWire (eq 10-11) -> passive_tension_n
    wires' torque on the massless exoskeleton -> ContactPad / ContactForce (eq 18-28)
    -> fingertip force contact_force_n and joint torques; HillPassiveMuscle (eq 1-3) and joint
    damping add theirs -> CoupledFingerChain (eq 29 with eq 9) -> theta_{mcp,pip,dip}
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Literal

import numpy as np

from rehab_hil.config import Field, Section, model_validator
from rehab_hil.models.contact import ContactForce, ContactPad
from rehab_hil.models.finger_chain import COUPLING, CoupledFingerChain
from rehab_hil.models.hill_muscle import HillPassiveMuscle
from rehab_hil.models.mechanics import ViscousFriction
from rehab_hil.models.passive_wire import PassiveWire, TendonExcursion
from rehab_hil.models.ports import ActuatorPort, AxisPort, MeasuredPort, Ports, TemperatureWire, Wire
from rehab_hil.models.sensors import Gain
from rehab_hil.models.sma_tanaka import SMATanakaWire
from rehab_hil.models.sma_thermal import SMAThermal
from rehab_hil.models.system import Part, SimulationResult
from rehab_hil.plants.experiments import Excitation, FitParameter, Scenario, random_levels
from rehab_hil.plants.registry import Plant
from rehab_hil.plants.sections import EncoderSection, ForceSensorSection, PlantConfig

__all__ = ["SMAExoskeleton", "SMAExoskeletonConfig", "build", "duty_profile", "ports", "tendon_lever_m"]

INPUTS = ("pwm_duty", "supply_voltage_v")
OUTPUTS = ("theta_mcp_deg", "theta_pip_deg", "theta_dip_deg", "contact_force_n", "sma_tension_n",
           "sma_temperature_c")
JOINTS = ("mcp", "pip", "dip")


class DriveSection(Section):
    supply_voltage_v: float = Field(gt=0.0, le=60.0, description="U, Table 5: 32 V")
    pwm_duty: float = Field(ge=0.0, le=1.0, description="tau, Table 5")


class SMASection(Section):
    length_m: float = Field(gt=0.0, le=10.0)
    radius_m: float = Field(gt=0.0, le=0.005)
    density_kg_m3: float = Field(gt=0.0, le=20000.0)
    resistivity_ohm_m: float = Field(gt=0.0, le=1e-3)
    specific_heat_j_per_kg_c: float = Field(gt=0.0, le=10000.0)
    h1_w_per_m2_c: float = Field(gt=0.0, le=1e5)
    h2_w_per_m2_c3: float = Field(ge=0.0, le=100.0)
    ambient_c: float = Field(ge=-40.0, le=60.0)
    martensite_modulus_pa: float = Field(gt=0.0, le=500e9)
    austenite_modulus_pa: float = Field(gt=0.0, le=500e9)
    thermoelastic_pa_per_c: float = Field(ge=0.0, le=100e6)
    stress_influence_pa_per_c: float = Field(gt=1e5, le=1e9, description="C_A in Pa/C (13.6 MPa/C)")
    austenite_start_c: float = Field(ge=-100.0, le=300.0)
    austenite_finish_c: float = Field(ge=-100.0, le=300.0)
    martensite_start_c: float = Field(ge=-100.0, le=300.0)
    martensite_finish_c: float = Field(ge=-100.0, le=300.0)
    max_recoverable_strain: float = Field(gt=0.0, le=0.1)
    prestrain: float = Field(ge=0.0, le=0.1)
    max_stress_pa: float = Field(gt=0.0, le=3e9)

    @model_validator(mode="after")
    def _temperatures(self) -> SMASection:
        if self.austenite_start_c >= self.austenite_finish_c:
            raise ValueError("austenite_start_c must be below austenite_finish_c (A_s < A_f)")
        if self.martensite_finish_c >= self.martensite_start_c:
            raise ValueError("martensite_finish_c must be below martensite_start_c (M_f < M_s)")
        if self.martensite_start_c > self.austenite_start_c:
            raise ValueError("martensite_start_c must not exceed austenite_start_c (the hysteresis band)")
        if self.prestrain > self.max_recoverable_strain:
            raise ValueError("prestrain must not exceed max_recoverable_strain (recovery is limited by eps_L)")
        return self


class PassiveWireSection(Section):
    radius_m: float = Field(gt=0.0, le=0.005)
    length_m: float = Field(gt=0.0, le=10.0)
    martensite_modulus_pa: float = Field(gt=0.0, le=500e9)
    pretension_n: float = Field(ge=0.0, le=100.0)


class TendonSection(Section):
    mcp_radius_m: float = Field(gt=0.0, le=0.05)
    pip_radius_m: float = Field(gt=0.0, le=0.05)
    dip_radius_m: float = Field(gt=0.0, le=0.05)


class FingerSection(Section):
    proximal_length_m: float = Field(gt=0.0, le=0.2)
    middle_length_m: float = Field(gt=0.0, le=0.2)
    distal_length_m: float = Field(gt=0.0, le=0.2)
    proximal_mass_kg: float = Field(gt=0.0, le=1.0)
    middle_mass_kg: float = Field(gt=0.0, le=1.0)
    distal_mass_kg: float = Field(gt=0.0, le=1.0)
    joint_damping_nm_s_per_rad: float = Field(gt=0.0, le=10.0)
    gravity_x_m_s2: float = Field(ge=-20.0, le=20.0)
    gravity_y_m_s2: float = Field(ge=-20.0, le=20.0)


class MuscleShapeSection(Section):
    k_pe: float = Field(gt=0.0, le=20.0, description="curve shape factor, eq 2")
    e_o: float = Field(gt=0.0, le=5.0, description="passive strain at F_o, eq 2")


class MuscleSection(Section):
    age_group: Literal["young", "old"]
    max_isometric_force_n: float = Field(gt=0.0, le=1000.0)
    optimal_fibre_length_m: float = Field(gt=0.0, le=1.0)
    tendon_slack_length_m: float = Field(gt=0.0, le=1.0)
    rest_length_ratio: float = Field(gt=0.0, le=2.0)
    mcp_moment_arm_m: float = Field(ge=0.0, le=0.05)
    pip_moment_arm_m: float = Field(ge=0.0, le=0.05)
    dip_moment_arm_m: float = Field(ge=0.0, le=0.05)
    young: MuscleShapeSection
    old: MuscleShapeSection


class ContactSection(Section):
    stiffness_n_per_m: float = Field(gt=0.0, le=1e7, description="k, eq 30")
    damping_n_s_per_m: float = Field(gt=0.0, le=1e5, description="c > 0 (a damper); eq 30's c < 0 is not")
    exo_radius_m: float = Field(gt=0.0, le=0.5)
    finger_radius_m: float = Field(gt=0.0, le=0.5)


class SessionSection(Section):
    cycles_per_minute: float = Field(gt=0.0, le=60.0, description="seed 000 sec VI.A: 5 per minute")
    heating_s: float = Field(gt=0.0, le=600.0)
    duty: float = Field(ge=0.0, le=1.0)
    duration_s: float = Field(gt=0.0, le=3600.0)

    @model_validator(mode="after")
    def _fits(self) -> SessionSection:
        if self.heating_s >= 60.0 / self.cycles_per_minute:
            raise ValueError("heating_s must be shorter than one cycle (60 / cycles_per_minute)")
        return self


class PwmStepSection(Section):
    duty: float = Field(ge=0.0, le=1.0)
    start_s: float = Field(ge=0.0, le=3600.0)
    heating_s: float = Field(gt=0.0, le=3600.0)
    duration_s: float = Field(gt=0.0, le=3600.0)


class PwmSweepSection(Section):
    duty_levels: list[float] = Field(min_length=1, max_length=100)
    hold_s: float = Field(gt=0.0, le=600.0)

    @model_validator(mode="after")
    def _levels(self) -> PwmSweepSection:
        for i, d in enumerate(self.duty_levels):
            if not 0.0 <= d <= 1.0:
                raise ValueError(f"duty_levels[{i}] = {d} is outside 0..1")
        return self


class ScenariosSection(Section):
    pwm_step: PwmStepSection
    pwm_sweep: PwmSweepSection


class SMAExoskeletonConfig(PlantConfig):
    drive: DriveSection
    sma: SMASection
    passive_wire: PassiveWireSection
    tendon: TendonSection
    finger: FingerSection
    muscle: MuscleSection
    contact: ContactSection
    encoder: EncoderSection
    force_sensor: ForceSensorSection
    session: SessionSection
    scenarios: ScenariosSection


def tendon_lever_m(cfg: SMAExoskeletonConfig) -> float:
    """s . r: tendon excursion per radian of the coupled MCP angle (eq 5 with eq 9)."""
    t = cfg.tendon
    return COUPLING[0] * t.mcp_radius_m + COUPLING[1] * t.pip_radius_m + COUPLING[2] * t.dip_radius_m


def chain_params(cfg: SMAExoskeletonConfig) -> dict[str, float]:
    """FingerChain parameters from Table 3: uniform rods, centre of mass mid-link (sec V)."""
    from rehab_hil.models.finger_chain import rod_link_params

    f = cfg.finger
    return rod_link_params((f.proximal_length_m, f.middle_length_m, f.distal_length_m),
                           (f.proximal_mass_kg, f.middle_mass_kg, f.distal_mass_kg),
                           (f.gravity_x_m_s2, f.gravity_y_m_s2))


def tanaka_params(cfg: SMAExoskeletonConfig) -> dict[str, float]:
    s = cfg.sma
    return dict(
        martensite_modulus_pa=s.martensite_modulus_pa, austenite_modulus_pa=s.austenite_modulus_pa,
        thermoelastic_pa_per_c=s.thermoelastic_pa_per_c, stress_influence_pa_per_c=s.stress_influence_pa_per_c,
        austenite_start_c=s.austenite_start_c, austenite_finish_c=s.austenite_finish_c,
        martensite_start_c=s.martensite_start_c, martensite_finish_c=s.martensite_finish_c,
        prestrain=s.prestrain, max_stress_pa=s.max_stress_pa, radius_m=s.radius_m, length_m=s.length_m,
        ambient_c=s.ambient_c,
    )


def muscle_params(cfg: SMAExoskeletonConfig) -> dict[str, float]:
    m = cfg.muscle
    shape = m.young if m.age_group == "young" else m.old
    return dict(max_isometric_force_n=m.max_isometric_force_n, optimal_fibre_length_m=m.optimal_fibre_length_m,
                rest_length_ratio=m.rest_length_ratio, k_pe=shape.k_pe, e_o=shape.e_o,
                moment_arm1_m=m.mcp_moment_arm_m, moment_arm2_m=m.pip_moment_arm_m,
                moment_arm3_m=m.dip_moment_arm_m)


def pad_params(cfg: SMAExoskeletonConfig) -> dict[str, float]:
    c, f = cfg.contact, cfg.finger
    return dict(stiffness_n_per_m=c.stiffness_n_per_m, damping_n_s_per_m=c.damping_n_s_per_m,
                exo_radius_m=c.exo_radius_m, finger_radius_m=c.finger_radius_m,
                length1_m=f.proximal_length_m, length2_m=f.middle_length_m, length3_m=f.distal_length_m)


def build(cfg: SMAExoskeletonConfig) -> list[Part]:
    """The coupled plant; external inputs ``pwm_duty`` and ``supply_voltage_v``."""
    s, pw = cfg.sma, cfg.passive_wire
    q = {"q1_rad": "theta_mcp_rad", "q2_rad": "theta_pip_rad", "q3_rad": "theta_dip_rad"}
    tau = {f"tau{i + 1}_nm": f"tau_{j}_nm" for i, j in enumerate(JOINTS)}
    rs = tendon_lever_m(cfg)
    exo_torque = [("sma_tension_n", rs), ("passive_tension_n", -rs)]
    parts: list[Part] = [
        SMAThermal.from_wire(
            "sma_thermal", connect={"duty": "pwm_duty", "voltage_v": "supply_voltage_v"},
            rename={"temperature_c": "sma_temperature_c"}, radius_m=s.radius_m, length_m=s.length_m,
            density_kg_m3=s.density_kg_m3, resistivity_ohm_m=s.resistivity_ohm_m,
            specific_heat_j_per_kg_c=s.specific_heat_j_per_kg_c, h1_w_per_m2_c=s.h1_w_per_m2_c,
            h2_w_per_m2_c3=s.h2_w_per_m2_c3, ambient_c=s.ambient_c),
        TendonExcursion("tendon", connect={**q, "offset_rad": "exo_offset_rad"},
                        rename={"excursion_m": "tendon_excursion_m"}, radius1_m=cfg.tendon.mcp_radius_m,
                        radius2_m=cfg.tendon.pip_radius_m, radius3_m=cfg.tendon.dip_radius_m),
        SMATanakaWire("sma_active", connect={"temperature_c": "sma_temperature_c", "excursion_m": "tendon_excursion_m"},
                      rename={"tension_n": "sma_tension_n", "stress_pa": "sma_stress_pa", "xi": "martensite_fraction"},
                      xd0=[1.0], **tanaka_params(cfg)),
        PassiveWire("sma_passive", connect={"excursion_m": "tendon_excursion_m"},
                    rename={"tension_n": "passive_tension_n"}, martensite_modulus_pa=pw.martensite_modulus_pa,
                    radius_m=pw.radius_m, length_m=pw.length_m, pretension_n=pw.pretension_n),
        ContactPad("pad", connect={"exo_torque_nm": exo_torque, **q},
                   rename={"phi_rad": "exo_offset_rad", "displacement_m": "contact_displacement_m"},
                   **pad_params(cfg)),
        ContactForce("contact", connect={"exo_torque_nm": exo_torque, **q, "phi_rad": "exo_offset_rad"},
                     rename={"force_n": "contact_force_n", "velocity_m_s": "contact_velocity_m_s",
                             **{f"tau{i + 1}_nm": f"tau_{j}_nm" for i, j in enumerate(JOINTS)}},
                     **pad_params(cfg)),
        HillPassiveMuscle("muscle", connect=q, rename={"force_n": "muscle_force_n",
                          **{f"tau{i + 1}_nm": f"tau_{j}_nm" for i, j in enumerate(JOINTS)}},
                          **muscle_params(cfg)),
    ]
    for j in JOINTS:
        parts.append(ViscousFriction(f"damping_{j}", connect={"velocity_rad_s": f"omega_{j}_rad_s"},
                                     rename={"torque_nm": f"tau_{j}_nm"},
                                     damping_nm_s_per_rad=cfg.finger.joint_damping_nm_s_per_rad))
    parts.append(CoupledFingerChain(
        "finger", connect=tau,
        rename={"q1_rad": "theta_mcp_rad", "q2_rad": "theta_pip_rad", "q3_rad": "theta_dip_rad",
                "qd1_rad_s": "omega_mcp_rad_s", "qd2_rad_s": "omega_pip_rad_s", "qd3_rad_s": "omega_dip_rad_s"},
        **chain_params(cfg)))
    for j in JOINTS:
        parts.append(Gain(f"{j}_deg", connect={"u": f"theta_{j}_rad"}, rename={"y": f"theta_{j}_deg"},
                          gain=180.0 / np.pi))
    return parts


def duty_profile(n_steps: int, step_s: float, segments: list[tuple[float, float, float]]) -> np.ndarray:
    """Per-step duty from (start_s, end_s, duty) segments; zero elsewhere."""
    t = np.arange(n_steps) * step_s
    d = np.zeros(n_steps)
    for start, end, duty in segments:
        d[(t >= start) & (t < end)] = duty
    return d


_EXTRA = ("martensite_fraction", "passive_tension_n", "muscle_force_n", "contact_displacement_m",
          "contact_velocity_m_s", "exo_offset_rad", "sma_stress_pa")


def bend_metrics(res: SimulationResult) -> dict[str, float]:
    """Peak joint angles, time to 90 % of the peak MCP angle, transformation start, peak values."""
    mcp = res["theta_mcp_deg"]
    k90 = int(np.argmax(mcp >= 0.9 * mcp.max())) if mcp.max() > 0 else 0
    xi = res.signals.get("martensite_fraction")
    k_tr = int(np.argmax(xi < 0.99)) if xi is not None and np.any(xi < 0.99) else -1
    return {
        "max_mcp_deg": float(mcp.max()), "max_pip_deg": float(res["theta_pip_deg"].max()),
        "max_dip_deg": float(res["theta_dip_deg"].max()), "t90_mcp_s": float(res.t[k90]),
        "transformation_start_s": float(res.t[k_tr]) if k_tr >= 0 else float("nan"),
        "max_temperature_c": float(res["sma_temperature_c"].max()),
        "max_tension_n": float(res["sma_tension_n"].max()),
        "max_contact_force_n": float(res["contact_force_n"].max()),
    }


def pwm_step_scenario(cfg: SMAExoskeletonConfig, duration_s: float | None = None) -> Scenario:
    """The 32 V bending experiment (Fig. 7-9): duty on for ``heating_s``, then natural cooling."""
    sc = cfg.scenarios.pwm_step
    n = SMAExoskeleton.n_steps(cfg, duration_s or sc.duration_s)
    duty = duty_profile(n, cfg.simulation.step_s, [(sc.start_s, sc.start_s + sc.heating_s, sc.duty)])
    return Scenario("pwm-step", n, inputs={"pwm_duty": duty, "supply_voltage_v": cfg.drive.supply_voltage_v},
                    extra_outputs=_EXTRA, metrics=bend_metrics)


def pwm_sweep_scenario(cfg: SMAExoskeletonConfig, duration_s: float | None = None) -> Scenario:
    """Fig. 10 as a staircase: each duty level held ``hold_s`` (heating branch only)."""
    sc = cfg.scenarios.pwm_sweep
    total = sc.hold_s * len(sc.duty_levels)
    n = SMAExoskeleton.n_steps(cfg, duration_s or total)
    segs = [(i * sc.hold_s, (i + 1) * sc.hold_s, d) for i, d in enumerate(sc.duty_levels)]
    duty = duty_profile(n, cfg.simulation.step_s, segs)

    def score(res: SimulationResult) -> dict[str, float]:
        out = {}
        for i, d in enumerate(sc.duty_levels):
            k = min(round((i + 1) * sc.hold_s / cfg.simulation.step_s) - 1, len(res.t) - 1)
            out[f"mcp_deg_at_duty_{d:.2f}"] = float(res["theta_mcp_deg"][k])
        return out

    return Scenario("pwm-sweep", n, inputs={"pwm_duty": duty, "supply_voltage_v": cfg.drive.supply_voltage_v},
                    extra_outputs=_EXTRA, metrics=score)


def session_scenario(cfg: SMAExoskeletonConfig, duration_s: float | None = None) -> Scenario:
    """Rehabilitation session: ``cycles_per_minute`` bends of ``heating_s`` at ``duty``, cooling between."""
    ss = cfg.session
    dur = duration_s or ss.duration_s
    n = SMAExoskeleton.n_steps(cfg, dur)
    period = 60.0 / ss.cycles_per_minute
    segs = [(k * period, k * period + ss.heating_s, ss.duty) for k in range(int(np.ceil(dur / period)))]
    duty = duty_profile(n, cfg.simulation.step_s, segs)

    def score(res: SimulationResult) -> dict[str, float]:
        return {"cycles": float(len(segs)), "max_mcp_deg": float(res["theta_mcp_deg"].max()),
                "min_mcp_deg_after_first": float(res["theta_mcp_deg"][res.t > period * 0.9].min())
                if dur > period else float("nan"),
                "max_temperature_c": float(res["sma_temperature_c"].max())}

    return Scenario("session", n, inputs={"pwm_duty": duty, "supply_voltage_v": cfg.drive.supply_voltage_v},
                    extra_outputs=_EXTRA, metrics=score)


def ports(cfg: SMAExoskeletonConfig) -> Ports:
    """The rig's view: PWM channel 0 switches the supply across the wire (duty -> ``pwm_duty``),
    the encoder reads the MCP angle, A0 is the Flexiforce (``force_sensor`` table); the MCP joint
    is the axis joint effects attach to."""
    fs = cfg.force_sensor
    damping = cfg.finger.joint_damping_nm_s_per_rad
    return Ports(
        actuators=(ActuatorPort(Wire("pwm_duty", (("sma_thermal", "duty"),)), "duty"),),
        axes=(AxisPort("mcp", "theta_mcp_rad", "omega_mcp_rad_s", "tau_mcp_nm", ("finger", "tau1_nm"), finger=True,
                       stick_damping_nm_s_per_rad=damping,
                       typical={"coulomb_friction.level_nm": 0.005, "viscous_friction.damping_nm_s_per_rad": 0.005,
                                "contact_spring_damper.stiffness_nm_per_rad": 0.05,
                                "contact_spring_damper.damping_nm_s_per_rad": 0.002,
                                "passive_muscle.scale_nm": 0.002, "passive_muscle.damping_nm_s_per_rad": 0.002}),),
        measured=(
            MeasuredPort("theta_mcp_deg", "angle", "deg", "encoder", Wire("theta_mcp_rad", (("mcp_deg", "u"),)),
                         counts_per_unit=cfg.encoder.counts_per_rev),
            MeasuredPort("contact_force_n", "force", "n", "adc", Wire("contact_force_n", ()),
                         counts_per_unit=fs.counts_per_n, offset_counts=fs.offset_counts),
            MeasuredPort("theta_pip_deg", "angle", "deg"), MeasuredPort("theta_dip_deg", "angle", "deg"),
            MeasuredPort("sma_tension_n", "force", "n"), MeasuredPort("sma_temperature_c", "temperature", "c"),
        ),
        transformation_temperature=(TemperatureWire(Wire("sma_temperature_c", (("sma_active", "temperature_c"),)),
                                                    cfg.sma.ambient_c),),
        constants={"supply_voltage_v": cfg.drive.supply_voltage_v},
        sums=tuple(f"tau_{j}_nm" for j in JOINTS),  # each joint: contact, passive muscle, damping
    )


class SMAExoskeleton(Plant):
    """Seed 000's SMA-driven soft finger exoskeleton on an index finger."""

    name = "sma_exoskeleton"
    config = SMAExoskeletonConfig
    inputs = INPUTS
    outputs = OUTPUTS
    build = staticmethod(build)
    ports = staticmethod(ports)
    scenarios = MappingProxyType({"pwm-step": pwm_step_scenario, "pwm-sweep": pwm_sweep_scenario,
                                  "session": session_scenario})
    fit_parameters = (  # seed 000 Table 5 (supply, h1), Table 1 (F_o): candidates of the discrepancy workflow
        FitParameter("drive.supply_voltage_v", inputs=("supply_voltage_v",)),
        FitParameter("sma.h1_w_per_m2_c", diagram=("sma_thermal.h1_w_per_m2_c",)),
        FitParameter("sma.h1_w_per_m2_c", diagram=("sma_thermal.h1_w_per_m2_c", "sma_thermal.h2_w_per_m2_c3"),
                     also=("sma.h2_w_per_m2_c3",), label="sma.convection (h1_w_per_m2_c and h2_w_per_m2_c3)"),
        FitParameter("muscle.max_isometric_force_n", diagram=("muscle.max_isometric_force_n",)),
    )

    @classmethod
    def actuator_power_w(cls, cfg: SMAExoskeletonConfig, effort: np.ndarray,
                         velocity_rad_s: np.ndarray) -> np.ndarray:
        """Joule heating U^2 tau / R of the wire (seed 000 eq 12), tau the PWM duty."""
        from rehab_hil.models.sma_thermal import wire_geometry

        s = cfg.sma
        _, r_ohm, _ = wire_geometry(s.radius_m, s.length_m, s.density_kg_m3, s.resistivity_ohm_m)
        return cfg.drive.supply_voltage_v**2 / r_ohm * np.clip(np.asarray(effort, float), 0.0, 1.0)

    excitation = Excitation(
        inputs=lambda t, rng: {"pwm_duty": random_levels(t, rng, (0.4, 0.6, 0.8, 1.0), (1.5, 4.0), 0.4),
                               "supply_voltage_v": np.full_like(t, 32.0)},
        mismatch=("damping_dip.damping_nm_s_per_rad", 1.1),
        noise={"theta_mcp_deg": 0.1, "theta_pip_deg": 0.1, "theta_dip_deg": 0.1, "contact_force_n": 0.02,
               "sma_tension_n": 0.05, "sma_temperature_c": 0.3},
    )
