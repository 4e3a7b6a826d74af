"""``--data`` as typed: the ``--record`` folder means its newest run (said so); a record that lacks
a channel the rig records is named."""

from __future__ import annotations

import pytest

from rehab_hil.cli import main
from rehab_hil.testing import CONFIGS

FE = CONFIGS / "finger_extensor.toml"


@pytest.fixture(scope="module")
def cycle_csv(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "cycle.csv"
    assert main(["simulate", "--config", str(FE), "--scenario", "cycle", "--duration", "3", "--out", str(out)]) == 0
    return out


def test_data_given_the_record_folder_takes_its_newest_run_and_says_which(tmp_path, cycle_csv, capsys):
    for name in ("20261101T090000Z-bench1", "20261108T090000Z-bench1", "20261103T090000Z-bench1"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "run.csv").write_bytes(cycle_csv.read_bytes())
    (tmp_path / "notes").mkdir()
    capsys.readouterr()
    assert main(["replay", "--config", str(FE), "--data", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    newest = tmp_path / "20261108T090000Z-bench1"
    assert f"--data {tmp_path} holds 3 runs: using the newest, {newest}" in err
    assert "20261103T090000Z-bench1, 20261101T090000Z-bench1" in err  # the others, newest first
    assert f"on {newest / 'run.csv'}" in out


def test_a_record_without_the_rigs_angle_is_named(tmp_path, cycle_csv, capsys):
    lines = cycle_csv.read_text().splitlines()
    header = lines[0].split(",")
    k = header.index("iris_angle_deg")
    cut = tmp_path / "no_angle.csv"
    cut.write_text("\n".join(",".join(c for i, c in enumerate(row.split(",")) if i != k) for row in lines) + "\n")
    capsys.readouterr()
    assert main(["replay", "--config", str(FE), "--data", str(cut)]) == 0
    err = capsys.readouterr().err
    assert f"{cut}: no 'iris_angle_deg' column (a finger_extensor output the rig records)" in err


def test_a_simulated_csv_beside_the_runs_is_not_taken_for_a_run(tmp_path, cycle_csv, capsys):
    """After the README's ``simulate --out out/run.csv`` and ``make run``: out/ holds both."""
    (tmp_path / "run.csv").write_bytes(cycle_csv.read_bytes())
    run = tmp_path / "20261101T090000Z-bench1"
    run.mkdir()
    (run / "run.csv").write_bytes(cycle_csv.read_bytes())
    capsys.readouterr()
    assert main(["replay", "--config", str(FE), "--data", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    assert f"--data {tmp_path} holds one run: using it, {run}" in err
    assert f"on {run / 'run.csv'}" in out


def test_a_folder_without_runs_is_one_line_naming_the_files_in_it(tmp_path, cycle_csv, capsys):
    (tmp_path / "run.csv").write_bytes(cycle_csv.read_bytes())
    capsys.readouterr()
    assert main(["replay", "--config", str(FE), "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"--data {tmp_path}: no run directory here" in err and "name the file (run.csv)" in err
