"""``rehab-hil trial`` end to end: a few patients, one short session each, on the local process pool
and on a real Dask scheduler with two workers (``dask scheduler`` / ``dask worker`` started here, on
127.0.0.1): the same seed gives the same outcomes; a patient whose session fails is recorded and the
others run; Ctrl-C writes what finished (exit 130, one line); trial.html draws in headless Chromium."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from rehab_hil.cli import main
from rehab_hil.report.browser import check_page, find_chromium
from rehab_hil.testing import free_port
from rehab_hil.trial.cohort import load_cohort
from rehab_hil.trial.run import TrialSpec, patient_task, run_tasks

pytestmark = [pytest.mark.xdist_group("trial"), pytest.mark.slow]  # one worker builds the module's local trial, once

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "finger_extensor.toml"
COHORT = ROOT / "profiles" / "sim" / "cohort.toml"
DURATION_S = "15.5"  # the first open at 3 s and one whole 12 s cycle of the Finger Extensor's session
ARGS = ["trial", "--config", str(CONFIG), "--controller", "assist_as_needed", "--cohort", str(COHORT),
        "--patients", "3", "--sessions", "1", "--duration", DURATION_S, "--seed", "15"]  # p0002 misses
MEASURES = {"success", "success_assisted", "success_last5", "assistance_ratio", "assistance_ratio_first",
            "assistance_ratio_last", "active_rom_deg", "sparc", "patient_torque_open_nm", "patient_torque_close_nm",
            "peak_temperature_c", "safety_events", "run_dir", "stop_reason"}


def _outcomes(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """What must not depend on where a patient ran: all but wall times and run folders' time stamps."""
    return [{**{k: v for k, v in p.items() if k != "wall_s"},
             "sessions": [{k: v for k, v in s.items() if k not in ("wall_s", "run_dir")} for s in p["sessions"]]}
            for p in doc["patients"]]


