"""Interchange CSV: round trip, and malformed files rejected with the line number."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.interchange import CsvError, read_csv, write_csv


def test_round_trip_keeps_every_value(tmp_path):
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(1e-4, 1e-3, 500))
    sig = {"iris_angle_deg": rng.normal(size=500) * 100, "motor_current_a": rng.normal(size=500)}
    p = write_csv(tmp_path / "run.csv", t, sig)
    rec = read_csv(p)
    np.testing.assert_allclose(rec.t, t, rtol=1e-9)
    for k, v in sig.items():
        np.testing.assert_allclose(rec[k], v, rtol=1e-9, atol=1e-12)


def test_reader_accepts_extra_columns_and_reports_missing_ones(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("time_s,iris_angle_deg,extra_thing_v\n0,1,2\n0.001,1.5,2\n")
    rec = read_csv(p)
    assert set(rec.signals) == {"iris_angle_deg", "extra_thing_v"}
    with pytest.raises(CsvError, match="missing columns \\['motor_voltage_v'\\]"):
        rec.require(["iris_angle_deg", "motor_voltage_v"], p)


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        ("", 1, "empty file"),
        ("t,x_v\n0,1\n", 1, "first column must be time_s"),
        ("time_s,Angle\n0,1\n", 1, "not <quantity>_<unit>"),
        ("time_s,x_v\n0,1\n0.1,abc\n", 3, "not a number"),
        ("time_s,x_v\n0,1\n0.1,nan\n", 3, "not finite"),
        ("time_s,x_v\n0,1\n0.1,2\n0.1,3\n", 4, "increase strictly"),
        ("time_s,x_v\n0,1\n0.1\n", 3, "expected 2 cells"),
        ("time_s,x_v\n", 2, "no data rows"),
    ],
)
def test_malformed_csv_names_the_line(tmp_path, text, line, fragment):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(CsvError) as exc:
        read_csv(p)
    assert exc.value.line == line
    assert fragment in str(exc.value)
    assert str(p) in str(exc.value)


def test_writer_refuses_names_without_units(tmp_path):
    with pytest.raises(ValueError, match="quantity"):
        write_csv(tmp_path / "x.csv", np.arange(3.0), {"angle": np.zeros(3)})


def test_a_reference_column_may_be_empty_where_nothing_was_tracked(tmp_path):
    t = np.arange(5) * 1e-3
    ref = np.array([np.nan, 7.89, 7.89, np.nan, np.nan])  # before the first command, the stop's rows
    p = write_csv(tmp_path / "run.csv", t, {"iris_angle_deg": np.full(5, 1.0), "iris_angle_reference_deg": ref})
    assert p.read_text().splitlines()[1:3] == ["0,1,", "0.001,1,7.89"]  # empty, neither 0 nor "nan"
    rec = read_csv(p)
    np.testing.assert_array_equal(np.isnan(rec["iris_angle_reference_deg"]), np.isnan(ref))


def test_an_empty_cell_of_any_other_column_names_the_line(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("time_s,iris_angle_deg,iris_angle_reference_deg\n0,1,\n0.001,,2\n")
    with pytest.raises(CsvError, match="column iris_angle_deg: not a number") as exc:
        read_csv(p)
    assert exc.value.line == 3
