"""Replaying a recording: bad inputs give clear errors naming the file."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.cli import main
from rehab_hil.discrepancy.replay import MIN_DURATION_S, check_recording
from rehab_hil.interchange import CsvError, Recording, write_csv

from .conftest import FE_CONFIG


def _rec(duration_s=5.0, rate_hz=500.0, **overrides):
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    sig = {"motor_voltage_v": np.sin(t), "patient_torque_nm": 0 * t, "iris_angle_deg": t, "motor_current_a": 0 * t}
    sig.update(overrides)
    return Recording(t, {k: v for k, v in sig.items() if v is not None})


def test_a_complete_recording_passes_and_lists_the_channels_present(fe):
    spec, _ = fe
    assert check_recording(spec, _rec(), "m.csv") == ["iris_angle_deg", "motor_current_a"]
    assert check_recording(spec, _rec(motor_current_a=None), "m.csv") == ["iris_angle_deg"]


def test_missing_input_columns_are_named_with_the_file(fe):
    spec, _ = fe
    with pytest.raises(CsvError, match=r"m\.csv:1: missing input columns \['motor_voltage_v'\]"):
        check_recording(spec, _rec(motor_voltage_v=None), "m.csv")


def test_a_recording_of_another_plant_is_refused(fe):
    spec, _ = fe
    t = np.arange(0.0, 5.0, 0.002)
    other = Recording(t, {"pwm_duty": 0 * t + 0.5, "supply_voltage_v": 0 * t + 32, "theta_mcp_deg": t})
    with pytest.raises(CsvError, match=r"missing input columns .* of plant 'finger_extensor'"):
        check_recording(spec, other, "sma.csv")


def test_no_output_column_too_short_and_constant_input_are_refused(fe):
    spec, _ = fe
    with pytest.raises(CsvError, match="no output column"):
        check_recording(spec, _rec(iris_angle_deg=None, motor_current_a=None), "m.csv")
    with pytest.raises(CsvError, match="too short"):
        check_recording(spec, _rec(duration_s=MIN_DURATION_S / 2), "m.csv")
    flat = _rec(motor_voltage_v=np.full(2500, 3.0))
    with pytest.raises(CsvError, match="constant"):
        check_recording(spec, flat, "m.csv")


def test_cli_prints_one_line_naming_the_file_for_bad_data(tmp_path, capsys):
    rec = _rec(motor_voltage_v=None)
    path = write_csv(tmp_path / "bad.csv", rec.t, rec.signals)
    code = main(["discrepancy", "--config", str(FE_CONFIG), "--data", str(path), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "bad.csv" in err and "motor_voltage_v" in err


def test_a_force_logged_in_whole_adc_counts_is_read_through_the_adc_even_from_a_plain_csv(tmp_path):
    """A lab's own logger writes a CSV without the rig's metadata: a force column on the Flexiforce's
    count grid (whole counts, never negative) still came through the 10-bit ADC, so the model is read
    through it too; a continuous force column (a simulation's) is not."""
    from rehab_hil.discrepancy.replay import Replay
    from rehab_hil.interchange import read_csv
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant

    from .conftest import ROOT

    cfg = load_config(ROOT / "configs" / "sma_exoskeleton.toml")
    t = np.arange(0.0, 4.0, 0.002)
    force = np.clip(np.sin(t), 0.0, None) * 2.0
    per_n = cfg.force_sensor.counts_per_n
    base = {"pwm_duty": (t % 2.0 < 1.0) * 0.8, "supply_voltage_v": 32.0 + 0 * t, "theta_mcp_deg": 10 * t}
    for name, f, expect in (("adc.csv", np.round(force * per_n) / per_n, True), ("sim.csv", force, False)):
        rec = read_csv(write_csv(tmp_path / name, t, {**base, "contact_force_n": f}))
        assert not rec.rig
        replay = Replay.build(get_plant("sma_exoskeleton"), cfg, rec)
        assert ("contact_force_n" in replay.adc_range) is expect, name
