"""The generic one-axis drive (plants/motor_axis.py) against its closed-form behaviour, and its
config: the EMPS reference model (configs/emps.toml) and the same axis declared rotary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.config import ConfigError, load_toml
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant, run_scenario
from rehab_hil.plants.experiments import Scenario
from rehab_hil.plants.motor_axis import MotorAxisConfig, axis_values
from rehab_hil.testing import servo_axis_config

ROOT = Path(__file__).resolve().parents[2]
EMPS = ROOT / "configs" / "emps.toml"


def _run(cfg: MotorAxisConfig, volts: float, seconds: float) -> np.ndarray:
    spec = get_plant("motor_axis")
    n = spec.n_steps(cfg, seconds)
    res = run_scenario(spec, cfg, Scenario("const", n, inputs={"drive_input_v": np.full(n, volts)}))
    return res["position_m"] if cfg.load.kind == "linear" else np.radians(res["angle_deg"])


def _with(path: Path, tmp_path: Path, edit) -> MotorAxisConfig:
    text = edit(path.read_text())
    out = tmp_path / "axis.toml"
    out.write_text(text)
    return load_config(out)  # type: ignore[return-value]


def test_a_constant_drive_reaches_the_speed_where_drive_equals_viscous_coulomb_and_offset() -> None:
    cfg = load_config(EMPS)
    v = axis_values(cfg)  # type: ignore[arg-type]
    q = _run(cfg, 2.0, 6.0)  # M / Fv = 0.47 s: steady after 6 s
    speed = (q[-1] - q[-1001]) / 1.0
    expected = (v["gain"] * 2.0 - v["coulomb"] - v["offset"]) / v["viscous"]
    assert speed == pytest.approx(expected, rel=2e-3)


def test_the_drive_input_saturates_at_the_drive_range() -> None:
    cfg = load_config(EMPS)
    assert np.allclose(_run(cfg, 25.0, 1.0), _run(cfg, 10.0, 1.0))
    assert not np.allclose(_run(cfg, 9.0, 1.0), _run(cfg, 10.0, 1.0))


def test_coulomb_friction_above_the_drive_force_holds_the_load_still() -> None:
    cfg = load_config(EMPS)
    v = axis_values(cfg)  # type: ignore[arg-type]
    volts = 0.9 * (v["coulomb"] + v["offset"]) / v["gain"]  # the offset pushes the same way as a positive drive
    q = _run(cfg, volts, 1.0)
    assert np.ptp(q) < 1e-6


def test_a_rotary_axis_through_a_transmission_reflects_the_rotor_inertia(tmp_path: Path) -> None:
    def rotary(text: str) -> str:
        text = text.replace('kind = "linear"', 'kind = "rotary"').replace("mass_kg = 95.1089", "inertia_kg_m2 = 0.5")
        text = text.replace("viscous_n_s_per_m = 203.5034", "viscous_nm_s_per_rad = 0.0")
        text = text.replace("coulomb_n ", "coulomb_nm ")
        text = text.replace("offset_n ", "offset_nm ").replace("force_constant_n_per_v", "torque_constant_nm_per_v")
        text = text.replace('feedback = "position_m"', 'feedback = "angle_deg"')
        return text.replace("[drive]", "[transmission]\nratio = 10.0\nrotor_inertia_kg_m2 = 0.002\n\n[drive]")
    cfg = _with(EMPS, tmp_path, rotary)
    v = axis_values(cfg)
    assert v["inertia"] == pytest.approx(0.5 + 0.002 * 100.0)
    assert v["gain"] == pytest.approx(351.5065188)
    q = _run(cfg, 0.5, 0.05)  # no viscous friction: q = F t^2 / (2 J)
    force = v["gain"] * 0.5 - v["coulomb"] - v["offset"]
    assert q[-1] - q[0] == pytest.approx(force * 0.05**2 / (2 * v["inertia"]), rel=0.05)


def test_a_linear_load_given_a_rotary_key_is_refused_naming_the_key(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(EMPS.read_text().replace("mass_kg = 95.1089", "mass_kg = 95.1089\ninertia_kg_m2 = 1.0"))
    with pytest.raises(ConfigError, match=r"bad.toml: load: .*inertia_kg_m2"):
        load_config(bad)


def test_the_nominal_config_is_the_reference_without_coulomb_and_offset() -> None:
    ref, nom = load_toml(EMPS), load_toml(ROOT / "configs" / "emps_nominal.toml")
    assert nom["load"]["coulomb_n"] == 0.0 and nom["load"]["offset_n"] == 0.0
    for key in ("mass_kg", "viscous_n_s_per_m"):
        assert nom["load"][key] == ref["load"][key]
    assert nom["drive"] == ref["drive"] and nom["recorded_controller"] == ref["recorded_controller"]


def test_the_recorded_controller_holds_a_step_within_the_offset_over_the_loop_stiffness() -> None:
    cfg = load_config(EMPS)
    spec = get_plant("motor_axis")
    res = run_scenario(spec, cfg, spec.scenarios["step"](cfg, 2.0))
    v = axis_values(cfg)  # type: ignore[arg-type]
    rc = cfg.recorded_controller
    stiffness = rc.kp_per_s * rc.kv_effort_s_per_unit * v["gain"]  # N/m of the P position loop
    # at rest Coulomb friction holds up to Fc: the error is within (|offset| + Fc) / stiffness of the target
    err = abs(res["position_m"][-1] - cfg.step_reference)
    assert err <= (abs(v["offset"]) + v["coulomb"]) / stiffness + 1e-9
    assert abs(res["drive_input_v"]).max() == pytest.approx(10.0)  # the step saturates the drive at first




def _servo(tmp_path: Path, drive: str) -> MotorAxisConfig:
    return load_config(servo_axis_config(tmp_path / "servo.toml", load="coulomb_nm = 0.02", drive=drive))  # type: ignore[return-value]


def _steady_speed(cfg: MotorAxisConfig, signal: str, value: float) -> tuple[float, np.ndarray]:
    spec = get_plant("motor_axis")
    n = spec.n_steps(cfg, 12.0)
    res = run_scenario(spec, cfg, Scenario("const", n, inputs={signal: np.full(n, value)}))
    return float(np.mean(res["velocity_rad_s"][-1000:])), res


def test_a_drive_commanded_in_torque_takes_newton_metres_as_its_input(tmp_path: Path) -> None:
    cfg = _servo(tmp_path, 'command = "torque"\nsaturation_nm = 0.2')
    assert get_plant("motor_axis").input_signals(cfg) == ("drive_torque_nm",)
    speed, res = _steady_speed(cfg, "drive_torque_nm", 0.05)
    assert speed == pytest.approx((0.05 - 0.02) / 4.0e-4, rel=2e-3)  # 75 rad/s: torque = Fc + Fv w
    # the tachometer output is the angle's rate (deg -> rad)
    rate = np.gradient(np.radians(res["angle_deg"]), 1e-3)
    assert np.allclose(res["velocity_rad_s"][100:-100], rate[100:-100], rtol=1e-3, atol=1e-3)
    assert _steady_speed(cfg, "drive_torque_nm", 1.0)[0] == pytest.approx((0.2 - 0.02) / 4.0e-4, rel=2e-3)


def test_a_drive_commanded_in_current_multiplies_it_by_its_torque_constant(tmp_path: Path) -> None:
    cfg = _servo(tmp_path, 'command = "current"\ntorque_constant_nm_per_a = 0.05\nsaturation_a = 3.0')
    assert get_plant("motor_axis").input_signals(cfg) == ("drive_current_a",)
    speed, _ = _steady_speed(cfg, "drive_current_a", 1.0)
    assert speed == pytest.approx((0.05 * 1.0 - 0.02) / 4.0e-4, rel=2e-3)


def test_a_current_command_without_its_torque_constant_is_a_config_error_naming_the_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"drive.torque_constant_nm_per_a is needed .*commanded in current"):
        _servo(tmp_path, 'command = "current"\nsaturation_a = 3.0')
    with pytest.raises(ConfigError, match=r"drive.saturation_nm is needed: the range of the torque command"):
        _servo(tmp_path, 'command = "torque"')
