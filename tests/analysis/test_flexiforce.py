"""FlexiForce A201 real data (tests/data/flexiforce/README.md): the static calibration refitted beside
the authors' linear fit, and creep and hysteresis identified from the dead-weight staircases."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from rehab_hil.analysis.flexiforce import STAIRCASE_LOADS_N, fit_static, read_points, staircase
from rehab_hil.cli import main

DATA = Path(__file__).resolve().parents[1] / "data" / "flexiforce"
POINTS = DATA / "static_calibration.csv"


def _runs(prefix: str) -> list[np.ndarray]:
    d = scipy.io.loadmat(DATA / "Sensor_Data_3_Runs_consec.mat")
    return [d[f"Sensor_{prefix}{i}"].ravel().astype(float) for i in (1, 2, 3)]


@pytest.mark.parametrize("sensor", ["A", "B"])
def test_the_refitted_calibration_is_no_worse_than_the_published_linear_fit(sensor: str) -> None:
    load, counts = read_points(POINTS)[sensor]
    fit = fit_static(sensor, load, counts)
    assert fit.published_rms_n is not None
    assert fit.rms_n[fit.model] <= fit.rms_n["linear"] <= fit.published_rms_n
    assert np.sqrt(np.mean((fit.force_n(counts) - load) ** 2)) == pytest.approx(fit.rms_n[fit.model])
    assert fit.coefficients[1] == pytest.approx(0.0035, rel=0.1)  # N per count, as the authors' 0.0033-0.0036


def test_a_known_staircase_with_creep_and_hysteresis_is_recovered() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(700) * 0.1
    load = np.repeat(STAIRCASE_LOADS_N, 100)
    tau, gain, width = 3.0, 300.0, 40.0  # s, counts per N, counts of hysteresis (unloading reads higher)
    runs = []
    for g in (1.0, 1.05, 0.97):
        y = np.empty_like(t)
        z = 0.0
        for k in range(t.size):  # creep: the reading approaches 1.03 x its step value with time constant tau
            start = y[k - 1] if k and load[k] == load[k - 1] else gain * g * load[k]
            z = load[k] * gain * g * 1.03 if load[k] > 0 else 0.0
            y[k] = start + (z - start) * (0.1 / tau) if k and load[k] == load[k - 1] else start
        y += np.where((np.arange(t.size) >= 400) & (load > 0), width, 0.0) + 700 + rng.normal(0, 2, t.size)
        runs.append(y)
    fit = staircase("synthetic", runs)
    assert fit.creep_time_constant_s == pytest.approx(tau, rel=0.25)
    assert fit.hysteresis_counts[6.916] == pytest.approx(width, abs=15.0)
    assert fit.gain_spread_pct == pytest.approx(8.0, abs=2.0)


@pytest.mark.parametrize(("sensor", "prefix"), [("B (upper)", "o"), ("A (lower)", "u")])
def test_the_real_staircases_creep_a_few_percent_in_five_seconds_and_unload_high(sensor: str, prefix: str) -> None:
    fit = staircase(sensor, _runs(prefix))
    assert 1.0 <= fit.creep_time_constant_s <= 20.0
    assert 1.0 <= fit.creep_pct_median <= 6.0  # the data's README: about 3 % in 5 s at constant load
    assert fit.hysteresis_counts[6.916] > 0.0  # unloading reads above loading at the same weight


def test_calibrate_force_points_reports_both_sensors(capsys: pytest.CaptureFixture) -> None:
    assert main(["calibrate", "force", "--points", str(POINTS)]) == 0
    out = capsys.readouterr().out
    assert "A" in out and "B" in out and "published" in out


def test_calibrate_force_points_with_a_bad_row_is_one_line_naming_the_line(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture) -> None:
    bad = tmp_path / "points.csv"
    bad.write_text(POINTS.read_text().replace("A,2.335,1339", "A,2.335,x"))
    assert main(["calibrate", "force", "--points", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "points.csv:4" in err
