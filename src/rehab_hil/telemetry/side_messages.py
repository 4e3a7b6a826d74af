"""``SideMessages``: the JSON messages a rig's ``TelemetryPublisher`` puts beside its state batches.

Safety events (``.../safety``) and the live twin's predictions and events (``.../twin``) are queued
by any thread and put by the publisher's worker, in order; the stats message (``.../stats``, once
per stats period and a final one) merges the loop's and the link's figures with the publisher's
counters. Each is versioned JSON (``codec.encode_json``); a put that fails is counted in ``errors``,
never raised (telemetry must not stop the worker).
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable, Mapping
from typing import Any

import zenoh

from rehab_hil.telemetry.codec import PayloadError, encode_json
from rehab_hil.telemetry.keys import RigKeys

__all__ = ["SideMessages"]


class SideMessages:
    """The side messages of one rig on ``session`` under ``keys``; ``stats_source()``, if given, is
    called on the worker thread for the loop and link figures of each stats message."""

    def __init__(self, session: zenoh.Session, keys: RigKeys,
                 stats_source: Callable[[], Mapping[str, Any]] | None) -> None:
        self._session, self._keys = session, keys
        # (key, kind, JSON body) for the worker to put beside the records: ``offer_safety``, the twin's
        # predictions and events (never counted with the samples' drops: those go into the batches)
        self._queued: collections.deque[tuple[str, str, dict[str, Any]]] = collections.deque(maxlen=4096)
        self.loop_stats: dict[str, Any] = {}  # the last loop and link figures (``update_stats``, the source)
        self.stats_source = stats_source
        self.errors = 0  # puts that failed

    def queue(self, key: str, kind: str, body: dict[str, Any]) -> None:
        """Queue one message for the worker (any thread)."""
        self._queued.append((key, kind, body))

    def put_queued(self) -> None:
        """Put the queued messages, oldest first (worker thread)."""
        while self._queued:
            key, kind, body = self._queued.popleft()
            self.put(key, kind, body)

    def put_stats(self, counters: Callable[[], dict[str, Any]], final: bool) -> None:
        """Put the stats message: the loop's figures (asked of ``stats_source`` now) and ``counters()``;
        ``final``: the last word, after the last batch on the same path (worker thread)."""
        if self.stats_source is not None:
            try:
                self.loop_stats = dict(self.stats_source())
            except Exception as e:  # a stats bug must not stop telemetry
                self.loop_stats = {"error": f"{type(e).__name__}: {e}"}
        body = {"rig": self._keys.rig_id, "time_s": time.time(), "loop": self.loop_stats, "telemetry": counters()}
        if final:  # the last word, after the last batch on the same path: a recording
            body["final"] = True  # knows from it how many samples it should have received
        self.put(self._keys.stats, "stats", body, final=final)

    def put(self, key: str, kind: str, body: dict[str, Any], final: bool = False) -> None:
        """Put one message now; ``final``: reliable and blocking, as the state batches."""
        try:
            if final:  # reliable and blocking like the state batches, so it arrives, and after them
                self._session.put(key, encode_json(kind, body), congestion_control=zenoh.CongestionControl.BLOCK)
            else:
                self._session.put(key, encode_json(kind, body))
        except (PayloadError, zenoh.ZError):
            self.errors += 1
