"""A whole trial, from the drawn cohort to ``trial.json`` and ``trial.html`` in the out folder.

Ctrl-C writes what finished: the patients that ended are in both files, the folders of the patients
that had not are removed (a local pool's workers are terminated; on a Dask cluster a session already
running ends on its worker, sees the ``.interrupted`` mark and removes its folder), and the
``KeyboardInterrupt`` goes on to the caller (the CLI's one line, exit 130).
"""

from __future__ import annotations

import datetime as dt
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rehab_hil.trial.cohort import Cohort
from rehab_hil.trial.patient_run import INTERRUPTED_MARK
from rehab_hil.trial.results import TRIAL_FILE, summary, write_trial_json
from rehab_hil.trial.run import TrialSpec, patient_task, run_tasks

__all__ = ["INTERRUPTED_MARK", "TRIAL_PAGE", "run_trial"]

TRIAL_PAGE = "trial.html"


def _now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def run_trial(spec: TrialSpec, cohort: Cohort, target: float,
              on_entry: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Draw the cohort, run every patient, write ``trial.json`` and ``trial.html``; the trial's document.
    ``on_entry`` sees each patient's entry as it ends (the progress bar)."""
    out = Path(spec.out)
    (out / "patients").mkdir(parents=True, exist_ok=True)
    tasks = [patient_task(spec, cohort, cohort.sample(spec.seed, i)) for i in range(spec.patients)]
    entries: dict[str, dict[str, Any]] = {}
    started, t0 = _now(), time.perf_counter()

    def done(entry: dict[str, Any]) -> None:
        entries[entry["id"]] = entry
        if on_entry is not None:
            on_entry(entry)

    try:
        run_tasks(spec, tasks, done)
    except KeyboardInterrupt:
        (out / INTERRUPTED_MARK).touch()
        for t in tasks:
            if t["id"] not in entries:
                shutil.rmtree(out / "patients" / t["id"], ignore_errors=True)
        _write(spec, cohort, target, entries, started, time.perf_counter() - t0, interrupted=True)
        raise
    return _write(spec, cohort, target, entries, started, time.perf_counter() - t0, interrupted=False)


def _write(spec: TrialSpec, cohort: Cohort, target: float, entries: dict[str, dict[str, Any]], started: str,
           wall_s: float, interrupted: bool) -> dict[str, Any]:
    """``trial.json`` and ``trial.html`` of the patients that ended (in patient order)."""
    from rehab_hil.trial.report import trial_page

    patients = [entries[k] for k in sorted(entries)]
    backend = (f"dask {spec.scheduler}" if spec.scheduler
               else f"local pool of {max(1, min(spec.workers or os.cpu_count() or 1, spec.patients))} processes")
    doc = {"trial": {**spec.as_dict(), "cohort_id": cohort.cohort_id, "cohort_note": cohort.note,
                     "backend": backend, "started": started, "ended": _now(), "wall_s": wall_s,
                     "interrupted": interrupted, "patients_finished": len(patients)},
           "summary": summary(patients, target), "patients": patients}
    out = Path(spec.out)
    write_trial_json(out / TRIAL_FILE, doc)
    trial_page(doc).write(out / TRIAL_PAGE)
    return doc
