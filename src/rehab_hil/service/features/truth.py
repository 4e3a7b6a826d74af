"""A simulated patient's truth as a session feature: the device writes the patient's true state (and, on
a heated actuator, the true actuator temperature) to a temporary ``sim_truth.csv``, moved into the run
directory once the device has closed it (``patient.truth.SimTruth``)."""

from __future__ import annotations

from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.patient.truth import TRUTH_FILE, SimTruth
from rehab_hil.service.features.base import Feature, SessionParts

__all__ = ["SimTruthFeature"]


class SimTruthFeature(Feature):
    """``sim_patient``: the truth file of the simulated patient (the session made ``truth`` before the rig)."""

    name = "sim_truth"

    def __init__(self, truth: SimTruth) -> None:
        self.truth = truth

    def open(self, parts: SessionParts) -> None:
        self.truth.run_dir = parts.run_dir

    def finish(self, result: RunResult) -> FeatureResult | None:
        where = str(self.truth.run_dir / TRUTH_FILE) if self.truth.run_dir is not None else None
        return FeatureResult(self.name, {"file": where})
