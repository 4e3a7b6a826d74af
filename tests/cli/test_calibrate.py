"""Force calibration on simulated weights through the Python simulated device on a real pty.

The simulated Flexiforce: a plant-side sensor model in this test (no device code changed). A real
FlexiForce's conductance follows force as a power law close to linear and reads higher while
unloading (hysteresis); here ``counts = 20 + 38 * F**0.85`` (op-amp circuit), +2.5 % on the way
down. The Finger Extensor sim device's A0 reads its ``patient_torque_nm`` input linearly
(512 + 100 counts per N m), so the test drives that knob as a programmable voltage on A0 with the
counts the sensor model gives for each known weight; the device adds its own ADC noise
(``--adc-noise-counts 1.5``) and quantisation, and the counts travel the serial protocol."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rehab_hil.calibration import (
    G0,
    ForceLimitError,
    fit_calibration,
    force_limit_counts,
    load_calibration,
    write_calibration,
)
from rehab_hil.cli.calibrate import measure
from rehab_hil.cli.doctor import firmware_configure_fallback, locked_configure
from rehab_hil.config import ConfigError
from rehab_hil.hardware import SerialHardware
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

ROOT = Path(__file__).resolve().parents[2]
FE = ROOT / "configs" / "finger_extensor.toml"


def flexiforce_counts(force_n: float, loading: bool) -> float:
    """The sensor model: op-amp output (counts) for a force, nonlinear, with unloading hysteresis."""
    c = 20.0 + 38.0 * force_n ** 0.85
    return c if loading else c * 1.025


def test_calibration_on_simulated_weights_fits_reports_hysteresis_and_sets_the_firmware_limit(tmp_path: Path) -> None:
    from rehab_hil.devices import spawn_device

    cfg = load_config(FE)
    binding = get_plant(cfg.plant).device(cfg)
    masses_g = [100.0, 200.0, 400.0, 700.0, 1000.0]
    with spawn_device("sim", FE, clock="realtime", extra_args=["--adc-noise-counts", "1.5", "--seed", "3"]) as dev:

        def place(mass_g: float, loading: bool) -> None:  # the weights, through the sensor model onto A0
            counts = flexiforce_counts(mass_g / 1000.0 * G0, loading)
            dev.control(f"input patient_torque_nm {(counts - 512.0) / 100.0}")

        hw = SerialHardware(dev.port, write_timeout_s=1.0)
        try:
            hw.connect(timeout=10.0)
            hw.configure(locked_configure(firmware_configure_fallback(cfg, binding)))
            tare, points = measure(hw, 0, masses_g, place, settle_s=0.05, average_s=0.25)
        finally:
            hw.close()
    assert tare == pytest.approx(20.0, abs=0.5)
    assert len(points) == 1 + len(masses_g) * 2
    cal, rms = fit_calibration(points, tare, "ff-a201-0042")
    d = cal.data
    # the power law is not linear in counts: a polynomial wins, and fits to a few hundredths of a newton
    assert d.model == "polynomial" and rms["conductance"] > d.fit_rms_n
    assert d.fit_rms_n < 0.12
    loads = np.array([p.force_n for p in points if p.loading])
    assert np.allclose(cal.force_n(np.array([p.counts for p in points if p.loading])), loads, atol=0.3)
    assert 1.0 < d.hysteresis_pct_fs < 5.0  # the model's 2.5 % of the reading, near full scale
    path = write_calibration(cal, tmp_path)
    assert path.name == "ff-a201-0042.toml"
    again = load_calibration(path)
    assert again.data.coefficients == d.coefficients and again.file == str(path)
    # the firmware limit from the calibration: the count just below the one the sensor gives at 8 N
    sma = load_config(ROOT / "configs" / "sma_exoskeleton.toml")
    sma_binding = get_plant(sma.plant).device(sma)
    lim = _with_limit(sma, 8.0)
    counts = force_limit_counts(lim, sma_binding, again)
    assert abs(counts - flexiforce_counts(8.0, True)) <= 4
    assert float(again.force_n(counts)) <= 8.0 < float(again.force_n(counts + 1))


def _with_limit(cfg: Any, max_force_n: float) -> Any:
    limits = cfg.rig.limits.model_copy(update={"max_force_n": max_force_n})
    return cfg.model_copy(update={"rig": cfg.rig.model_copy(update={"limits": limits})})


def test_a_force_limit_beyond_the_adc_is_refused_not_disabled() -> None:
    cfg = load_config(ROOT / "configs" / "tcp_finger.toml")  # 100 counts/N from 0: 10.23 N is the top
    binding = get_plant(cfg.plant).device(cfg)
    assert force_limit_counts(_with_limit(cfg, 10.0), binding) == 1000
    with pytest.raises(ForceLimitError, match=r"max_force_n = 10.5 N is 1050 ADC counts.*below 1023"):
        force_limit_counts(_with_limit(cfg, 10.5), binding)
    fe = load_config(FE)  # A0 is a torque sensor: no firmware force limit, as before
    assert force_limit_counts(fe, get_plant(fe.plant).device(fe)) == 1023


def test_a_calibration_that_cannot_reach_the_limit_is_refused() -> None:
    from rehab_hil.calibration import CalibrationPoint

    pts = [CalibrationPoint(f, 20 + 30 * f) for f in (0.0, 1.0, 2.0, 4.0, 6.0)]
    cal, _ = fit_calibration(pts, 20.0, "s1")
    assert cal.data.model == "conductance"
    assert cal.limit_counts(10.0) == 320
    with pytest.raises(ForceLimitError, match="beyond the ADC range"):
        cal.limit_counts(40.0)


def test_bad_calibration_files_name_the_file_and_key(tmp_path: Path) -> None:
    from rehab_hil.calibration import CalibrationPoint

    cal, _ = fit_calibration([CalibrationPoint(f, 20 + 30 * f) for f in (0.0, 1.0, 2.0, 4.0)], 20.0, "s2")
    path = write_calibration(cal, tmp_path)
    path.write_text(path.read_text().replace('circuit = "opamp"', 'circuit = "bridge"'))
    with pytest.raises(ConfigError, match=r"s2.toml: circuit: "):
        load_calibration(path)
    other = tmp_path / "s3.toml"
    other.write_text(write_calibration(cal, tmp_path / "x").read_text())
    with pytest.raises(ConfigError, match=r"s3.toml: sensor_id: 's2' does not match"):
        load_calibration(other)
    with pytest.raises(ValueError, match="sensor id"):
        fit_calibration([CalibrationPoint(f, 20 + 30 * f) for f in (0.0, 1.0, 2.0)], 20.0, "../etc")


def test_calibration_summary_records_the_linear_map_and_the_firmware_limit() -> None:
    from rehab_hil.calibration import calibration_summary

    sma_cfg = load_config(ROOT / "configs" / "sma_exoskeleton.toml")
    sma = calibration_summary(sma_cfg, get_plant(sma_cfg.plant).device(sma_cfg))
    assert sma["calibration"] is None and sma["linear_map"] == {"counts_per_n": 9.3, "offset_counts": 0.0}
    assert sma["firmware_force_limit_counts"] == 186  # floor(9.3 counts/N x 20 N)
    fe_cfg = load_config(FE)
    fe = calibration_summary(fe_cfg, get_plant(fe_cfg.plant).device(fe_cfg))
    assert fe["force_sensor"] is None and fe["firmware_force_limit_counts"] == 1023


def test_a_config_references_its_calibration_relative_to_itself_and_the_firmware_limit_uses_it(tmp_path: Path) -> None:
    from rehab_hil.calibration import CalibrationPoint, calibration_summary
    from rehab_hil.plants import get_plant

    cal, _ = fit_calibration([CalibrationPoint(f, 20 + 30 * f) for f in (0.0, 1.0, 2.0, 4.0, 8.0)], 20.0, "fs-07")
    write_calibration(cal, tmp_path / "calibrations")
    (tmp_path / "configs").mkdir()
    sma = ROOT / "configs" / "sma_exoskeleton.toml"
    ref = 'force_calibration = "../calibrations/fs-07.toml"\n\n'
    text = sma.read_text().replace("[rig.limits]", ref + "[rig.limits]", 1)
    path = tmp_path / "configs" / "rig.toml"
    path.write_text(text)
    cfg = load_config(path)
    assert cfg.rig.force_calibration == str((tmp_path / "calibrations" / "fs-07.toml").resolve())
    binding = get_plant(cfg.plant).device(cfg)
    linear = force_limit_counts(load_config(sma), binding)
    assert force_limit_counts(cfg, binding) == cal.limit_counts(cfg.rig.limits.max_force_n) != linear
    assert calibration_summary(cfg, get_plant(cfg.plant).device(cfg))["calibration"]["sensor_id"] == "fs-07"
    path.write_text(text.replace("fs-07.toml", "fs-99.toml"))
    with pytest.raises(ConfigError, match=r"rig\.toml: rig\.force_calibration: .*/calibrations/fs-99\.toml: no such"):
        load_config(path)


def test_the_printed_reference_is_the_path_the_config_resolves(tmp_path: Path, monkeypatch) -> None:
    """``calibrate`` run from the repository root writes calibrations/fs-07.toml; the line it prints
    for configs/rig.toml names it from the config's folder, where force_calibration is read."""
    from rehab_hil.calibration import CalibrationPoint
    from rehab_hil.cli.calibrate import reference_line

    monkeypatch.chdir(tmp_path)
    cal, _ = fit_calibration([CalibrationPoint(f, 20 + 30 * f) for f in (0.0, 1.0, 2.0, 4.0, 8.0)], 20.0, "fs-07")
    written = write_calibration(cal, Path("calibrations"))
    (tmp_path / "configs").mkdir()
    config = Path("configs/rig.toml")
    line = reference_line(written, config)
    assert line == ('reference it in configs/rig.toml with [rig] force_calibration = "../calibrations/fs-07.toml" '
                    "(a path from its folder)")
    ref = line.split("force_calibration = ")[1].split(" (")[0]
    sma = (ROOT / "configs" / "sma_exoskeleton.toml").read_text()
    config.write_text(sma.replace("[rig.limits]", f"force_calibration = {ref}\n\n[rig.limits]", 1))
    assert load_config(config).rig.force_calibration == str(written.resolve())
