"""Robotic index finger driven by a TCP nylon muscle through a tendon (seed 001).

Signal chain (PIS, power input simulation, seed 001 sec 4):

    power_w -> TF1 (eq 2a) -> tcp_temperature_c -> TF2 (eq 2b) -> tcp_force_n
    tau = F e, split alpha/beta/gamma onto MCP/PIP/DIP (eq 6)
    3-link Euler-Lagrange finger M q'' + C q' + G = tau - K q - c_d q' (eq 3-5)

The lumped-capacitance model (eq 1a) can replace TF1 (``muscle.model = "lumped"``). FIS (force
input simulation) feeds a force profile on ``measured_force_n``, which the tendon adds to the
muscle's force (zero in FIS, where the power is zero). The finger chain is the shared
``FingerChain`` (full M, C, G); seed 001 kept only the diagonal of M and dropped C, which is
immaterial here (the finger is overdamped and moves quasi-statically, docs/tcp_finger.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Literal

import numpy as np

from rehab_hil.config import Field, Section, model_validator
from rehab_hil.models.finger_chain import CHAIN_PARAMS, FingerChain, chain_param_vector, mass_matrix
from rehab_hil.models.lti import lti_part
from rehab_hil.models.mechanics import TorsionSpring, ViscousFriction
from rehab_hil.models.ports import ActuatorPort, AxisPort, HeatPort, MeasuredPort, Ports, Wire
from rehab_hil.models.sensors import Gain
from rehab_hil.models.system import Diagram, Part, SimulationResult
from rehab_hil.models.tcp_tendon import TendonTorqueSplit
from rehab_hil.models.tcp_thermal import LumpedThermal
from rehab_hil.plants.experiments import Excitation, Scenario, random_levels
from rehab_hil.plants.registry import Plant
from rehab_hil.plants.sections import EncoderSection, ForceSensorSection, PlantConfig

if TYPE_CHECKING:  # python-control takes seconds to import: only where it is used
    import control

__all__ = [
    "JOINTS",
    "TcpFinger",
    "TcpFingerConfig",
    "build",
    "fastest_finger_pole",
    "muscle_tf",
    "sensitivity",
    "sensitivity_table",
    "static_angles_deg",
    "table1",
]

INPUTS = ("power_w", "measured_force_n")
OUTPUTS = ("tcp_temperature_c", "tcp_force_n", "theta_mcp_deg", "theta_pip_deg", "theta_dip_deg")
JOINTS = ("mcp", "pip", "dip")


class TFEntry(Section):
    num: list[float] = Field(min_length=1, max_length=4, description="numerator, highest power first")
    den: list[float] = Field(min_length=2, max_length=4, description="denominator, highest power first")
    fit_pct: float = Field(ge=-1000.0, le=100.0, description="fit % printed in Table 1")

    @model_validator(mode="after")
    def _proper(self) -> TFEntry:
        if len(self.num) > len(self.den):
            raise ValueError("transfer function must be proper (numerator order <= denominator order)")
        if self.den[0] == 0.0:
            raise ValueError("leading denominator coefficient must be non-zero")
        return self


class LumpedSection(Section):
    mass_kg: float = Field(gt=0.0, le=0.1, description="m of eq 1a")
    specific_heat_j_per_kg_k: float = Field(gt=0.0, le=10000.0, description="c_p of eq 1a")
    convection_w_per_m2_k: float = Field(ge=0.0, le=1000.0, description="h of eq 1a")
    area_m2: float = Field(gt=0.0, le=1.0, description="A_c of eq 1a")


class MuscleSection(Section):
    model: Literal["transfer_function", "lumped"]
    thermal_tf: str = Field(min_length=1, description="Table 1 entry used as TF1 (eq 2a)")
    force_tf: str = Field(min_length=1, description="Table 1 entry used as TF2 (eq 2b)")
    ambient_c: float = Field(ge=-40.0, le=60.0)
    max_power_w: float = Field(gt=0.0, le=500.0, description="power at PWM duty 1")
    lumped: LumpedSection


class FingerSection(Section):
    link_lengths_m: list[float] = Field(min_length=3, max_length=3)
    link_masses_kg: list[float] = Field(min_length=3, max_length=3)
    link_inertias_kg_m2: list[float] = Field(min_length=3, max_length=3)
    gravity_m_s2: list[float] = Field(min_length=2, max_length=2)
    spring_nm_per_deg: float = Field(gt=0.0, le=1.0, description="K of every joint (Table 2)")
    damping_nm_s_per_rad: float = Field(ge=0.0, le=1.0, description="c_d of every joint (Table 2)")

    @model_validator(mode="after")
    def _positive(self) -> FingerSection:
        for key in ("link_lengths_m", "link_masses_kg", "link_inertias_kg_m2"):
            if any(not (0.0 < v < 10.0) for v in getattr(self, key)):
                raise ValueError(f"{key}: every value must be positive (and below 10)")
        return self


class TendonSection(Section):
    moment_arm_m: float = Field(gt=0.0, le=0.2, description="e of eq 6")
    alpha: float = Field(ge=0.0, le=10.0)
    beta: float = Field(ge=0.0, le=10.0)
    gamma: float = Field(ge=0.0, le=10.0)


class PulseSection(Section):
    power_w: float = Field(ge=0.0, le=200.0)
    on_s: float = Field(gt=0.0, le=600.0)
    duration_s: float = Field(gt=0.0, le=3600.0)


class RegularSection(PulseSection):
    off_s: float = Field(ge=0.0, le=3600.0)


class FisSection(Section):
    force_n: float = Field(ge=0.0, le=100.0)
    on_s: float = Field(gt=0.0, le=600.0)
    duration_s: float = Field(gt=0.0, le=3600.0)


class ScenariosSection(Section):
    pulse: PulseSection
    regular: RegularSection
    fis: FisSection


class SensitivitySection(Section):
    power_w: float = Field(gt=0.0, le=200.0)
    factors: list[float] = Field(min_length=1, max_length=8)


class TcpFingerConfig(PlantConfig):
    muscle: MuscleSection
    table1: dict[str, TFEntry]
    finger: FingerSection
    tendon: TendonSection
    scenarios: ScenariosSection
    sensitivity: SensitivitySection
    encoder: EncoderSection
    force_sensor: ForceSensorSection

    @model_validator(mode="after")
    def _chosen_tfs_exist(self) -> TcpFingerConfig:
        for key in ("thermal_tf", "force_tf"):
            name = getattr(self.muscle, key)
            if name not in self.table1:
                raise ValueError(f"muscle.{key} = {name!r} is not a [table1] entry ({sorted(self.table1)})")
        h = self.simulation.step_s / self.simulation.substeps
        for key in ("thermal_tf", "force_tf"):
            name = getattr(self.muscle, key)
            pole = float(np.max(np.abs(np.roots(self.table1[name].den))))
            if pole * h > RK4_LIMIT:
                raise ValueError(f"table1.{name} (muscle.{key}) has a pole at {pole:.4g} 1/s: RK4 is unstable at "
                                 f"h = {h:g} s; raise simulation.substeps")
        fastest = fastest_finger_pole(self)
        if fastest * h > RK4_LIMIT:
            raise ValueError(f"finger: the stiffest joint mode ({fastest:.4g} 1/s) makes RK4 unstable at "
                             f"h = {h:g} s ({fastest * h:.3g} > {RK4_LIMIT}); raise simulation.substeps "
                             f"or lower finger.damping_nm_s_per_rad")
        return self


RK4_LIMIT = 2.5  # |lambda h| below RK4's real-axis stability bound 2.785, with a margin


def fastest_finger_pole(cfg: TcpFingerConfig) -> float:
    """Largest |eigenvalue| of the finger linearised at rest: M(0) q'' + c_d q' + K q = 0 (eq 5 with
    eq 3's springs and damping), in 1/s; decides the largest stable RK4 step."""
    M = np.empty((3, 3))
    mass_matrix(np.zeros(3), chain_param_vector(_chain_params(cfg)), M)
    k = cfg.finger.spring_nm_per_deg * 180.0 / math.pi
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [-k * Minv, -cfg.finger.damping_nm_s_per_rad * Minv]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def table1(cfg: TcpFingerConfig) -> dict[str, control.TransferFunction]:
    """Every transfer function of seed 001 Table 1 as a python-control object."""
    import control

    return {name: control.tf(e.num, e.den, name=name) for name, e in cfg.table1.items()}


