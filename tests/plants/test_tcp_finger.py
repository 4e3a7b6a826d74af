"""TCP finger (seed 001): muscle force peaks, lumped thermal model, static angles, FIS/PIS,
sensitivity, config errors and rig binding."""

from __future__ import annotations

from pathlib import Path

import control
import numpy as np
import pytest

from rehab_hil.config import ConfigError
from rehab_hil.loading import load_config
from rehab_hil.models.system import Diagram
from rehab_hil.plants import get_plant, run_scenario
from rehab_hil.plants.tcp_finger import (
    JOINTS,
    TcpFinger,
    build,
    fis_scenario,
    muscle_tf,
    pulse_scenario,
    sensitivity,
    static_angles_deg,
)

CFG_PATH = Path(__file__).resolve().parents[2] / "configs" / "tcp_finger.toml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(CFG_PATH)


@pytest.fixture(scope="module")
def plant(cfg):
    diagram = Diagram(build(cfg), inputs=TcpFinger.inputs, sums=TcpFinger.ports(cfg).sums)
    return diagram, diagram.compile(cfg.simulation.step_s, cfg.simulation.substeps)


def _run(plant, scenario, params=None, outputs=None):
    _, system = plant
    inputs = {k: v for k, v in scenario.inputs.items() if k in system.input_names}
    return system.simulate(scenario.n_steps, inputs, outputs=outputs, params=params)


@pytest.mark.parametrize(("power_w", "peak_n"), [(34.0, 1.75), (40.0, 2.06), (47.0, 2.42)])
def test_tf1_tf2_force_peak_for_a_1s_pulse_matches_seed_001(cfg, plant, power_w, peak_n):
    res = _run(plant, pulse_scenario(cfg, power_w=power_w), outputs=["tcp_force_n"])
    assert np.max(res["tcp_force_n"]) == pytest.approx(peak_n, rel=0.01)
    # and python-control's series TF1*TF2 agrees with the compiled part chain
    ref = control.forced_response(muscle_tf(cfg), T=res.t, U=np.where(res.t < 1.0, power_w, 0.0)).outputs
    np.testing.assert_allclose(res["tcp_force_n"], ref, atol=2e-3 * peak_n)


@pytest.mark.slow  # compiles a second diagram structure
def test_lumped_capacitance_muscle_follows_eq_1b(cfg):
    lumped = cfg.model_copy(update={"muscle": cfg.muscle.model_copy(update={"model": "lumped"})})
    lu = lumped.muscle.lumped
    a = 1.0 / (lu.mass_kg * lu.specific_heat_j_per_kg_k)
    b = lu.convection_w_per_m2_k * lu.area_m2 * a
    sc = pulse_scenario(lumped, power_w=40.0, duration_s=10.0)
    res = run_scenario(get_plant("tcp_finger"), lumped, sc)
    rise = control.forced_response(control.tf([a], [1.0, b]), T=res.t, U=sc.inputs["power_w"]).outputs
    np.testing.assert_allclose(res["tcp_temperature_c"], lumped.muscle.ambient_c + rise, atol=1e-3 * rise.max())
    # the configured m, c_p, h, A_c reproduce Table 1's first-order TF_TP01 = 4.017 / (s + 0.05167)
    assert a == pytest.approx(4.017, rel=1e-3) and b == pytest.approx(0.05167, rel=1e-3)


def test_a_steady_tendon_force_settles_at_the_eq_6_static_angles(cfg, plant):
    diagram, system = plant
    p = system.params.copy()
    p[diagram.param_index("finger.gravity_y_m_s2")] = 0.0
    res = system.simulate(3000, {"power_w": 0.0, "measured_force_n": 3.0},
                          outputs=[f"theta_{j}_deg" for j in JOINTS], params=p)
    final = np.array([res[f"theta_{j}_deg"][-1] for j in JOINTS])
    np.testing.assert_allclose(final, static_angles_deg(cfg, 3.0), rtol=5e-3)
    # Table 2 as printed: 3 N gives ~5.5 deg at the MCP, far below Table 3's 24-31 deg
    assert static_angles_deg(cfg, 3.0)[0] == pytest.approx(5.51, abs=0.01)


def test_fis_drives_the_finger_with_the_force_alone(cfg, plant):
    res = _run(plant, fis_scenario(cfg))
    assert np.all(res["tcp_force_n"] == 0.0)  # the unpowered muscle contributes nothing
    peaks = [np.max(res[f"theta_{j}_deg"]) for j in JOINTS]
    assert peaks[0] > peaks[1] > peaks[2] > 0.0  # alpha > beta > gamma


def test_doubling_k_lowers_every_peak_angle_and_halving_raises_it(cfg):
    rows = {(r.parameter, r.factor): r for r in sensitivity(cfg, factors=[2.0, 0.5])}
    nominal = rows[("nominal", 1.0)].peak_deg
    for k in range(3):
        assert rows[("K", 2.0)].peak_deg[k] < nominal[k] < rows[("K", 0.5)].peak_deg[k]
    # seed 001 sec 5.2: inertia has "little or no effect", K the largest
    for k in range(3):
        assert rows[("inertia", 2.0)].mse_deg2[k] < rows[("K", 2.0)].mse_deg2[k]
        assert rows[("K", 0.5)].mse_deg2[k] > rows[("K", 2.0)].mse_deg2[k]


def test_an_unknown_table1_model_is_refused_naming_file_and_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(CFG_PATH.read_text().replace('thermal_tf = "TP002"', 'thermal_tf = "TP9"'))
    with pytest.raises(ConfigError, match=r"muscle\.thermal_tf") as e:
        load_config(bad)
    assert str(bad) in str(e.value)


def test_a_negative_spring_constant_is_refused(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(CFG_PATH.read_text().replace("spring_nm_per_deg = 6.12e-4", "spring_nm_per_deg = -6.12e-4"))
    with pytest.raises(ConfigError, match=r"finger\.spring_nm_per_deg"):
        load_config(bad)


def test_device_binding_maps_pwm_duty_to_power_and_reads_mcp_and_force(cfg):
    b = TcpFinger.device(cfg)
    assert b.duty_inputs["power_w"].scale == cfg.muscle.max_power_w
    assert not b.duty_inputs["power_w"].signed
    assert b.encoder_signal == "theta_mcp_rad"
    assert b.adc[0].signal == "tcp_force_n"
    produced = Diagram(b.parts, inputs=TcpFinger.inputs, sums=b.sums).signal_names
    assert "theta_mcp_rad" in produced and "tcp_force_n" in produced


def test_a_damping_that_makes_the_integrator_unstable_is_refused(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(CFG_PATH.read_text().replace("damping_nm_s_per_rad = 1.0e-3", "damping_nm_s_per_rad = 0.05"))
    with pytest.raises(ConfigError, match=r"(?i)rk4 unstable") as e:
        load_config(bad)
    assert "simulation.substeps" in str(e.value)


def test_a_muscle_transfer_function_too_fast_for_the_step_is_refused(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(CFG_PATH.read_text().replace("den = [1.0, 0.2947]", "den = [1.0, 5000.0]"))
    with pytest.raises(ConfigError, match=r"(?i)table1\.FT1") as e:
        load_config(bad)
    assert "substeps" in str(e.value)
