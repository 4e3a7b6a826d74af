"""The loop's side of learning on the rig: collect each cycle's error, update off the loop, swap at a boundary.

``controllers/rig_learning.py`` computes an update; here ``RigLearning`` runs it in a session
without costing the real-time loop anything but a few array writes per sample:

- after each command is out (``ControllerRuntime.advance``), the sample's tracking error and the
  applied effort are written into the row of the table that was read (``record``);
- ``lead_s`` before each swap point, once a whole cycle has been seen since the last swap, a copy
  of that cycle goes to a worker thread, which computes the next table (the numba engine of the
  envelope's thermal check releases the GIL);
- at the swap point (``swap_s`` into each period: the middle of the closed hold, where the wire
  is cold and the table idle) the loop takes the new table if it is ready, between two samples.
  A real-time session never waits for it (a late update is counted and taken at the next swap
  point); a lockstep session does (its time is virtual: nothing is lost, and the run is the same
  every time).

A re-plan on the model updated by the twin's thermal estimates (``service/replan.py``) hands a
new model table to ``rebase``: at the next swap point it becomes both the table in force and the
one the forgetting pulls toward (an update computed from the old table meanwhile is dropped).

Each accepted table is written to ``store`` (``TableStore``) by the worker, so the next session
on the same rig, patient and plan starts from it, and a session with another patient (or none) never
does. ``log`` says what each update did.
"""

from __future__ import annotations

import hashlib
import os
import queue
import threading
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.controllers.rig_learning import RigLearner, RigLearningSpec
from rehab_hil.models.engine import cache_dir
from rehab_hil.outputs import replacing
from rehab_hil.service.identity import store_name

__all__ = ["LEAD_S", "LOCKSTEP_REPLAN_WAIT_S", "RigLearning", "TableStore", "default_store_dir"]

LEAD_S = 0.5  # a cycle's copy goes to the worker this long before the swap point [s]: the update takes ~10-50 ms
LOCKSTEP_WAIT_S = 30.0  # a lockstep session waits at most this long (wall time) for an update
LOCKSTEP_REPLAN_WAIT_S = 120.0  # ... and for a re-plan (a model learning: ~6 s idle, a minute on a busy machine)


def default_store_dir() -> Path:
    """Where learned tables are kept: ``~/.cache/rehab-hil/rig_learning`` (``REHAB_HIL_CACHE_DIR``
    or ``XDG_CACHE_HOME`` move it with the plan cache; ``REHAB_HIL_LEARNING_DIR`` moves it alone:
    the test suite gives each test its own)."""
    env = os.environ.get("REHAB_HIL_LEARNING_DIR")
    return Path(env) if env else cache_dir().parent / "rig_learning"


class TableStore:
    """One learned table per rig, patient and plan (``service.identity``: the session's ``SessionIdentity``,
    each part through ``store_name``): ``<dir>/<rig>/<patient>-<plan>.npz`` holding the table, the trials it
    took and the plan's key (a table for another plan is never used). Writes are atomic (a killed session
    leaves the previous table)."""

    def __init__(self, directory: Path, rig: str, patient: str | None, plan_key: str) -> None:
        self.plan_key = plan_key
        plan = hashlib.sha1(plan_key.encode()).hexdigest()[:16]
        self.path = Path(directory) / store_name(rig) / f"{store_name(patient)}-{plan}.npz"

    def load(self, n: int) -> tuple[np.ndarray, int] | None:
        """The stored table and its trial count, or None (none, damaged, another plan or length)."""
        try:
            with np.load(self.path) as z:
                if str(z["plan_key"]) != self.plan_key or z["table"].shape != (n,):
                    return None
                return np.asarray(z["table"], float), int(z["trials"])
        except (OSError, ValueError, KeyError):
            return None

    def save(self, table: np.ndarray, trials: int) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with replacing(self.path) as tmp, open(tmp, "wb") as f:  # a file object: savez adds no suffix
            np.savez(f, table=table, trials=np.array(trials), plan_key=np.array(self.plan_key))