def muscle_tf(cfg: TcpFingerConfig) -> control.TransferFunction:
    """TF1 * TF2: power [W] -> force [N], the electro-thermo-mechanical muscle (seed 001 Fig. 5(iii))."""

    tfs = table1(cfg)
    return tfs[cfg.muscle.thermal_tf] * tfs[cfg.muscle.force_tf]


def _chain_params(cfg: TcpFingerConfig) -> dict[str, float]:
    f = cfg.finger
    values = [*f.link_lengths_m, *f.link_masses_kg, *(0.5 * v for v in f.link_lengths_m),
              *f.link_inertias_kg_m2, *f.gravity_m_s2]
    return dict(zip(CHAIN_PARAMS, values, strict=True))


def _muscle(cfg: TcpFingerConfig) -> list[Part]:
    m = cfg.muscle
    tfs = table1(cfg)
    if m.model == "transfer_function":
        thermal: Part = lti_part("tf1", tfs[m.thermal_tf], u0=0.0, y0=m.ambient_c,
                                 connect={"u": "power_w"}, rename={"y": "tcp_temperature_c"})
    else:
        lu = m.lumped
        thermal = LumpedThermal("thermal", connect={"power_w": "power_w"},
                                rename={"temperature_c": "tcp_temperature_c",
                                        "temperature_rise_k": "tcp_temperature_rise_k"},
                                mass_kg=lu.mass_kg, specific_heat_j_per_kg_k=lu.specific_heat_j_per_kg_k,
                                convection_w_per_m2_k=lu.convection_w_per_m2_k, area_m2=lu.area_m2,
                                ambient_c=m.ambient_c)
    force = lti_part("tf2", tfs[m.force_tf], u0=m.ambient_c, y0=0.0,
                     connect={"u": "tcp_temperature_c"}, rename={"y": "tcp_force_n"})
    return [thermal, force]


