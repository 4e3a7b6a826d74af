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

__all__ = ["profile_toml", "run_patient"]


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
    """Run one patient's sessions (``task``: ``trial.run.patient_task``); its entry of ``trial.json``."""
    t0 = time.perf_counter()
    folder = Path(task["out"]) / "patients" / task["id"]
    folder.mkdir(parents=True, exist_ok=True)
    entry: dict[str, Any] = {k: task[k] for k in ("id", "patient_id", "stratum", "fugl_meyer_ue", "seed", "traits",
                                                 "parameters")}
    entry.update(folder=f"patients/{task['id']}", sessions=[], error=None)
    profile = dict(task["profile"])
    for k in range(task["sessions"]):
        if (Path(task["out"]) / ".interrupted").exists():  # the trial was stopped (Ctrl-C) while this waited or ran
            shutil.rmtree(folder, ignore_errors=True)
            entry["error"] = {"session": k + 1, "type": "Interrupted", "message": "the trial was interrupted",
                              "traceback": ""}
            break
        if "recovery" in profile:  # a patient who recovers: one more session done each time
            rec = dict(profile["recovery"])
            rec["sessions_done"] = int(task["profile"]["recovery"].get("sessions_done", 0)) + k
            profile["recovery"] = rec
        path = folder / ("patient.toml" if k == 0 or "recovery" not in profile else f"patient-session{k + 1}.toml")
        path.write_text(profile_toml(profile, task["header"]), encoding="utf-8")
        try:
            entry["sessions"].append(_session(task, folder, path, k))
        except Exception as e:  # the patient's failure, recorded; the trial goes on
            entry["error"] = {"session": k + 1, "type": type(e).__name__, "message": str(e),
                              "traceback": traceback.format_exc(limit=-8)}
            break
    if (Path(task["out"]) / ".interrupted").exists():  # stopped while the last session ran: not in trial.json
        shutil.rmtree(folder, ignore_errors=True)
    entry["wall_s"] = time.perf_counter() - t0
    return entry


def _session(task: dict[str, Any], folder: Path, patient: Path, k: int) -> dict[str, Any]:
    """One session of the patient; the device line and any warning the session prints are kept as notes."""
    from rehab_hil.service.session import open_session
    from rehab_hil.trial.measures import session_measures

    t0 = time.perf_counter()
    said = io.StringIO()
    with contextlib.redirect_stderr(said), contextlib.redirect_stdout(said), open_session(
            task["config"], "inprocess", controller=task["controller"], sim_patient=patient, record=folder,
            assistance_store=folder / "assistance", learning_store=folder / "learning", twin=task["twin"]) as s:
        s.run(task["duration_s"])
        measures = session_measures(s)
    if measures["run_dir"] is not None:
        measures["run_dir"] = Path(measures["run_dir"]).relative_to(Path(task["out"])).as_posix()
    notes = [line for line in said.getvalue().splitlines() if line.strip() and not line.startswith("device: ")]
    return {"session": k + 1, **measures, "notes": notes, "wall_s": time.perf_counter() - t0}
