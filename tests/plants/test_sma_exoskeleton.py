"""SMA exoskeleton plant (seed 000): config validation, the coupled bend, hysteresis, rig binding, CLI."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.analysis.sma_experiments import compile_plant
from rehab_hil.config import ConfigError
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.plants import sma_exoskeleton as sx

CFG_PATH = Path(__file__).resolve().parents[2] / "configs" / "sma_exoskeleton.toml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(CFG_PATH)


@pytest.fixture(scope="module")
def system(cfg):
    return compile_plant(cfg)


def test_config_loads_into_the_registered_schema(cfg):
    assert isinstance(cfg, sx.SMAExoskeletonConfig)
    spec = get_plant("sma_exoskeleton")
    assert set(spec.scenarios) == {"pwm-step", "pwm-sweep", "session"}
    assert spec.inputs == ("pwm_duty", "supply_voltage_v")


@pytest.mark.parametrize(("old", "new", "key", "words"), [
    ("radius_m = 0.00015                  # r_SMA", "radius_m = -0.00015 #", "sma.radius_m", "greater than"),
    ("austenite_start_c = 66.0", "austenite_start_c = 80.0", "sma", "A_s < A_f"),
    ("martensite_finish_c = 42.0", "martensite_finish_c = 60.0", "sma", "M_f < M_s"),
    ("prestrain = 0.0117", "prestrain = 0.08", "sma", "eps_L"),
    ("pwm_duty = 1.0", "pwm_duty = 1.5", "drive.pwm_duty", "less than or equal"),
    ("duty_levels = [0.4,", "duty_levels = [-0.1,", "scenarios.pwm_sweep", "outside 0..1"),
    ("damping_n_s_per_m = 50.0", "damping_n_s_per_m = -373.0", "contact.damping_n_s_per_m", "greater than"),
    ('age_group = "young"', 'age_group = "middle"', "muscle.age_group", ""),
    ("heating_s = 5.0                     # 5 s bend", "heating_s = 13.0 #", "session", "shorter than one cycle"),
])
def test_bad_parameters_are_rejected_naming_the_key(tmp_path, old, new, key, words):
    text = CFG_PATH.read_text()
    assert old in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_config(bad)
    assert err.value.key == key
    assert str(bad) in str(err.value) and words.lower() in err.value.message.lower()


@pytest.mark.slow
def test_pwm_step_bends_all_joints_with_the_eq9_ratios_and_the_finger_returns_when_cooled(cfg, system):
    sc = sx.pwm_step_scenario(cfg)
    res = system.simulate(sc.n_steps, sc.inputs, outputs=list(sx.OUTPUTS))
    mcp = res["theta_mcp_deg"]
    assert res["sma_temperature_c"][0] == pytest.approx(cfg.sma.ambient_c)
    assert 20.0 < mcp.max() < 60.0  # a real bend, of the order of seed 000's 37.5 deg
    np.testing.assert_allclose(res["theta_pip_deg"], 1.2 * mcp, atol=1e-9)
    np.testing.assert_allclose(res["theta_dip_deg"], 0.8 * mcp, atol=1e-9)
    assert mcp[res.t < 0.1].max() < 1.0  # nothing happens before the wire reaches A_s
    assert mcp[-1] < 0.05 * mcp.max()  # cooled back to martensite: the passive wire extends it
    assert res["sma_tension_n"].max() > 0 and res["contact_force_n"].max() > 0


@pytest.mark.slow
def test_angle_at_one_temperature_differs_heating_and_cooling(cfg, system):
    """Quasi-static duty ramp up then down: thermal hysteresis of the whole plant."""
    n = 30000
    duty = np.concatenate([np.linspace(0.0, 0.6, n // 2), np.linspace(0.6, 0.0, n // 2)])
    res = system.simulate(n, {"pwm_duty": duty, "supply_voltage_v": 32.0},
                          outputs=["sma_temperature_c", "theta_mcp_deg"])
    temp, ang = res["sma_temperature_c"], res["theta_mcp_deg"]
    half = n // 2
    k_up = int(np.argmax(temp[:half] >= 68.0))
    k_down = half + int(np.argmax(temp[half:] <= 68.0))
    assert temp[k_up] == pytest.approx(68.0, abs=0.5) and temp[k_down] == pytest.approx(68.0, abs=0.5)
    assert ang[k_down] - ang[k_up] > 10.0


def test_device_binding_drives_the_wire_from_pwm_channel_0_and_reads_mcp_and_force(cfg):
    dev = sx.SMAExoskeleton.device(cfg)
    assert dev.duty_inputs["pwm_duty"].channel == 0 and dev.duty_inputs["pwm_duty"].scale == 1.0
    assert dev.constant_inputs == {"supply_voltage_v": 32.0}
    assert dev.encoder_signal == "theta_mcp_rad" and dev.encoder_counts_per_rev == cfg.encoder.counts_per_rev
    assert [a.signal for a in dev.adc] == ["contact_force_n"]
    assert dev.adc[0].counts_per_unit == cfg.force_sensor.counts_per_n
    produced = {s for p in dev.parts for s in p.signal_names}
    assert dev.encoder_signal in produced and "contact_force_n" in produced


@pytest.mark.slow
def test_simulate_command_writes_the_canonical_signals(tmp_path, system):
    from rehab_hil.cli import simulate

    out = tmp_path / "run.csv"
    parser = argparse.ArgumentParser()
    simulate.add_parser(parser.add_subparsers())
    args = parser.parse_args(["simulate", "--config", str(CFG_PATH), "--scenario", "pwm-step",
                              "--duration", "1.0", "--out", str(out)])
    assert simulate.run(args) == 0
    with out.open() as fh:
        header = next(csv.reader(fh))
    for name in (*sx.INPUTS, *sx.OUTPUTS):
        assert name in header


@pytest.mark.slow
def test_simulated_rig_reads_the_bent_mcp_angle_through_the_encoder(cfg, system):
    """Full PWM on channel 0 for 1.5 s through the device-side plant I/O: the encoder count is
    the model's MCP angle in counts, and the Flexiforce ADC stays within 0..1023."""
    from rehab_hil.devices.plant_io import PlantIO
    from rehab_hil.protocol import DUTY_FULL

    io = PlantIO(sx.SMAExoskeleton.device(cfg))
    for _ in range(1500):
        enc, adc0, _ = io.tick((DUTY_FULL, 0), 0)
    res = system.simulate(1500, {"pwm_duty": 1.0, "supply_voltage_v": 32.0}, outputs=["theta_mcp_rad"])
    expect = res["theta_mcp_rad"][-1] * cfg.encoder.counts_per_rev / (2 * np.pi)
    assert abs(enc - expect) <= 2
    assert enc > 20.0 / 360.0 * cfg.encoder.counts_per_rev  # bent by more than 20 deg
    assert 0 <= adc0 <= 1023
