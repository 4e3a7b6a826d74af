"""``rehab-hil calibrate force --device sim --yes`` end to end: the simulated rig carries each known
weight on its force sensor (control ``load``), so the calibration measures the sensor the config
declares (SMA exoskeleton: 9.3 counts per N on ADC0)."""

from __future__ import annotations

import tomllib

import pytest

from rehab_hil.calibration import G0
from rehab_hil.cli import main
from rehab_hil.testing import CONFIGS


@pytest.mark.slow
def test_calibrate_force_runs_end_to_end_on_the_simulated_rig(tmp_path, capsys):
    assert main(["calibrate", "force", "--config", str(CONFIGS / "sma_exoskeleton.toml"), "--device", "sim",
                 "--sensor-id", "sim1", "--weights-g", "100,200,500", "--yes", "--settle", "0.2", "--average", "0.2",
                 "--out-dir", str(tmp_path)]) == 0
    cal = tomllib.loads((tmp_path / "sim1.toml").read_text())
    loads = [0.0, 100 * G0 / 1000, 200 * G0 / 1000, 500 * G0 / 1000]
    assert cal["points_force_n"] == pytest.approx(loads + loads[-2::-1])
    # the simulated sensor: counts = 9.3 per N, rounded by the 10-bit ADC, up and down alike
    assert cal["points_counts"] == [round(9.3 * f) for f in loads + loads[-2::-1]]
    assert cal["hysteresis_pct_fs"] == 0.0
