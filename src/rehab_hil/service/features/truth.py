"""A simulated rig's truth as a session feature: the device writes its true state (the heated actuator's
temperature, with or without a patient, and a simulated patient's state) to a temporary
``sim_truth.csv``, moved into the run directory once the device has closed it
(``patient.truth.SimTruth``)."""

from __future__ import annotations

from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.patient.truth import TRUTH_FILE, SimTruth
from rehab_hil.service.features.base import Feature, SessionParts

__all__ = ["SimTruthFeature"]


class SimTruthFeature(Feature):
    """The truth file of a simulated rig (the session made ``truth`` before the rig): a simulated patient's
    session, or any recorded session on a simulated rig."""

    name = "sim_truth"

    def __init__(self, truth: SimTruth) -> None:
        self.truth = truth

    def open(self, parts: SessionParts) -> None:
        self.truth.run_dir = parts.run_dir

    def finish(self, result: RunResult) -> FeatureResult | None:
        where = str(self.truth.run_dir / TRUTH_FILE) if self.truth.run_dir is not None else None
        return FeatureResult(self.name, {"file": where}, {"sim_truth": TRUTH_FILE} if where is not None else {})
