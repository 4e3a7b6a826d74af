"""``rehab-hil twin RUN``: the live twin on a recorded session gives the events the live twin gives,
with the run's own config or another model; its mistakes are one line."""

from __future__ import annotations

import json

import pytest

from rehab_hil.cli import main
from rehab_hil.testing import CONFIGS, config_with_changes

FE = CONFIGS / "finger_extensor.toml"


# the tests that read the recorded session run on one xdist worker, so it is recorded once (under make
# test's two workers each recorded its own: 2.5 and 1.7 s of set-up)
FRICTION_RUN = pytest.mark.xdist_group("twin_cli_friction_run")


@pytest.fixture(scope="module")
def friction_run(tmp_path_factory):
    """A recorded 11 s Finger Extensor session (no twin) whose friction appears at 5 s."""
    tmp = tmp_path_factory.mktemp("twin_cli")
    host = tmp / "host.toml"
    host.write_text(FE.read_text() + "\n[twin]\nlearn_s = 2.5\n")
    device = config_with_changes(FE, tmp / "device.toml", effects=[
        {"name": "coulomb_friction", "params": {"level_nm": 0.05}, "start_s": 5.0}])
    assert main(["run", "--config", str(host), "--sim-plant", str(device), "--device", "inprocess", "--duration",
                 "11", "--record", str(tmp / "runs"), "--no-display"]) == 0
    (run,) = (tmp / "runs").iterdir()
    return run, host


@FRICTION_RUN
def test_the_twin_on_a_recording_finds_the_change_and_names_it(friction_run, tmp_path, capsys):
    run, _ = friction_run
    capsys.readouterr()
    assert main(["twin", str(run), "--out", str(tmp_path)]) == 0  # the run's own config, from metadata.json
    out = capsys.readouterr().out
    assert "model_mismatch iris_angle_deg" in out and "coulomb_friction" in out
    (ev,) = json.loads((tmp_path / "twin.json").read_text())["model_events"]
    assert 4.7 <= ev["t_s"] <= 6.0
    assert (tmp_path / "twin.csv").read_text().count("\n") > 10_000


@FRICTION_RUN
def test_a_model_that_has_the_friction_sees_no_change_before_it_appears(friction_run, tmp_path, capsys):
    """Judged with the friction in the model from the start: before 5 s the model is wrong, after
    it right; the twin learns its normal level on the wrong part and sees the residual fall, not rise."""
    run, _ = friction_run
    model = config_with_changes(FE, tmp_path / "with_friction.toml",
                                effects=[{"name": "coulomb_friction", "params": {"level_nm": 0.05}}])
    model.write_text(model.read_text() + "\n[twin]\nlearn_s = 2.5\n")
    capsys.readouterr()
    assert main(["twin", str(run), "--config", str(model)]) == 0
    assert "no model event" in capsys.readouterr().out


@pytest.mark.parametrize("args,says", [
    (["{tmp}/none"], "not found"),
    (["{tmp}"], "no run.csv"),
])
def test_mistakes_are_one_line(args, says, tmp_path, capsys):
    capsys.readouterr()
    assert main(["twin", *[a.replace("{tmp}", str(tmp_path)) for a in args]]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rehab-hil twin: error: ") and says in err and "\n" not in err