def build(cfg: TcpFingerConfig) -> list[Part]:
    """The plant as parts; external inputs ``power_w`` (PIS) and ``measured_force_n`` (FIS)."""
    f, td = cfg.finger, cfg.tendon
    k_rad = f.spring_nm_per_deg * 180.0 / math.pi
    parts = [
        *_muscle(cfg),
        TendonTorqueSplit("tendon", connect={"force_n": ["tcp_force_n", "measured_force_n"]},
                          moment_arm_m=td.moment_arm_m, alpha=td.alpha, beta=td.beta, gamma=td.gamma),
        FingerChain("finger", rename={f"q{i}_rad": f"theta_{j}_rad" for i, j in enumerate(JOINTS, 1)}
                    | {f"qd{i}_rad_s": f"omega_{j}_rad_s" for i, j in enumerate(JOINTS, 1)},
                    **_chain_params(cfg)),
    ]
    for i, j in enumerate(JOINTS, 1):
        parts += [
            TorsionSpring(f"spring_{j}", connect={"angle_rad": f"theta_{j}_rad"}, rename={"torque_nm": f"tau{i}_nm"},
                          stiffness_nm_per_rad=k_rad, rest_angle_rad=0.0),
            ViscousFriction(f"damping_{j}", connect={"velocity_rad_s": f"omega_{j}_rad_s"},
                            rename={"torque_nm": f"tau{i}_nm"}, damping_nm_s_per_rad=f.damping_nm_s_per_rad),
            Gain(f"deg_{j}", connect={"u": f"theta_{j}_rad"}, rename={"y": f"theta_{j}_deg"}, gain=180.0 / math.pi),
        ]
    return parts


def static_angles_deg(cfg: TcpFingerConfig, force_n: float, moment_arm_m: float | None = None) -> np.ndarray:
    """Rest angles under a steady tendon force without gravity: theta_k = fraction_k F e / K (eq 5-6
    with q' = q'' = 0, phi_k = K q_k)."""
    e = cfg.tendon.moment_arm_m if moment_arm_m is None else moment_arm_m
    fractions = np.array([cfg.tendon.alpha, cfg.tendon.beta, cfg.tendon.gamma])
    return fractions * force_n * e / cfg.finger.spring_nm_per_deg


def _square(cfg: TcpFingerConfig, n: int, level: float, on_s: float, period_s: float | None = None) -> np.ndarray:
    t = np.arange(n) * cfg.simulation.step_s
    phase = t if period_s is None else np.mod(t, period_s)
    return np.where(phase < on_s - 1e-12, level, 0.0)


