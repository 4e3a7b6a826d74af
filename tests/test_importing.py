"""A lab logger's files through a mapping (rehab_hil.importing, rehab-hil import), on a real
EMPS .mat excerpt (tests/data/emps/README.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from rehab_hil.cli import main
from rehab_hil.config import ConfigError
from rehab_hil.importing import load_mapping, read_mapped, unit_factor
from rehab_hil.interchange import CsvError, read_csv

ROOT = Path(__file__).resolve().parents[1]
MAT = ROOT / "tests" / "data" / "emps" / "pulses_first_0.5s.mat"
EMPS = ROOT / "configs" / "emps.toml"


def test_the_emps_mapping_reads_the_mat_variables_as_model_signals() -> None:
    raw = scipy.io.loadmat(MAT)
    rec = read_mapped(MAT, load_mapping(EMPS))
    assert set(rec.signals) == {"position_m", "position_reference_m", "drive_input_v", "disturbance_v"}
    assert np.array_equal(rec["position_m"], raw["qm"].ravel())
    assert np.array_equal(rec["disturbance_v"], raw["pulses_N"].ravel().astype(float))
    assert rec.t[0] == 0.0 and np.median(np.diff(rec.t)) == pytest.approx(1e-3, rel=1e-3)


def test_units_and_scale_convert_to_the_signal_names_unit(tmp_path: Path) -> None:
    mapping = tmp_path / "map.toml"
    mapping.write_text('[import]\nsample_time_s = 0.002\n[import.signals.position_m]\nvariable = "qm"\n'
                       'unit = "mm"\nscale = 2.0\noffset = 1.0\n[import.signals.angle_rad]\nvariable = "qg"\n'
                       'unit = "deg"\n')
    raw = scipy.io.loadmat(MAT)
    rec = read_mapped(MAT, load_mapping(mapping))
    assert np.allclose(rec["position_m"], (raw["qm"].ravel() * 2.0 + 1.0) * 1e-3)
    assert np.allclose(rec["angle_rad"], np.radians(raw["qg"].ravel()))
    assert rec.t[-1] == pytest.approx(0.002 * (rec.t.size - 1))
    assert unit_factor("ms", "time_s") == 1e-3


def test_a_csv_logger_file_is_read_by_its_header(tmp_path: Path) -> None:
    f = tmp_path / "log.csv"
    f.write_text("stamp_ms,pos_mm\n0,1.0\n10,2.0\n20,4.0\n")
    m = tmp_path / "map.toml"
    m.write_text('[import]\ntime = "stamp_ms"\ntime_unit = "ms"\n[import.signals.position_m]\nvariable = "pos_mm"\n'
                 'unit = "mm"\n')
    rec = read_mapped(f, load_mapping(m))
    assert np.allclose(rec.t, [0.0, 0.01, 0.02]) and np.allclose(rec["position_m"], [1e-3, 2e-3, 4e-3])


def test_a_missing_variable_is_named_with_the_file_and_the_mapping_key(tmp_path: Path) -> None:
    m = tmp_path / "map.toml"
    m.write_text('[import]\ntime = "t"\n[import.signals.position_m]\nvariable = "q_motor"\nunit = "m"\n')
    with pytest.raises(CsvError, match=r"pulses_first_0.5s.mat: no variable 'q_motor' .*signals.position_m"):
        read_mapped(MAT, load_mapping(m))


def test_a_unit_that_does_not_convert_is_a_config_error_naming_the_key(tmp_path: Path) -> None:
    m = tmp_path / "map.toml"
    m.write_text('[import]\ntime = "t"\n[import.signals.position_m]\nvariable = "qm"\nunit = "V"\n')
    with pytest.raises(ConfigError, match=r"map.toml: import: .*signals.position_m.unit"):
        load_mapping(m)


def test_rehab_hil_import_writes_an_interchange_csv_from_the_config_mapping(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "pulses.csv"
    assert main(["import", "--config", str(EMPS), "--data", str(MAT), "--out", str(out)]) == 0
    rec = read_csv(out)
    assert rec.t.size == 500 and np.allclose(rec["drive_input_v"], scipy.io.loadmat(MAT)["vir"].ravel())
    assert "500 rows" in capsys.readouterr().out


def test_rehab_hil_import_refuses_a_signal_the_plant_lacks_in_one_line(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture) -> None:
    cfg = tmp_path / "emps.toml"
    cfg.write_text(EMPS.read_text().replace("[import.signals.position_m]", "[import.signals.carriage_m]"))
    assert main(["import", "--config", str(cfg), "--data", str(MAT), "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "import.signals" in err and "carriage_m" in err and not (tmp_path / "x.csv").exists()
