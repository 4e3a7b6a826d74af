"""Where the live twin's predictions and events go: the recording, zenoh and Foxglove.

Each is a ``TwinListener`` (``prediction``, ``mismatch``) called from the twin's thread; none
blocks. Topics: MCAP and Foxglove ``/twin/prediction`` (measured, predicted, residual and CUSUM
per channel, 100 Hz) and model-mismatch events on ``/rig/event`` beside the safety events; zenoh
``rehab/<rig>/twin`` with kinds ``prediction`` and ``model_mismatch`` (docs/telemetry.md).
"""

from __future__ import annotations

import json
import math
from typing import Any

from rehab_hil.twin.monitor import MismatchEvent

__all__ = ["EVENT_KIND", "GENERIC_TWIN_FIELDS", "PREDICTION_TOPIC", "FoxgloveOutput", "RecordingOutput",
           "ZenohOutput", "prediction_topic"]

PREDICTION_TOPIC = "/twin/prediction"
# plant-independent fields of every prediction message, so one Foxglove layout plots every plant's twin
GENERIC_TWIN_FIELDS = ("angle_measured_deg", "angle_predicted_deg", "angle_residual_deg", "cusum_max_counts")
PREDICTION_SCHEMA = "rehab_hil.TwinPrediction"
EVENT_KIND = "model_mismatch"


def prediction_topic(prefix: str = "/rig") -> str:
    """A rig's twin prediction topic: ``/twin/prediction`` for the one rig of a session (as recorded),
    ``/rigs/<rig>/twin/prediction`` beside that rig's channels in a lab view."""
    return PREDICTION_TOPIC if prefix == "/rig" else f"{prefix}{PREDICTION_TOPIC}"


class RecordingOutput:
    """Predictions and events into the session's MCAP (the recorder's thread writes them)."""

    def __init__(self, recorder: Any) -> None:
        self.recorder = recorder

    def prediction(self, msg: dict[str, float]) -> None:
        self.recorder.message(PREDICTION_TOPIC, PREDICTION_SCHEMA, msg)

    def mismatch(self, event: MismatchEvent, final: bool) -> None:
        if final:  # one event per mismatch, with its cause once diagnosed
            self.recorder.event(event.t_s, EVENT_KIND, event.text())


class ZenohOutput:
    """Predictions and events on ``rehab/<rig>/twin`` (``TelemetryPublisher.offer_twin``)."""

    def __init__(self, publisher: Any) -> None:
        self.publisher = publisher

    def prediction(self, msg: dict[str, float]) -> None:
        self.publisher.offer_twin("prediction", {k: (v if math.isfinite(v) else None) for k, v in msg.items()})

    def mismatch(self, event: MismatchEvent, final: bool) -> None:
        body = {k: v for k, v in event.as_dict().items() if k != "kind"}  # the envelope carries the kind
        self.publisher.offer_twin(EVENT_KIND, {**body, "final": final, "text": event.text()})


class FoxgloveOutput:
    """Predictions on Foxglove's ``/twin/prediction`` and events on the rig's ``/rig/event``."""

    def __init__(self, live: Any, feed: Any) -> None:
        self.live, self.feed = live, feed
        self.topic = prediction_topic(feed.prefix)
        self._channel: Any = None

    def prediction(self, msg: dict[str, float]) -> None:
        import foxglove

        if self._channel is None:
            schema = foxglove.Schema(name=PREDICTION_SCHEMA, encoding="jsonschema", data=json.dumps(
                {"title": PREDICTION_SCHEMA, "type": "object",
                 "properties": {k: {"type": "number"} for k in msg}}).encode())
            self._channel = foxglove.Channel(self.topic, schema=schema, message_encoding="json",
                                             context=self.live.context)
        if self._channel.has_sinks():
            self._channel.log(json.dumps({k: (v if math.isfinite(v) else None) for k, v in msg.items()}).encode())

    def mismatch(self, event: MismatchEvent, final: bool) -> None:
        if final:
            self.feed.event(event.t_s, EVENT_KIND, event.text())