def _peaks(res: SimulationResult) -> dict[str, float]:
    out = {f"peak_{j}_deg": float(np.max(res[f"theta_{j}_deg"])) for j in JOINTS}
    out["peak_force_n"] = float(np.max(res["tcp_force_n"]))
    if "tcp_temperature_c" in res.signals:
        out["peak_temperature_c"] = float(np.max(res["tcp_temperature_c"]))
    return out


def pulse_scenario(cfg: TcpFingerConfig, duration_s: float | None = None, power_w: float | None = None) -> Scenario:
    """PIS, pulsed actuation: power_w for on_s (1 s), then natural cooling (seed 001 sec 3.1, 5.1)."""
    sc = cfg.scenarios.pulse
    n = TcpFinger.n_steps(cfg, duration_s or sc.duration_s)
    p = sc.power_w if power_w is None else power_w
    return Scenario("pulse", n, inputs={"power_w": _square(cfg, n, p, sc.on_s), "measured_force_n": 0.0},
                    metrics=_peaks)


def regular_scenario(cfg: TcpFingerConfig, duration_s: float | None = None,
                     power_w: float | None = None) -> Scenario:
    """PIS, regular actuation: a square wave of power (on_s on, off_s off) over duration_s."""
    sc = cfg.scenarios.regular
    n = TcpFinger.n_steps(cfg, duration_s or sc.duration_s)
    p = sc.power_w if power_w is None else power_w
    return Scenario("regular", n, inputs={"power_w": _square(cfg, n, p, sc.on_s, sc.on_s + sc.off_s),
                                          "measured_force_n": 0.0}, metrics=_peaks)


def fis_scenario(cfg: TcpFingerConfig, duration_s: float | None = None, force_n: float | None = None) -> Scenario:
    """FIS: a tendon force pulse (Table 2: 3 N) drives the finger; the muscle is unpowered."""
    sc = cfg.scenarios.fis
    n = TcpFinger.n_steps(cfg, duration_s or sc.duration_s)
    f = sc.force_n if force_n is None else force_n
    return Scenario("fis", n, inputs={"power_w": 0.0, "measured_force_n": _square(cfg, n, f, sc.on_s)},
                    extra_outputs=("measured_force_n",), metrics=_peaks)


@dataclass(frozen=True)
class SensitivityRow:
    """One parameter variation: MSE [deg^2] and peak angle [deg] of each joint vs the nominal run."""

    parameter: str
    factor: float
    mse_deg2: tuple[float, float, float]
    peak_deg: tuple[float, float, float]


_SENS_GROUPS = {
    "mass": [f"finger.mass{i}_kg" for i in (1, 2, 3)],
    "inertia": [f"finger.inertia{i}_kg_m2" for i in (1, 2, 3)],
    "damping": [f"damping_{j}.damping_nm_s_per_rad" for j in JOINTS],
    "K": [f"spring_{j}.stiffness_nm_per_rad" for j in JOINTS],
}


def sensitivity(cfg: TcpFingerConfig, power_w: float | None = None,
                factors: Sequence[float] | None = None) -> list[SensitivityRow]:
    """Seed 001 sec 5.2: scale link mass, inertia, damping and K; MSE of each joint angle against
    the nominal PIS pulse. One compiled diagram, every variation passed as a parameter vector."""
    power = cfg.sensitivity.power_w if power_w is None else power_w
    factors = list(cfg.sensitivity.factors if factors is None else factors)
    sc = pulse_scenario(cfg, power_w=power)
    diagram = Diagram(build(cfg), inputs=INPUTS, sums=ports(cfg).sums)
    system = diagram.compile(cfg.simulation.step_s, cfg.simulation.substeps)
    outputs = [f"theta_{j}_deg" for j in JOINTS]
    inputs = {k: v for k, v in sc.inputs.items() if k in system.input_names}

    def run(p: np.ndarray) -> np.ndarray:
        res = system.simulate(sc.n_steps, inputs, outputs=outputs, params=p)
        return np.column_stack([res[o] for o in outputs])

    nominal = run(system.params)
    rows = [SensitivityRow("nominal", 1.0, (0.0, 0.0, 0.0), tuple(float(v) for v in nominal.max(axis=0)))]
    for name, keys in _SENS_GROUPS.items():
        for fac in factors:
            p = system.params.copy()
            for key in keys:
                p[diagram.param_index(key)] *= fac
            ang = run(p)
            mse = np.mean((ang - nominal) ** 2, axis=0)
            rows.append(SensitivityRow(name, float(fac), tuple(float(v) for v in mse),
                                       tuple(float(v) for v in ang.max(axis=0))))
    return rows


