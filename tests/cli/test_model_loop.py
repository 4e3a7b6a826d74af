"""The model loop from the command line, as a user runs it: a simulated rig whose plant hides an
effect the host's model lacks -> ``rehab-hil run --record`` -> ``rehab-hil discrepancy`` on the run
directory names the effect -> ``augmented.toml`` -> ``rehab-hil replay`` and a new session on the
augmented model match the recording much better. Clean recordings name nothing.

What the workflow finds in a record, effect by effect, is the subject of tests/discrepancy/ (each hidden
effect on simulated records of the plant: test_workflow, test_other_plants); here the subject is the
loop through the command line and a session's recording, on both plants (the Finger Extensor's Coulomb
friction over the pty and the firmware, the SMA driver's dead zone improving what the rig does)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv
from rehab_hil.loop.recorder import read_mcap

ROOT = Path(__file__).resolve().parents[2]
FE = ROOT / "configs" / "finger_extensor.toml"
SMA = ROOT / "configs" / "sma_exoskeleton.toml"


def _with_effect(src: Path, dest: Path, name: str, params: str) -> Path:
    dest.write_text(src.read_text() + f'\n[[effects]]\nname = "{name}"\nparams = {{ {params} }}\n')
    return dest


def _session(config: Path, root: Path, capsys, *, device: str = "sim", sim_plant: Path | None = None,
             duration: float = 10.0) -> Path:
    """A recorded lockstep session. ``device="inprocess"`` runs the same device logic and plant in the
    host process, one sample per command as ``sim --lockstep`` does over the pty, and records the same
    samples (a 10 s Finger Extensor session, the SMA sessions with a hidden dead zone, the clean 6 s Finger
    Extensor session: every CSV column equal but the host's wall-clock ``host_time_s``)
    without a device process to start and a pty round trip per sample; the sessions whose subject is
    the recording, not the link, run there. The pty path with ``--sim-plant`` is the first session of
    the Coulomb test, the firmware's the simavr test."""
    args = ["run", "--config", str(config), "--device", device, "--duration", str(duration), "--record", str(root),
            "--no-display", "--rig-id", "bench1"]
    if device in ("sim", "avr"):
        args.append("--lockstep")
    if sim_plant is not None:
        args += ["--sim-plant", str(sim_plant)]
    code = main(args)
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    runs = sorted(root.iterdir())
    return runs[-1]


def _discrepancy(config: Path, data: Path, out: Path, capsys, *extra: str) -> dict:
    code = main(["discrepancy", "--config", str(config), "--data", str(data), "--out", str(out), *extra])
    printed = capsys.readouterr()
    assert code == 0, printed.out + printed.err
    return json.loads((out / "report.json").read_text())


def _replay_rmse(config: Path, data: Path, channel: str, capsys) -> float:
    assert main(["replay", "--config", str(config), "--data", str(data)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith(channel))
    return float(line.split("RMSE")[1].split()[0])


@pytest.mark.slow
def test_hidden_coulomb_friction_is_found_in_a_session_recording_and_the_augmented_model_closes_the_loop(
        tmp_path, capsys):
    device = _with_effect(FE, tmp_path / "rig_plant.toml", "coulomb_friction", "level_nm = 0.03")
    run = _session(FE, tmp_path / "runs", capsys, sim_plant=device)
    meta = json.loads((run / "metadata.json").read_text())
    assert meta["plant"] == "finger_extensor" and meta["sim_plant"]["config_path"] == str(device)
    assert meta["firmware"]["protocol_version"] >= 1 and meta["rig_id"] == "bench1"
    assert meta["safety_events"] == [] and meta["rows"] >= 9000

    report = _discrepancy(FE, run, tmp_path / "report", capsys)
    assert [c["effect"] for c in report["chosen"]] == ["coulomb_friction"]
    assert report["chosen"][0]["params"]["level_nm"] == pytest.approx(0.03, rel=0.15)

    augmented = tmp_path / "report" / "augmented.toml"
    before = _replay_rmse(FE, run, "iris_angle_deg", capsys)
    after = _replay_rmse(augmented, run, "iris_angle_deg", capsys)
    assert after < 0.2 * before, (before, after)

    # a new session whose simulated rig runs the augmented model behaves like the rig did
    again = read_csv(_session(FE, tmp_path / "again", capsys, device="inprocess", sim_plant=augmented) / "run.csv")
    nominal = read_csv(_session(FE, tmp_path / "nominal", capsys, device="inprocess") / "run.csv")
    rig = read_csv(run / "run.csv")
    n = min(len(rig.t), len(again.t), len(nominal.t))

    def gap(rec):
        return float(np.sqrt(np.mean((rec["iris_angle_deg"][:n] - rig["iris_angle_deg"][:n]) ** 2)))

    assert gap(again) < 0.3 * gap(nominal), (gap(again), gap(nominal))


@pytest.mark.slow
def test_a_clean_session_recording_names_nothing_and_reads_from_csv_mcap_or_the_directory(tmp_path, capsys):
    run = _session(FE, tmp_path / "runs", capsys, device="inprocess", duration=6.0)
    report = _discrepancy(FE, run, tmp_path / "report", capsys)
    assert report["chosen"] == []
    csv, mcap = read_csv(run / "run.csv"), None
    rows = [m for topic, _, m in read_mcap(run / "run.mcap") if topic == "/rig/sample"]
    mcap = np.array([r["iris_angle_deg"] for r in rows])
    np.testing.assert_allclose(mcap, csv["iris_angle_deg"], atol=1e-6)  # the two files hold the same samples
    r_mcap = _discrepancy(FE, run / "run.mcap", tmp_path / "report_mcap", capsys)
    assert r_mcap["chosen"] == [] and r_mcap["samples"] == report["samples"]


@pytest.mark.slow
@pytest.mark.firmware
def test_hidden_coulomb_friction_behind_the_real_firmware_in_simavr_is_found(tmp_path, capsys):
    from rehab_hil.devices import avr_device

    reason = avr_device.unavailable_reason()
    if reason:
        pytest.skip(reason)
    device = _with_effect(FE, tmp_path / "rig_plant.toml", "coulomb_friction", "level_nm = 0.03")
    # the firmware in virtual time (--lockstep): the config's own watchdog and link budget, the same
    # session on an idle and on a loaded machine
    run = _session(FE, tmp_path / "runs", capsys, device="avr", sim_plant=device)
    meta = json.loads((run / "metadata.json").read_text())
    assert meta["device"]["kind"] == "avr" and meta["firmware"]["version"]
    report = _discrepancy(FE, run, tmp_path / "report", capsys)
    assert [c["effect"] for c in report["chosen"]] == ["coulomb_friction"]
    assert report["chosen"][0]["params"]["level_nm"] == pytest.approx(0.03, rel=0.2)


@pytest.mark.slow
def test_the_model_loop_improves_what_the_rig_does_an_augmented_model_halves_the_tracking_error(tmp_path, capsys):
    """Issue 22 item 4: a rig whose SMA driver has a dead zone the host's model lacks -> a session with
    the nominal model's controller -> discrepancy names it -> a session with the augmented model's
    controller on the same rig tracks at least twice as well (its feedforward pays the dead zone)."""
    rig = _with_effect(SMA, tmp_path / "rig_plant.toml", "actuator_dead_zone", "width_duty = 0.08")
    before = _session(SMA, tmp_path / "before", capsys, device="inprocess", sim_plant=rig, duration=30.0)
    # one round: the dead zone among the chosen is what the test asks; with the default two rounds the
    # second scored every candidate again and chose none (same chosen, same augmented.toml)
    report = _discrepancy(SMA, before, tmp_path / "report", capsys, "--max-effects", "1")
    assert "actuator_dead_zone" in [c["effect"] for c in report["chosen"]]
    augmented = tmp_path / "report" / "augmented.toml"
    after = _session(augmented, tmp_path / "after", capsys, device="inprocess", sim_plant=rig, duration=30.0)
    b, a = (json.loads((run / "metadata.json").read_text()) for run in (before, after))
    assert b["controller"] == a["controller"] == "model_based"
    assert len(b["session_cycles"]) == len(a["session_cycles"]) == 2  # 4.8 s rest + 2 x 12 s cycles < 30 s < 3 cycles
    assert a["safety_events"] == [] and b["safety_events"] == []
    assert a["session"]["rmse_deg"] <= 0.5 * b["session"]["rmse_deg"], (b["session"], a["session"])
