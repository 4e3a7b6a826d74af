"""Where the live twin's predictions and events go: the loop's other sinks.

Each is a ``TwinListener`` (``prediction``, ``mismatch``) called from the twin's thread; none
blocks. ``SinkOutput`` offers records to a sink (the recorder, the Foxglove feed): ``MessageRecord``
s on ``/twin/prediction`` (measured, predicted, residual and CUSUM per channel, 100 Hz) and
model-mismatch and thermal-change ``EventRecord`` s, which go on ``/rig/event`` beside the safety events.
``ZenohOutput``: ``rehab/<rig>/twin`` with kinds ``prediction``, ``model_mismatch`` and ``thermal_change``
(docs/telemetry.md).
"""

from __future__ import annotations

import math
from typing import Any

from rehab_hil.loop.records import EventRecord, MessageRecord
from rehab_hil.twin.monitor import MismatchEvent
from rehab_hil.twin.thermal import THERMAL_EVENT, ThermalEvent

__all__ = ["EVENT_KIND", "GENERIC_TWIN_FIELDS", "PREDICTION_TOPIC", "SinkOutput", "ZenohOutput", "prediction_topic"]

PREDICTION_TOPIC = "/twin/prediction"
# plant-independent fields of every prediction message, so one Foxglove layout plots every plant's twin
GENERIC_TWIN_FIELDS = ("angle_measured_deg", "angle_predicted_deg", "angle_residual_deg", "cusum_max_counts")
PREDICTION_SCHEMA = "rehab_hil.TwinPrediction"
EVENT_KIND = "model_mismatch"


def prediction_topic(prefix: str = "/rig") -> str:
    """A rig's twin prediction topic: ``/twin/prediction`` for the one rig of a session (as recorded),
    ``/rigs/<rig>/twin/prediction`` beside that rig's channels in a lab view."""
    return PREDICTION_TOPIC if prefix == "/rig" else f"{prefix}{PREDICTION_TOPIC}"


class SinkOutput:
    """Predictions and final mismatch events offered to one sink (the recorder writes them into the
    session's MCAP, the Foxglove feed shows them); a full sink counts them as dropped."""

    def __init__(self, sink: Any) -> None:
        self.sink = sink

    def prediction(self, msg: dict[str, float]) -> None:
        self.sink.offer(MessageRecord(PREDICTION_TOPIC, PREDICTION_SCHEMA, msg))

    def mismatch(self, event: MismatchEvent, final: bool) -> None:
        if final:  # one event per mismatch, with its cause once diagnosed
            self.sink.offer(EventRecord(event.t_s, EVENT_KIND, event.text()))

    def thermal(self, event: ThermalEvent) -> None:
        self.sink.offer(EventRecord(event.t_s, THERMAL_EVENT, event.text()))


class ZenohOutput:
    """Predictions and events on ``rehab/<rig>/twin`` (``TelemetryPublisher.offer_twin``)."""

    def __init__(self, publisher: Any) -> None:
        self.publisher = publisher

    def prediction(self, msg: dict[str, float]) -> None:
        self.publisher.offer_twin("prediction", {k: (v if math.isfinite(v) else None) for k, v in msg.items()})

    def mismatch(self, event: MismatchEvent, final: bool) -> None:
        body = {k: v for k, v in event.as_dict().items() if k != "kind"}  # the envelope carries the kind
        self.publisher.offer_twin(EVENT_KIND, {**body, "final": final, "text": event.text()})

    def thermal(self, event: ThermalEvent) -> None:
        body = {k: v for k, v in event.as_dict().items() if k != "kind"}
        self.publisher.offer_twin(THERMAL_EVENT, {**body, "text": event.text()})
