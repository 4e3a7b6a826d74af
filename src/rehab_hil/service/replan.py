"""The model loop closed live: the feedforward re-planned on the twin's thermal estimates, between cycles.

When the twin's thermal estimate (``twin/thermal.py``) finds the room, the convection or the supply
beyond its interval around the config's value, and the fit explains what the rig does, the
controller's feedforward is learned again on the model with those values (``plants.changes.
with_values``; the same ``build_controller`` and plan cache as the session's start) on a worker
thread, and the learning on the rig takes the new table at its next swap point in the closed hold
(``RigLearning.rebase``): it becomes the table in force and the one the forgetting pulls toward,
and the controller's own parts take the re-built controller's parameter values (its thermal
observer runs on the estimated room, draft and supply, its ceiling on the new plan's peak).
The re-plan takes seconds (a new model learning, ~6 s for the SMA); the loop never waits for it in
real time (a lockstep session does, at the swap point: its time is virtual). Only one re-plan runs
at a time; estimates that arrive meanwhile are planned on next, the latest only.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from rehab_hil.controllers.build import build_controller
from rehab_hil.plants.changes import with_values
from rehab_hil.service.rig_learning import RigLearning

__all__ = ["ThermalReplan"]


class ThermalReplan:
    """Re-plans a controller's feedforward on updated thermal config values; see the module docstring.
    ``request`` is the twin's ``on_thermal_change`` hook (it returns at once)."""

    def __init__(self, cfg: Any, controller: str, reference: Any, learning: RigLearning, source: str = "") -> None:
        self.cfg, self.controller, self.reference, self.learning = cfg, controller, reference, learning
        self.source = source
        self._lock = threading.Lock()
        self._next: dict[str, float] | None = None
        self._thread: threading.Thread | None = None
        self.requests = 0

    def request(self, updates: dict[str, float]) -> str:
        """Plan on ``updates`` ({config key: value}) now, or after the running re-plan; says what it does."""
        with self._lock:
            self.requests += 1
            self._next = dict(updates)
            if self._thread is None or not self._thread.is_alive():
                self.learning.expect_rebase()
                self._thread = threading.Thread(target=self._work, name="thermal-replan", daemon=True)
                self._thread.start()
        keys = ", ".join(f"{k} = {v:.4g}" for k, v in updates.items())
        return f"the feedforward is re-planned on {keys} and taken at the next cycle boundary"

    def _work(self) -> None:
        while True:
            with self._lock:
                updates, self._next = self._next, None
                if updates is None:
                    return
            self._plan(updates)

    def _plan(self, updates: dict[str, float]) -> None:
        """One re-plan: the model with ``updates``, its learned table handed to the learning."""
        start = time.monotonic()
        info: dict[str, Any] = {"replan_updates": updates}
        try:
            cfg = with_values(self.cfg, updates)
            built = build_controller(cfg, self.controller, self.reference, self.source, check=False)
            table = next(iter(built.plan.signals.values())) if built.plan is not None else None
            if table is None or len(table) != self.learning.spec.n:
                raise ValueError("the re-planned controller has no table of this session's length")
            info["replan_model_rmse_deg"] = float(built.plan.figures.get("model_rmse_deg", float("nan")))
            info["replan_ceiling_c"] = float(built.plan.figures.get("ceiling_c", float("nan")))
            retune = (built.diagram.compile(built.ctx.period_s, 1).params, dict(built.constants))
        except Exception as e:  # a failed re-plan leaves the table as it is, said so
            info["replan_error"] = f"{type(e).__name__}: {e}"
            table, retune = None, None
        info["replan_s"] = time.monotonic() - start
        self.learning.rebase(table, info, retune)

    def close(self, timeout_s: float = 30.0) -> None:
        """Wait for a running re-plan (its table is no longer taken once the loop has stopped)."""
        with self._lock:
            self._next = None
            th = self._thread
        if th is not None:
            th.join(timeout_s)
