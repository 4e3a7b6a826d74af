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


# --- lab file formats (issue 38 item 4): files written here as a lab's logger writes them ---

def _matrix(n: int = 400) -> np.ndarray:
    """A logger's one matrix: time, command, two unused columns, angle, torque, velocity (n x 7)."""
    t = np.arange(n) * 1e-3
    return np.column_stack([t, np.sign(np.sin(7 * t)), t * 0, t * 0 + 2, np.sin(3 * t), 0.1 * np.cos(t),
                            3 * np.cos(3 * t)])


def _matrix_mapping(tmp_path: Path) -> Path:
    m = tmp_path / "map.toml"
    m.write_text('[import]\ntime = "data(:,1)"\n[import.signals.angle_rad]\nvariable = "data(:,5)"\nunit = "rad"\n'
                 '[import.signals.drive_torque_nm]\nvariable = "data(:, 6)"\nunit = "N m"\n'
                 '[import.signals.velocity_rad_s]\nvariable = "data(:,end)"\nunit = "rad/s"\n')
    return m


def test_a_mat_matrix_column_is_named_as_matlab_indexes_it(tmp_path: Path) -> None:
    data = _matrix()
    f = tmp_path / "servo.mat"
    scipy.io.savemat(f, {"data": data})
    rec = read_mapped(f, load_mapping(_matrix_mapping(tmp_path)))
    assert np.allclose(rec.t, data[:, 0]) and np.allclose(rec["angle_rad"], data[:, 4])
    assert np.allclose(rec["drive_torque_nm"], data[:, 5]) and np.allclose(rec["velocity_rad_s"], data[:, 6])


def test_a_whole_matrix_is_refused_with_the_indexing_to_use(tmp_path: Path) -> None:
    f = tmp_path / "servo.mat"
    scipy.io.savemat(f, {"data": _matrix()})
    m = tmp_path / "map.toml"
    m.write_text('[import]\nsample_time_s = 0.001\n[import.signals.angle_rad]\nvariable = "data"\nunit = "rad"\n')
    with pytest.raises(CsvError, match=r"servo.mat: variable 'data' .* shape \(400, 7\), not a vector: .*data\(:,1\)"):
        read_mapped(f, load_mapping(m))
    m.write_text('[import]\nsample_time_s = 0.001\n[import.signals.angle_rad]\nvariable = "data(:,8)"\nunit = "rad"\n')
    with pytest.raises(CsvError, match=r"index 8 is outside 1..7 .*MATLAB counts from 1"):
        read_mapped(f, load_mapping(m))


def test_a_struct_field_is_read_by_its_dotted_name(tmp_path: Path) -> None:
    f = tmp_path / "log.mat"
    scipy.io.savemat(f, {"run": {"t": np.arange(50) * 0.01, "q": np.linspace(0, 1, 50)}})
    m = tmp_path / "map.toml"
    m.write_text('[import]\ntime = "run.t"\n[import.signals.angle_rad]\nvariable = "run.q"\nunit = "rad"\n')
    rec = read_mapped(f, load_mapping(m))
    assert rec.t[-1] == pytest.approx(0.49) and rec["angle_rad"][-1] == pytest.approx(1.0)


def _write_v73(path: Path, variables: dict[str, np.ndarray]) -> None:
    """A MATLAB v7.3 MAT-file as MATLAB lays it out: HDF5 behind a 512-byte text header, each matrix
    stored column-major (h5py sees it transposed) with its MATLAB_class attribute."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            ds = f.create_dataset(name, data=np.asarray(value, float).T)
            ds.attrs["MATLAB_class"] = np.bytes_("double")
    with path.open("r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sat Nov 28 04:00:00 2026 HDF5 schema 1.00 ."
                 .ljust(116) + b"\x00" * 8 + b"\x00\x02IM")


def test_a_matlab_v73_file_is_read_through_hdf5_in_matlab_order(tmp_path: Path) -> None:
    data = _matrix()
    f = tmp_path / "servo73.mat"
    _write_v73(f, {"data": data})
    rec = read_mapped(f, load_mapping(_matrix_mapping(tmp_path)))
    assert np.allclose(rec.t, data[:, 0]) and np.allclose(rec["angle_rad"], data[:, 4])
    assert np.allclose(rec["velocity_rad_s"], data[:, 6])


@pytest.mark.parametrize(("content", "what"), [
    (b"time,angle\n0,1\n", r"not a MAT file"),
    (None, r"cut short|cannot be read|cannot read"),
])
def test_a_file_that_is_not_what_it_claims_is_one_line_naming_it(tmp_path: Path, content: bytes | None,
                                                                   what: str) -> None:
    f = tmp_path / "bad.mat"
    if content is None:  # a real MAT file cut in the middle, as a full disk or an aborted copy leaves it
        scipy.io.savemat(f, {"data": _matrix()}, do_compression=True)
        f.write_bytes(f.read_bytes()[:300])
    else:
        f.write_bytes(content)
    with pytest.raises(CsvError, match=rf"bad.mat: .*({what})") as info:
        read_mapped(f, load_mapping(_matrix_mapping(tmp_path)))
    assert "\n" not in str(info.value)


def test_a_cut_v73_file_is_one_line_naming_it(tmp_path: Path) -> None:
    f = tmp_path / "cut73.mat"
    _write_v73(f, {"data": _matrix()})
    f.write_bytes(f.read_bytes()[:1200])
    with pytest.raises(CsvError, match=r"cut73.mat: cannot read as a MATLAB v7.3 \(HDF5\) file") as info:
        read_mapped(f, load_mapping(_matrix_mapping(tmp_path)))
    assert "\n" not in str(info.value)


def test_a_semicolon_logger_csv_with_a_time_column_is_read(tmp_path: Path) -> None:
    f = tmp_path / "logger.csv"
    f.write_text('"time";"speed_rpm"\n0;60\n0.5;120\n1.0;0\n')
    m = tmp_path / "map.toml"
    m.write_text('[import]\ntime = "time"\n[import.signals.velocity_rad_s]\nvariable = "speed_rpm"\nunit = "rpm"\n')
    rec = read_mapped(f, load_mapping(m))
    assert np.allclose(rec["velocity_rad_s"], [2 * np.pi, 4 * np.pi, 0.0])
    assert unit_factor("deg/s", "velocity_rad_s") == pytest.approx(np.pi / 180)


def test_a_v73_file_without_h5py_says_what_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    f = tmp_path / "servo73.mat"
    _write_v73(f, {"data": _matrix()})
    monkeypatch.setitem(sys.modules, "h5py", None)  # an install without h5py: its import fails
    with pytest.raises(CsvError, match=r"servo73.mat: a MATLAB v7.3 \(HDF5\) file; reading it needs h5py"):
        read_mapped(f, load_mapping(_matrix_mapping(tmp_path)))


def test_rehab_hil_import_of_a_file_that_is_not_a_mat_file_is_one_line(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture) -> None:
    fake = tmp_path / "log.mat"
    fake.write_bytes(b"\x00\x01 not matlab at all" * 20)
    assert main(["import", "--config", str(EMPS), "--data", str(fake), "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "log.mat:" in err and len(err.splitlines()) == 1 and "Traceback" not in err