@pytest.fixture(scope="module")
def local_trial(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("trial") / "local"
    assert main([*ARGS, "--out", str(out), "--workers", "2"]) == 0
    return out


def test_a_trial_runs_each_patient_on_the_local_pool_and_writes_its_outcomes(local_trial):
    doc = json.loads((local_trial / "trial.json").read_text())
    assert doc["trial"]["patients_finished"] == 3 and not doc["trial"]["interrupted"]
    assert [p["id"] for p in doc["patients"]] == ["p0000", "p0001", "p0002"]
    for p in doc["patients"]:
        assert p["error"] is None, p["error"]
        assert "voluntary.flexion_capacity_nm" in p["parameters"] and p["stratum"] in ("mild", "moderate", "severe")
        (s,) = p["sessions"]
        assert MEASURES <= set(s) and s["cycles"] == 1 and s["stop_reason"] == "duration reached"
        assert 0.0 <= s["success_assisted"] <= 1.0 and s["assistance_start"] is not None
        run = local_trial / s["run_dir"]
        assert run.parent == local_trial / "patients" / p["id"]
        assert {"metadata.json", "run.csv", "sim_truth.csv"} <= {f.name for f in run.iterdir()}
        assert (local_trial / p["folder"] / "patient.toml").exists()
        assert list((local_trial / p["folder"] / "assistance").rglob("*.json"))  # the kept assistance
    assert doc["summary"]["patients"] == 3 and (local_trial / "trial.html").exists()


def test_record_failed_records_only_the_patients_who_miss_the_target_with_the_same_outcomes(local_trial, tmp_path):
    out = tmp_path / "failed-only"
    assert main([*ARGS, "--out", str(out), "--workers", "2", "--record", "failed"]) == 0
    doc = json.loads((out / "trial.json").read_text())
    recorded = json.loads((local_trial / "trial.json").read_text())
    assert _outcomes(doc) == [{**p, "replay_identical": True} if p["sessions"][0]["success_assisted"] < 0.8 else p
                              for p in _outcomes(recorded)]  # unrecorded sessions measure the same
    for p in doc["patients"]:
        (s,) = p["sessions"]
        missed = s["success_assisted"] < 0.8
        assert (s["run_dir"] is not None) == missed and p.get("replay_identical", missed) is missed
        assert (out / p["folder"] / "patient.toml").exists()
    assert any(p.get("replay_identical") for p in doc["patients"]), "no patient missed: the test shows nothing"


def test_the_same_seed_gives_the_same_outcomes_on_a_dask_cluster(local_trial, tmp_path):
    port = free_port()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    common = ["--host", "127.0.0.1", "--no-dashboard"]
    scheduler = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--port", str(port), *common],
                                 env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = subprocess.Popen([sys.executable, "-m", "dask", "worker", f"tcp://127.0.0.1:{port}", "--nworkers", "2",
                                "--nthreads", "1", *common], env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    try:
        _wait_for_workers(f"tcp://127.0.0.1:{port}", 2)
        out = tmp_path / "dask"
        assert main([*ARGS, "--out", str(out), "--scheduler", f"tcp://127.0.0.1:{port}"]) == 0
    finally:
        for proc in (workers, scheduler):
            proc.send_signal(signal.SIGINT)  # dask's own clean shutdown
        for proc in (workers, scheduler):
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    dask_doc = json.loads((out / "trial.json").read_text())
    local_doc = json.loads((local_trial / "trial.json").read_text())
    assert dask_doc["trial"]["backend"].startswith("dask tcp://127.0.0.1:")
    assert _outcomes(dask_doc) == _outcomes(local_doc)
    assert all((out / s["run_dir"] / "run.csv").exists() for p in dask_doc["patients"] for s in p["sessions"])


def _wait_for_workers(address: str, n: int, timeout_s: float = 60.0) -> None:
    from distributed import Client

    with Client(address, timeout="30s") as client:
        client.wait_for_workers(n, timeout=timeout_s)


def test_a_patient_whose_session_fails_is_recorded_and_the_others_run(tmp_path):
    cohort = load_cohort(COHORT)
    spec = TrialSpec(config=str(CONFIG), controller="assist_as_needed", cohort=str(COHORT), patients=2, sessions=2,
                     duration_s=float(DURATION_S), seed=3, out=str(tmp_path), workers=2)
    tasks = [patient_task(spec, cohort, cohort.sample(3, i)) for i in range(2)]
    tasks[0]["profile"] = {**tasks[0]["profile"], "voluntary": {**tasks[0]["profile"]["voluntary"],
                                                                 "flexion_capacity_nm": -1.0}}  # not a patient
    entries: list[dict[str, Any]] = []
    run_tasks(spec, tasks, entries.append)
    by_id = {e["id"]: e for e in entries}
    bad, good = by_id["p0000"], by_id["p0001"]
    assert bad["sessions"] == [] and bad["error"]["session"] == 1 and bad["error"]["type"].endswith("Error")
    assert "voluntary.flexion_capacity_nm" in bad["error"]["message"]
    assert good["error"] is None and [s["session"] for s in good["sessions"]] == [1, 2]
    assert good["sessions"][1]["assistance_resumed"]  # the second session started where the first ended
    assert good["sessions"][1]["assistance_start"] == good["sessions"][0]["assistance_end"]


def test_ctrl_c_writes_the_patients_that_finished_and_says_so_in_one_line(tmp_path):
    out = tmp_path / "stopped"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "rehab_hil.cli", *ARGS[:ARGS.index("--patients")],
                             "--patients", "6", "--duration", DURATION_S, "--out", str(out), "--workers", "1"],
                            env=env, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            start_new_session=True)
    assert proc.stderr is not None
    seen = []
    t0 = time.monotonic()
    for line in proc.stderr:  # not a terminal: one line per patient that ends
        seen.append(line)
        if line.startswith("rehab-hil trial: 1/6 ") or time.monotonic() - t0 > 240:
            break
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    rest = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130, "".join(seen) + rest
    assert rest.strip().splitlines()[-1] == "rehab-hil trial: interrupted"
    doc = json.loads((out / "trial.json").read_text())
    assert doc["trial"]["interrupted"] and 1 <= doc["trial"]["patients_finished"] < 6
    done = {p["id"] for p in doc["patients"]}
    assert {d.name for d in (out / "patients").iterdir()} == done  # no half-run patient's folder
    assert (out / "trial.html").exists()


@pytest.mark.skipif(find_chromium() is None, reason="no chromium: scripts/install_browser.sh installs it")
def test_trial_html_draws_every_plot_in_headless_chromium(local_trial):
    check = check_page(local_trial / "trial.html")
    assert check.state == "drawn" and check.errors == [] and check.page_error == ""
    assert check.plots == check.drawn == 2  # outcomes' distributions, success against each parameter
    page = (local_trial / "trial.html").read_text()
    assert 'href="patients/p0000/patient.toml"' in page
