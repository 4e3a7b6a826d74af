"""A fourth plant is one module: a toy rotor declared here registers itself, loads its config,
simulates, takes library effects through its ports and sits behind the simulated rig's I/O."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np
import pytest

from rehab_hil.config import Field, Section
from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.loading import load_config
from rehab_hil.models.mechanics import RotaryInertia, ViscousFriction
from rehab_hil.models.ports import ActuatorPort, AxisPort, MeasuredPort, Ports, Wire
from rehab_hil.models.sensors import Gain
from rehab_hil.plants import registry
from rehab_hil.plants.experiments import Scenario
from rehab_hil.plants.registry import Plant, compose, get_plant
from rehab_hil.plants.sections import EffectSpec, EncoderSection, PlantConfig

TOY_TOML = """
plant = "toy_rotor"

[simulation]
step_s = 0.001
substeps = 2

[rotor]
inertia_kg_m2 = 0.001
damping_nm_s_per_rad = 0.01
max_torque_nm = 0.05

[encoder]
counts_per_rev = 4096

[rig]
port = "sim"
baud = 1000000
sample_rate_hz = 1000.0
watchdog_ms = 50

[rig.limits]
max_duty = 1.0
min_angle_deg = -360.0
max_angle_deg = 360.0
max_force_n = 50.0
max_heating_s = 60.0
max_temperature_c = 100.0
link_loss_periods = 50
stuck_sensor_s = 0.0
stuck_min_duty = 0.5
stuck_min_error_deg = 10.0
stuck_min_motion_deg = 1.0
"""


class RotorSection(Section):
    inertia_kg_m2: float = Field(gt=0.0, le=1.0)
    damping_nm_s_per_rad: float = Field(ge=0.0, le=10.0)
    max_torque_nm: float = Field(gt=0.0, le=10.0, description="torque at PWM duty 1")


class ToyConfig(PlantConfig):
    rotor: RotorSection
    encoder: EncoderSection


def _build(cfg: ToyConfig) -> list:
    r = cfg.rotor
    return [
        RotaryInertia("rotor", connect={"torque_nm": "rotor_torque_nm"},
                      rename={"angle_rad": "rotor_angle_rad", "velocity_rad_s": "rotor_velocity_rad_s"},
                      inertia_kg_m2=r.inertia_kg_m2),
        Gain("drive", connect={"u": "drive_torque_nm"}, rename={"y": "rotor_torque_nm"}, gain=1.0),
        ViscousFriction("damping", connect={"velocity_rad_s": "rotor_velocity_rad_s"},
                        rename={"torque_nm": "rotor_torque_nm"}, damping_nm_s_per_rad=r.damping_nm_s_per_rad),
        Gain("deg", connect={"u": "rotor_angle_rad"}, rename={"y": "rotor_angle_deg"}, gain=180.0 / np.pi),
    ]


def _ports(cfg: ToyConfig) -> Ports:
    return Ports(
        actuators=(ActuatorPort(Wire("drive_torque_nm", (("drive", "u"),)), "nm",
                                duty_scale=cfg.rotor.max_torque_nm),),
        axes=(AxisPort("rotor", "rotor_angle_rad", "rotor_velocity_rad_s", "rotor_torque_nm", ("rotor", "torque_nm"),
                       stick_damping_nm_s_per_rad=0.01),),
        measured=(MeasuredPort("rotor_angle_deg", "angle", "deg", "encoder",
                               Wire("rotor_angle_rad", (("deg", "u"),)), counts_per_unit=cfg.encoder.counts_per_rev),),
        sums=("rotor_torque_nm",),  # the drive and the damping
    )


def _spin(cfg: ToyConfig, duration_s: float | None = None) -> Scenario:
    n = ToyRotor.n_steps(cfg, duration_s or 1.0)
    return Scenario("spin", n, inputs={"drive_torque_nm": 0.02})


class ToyRotor(Plant, register=False):
    name = "toy_rotor"
    config = ToyConfig
    inputs = ("drive_torque_nm",)
    outputs = ("rotor_angle_deg",)
    build = staticmethod(_build)
    ports = staticmethod(_ports)
    scenarios = MappingProxyType({"spin": _spin})


@pytest.fixture
def toy(tmp_path):
    """The toy plant registered (as a plant module's class statement would) for one test."""
    registry._REGISTRY[ToyRotor.name] = ToyRotor
    path = tmp_path / "toy.toml"
    path.write_text(TOY_TOML)
    yield path
    del registry._REGISTRY[ToyRotor.name]


def test_a_registered_toy_plant_loads_and_simulates_to_its_analytic_speed(toy):
    cfg = load_config(toy)
    assert isinstance(cfg, ToyConfig) and get_plant("toy_rotor") is ToyRotor
    res = registry.run_scenario(ToyRotor, cfg, ToyRotor.scenarios["spin"](cfg, 2.0))
    speed = np.gradient(np.deg2rad(res["rotor_angle_deg"]), res.t)[-10]
    assert speed == pytest.approx(0.02 / cfg.rotor.damping_nm_s_per_rad, rel=0.02)  # T / b after 20 tau


def test_library_effects_attach_to_the_toy_plant_through_its_ports(toy):
    cfg = load_config(toy)
    assert {"coulomb_friction", "viscous_friction", "backlash", "time_delay",
            "contact_spring_damper"} <= set(ToyRotor.applicable_effects(cfg))
    assert "sma_hysteresis" not in ToyRotor.applicable_effects(cfg)
    stuck = cfg.model_copy(update={"effects": [EffectSpec(name="coulomb_friction", params={"level_nm": 0.03})]})
    res = registry.run_scenario(ToyRotor, stuck, ToyRotor.scenarios["spin"](stuck))
    assert np.ptp(res["rotor_angle_deg"]) < 1e-6  # 0.02 N m cannot break 0.03 N m of stiction


def test_the_toy_plant_sits_behind_the_simulated_rig_io(toy):
    cfg = load_config(toy)
    binding = ToyRotor.device(cfg)
    assert binding.encoder_signal == "rotor_angle_rad" and binding.duty_inputs["drive_torque_nm"].scale == 0.05
    assert [p.name for p in binding.parts] == [p.name for p in compose(ToyRotor, cfg)]
    io = PlantIO(binding)
    counts = [io.tick([10000, 0], 0)[0] for _ in range(500)]
    assert counts[0] == 0 and counts[-1] > 0  # full duty spins it forward


def test_a_config_effect_the_toy_has_no_port_for_is_refused_naming_the_key(toy):
    toy.write_text(TOY_TOML + '\n[[effects]]\nname = "sma_hysteresis"\nparams = { width_c = 5.0 }\n')
    with pytest.raises(ValueError, match=r"effects\.0\.name: effect 'sma_hysteresis' does not apply to plant "
                                         r"'toy_rotor' \(it needs a 'transformation_temperature' port\)"):
        load_config(toy)
