"""Live view in Foxglove: a Foxglove WebSocket server (foxglove-sdk) fed with a rig's loop records.

``FoxgloveLive`` owns one server (127.0.0.1 by default); ``add_rig`` gives a ``RigFeed`` per rig,
which is one of the loop's sinks ("foxglove", a ``loop.sinks.ThreadedSink``: ``offer`` only
appends to a bounded deque, a full one drops and counts; its thread logs). Channels per rig
(``<prefix>`` is ``/rig`` for one rig, so the layout in
``docs/foxglove_layout.json`` and the MCAP recordings use the same topics): ``<prefix>/sample``,
``<prefix>/command``, ``<prefix>/event``, ``<prefix>/stats``, all JSON with JSON schemas. Sample and
command messages are exactly the recorder's MCAP messages (``loop.recorder``); extra channels (the
twin's ``/twin/prediction``) come as ``MessageRecord`` s. docs/telemetry.md.
"""

from __future__ import annotations

import collections
import contextlib
import json
import math
import os
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import foxglove

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loop.recorder import GENERIC_FIELDS, Recorder, csv_columns, generic_fields
from rehab_hil.loop.records import CommandRecord, EventRecord, MessageRecord, SampleRecord
from rehab_hil.loop.sinks import ThreadedSink
from rehab_hil.loop.stats import loop_stats
from rehab_hil.telemetry.ws_subprotocol import SubprotocolFront

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "FoxgloveError", "FoxgloveLive", "LiveView", "RigFeed", "rig_prefix",
           "topics"]

POLL_S = 0.005  # the longest records wait for the feed's thread when nobody wakes it (a zenoh bridge)
STATS_S = 1.0

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
KINDS = ("sample", "command", "event", "stats")
_NUMBER = {"type": "number"}


def sample_fields(binding: DeviceBinding) -> list[str]:
    """Fields of a sample message: the recorder's row, then the plant-independent names layouts plot."""
    return ["time_s", *csv_columns(binding), *GENERIC_FIELDS]


def _clean(v: Any) -> Any:
    return v if not isinstance(v, float) or math.isfinite(v) else None


class _Binding:  # what Recorder._row reads of a recorder
    def __init__(self, binding: DeviceBinding) -> None:
        self.binding = binding


def sample_message(binding: DeviceBinding, rec: Any) -> dict[str, Any]:
    """The recorder's MCAP sample message for ``rec`` (same fields, same values)."""
    row = Recorder._row(_Binding(binding), rec)  # type: ignore[arg-type]
    return {k: _clean(v) for k, v in {**row, **generic_fields(rec)}.items()}


def command_message(rec: Any) -> dict[str, Any]:
    """The recorder's MCAP command message for ``rec``."""
    c = rec.command
    return {"host_time_s": rec.host_time_s, "duty0_ratio": c.duty[0], "duty1_ratio": c.duty[1],
            "direction_bits": c.direction, "enable_bool": int(c.enable), "seq": rec.command_seq,
            "reference_deg": _clean(c.reference_deg)}


class FoxgloveError(RuntimeError):
    """The Foxglove server cannot start (e.g. its port is in use); the message is one line."""


def rig_prefix(rig: str | None, several: bool) -> str:
    """Topic prefix of a rig: ``/rig`` when a server shows one rig, ``/rigs/<rig>`` when it shows several."""
    return f"/rigs/{rig}" if several and rig else "/rig"


def topics(prefix: str = "/rig") -> dict[str, str]:
    """Topic of each channel kind under ``prefix``."""
    return {k: f"{prefix}/{k}" for k in KINDS}


def _schema(name: str, properties: Mapping[str, Any]) -> foxglove.Schema:
    body = {"title": name, "type": "object", "properties": dict(properties)}
    return foxglove.Schema(name=name, encoding="jsonschema", data=json.dumps(body).encode())