class ReplanHandoff:
    """A re-planned model table on its way from the re-plan's thread to the loop's next swap point:
    the table (already fitted), what the re-plan says of it and the re-built controller's retune."""

    def __init__(self) -> None:
        self._waiting: tuple[np.ndarray, dict[str, Any], Any] | None = None
        self._due = threading.Event()  # set while a re-plan runs: a lockstep swap waits for it
        self._ready = threading.Event()

    def expect(self) -> None:
        """A re-plan has started."""
        self._ready.clear()
        self._due.set()

    def put(self, fitted: tuple[np.ndarray, dict[str, Any], Any] | None) -> None:
        """The re-plan's result (None: it failed), from any thread."""
        if fitted is not None:
            self._waiting = fitted
        self._due.clear()
        self._ready.set()

    def take(self, wait_s: float = 0.0) -> tuple[np.ndarray, dict[str, Any], Any] | None:
        """The waiting result, once; with ``wait_s`` a re-plan still running is waited for that long."""
        if wait_s > 0.0 and self._due.is_set():
            self._ready.wait(wait_s)
        taken, self._waiting = self._waiting, None
        return taken


class RigLearning:
    """One session's learning on the rig; see the module docstring. ``table`` is the array the
    runtime reads (replaced, never written in place, at a swap)."""

    def __init__(self, spec: RigLearningSpec, base: np.ndarray, store: TableStore | None = None,
                 lockstep: bool = False) -> None:
        self.spec, self.store, self.lockstep = spec, store, lockstep
        self.learner = RigLearner(spec, base)
        self.learner.prepare()  # before the loop: nothing slow is left for the worker's first update
        n = spec.n
        self.table = np.asarray(base, float).copy()
        self.trials = 0  # updates this table has taken on the rig (across sessions, when stored)
        self.resumed = False
        stored = store.load(n) if store is not None else None
        if stored is not None:
            self.table, self.trials = stored
            self.resumed = True
        self._start = (self.table, self.trials)  # what the store held: put back if the session trips
        self._error = np.zeros(n)
        self._effort = np.zeros(n)
        self._cut = np.zeros(n, bool)
        self._next_submit = spec.swap_s - LEAD_S
        self._next_swap = spec.swap_s
        self._last_swap_t = 0.0
        self._pending = False
        self._result: tuple[np.ndarray, dict[str, float]] | None = None
        self._done = threading.Event()
        self._jobs: queue.Queue[Any] = queue.Queue(maxsize=1)
        self.log: list[dict[str, float]] = []  # one entry per swap: when, trial, what the update did
        self.late = 0  # updates not ready at their swap point (real time only)
        self.forgotten = False  # the store put back as the session found it (it ended in a safety trip)
        self._replan = ReplanHandoff()
        self._drop_result = False  # the worker's update in flight was made from a table a re-plan replaced
        self._retune: Any = None  # the re-plan's controller parameters taken with its table, for the runtime once
        self.catch_up: Any = None  # lockstep: called at each swap point, returns once the twin has caught up
        self._worker: threading.Thread | None = threading.Thread(target=self._work, name="rig-learning", daemon=True)
        self._worker.start()

    def record(self, t_s: float, row: int, error_deg: float, effort: float, saturation: float = 0.0
               ) -> np.ndarray | None:
        """One controlled sample (after its command is out): the error, the applied effort and the
        demand the limit did not apply (a ceiling's or the guard's cut, the clamp); returns a new
        table to read from now on at a swap point, else None."""
        if 0 <= row < len(self._error):
            self._error[row] = error_deg
            self._effort[row] = effort
            self._cut[row] = saturation > 1e-9
        if t_s >= self._next_submit:
            self._next_submit += self.spec.period_s
            if t_s - self._last_swap_t >= self.spec.period_s - LEAD_S - 1e-9 and not self._pending:
                self._submit()
        if t_s >= self._next_swap:
            self._next_swap += self.spec.period_s
            return self._swap(t_s)
        return None

    def _submit(self) -> None:
        self._pending = True
        self._done.clear()
        self._jobs.put((self.table, self._error.copy(), self._effort.copy(), self._cut.copy(), self.trials + 1))

    def _work(self) -> None:
        """The worker thread: one update per job; the accepted table stored as it is made."""
        while (job := self._jobs.get()) is not None:
            table, error, effort, cut, trial = job
            try:
                new, info = self.learner.update(table, error, effort, cut)
                if self.store is not None:
                    self.store.save(new, trial)
                self._result = (new, info)
            except Exception as e:  # a failed update leaves the table as it is, said so
                self._result = (table, {"learn_failed": 1.0, "learn_error": str(e)})  # type: ignore[dict-item]
            self._done.set()

    def expect_rebase(self) -> None:
        """A re-plan has started (a lockstep session's next swap waits for its table)."""
        self._replan.expect()

    def rebase(self, table: np.ndarray | None, info: dict[str, Any], retune: Any = None) -> None:
        """A re-planned model table (from any thread), taken at the next swap point with ``retune``
        (the re-built controller's parameters and constants, for ``ControllerRuntime.retune``);
        None: the re-plan failed (``info`` says why) and the table stays."""
        if table is None:
            self.log.append({"t_s": float("nan"), "trial": float(self.trials), **info})
        self._replan.put(None if table is None else (self.learner.fit(np.asarray(table, float)), info, retune))

    def take_retune(self) -> Any:
        """The re-planned controller's (parameters, constants) that came with the table just swapped in, once."""
        out, self._retune = self._retune, None
        return out

    def _take_rebase(self, t_s: float) -> np.ndarray | None:
        """At a swap point: the re-planned table, if one is ready (a lockstep session waits for a
        re-plan that is running)."""
        if self.lockstep and self.catch_up is not None:
            self.catch_up()  # what the twin makes of the samples so far is known at the same point every run
        taken = self._replan.take(LOCKSTEP_REPLAN_WAIT_S if self.lockstep else 0.0)
        if taken is None:
            return None
        table, info, self._retune = taken
        self.learner.base = table.copy()  # the forgetting now pulls toward the re-planned model's table
        self.table = table
        self._last_swap_t = t_s
        self._drop_result = self._pending  # an update from the replaced table is not used
        self.log.append({"t_s": t_s, "trial": float(self.trials), "learn_replanned": 1.0, **info})
        return table

    def _swap(self, t_s: float) -> np.ndarray | None:
        """At a swap point: a re-planned table, else the worker's table, if there is one (a lockstep
        session waits for it)."""
        rebased = self._take_rebase(t_s)
        if rebased is not None:
            return rebased
        if not self._pending:
            return None
        if not self._done.is_set() and not (self.lockstep and self._done.wait(LOCKSTEP_WAIT_S)):
            self.late += 1
            return None  # real time: never wait; it is taken at the next swap point
        self._pending = False
        assert self._result is not None
        new, info = self._result
        self._result = None
        if self._drop_result:
            self._drop_result = False
            return None
        self.trials += 1
        self.table = new
        self._last_swap_t = t_s
        self.log.append({"t_s": t_s, "trial": float(self.trials), **info})
        return new

    def close(self) -> None:
        """Stop the worker (its last update, if any, is already stored)."""
        if self._worker is not None:
            self._jobs.put(None)
            self._worker.join(timeout=5.0)
            self._worker = None

    def forget_session(self) -> None:
        """Leave the store as this session found it (after a safety trip: what was learned in a
        session that ended in one is not carried into the next). Call after ``close``."""
        if self.store is None:
            return
        if self.resumed:
            self.store.save(*self._start)
        else:
            self.store.path.unlink(missing_ok=True)
        self.forgotten = True

    def summary(self) -> dict[str, Any]:
        """What the session's learning did (metadata.json ``rig_learning``)."""
        replans = [e for e in self.log if "learn_replanned" in e or "replan_error" in e]
        return {"enabled": True, "resumed": self.resumed, "trials": self.trials,
                "updates": len(self.log) - len(replans), "replans": replans,
                "late": self.late, "store": str(self.store.path) if self.store is not None else None,
                "kept": not self.forgotten,
                "gain_per_deg": self.spec.gain_per_deg, "forgetting": self.spec.forgetting}
