"""The learning on the rig as a session feature: the stored table to start from, each command record fed
to the learning (``service.rig_learning``), its tables offered to the loop at the swap points, and with
the twin the thermal re-plan (``service.replan``). A session that ended in a safety trip teaches the next
one nothing."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rehab_hil.loop.records import CommandRecord
from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.service.errors import SessionError
from rehab_hil.service.features.base import Feature, LoopHandle, SessionParts
from rehab_hil.service.replan import ThermalReplan
from rehab_hil.service.rig_learning import LOCKSTEP_REPLAN_WAIT_S, RigLearning, TableStore, default_store_dir

__all__ = ["RigLearningFeature", "learning_wanted", "per_cycle_learning"]


def learning_wanted(controller: Any, asked: bool | None) -> bool:
    """Whether the session learns on the rig: asked for, else the controller's ``rig_learning``; refused
    in one line for a controller with no periodic plan."""
    declared = getattr(controller, "controller", None)
    spec = getattr(declared, "rig_learning", None)
    if spec is None and asked:
        raise SessionError("rig_learning", f"controller {controller.name!r} has no periodic plan to learn on the rig")
    on = spec is not None and spec.enabled if asked is None else asked
    return bool(on and spec is not None and declared.plan is not None and controller.reference.kind == "session")


class RigLearningFeature(Feature):
    """``rig_learning``: the feedforward learned cycle after cycle from the measured error (docs/controllers.md)."""

    name = "rig_learning"

    def __init__(self) -> None:
        self.learning: RigLearning | None = None
        self.replan: ThermalReplan | None = None
        self.runtime: Any = None
        self.loop: LoopHandle | None = None
        self.refused = 0  # tables the loop process had not room for (taken at a later swap point)
        self.twin_run: Any = None

    def open(self, parts: SessionParts) -> None:
        runtime = self.runtime = parts.controller
        spec, plan = runtime.controller.rig_learning, runtime.controller.plan
        opts = parts.options.learning
        store = TableStore(opts.learning_store or default_store_dir(), parts.identity.rig, parts.identity.patient,
                           spec.plan_key)
        self.learning = RigLearning(spec, next(iter(plan.signals.values())), store, lockstep=parts.lockstep)
        runtime.learn_on_rig(self.learning.table)
        twin = parts.features.get("twin")
        if opts.thermal_replan and twin is not None and twin.run.twin.thermal is not None:  # type: ignore[attr-defined]
            self.replan = ThermalReplan(parts.cfg, runtime.name, runtime.reference, self.learning,
                                        str(parts.config_path))
            self.twin_run = run = twin.run  # type: ignore[attr-defined]
            self.learning.catch_up = lambda: run.live.catch_up(LOCKSTEP_REPLAN_WAIT_S)

    def feeds(self) -> list[Callable[[CommandRecord], None]]:
        return [self._record]

    def started(self, loop: LoopHandle) -> None:
        """The loop takes the tables; the twin's thermal hook re-plans (after a hook the user set)."""
        self.loop = loop
        if self.replan is not None:
            self.twin_run.on_thermal_change = _chained(self.twin_run.on_thermal_change, self.replan.request)

    def _record(self, rec: CommandRecord) -> None:
        """One controlled sample; at a swap point the new table (and a re-plan's retune) to the loop."""
        learning, loop = self.learning, self.loop
        assert learning is not None and loop is not None
        new = learning.record(rec.time_s, rec.row, rec.error_deg, rec.effort, rec.saturation)
        if new is not None and not loop.offer_table(new, learning.take_retune()):
            self.refused += 1

    def finish(self, result: RunResult) -> FeatureResult | None:
        learning = self.learning
        assert learning is not None
        if self.replan is not None:
            self.replan.close()
        learning.close()
        if result.events:  # a session that ended in a safety trip teaches the next one nothing
            learning.forget_session()
        summary = {**learning.summary(), "refused": self.refused}
        swapped = getattr(self.runtime, "swapped_at", [])
        if swapped:  # a loop process took the tables at its own swap windows
            summary["swapped_at_s"] = [round(t, 4) for t in swapped]
        cyc = result.session_cycles = per_cycle_learning(result.session_cycles, learning.log,
                                                         self.runtime.reference.period_s)
        lines = ()
        if cyc:
            lines = (("learning on the rig", f"per-cycle RMSE {cyc[0]['rmse_deg']:.2f} -> {cyc[-1]['rmse_deg']:.2f} "
                      f"deg; {summary['updates']} updates ({summary['trials']} in all, "
                      f"{'resumed' if summary['resumed'] else 'from the model'}); {summary['store']}"),)
        return FeatureResult(self.name, summary, {"rig_learning": summary}, lines)

    def close(self) -> None:
        if self.replan is not None:
            self.replan.close()
        if self.learning is not None:
            self.learning.close()


def per_cycle_learning(cycles: Sequence[dict[str, float]], log: list[dict[str, Any]],
                       period_s: float) -> list[dict[str, Any]]:
    """Each cycle's figures with what the learning did: ``learn_trial``, the table in force when
    the cycle started (0: the model's, or the stored one's count), and the update made from it
    (swapped in during its closed hold: the share kept, the change, the predicted peak)."""
    out = []
    for c in cycles:
        start = c["start_s"]
        before = [e for e in log if e["t_s"] <= start]
        row: dict[str, Any] = {**c, "learn_trial": before[-1]["trial"] if before else (log[0]["trial"] - 1 if log
                                                                                         else 0.0)}
        for made in (e for e in log if start < e["t_s"] <= start + period_s):  # an update, a re-plan
            row.update({k: v for k, v in made.items() if k.startswith("learn_") and k != "learn_error_rmse_deg"})
        out.append(row)
    return out


def _chained(first: Callable[[dict[str, float]], Any] | None, then: Callable[[dict[str, float]], str]
             ) -> Callable[[dict[str, float]], str]:
    """A thermal-change hook that calls a user's own hook (set before ``run``) and then the re-plan."""
    if first is None:
        return then

    def hook(updates: dict[str, float]) -> str:
        first(updates)
        return then(updates)
    return hook