def sensitivity_table(rows: Sequence[SensitivityRow]) -> str:
    """The rows as text: MSE [deg^2] and peak angle [deg] per joint (seed 001 Fig. 11-12)."""
    head = (f"{'parameter':>10} {'factor':>6} | {'MSE MCP':>9} {'MSE PIP':>9} {'MSE DIP':>9} | "
            f"{'peak MCP':>8} {'peak PIP':>8} {'peak DIP':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r.parameter:>10} {r.factor:6.2f} | " + " ".join(f"{v:9.4g}" for v in r.mse_deg2)
                     + " | " + " ".join(f"{v:8.3f}" for v in r.peak_deg))
    return "\n".join(lines)


def ports(cfg: TcpFingerConfig) -> Ports:
    """The rig's view: PWM channel 0 heats the muscle (power_w = max_power_w x duty); the encoder
    reads the MCP joint; A0 reads the tendon force (``force_sensor`` table). Heat and the actuator
    enter whichever thermal model the config chose."""
    fs, m = cfg.force_sensor, cfg.muscle
    heat_in = ("tf1", "u") if m.model == "transfer_function" else ("thermal", "power_w")
    return Ports(
        actuators=(ActuatorPort(Wire("power_w", (heat_in,)), "w", duty_scale=m.max_power_w),),
        axes=(AxisPort("mcp", "theta_mcp_rad", "omega_mcp_rad_s", "tau1_nm", ("finger", "tau1_nm"), finger=True,
                       stick_damping_nm_s_per_rad=cfg.finger.damping_nm_s_per_rad,
                       typical={"coulomb_friction.level_nm": 0.002, "viscous_friction.damping_nm_s_per_rad": 0.0005,
                                "contact_spring_damper.stiffness_nm_per_rad": 0.01,
                                "contact_spring_damper.damping_nm_s_per_rad": 0.0002,
                                "passive_muscle.scale_nm": 0.001, "passive_muscle.damping_nm_s_per_rad": 0.0002}),),
        measured=(
            MeasuredPort("theta_mcp_deg", "angle", "deg", "encoder", Wire("theta_mcp_rad", (("deg_mcp", "u"),)),
                         counts_per_unit=cfg.encoder.counts_per_rev),
            MeasuredPort("tcp_force_n", "force", "n", "adc", Wire("tcp_force_n", ()),
                         counts_per_unit=fs.counts_per_n, offset_counts=fs.offset_counts),
            MeasuredPort("tcp_temperature_c", "temperature", "c"),
            MeasuredPort("theta_pip_deg", "angle", "deg"), MeasuredPort("theta_dip_deg", "angle", "deg"),
        ),
        heat=(HeatPort("tcp_temperature_c", heat_in, m.ambient_c),),
        constants={"measured_force_n": 0.0},
        sums=tuple(f"tau{i}_nm" for i in range(1, len(JOINTS) + 1)),  # each joint: tendon, spring, damping
    )


class TcpFinger(Plant):
    """Seed 001's robotic index finger driven by a TCP nylon muscle."""

    name = "tcp_finger"
    config = TcpFingerConfig
    inputs = INPUTS
    outputs = OUTPUTS
    optional_inputs = ("measured_force_n",)  # used only in FIS runs
    build = staticmethod(build)
    ports = staticmethod(ports)
    scenarios = MappingProxyType({"pulse": pulse_scenario, "regular": regular_scenario, "fis": fis_scenario})

    @classmethod
    def actuator_power_w(cls, cfg: TcpFingerConfig, effort: np.ndarray, velocity_rad_s: np.ndarray) -> np.ndarray:
        """The actuator input is the electrical power itself (seed 001's PIS)."""
        return np.maximum(np.asarray(effort, float), 0.0)

    excitation = Excitation(
        inputs=lambda t, rng: {"power_w": random_levels(t, rng, (34.0, 40.0, 47.0), (1.0, 4.0), 0.5),
                               "measured_force_n": np.zeros_like(t)},
        mismatch=("damping_dip.damping_nm_s_per_rad", 1.1),
        noise={"tcp_temperature_c": 0.2, "tcp_force_n": 0.01, "theta_mcp_deg": 0.1, "theta_pip_deg": 0.1,
               "theta_dip_deg": 0.1},
    )