def schemas(binding: DeviceBinding) -> dict[str, foxglove.Schema]:
    """JSON schemas of the four channels (sample and command as in the recorder's MCAP)."""
    cmd = ("host_time_s", "duty0_ratio", "duty1_ratio", "direction_bits", "enable_bool", "seq", "reference_deg")
    return {
        "sample": _schema("rehab_hil.Sample", {f: _NUMBER for f in sample_fields(binding)}),
        "command": _schema("rehab_hil.Command", {f: _NUMBER for f in cmd}),
        "event": _schema("rehab_hil.Event", {"time_s": _NUMBER, "kind": {"type": "string"},
                                             "detail": {"type": "string"}}),
        "stats": _schema("rehab_hil.Stats", {"rig": {"type": "string"}, "time_s": _NUMBER,
                                             "loop": {"type": "object"}, "telemetry": {"type": "object"}}),
    }


class RigFeed(ThreadedSink):
    """One rig's channels on a ``FoxgloveLive`` server; a loop sink ("foxglove": ``offer`` never blocks)."""

    def __init__(self, live: FoxgloveLive, binding: DeviceBinding, prefix: str, queue_size: int) -> None:
        super().__init__("foxglove", queue_size, poll_s=POLL_S, tick_s=STATS_S)
        self.binding, self.prefix, self.context = binding, prefix, live.context
        self.topics = topics(prefix)
        sch = schemas(binding)
        self.channels = {k: foxglove.Channel(self.topics[k], schema=sch[k], message_encoding="json",
                                             context=live.context) for k in KINDS}
        self._extra: dict[str, foxglove.Channel] = {}  # topic -> channel of a ``MessageRecord``
        self._stats: collections.deque[dict[str, Any]] = collections.deque(maxlen=64)
        self._stats_source: Callable[[], Mapping[str, Any]] | None = None
        self._last_time_s = -math.inf
        self._anchor_ns: int | None = None
        self.sent = 0
        self.start()

    # -- any thread -------------------------------------------------------------------------------
    def event(self, time_s: float, kind: str, detail: str = "") -> None:
        """Publish a safety or link event on ``<prefix>/event`` (as the recorder writes it)."""
        self.offer(EventRecord(time_s, kind, detail))

    def stats(self, msg: Mapping[str, Any]) -> None:
        """Publish a stats message (the zenoh ``stats`` body) on ``<prefix>/stats``."""
        self._stats.append(dict(msg))

    def set_stats_source(self, source: Callable[[], Mapping[str, Any]] | None) -> None:
        """A callable the feed's thread asks once per second for the loop and link figures."""
        self._stats_source = source

    # -- the feed's thread ------------------------------------------------------------------------
    def _log_time(self, host_time_s: float) -> int:
        # anchored on the first record: keeps the rig's own spacing of records, on this machine's clock
        if self._anchor_ns is None:
            self._anchor_ns = time.time_ns() - int(host_time_s * 1e9)
        return self._anchor_ns + int(host_time_s * 1e9)

    def handle(self, rec: Any) -> None:
        t = type(rec)
        if t is SampleRecord:
            if rec.state is None or rec.time_s <= self._last_time_s:
                return  # what the recorder skips too
            self._last_time_s = rec.time_s
            ch = self.channels["sample"]
            if ch.has_sinks():
                ch.log(json.dumps(sample_message(self.binding, rec)).encode(), log_time=self._log_time(rec.host_time_s))
                self.sent += 1
            time.sleep(0)  # let the loop thread have the interpreter
        elif t is CommandRecord:
            ch = self.channels["command"]
            if ch.has_sinks():
                ch.log(json.dumps(command_message(rec)).encode(), log_time=self._log_time(rec.host_time_s))
                self.sent += 1
        elif t is EventRecord:
            body = {"time_s": _clean(float(rec.time_s)), "kind": rec.kind, "detail": rec.detail}
            with contextlib.suppress(Exception):
                self.channels["event"].log(json.dumps(body, default=str).encode())
        elif t is MessageRecord:
            self._message(rec)

    def _message(self, rec: MessageRecord) -> None:
        """An extra channel's message (the twin's ``/twin/prediction``), under this rig's prefix."""
        topic = rec.topic if self.prefix == "/rig" else f"{self.prefix}{rec.topic}"
        ch = self._extra.get(topic)
        if ch is None:
            schema = _schema(rec.schema, {k: _NUMBER for k in rec.body})
            ch = self._extra[topic] = foxglove.Channel(topic, schema=schema, message_encoding="json",
                                                       context=self.context)
        if ch.has_sinks():
            ch.log(json.dumps({k: _clean(v) for k, v in rec.body.items()}).encode())

    def tick(self) -> None:
        """Once a second: the loop and link figures on ``<prefix>/stats``."""
        if self._stats_source is not None:
            try:
                body = dict(self._stats_source())
            except Exception as e:  # a stats bug must not stop the live view
                body = {"error": f"{type(e).__name__}: {e}"}
            self._stats.append({"time_s": time.time(), "loop": body,
                                "telemetry": {"offered": self.offered, "dropped": self.dropped, "sent": self.sent}})
        self._log_stats()

    def finish(self) -> None:
        self._log_stats()

    def _log_stats(self) -> None:
        while self._stats:
            body = self._stats.popleft()
            with contextlib.suppress(Exception):
                self.channels["stats"].log(json.dumps(body, default=str).encode())


