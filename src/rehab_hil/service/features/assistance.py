"""Assist-as-needed's assistance kept across sessions as a session feature: the session starts where this
patient's last one on this rig and config ended (``service.assist_store``), and saves where it ends."""

from __future__ import annotations

from typing import Any

from rehab_hil.controllers.assist_as_needed import learned_directions
from rehab_hil.controllers.build import settings_for
from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.service.assist_store import AssistanceStore, KeptAssistance, default_assistance_dir
from rehab_hil.service.features.base import Feature, SessionParts

__all__ = ["KeptAssistanceFeature", "assistance_directions", "assistance_line"]


def assistance_directions(controller: Any) -> dict[str, str]:
    """The assistance states a controller learns per direction ({} for one that learns none)."""
    declared = getattr(controller, "controller", None)
    if declared is None or controller.reference.kind != "session":
        return {}
    return learned_directions(declared)


def assistance_line(a: dict[str, Any]) -> str:
    """Where assist-as-needed started and what it saved for the patient's next session."""
    how = "fresh" if a["fresh"] else "resumed" if a["resumed"] else "from the config" + (
        " (the store was not usable)" if a["problem"] else "")
    moves = ", ".join(f"{d} {a['start'][d]:.2f} -> {a['end'][d]:.2f}" for d in a["end"])
    saved = a["error"] or f"saved (session {a['sessions']}): {a['store']}"
    return f"{moves}; {how}; {saved}"


class KeptAssistanceFeature(Feature):
    """An assist-as-needed controller's assistance per patient, rig and config (docs/patient.md)."""

    name = "assistance"

    def __init__(self) -> None:
        self.kept: KeptAssistance | None = None

    def open(self, parts: SessionParts) -> None:
        """Start from the stored assistance; a store that cannot be used is one note (the CLI's warning
        line) and the config's start."""
        runtime, opts = parts.controller, parts.options.learning
        directions = assistance_directions(runtime)
        gains = settings_for(parts.cfg, runtime.name, str(parts.config_path))
        key = {"plant": parts.cfg.plant, "controller": runtime.name, "directions": sorted(directions),
               "feedback": {k: getattr(gains, k) for k in ("kp_per_deg", "ki_per_deg_s", "kd_s_per_deg")}}
        store = AssistanceStore(opts.assistance_store or default_assistance_dir(), parts.identity.rig,
                                parts.identity.patient, parts.config_path.stem, key)
        self.kept = KeptAssistance(store, runtime, directions, opts.fresh_assistance)
        if self.kept.problem:
            runtime.notes.append(self.kept.problem)

    def finish(self, result: RunResult) -> FeatureResult | None:
        assert self.kept is not None
        ended = f"{result.events[0].reason}: {result.stop_reason}" if result.events else result.stop_reason
        summary = self.kept.finish(ended)
        return FeatureResult(self.name, summary, {"assistance_store": summary},
                             (("assistance kept", assistance_line(summary)),))

    def failed(self, error: BaseException) -> None:
        """The loop raised: what was learned so far is kept."""
        if self.kept is not None:
            self.kept.finish(f"error: {type(error).__name__}")
