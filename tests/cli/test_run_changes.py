"""``rehab-hil run --sim-plant`` with an effect that starts mid-session (issue 23 item 5): through the
real CLI, the simulated device on a pty in lockstep, the recording equals a run without the change
before the change's start and differs after it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv
from rehab_hil.testing import CONFIGS, config_with_changes

FE = CONFIGS / "finger_extensor.toml"


def _session(root: Path, capsys, sim_plant: Path | None) -> tuple[np.ndarray, np.ndarray]:
    """(time [s], iris angle [deg]) of a 2 s PID step session on the lockstep simulated device."""
    args = ["run", "--config", str(FE), "--device", "sim", "--lockstep", "--controller", "pid", "--reference",
            "step", "--duration", "2.0", "--record", str(root), "--no-display"]
    if sim_plant is not None:
        args += ["--sim-plant", str(sim_plant)]
    code = main(args)
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    (run,) = root.iterdir()
    rec = read_csv(run / "run.csv")
    return np.asarray(rec.t), np.asarray(rec["iris_angle_deg"])


@pytest.mark.slow
def test_a_load_appearing_at_one_second_changes_the_recording_only_from_then(tmp_path, capsys):
    rig = config_with_changes(FE, tmp_path / "rig.toml", effects=[
        {"name": "constant_load", "params": {"level_nm": 0.4}, "start_s": 1.0}])
    t0, plain = _session(tmp_path / "plain", capsys, None)
    t1, changed = _session(tmp_path / "changed", capsys, rig)
    assert np.array_equal(t0, t1) and t0[-1] >= 1.99
    before, after = t0 < 1.0, t0 > 1.05
    assert np.array_equal(plain[before], changed[before])  # the same session, sample for sample
    assert np.abs(plain[t0 > 0.5] - 59.58).max() < 3.0  # settled at the step's target by then
    assert np.abs(plain[after] - changed[after]).max() > 1.0  # 0.4 N m against the opening pushes it back


@pytest.mark.slow
def test_simulate_warns_and_runs_a_scheduled_effect_from_the_start(tmp_path, capsys):
    """Outside a simulated rig the config is taken as written: the same trace as the effect without start_s."""
    effect = {"name": "constant_load", "params": {"level_nm": 0.4}}
    at_once = config_with_changes(FE, tmp_path / "at_once.toml", effects=[effect])
    later = config_with_changes(FE, tmp_path / "later.toml", effects=[{**effect, "start_s": 0.5}],
                                changes=[{"key": "motor.supply_v", "scale": 0.5}])
    traces = []
    for cfg in (at_once, later):
        out = tmp_path / f"{cfg.stem}.csv"
        assert main(["simulate", "--config", str(cfg), "--scenario", "step", "--duration", "1", "--out", str(out)]) == 0
        traces.append(read_csv(out)["iris_angle_deg"])
    printed = capsys.readouterr().out
    assert printed.count("warning:") == 1 and f"{later} schedules changes mid-session" in printed
    assert np.array_equal(traces[0], traces[1])
