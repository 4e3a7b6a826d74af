"""One patient of a trial, on whichever process runs it: the drawn profile written into the patient's
folder, then the patient's sessions one after the other on the in-process rig (lockstep), the learned
assistance carried from each session to the next by the patient's own assistance store.

``run_patient(task)`` takes and returns plain data (a local pool and a Dask worker pickle it), and
never raises for a session that fails: the error is the patient's entry, and the trial goes on.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import time
import traceback
from pathlib import Path
from typing import Any

from rehab_hil.trial.results import meets_target

__all__ = ["INTERRUPTED_MARK", "profile_toml", "run_patient"]

INTERRUPTED_MARK = ".interrupted"  # in the out folder: the trial was stopped (trial.driver)


def profile_toml(profile: dict[str, Any], header: str) -> str:
    """A PATIENT.toml of a drawn profile (scalars, then one table each), ``header`` as its comment."""
    lines = [f"# {line}" for line in header.splitlines()]
    tables = {k: v for k, v in profile.items() if isinstance(v, dict)}
    lines += [f"{k} = {_toml_value(v)}" for k, v in profile.items() if k not in tables]
    for name, table in tables.items():
        lines += ["", f"[{name}]", *(f"{k} = {_toml_value(v)}" for k, v in table.items())]
    return "\n".join(lines) + "\n"


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)  # a Python float's repr is a TOML float (1e-05, 0.5); never inf or nan here
    return json.dumps(str(v))  # a TOML basic string


def run_patient(task: dict[str, Any]) -> dict[str, Any]:
    """Run one patient's sessions (``task``: ``trial.run.patient_task``); its entry of ``trial.json``.
    Whatever fails (a session, the patient's folder) is the entry's ``error``, never an exception: a
    pool or a cluster goes on with the other patients. ``task["record"]`` "failed": the sessions run
    unrecorded, and a patient who misses the target runs them again, recorded, from the same start
    (lockstep sessions repeat exactly: ``replay_identical`` says whether they did)."""
    t0 = time.perf_counter()
    out = Path(task["out"])
    folder = out / "patients" / task["id"]
    entry: dict[str, Any] = {k: task[k] for k in ("id", "patient_id", "stratum", "fugl_meyer_ue", "seed", "traits",
                                                 "parameters")}
    entry.update(folder=f"patients/{task['id']}", sessions=[], error=None)
    record_all = task.get("record", "all") == "all"
    entry["error"] = _sessions(task, folder, entry["sessions"], record_all)
    if not record_all and not (out / INTERRUPTED_MARK).exists() and not meets_target(entry, task["target_success"]):
        first = entry["sessions"]
        for store in ("assistance", "learning"):  # the replay starts where the first pass started
            shutil.rmtree(folder / store, ignore_errors=True)
        entry["sessions"] = []
        entry["error"] = _sessions(task, folder, entry["sessions"], True)
        entry["replay_identical"] = _outcomes(first) == _outcomes(entry["sessions"])
    if (out / INTERRUPTED_MARK).exists():  # stopped while this ran: not in trial.json, and no half folder
        shutil.rmtree(folder, ignore_errors=True)
    entry["wall_s"] = time.perf_counter() - t0
    return entry


def _sessions(task: dict[str, Any], folder: Path, into: list[dict[str, Any]], record: bool) -> dict[str, Any] | None:
    """The patient's sessions in order, each one's measures appended to ``into``; the error that
    stopped them (None: all ran)."""
    k = 0
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for k in range(task["sessions"]):
            if (Path(task["out"]) / INTERRUPTED_MARK).exists():  # the trial was stopped (Ctrl-C) meanwhile
                raise _Interrupted("the trial was interrupted")
            into.append(_session(task, folder, _profile_file(task, folder, k), k, record))
    except Exception as e:  # the patient's failure, recorded; the trial goes on
        return {"session": k + 1, "type": type(e).__name__, "message": str(e),
                "traceback": traceback.format_exc(limit=-8)}
    return None


def _outcomes(sessions: list[dict[str, Any]]) -> str:
    """The sessions' measures without what may differ between two runs (wall time, folder, notes)."""
    return json.dumps([{k: v for k, v in s.items() if k not in ("wall_s", "run_dir", "notes")} for s in sessions],
                      sort_keys=True, default=str)


class _Interrupted(Exception):
    """The trial's Ctrl-C, seen by a patient still queued or running (on a Dask worker)."""


def _profile_file(task: dict[str, Any], folder: Path, k: int) -> Path:
    """The patient's file for session ``k`` (from 0): ``patient.toml``; a patient who recovers
    (``[recovery]``) has one more session done each time, in ``patient-session<k+1>.toml``."""
    profile = dict(task["profile"])
    name = "patient.toml"
    if "recovery" in profile and k > 0:
        rec = dict(profile["recovery"])
        rec["sessions_done"] = int(rec.get("sessions_done", 0)) + k
        profile["recovery"] = rec
        name = f"patient-session{k + 1}.toml"
    path = folder / name
    path.write_text(profile_toml(profile, task["header"]), encoding="utf-8")
    return path


def _session(task: dict[str, Any], folder: Path, patient: Path, k: int, record: bool) -> dict[str, Any]:
    """One session of the patient; the device line and any warning the session prints are kept as notes."""
    from rehab_hil.service.session import open_session
    from rehab_hil.trial.measures import session_measures

    t0 = time.perf_counter()
    said = io.StringIO()
    with contextlib.redirect_stderr(said), contextlib.redirect_stdout(said), open_session(
            task["config"], "inprocess", controller=task["controller"], sim_patient=patient,
            record=folder if record else None,
            assistance_store=folder / "assistance", learning_store=folder / "learning", twin=task["twin"]) as s:
        s.run(task["duration_s"])
        measures = session_measures(s)
    if measures["run_dir"] is not None:
        measures["run_dir"] = Path(measures["run_dir"]).relative_to(Path(task["out"])).as_posix()
    notes = [line for line in said.getvalue().splitlines() if line.strip() and not line.startswith("device: ")]
    return {"session": k + 1, **measures, "notes": notes, "wall_s": time.perf_counter() - t0}
