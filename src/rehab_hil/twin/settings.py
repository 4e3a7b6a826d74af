"""The ``[twin]`` table of a plant config: whether the model runs beside the rig, and how it judges."""

from __future__ import annotations

from pydantic import Field

from rehab_hil.config import Section
from rehab_hil.twin.monitor import MonitorSettings

__all__ = ["TwinSection"]


class TwinSection(Section):
    """The live twin (docs/twin.md): the plant model beside the rig, its residual test and the
    online estimate of the patient's interaction parameters."""

    enabled: bool = Field(False, description="run the twin in every `rehab-hil run` (also: run --twin)")
    segment_s: float = Field(0.25, gt=0.0, le=5.0, description="re-anchoring period: each residual is what the "
                             "model got wrong in this long from a measured start [s]")
    channels: list[str] = Field(default_factory=list, description="measured outputs whose residual is tested "
                                "(default: every output the rig measures)")
    learn_s: float = Field(10.0, gt=0.0, description="the normal residual level is learned over this long [s]")
    settle_s: float = Field(1.0, ge=0.0, description="... starting this long into the session [s]")
    drift_sigma: float = Field(4.0, gt=0.0, description="allowed excess over the normal level, in its spreads")
    min_excess_counts: float = Field(0.4, ge=0.0, description="... and at least this many sensor counts")
    threshold_counts: float = Field(1.5, gt=0.0, description="CUSUM alarm level [counts x segments]")
    stop_on_mismatch: bool = Field(False, description="a model mismatch trips the rig into its safe state "
                                   "(default: an event only)")
    diagnose: bool = Field(True, description="name the likeliest cause of a mismatch on the recent window")
    diagnose_window_s: float = Field(5.0, gt=0.5, le=30.0, description="data after the change the diagnosis "
                                     "fits on [s]")
    estimate: list[str] = Field(default_factory=list, description="interaction parameters estimated online, as "
                                "diagram parameters (part.param) or effect parameters (effect.param); default: "
                                "the contact's stiffness and damping when the model has a contact")
    estimate_segment_s: float | None = Field(None, gt=0.0, le=5.0, description="re-anchoring period of the online "
                                             "estimate's own model [s] (default: segment_s); a slow plant's "
                                             "monitor may look over longer segments than its estimate needs")
    forgetting_s: float = Field(2.0, gt=0.0, description="memory of the online estimate (RLS forgetting) [s]")
    min_realtime_factor: float = Field(5.0, gt=0.0, description="the model must run this many times faster than "
                                       "real time here, per model run a segment needs (the twin, the estimate and "
                                       "one per estimated parameter), or the twin is refused at start")

    def monitor(self) -> MonitorSettings:
        return MonitorSettings(learn_s=self.learn_s, settle_s=self.settle_s, drift_sigma=self.drift_sigma,
                               min_excess_counts=self.min_excess_counts, threshold_counts=self.threshold_counts)
