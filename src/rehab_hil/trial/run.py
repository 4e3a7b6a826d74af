"""A trial: the cohort drawn into one task per patient, the tasks run on a local process pool or a Dask
cluster, each finished patient handed back as it ends.

The patients are drawn here, before anything runs (``Cohort.sample``: each from its own stream of the
trial's seed), so a patient's profile does not depend on where or when it runs; each patient's
sessions run in one task, in order, on one process (its learned assistance carried across them). The
sessions are lockstep and deterministic: the same seed gives the same outcomes on either backend.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import uuid
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from typing import Any

from rehab_hil.trial.cohort import Cohort, SampledPatient
from rehab_hil.trial.patient_run import run_patient

__all__ = ["TrialSpec", "dask_results", "local_results", "patient_task", "run_tasks"]


@dataclass(frozen=True)
class TrialSpec:
    """What ``rehab-hil trial`` was asked (paths absolute: a worker may run in another folder)."""

    config: str
    controller: str
    cohort: str
    patients: int
    sessions: int
    duration_s: float
    seed: int
    out: str
    twin: bool = False
    scheduler: str | None = None
    workers: int | None = None  # the local pool's processes (None: the machine's cores)
    record: str = "all"  # "all": every session's run folder; "failed": only the patients who miss the target
    target_success: float = 0.8  # success of the driven moves a patient must reach (trial.results.meets_target)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def patient_task(spec: TrialSpec, cohort: Cohort, patient: SampledPatient) -> dict[str, Any]:
    """Everything a worker needs for one patient, as plain data."""
    header = (f"A patient drawn from the cohort {cohort.cohort_id} ({spec.cohort}), stratum {patient.stratum}:\n"
              f"trial seed {spec.seed}, patient {patient.index} (rehab-hil trial). Run alone: rehab-hil run "
              f"--config {spec.config} --device inprocess --sim-patient THIS_FILE")
    return {"id": patient.patient_id, "patient_id": patient.profile["patient_id"], "stratum": patient.stratum,
            "fugl_meyer_ue": patient.fugl_meyer_ue, "seed": patient.seed, "index": patient.index,
            "traits": list(patient.traits), "parameters": patient.parameters, "profile": patient.profile,
            "header": header, "config": spec.config, "controller": spec.controller, "sessions": spec.sessions,
            "duration_s": spec.duration_s, "out": spec.out, "twin": spec.twin, "record": spec.record,
            "target_success": spec.target_success}


def _quiet_worker() -> None:
    """A pool worker ignores Ctrl-C: the terminal's SIGINT reaches the whole process group, and the
    trial's process, not each worker, decides what stops (it terminates the pool)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def local_results(tasks: list[dict[str, Any]], workers: int | None) -> Iterator[dict[str, Any]]:
    """Each patient's entry as it finishes, on a pool of ``workers`` processes (default: the cores,
    never more than the patients). Spawned, not forked: a fork would copy the trial's threads' locks.
    Leaving the iteration early (Ctrl-C) terminates the workers and the sessions they ran."""
    n = max(1, min(workers or os.cpu_count() or 1, len(tasks)))
    pool = multiprocessing.get_context("spawn").Pool(n, initializer=_quiet_worker)
    try:
        yield from pool.imap_unordered(run_patient, tasks)
        pool.close()
    finally:
        pool.terminate()
        pool.join()


def dask_results(tasks: list[dict[str, Any]], address: str) -> Iterator[dict[str, Any]]:
    """Each patient's entry as it finishes, on the Dask cluster whose scheduler is at ``address``.
    A task lost with its worker comes back as the patient's error. Leaving early cancels what has
    not finished (a task already running on a worker runs to its end: Dask cannot stop it)."""
    from distributed import Client, as_completed

    trial = uuid.uuid4().hex[:12]  # keys of this trial only: a key the scheduler knows would return its old result
    with Client(address, timeout="20s") as client:
        futures = [client.submit(run_patient, t, key=f"rehab-hil-trial-{trial}-{t['id']}", pure=False)
                   for t in tasks]
        by_key = {f.key: t for f, t in zip(futures, tasks, strict=True)}
        try:
            for fut in as_completed(futures):
                try:
                    yield fut.result()
                except Exception as e:  # the worker died or the task could not run there
                    yield _lost(by_key[fut.key], e)
        finally:
            client.cancel(futures)


def _lost(task: dict[str, Any], e: BaseException) -> dict[str, Any]:
    """The entry of a patient whose task never returned (its worker died)."""
    entry = {k: task[k] for k in ("id", "patient_id", "stratum", "fugl_meyer_ue", "seed", "traits", "parameters")}
    entry.update(folder=f"patients/{task['id']}", sessions=[], wall_s=None,
                 error={"session": None, "type": type(e).__name__, "message": str(e), "traceback": ""})
    return entry


def run_tasks(spec: TrialSpec, tasks: list[dict[str, Any]],
              on_done: Callable[[dict[str, Any]], None]) -> None:
    """Run every task on the spec's backend, calling ``on_done`` with each patient's entry as it ends."""
    results = dask_results(tasks, spec.scheduler) if spec.scheduler else local_results(tasks, spec.workers)
    try:
        for entry in results:
            on_done(entry)
    finally:
        results.close()