class FoxgloveLive:
    """A Foxglove WebSocket server on ``host:port`` (port 0: any free one) with its own channel context;
    clients may ask for the ``foxglove.sdk.v1`` or the classic ``foxglove.websocket.v1`` subprotocol
    (``ws_subprotocol.SubprotocolFront``)."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, name: str = "rehab-hil",
                 message_backlog: int = 4096) -> None:
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise FoxgloveError(f"port must be an integer in 0..65535, got {port!r}")
        self.context = foxglove.Context()
        try:  # the SDK's server on a private loopback port, behind a front that takes both subprotocols
            self.server = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=self.context,
                                                message_backlog_size=message_backlog)
        except Exception as e:  # the SDK raises RuntimeError("FoxgloveError: Failed to bind port: ...")
            why = str(e).removeprefix("FoxgloveError: ").splitlines()[0] if str(e) else type(e).__name__
            raise FoxgloveError(f"cannot serve Foxglove on {host}:{port}: {why}") from None
        try:
            self.front = SubprotocolFront(host, port, self.server.port)
        except OSError as e:
            with contextlib.suppress(Exception):
                self.server.stop()
            why = os.strerror(e.errno) if e.errno else str(e)
            raise FoxgloveError(f"cannot serve Foxglove on {host}:{port}: Failed to bind port: {why}") from None
        self.host, self.port = host, self.front.port
        self.feeds: list[RigFeed] = []
        self._lock = threading.Lock()
        self._closed = False

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def add_rig(self, binding: DeviceBinding, prefix: str = "/rig", queue_size: int = 20_000) -> RigFeed:
        """Advertise one rig's four channels under ``prefix`` and return its feed."""
        feed = RigFeed(self, binding, prefix, queue_size)
        with self._lock:
            self.feeds.append(feed)
        return feed

    def close(self) -> None:
        """Send what the feeds hold, then stop the server; idempotent."""
        if self._closed:
            return
        self._closed = True
        with self._lock:
            feeds = list(self.feeds)
        for feed in feeds:
            feed.close(timeout_s=5.0)
        self.front.close()
        with contextlib.suppress(Exception):
            self.server.stop()

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LiveView:
    """What ``rehab-hil run --foxglove`` adds to a session: the server and the rig's feed (``sink``,
    one of the loop's sinks beside the recorder and zenoh telemetry)."""

    def __init__(self, live: FoxgloveLive, feed: RigFeed) -> None:
        self.live, self.feed = live, feed
        self.sink = feed

    def watch(self, service: Any, hw: Any) -> None:
        """Loop progress and link figures on ``/rig/stats`` once per second."""
        self.feed.set_stats_source(loop_stats(service, hw))

    def close(self) -> None:
        """Send what the feed holds, stop the Foxglove server."""
        self.live.close()
