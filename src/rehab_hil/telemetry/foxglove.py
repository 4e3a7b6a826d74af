"""Live view in Foxglove: a Foxglove WebSocket server (foxglove-sdk) fed with a rig's loop records.

``FoxgloveLive`` owns one server (127.0.0.1 by default) and one worker thread; ``add_rig`` gives a
``RigFeed`` per rig, which is a loop telemetry sink (``offer`` only appends to a bounded deque, a full
one drops and counts). Channels per rig (``<prefix>`` is ``/rig`` for one rig, so the layout in
``docs/foxglove_layout.json`` and the MCAP recordings use the same topics): ``<prefix>/sample``,
``<prefix>/command``, ``<prefix>/event``, ``<prefix>/stats``, all JSON with JSON schemas. Sample and
command messages are exactly the recorder's MCAP messages (``service.recorder``). docs/telemetry.md.
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
from rehab_hil.service.recorder import GENERIC_FIELDS, Recorder, csv_columns, generic_fields
from rehab_hil.service.telemetry import loop_stats
from rehab_hil.telemetry.ws_subprotocol import SubprotocolFront

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "FoxgloveError", "FoxgloveLive", "LiveView", "RigFeed", "rig_prefix",
           "topics"]

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


class RigFeed:
    """One rig's channels on a ``FoxgloveLive`` server; a loop telemetry sink (``offer`` never blocks)."""

    def __init__(self, live: FoxgloveLive, binding: DeviceBinding, prefix: str, queue_size: int) -> None:
        self.binding, self.prefix = binding, prefix
        self.topics = topics(prefix)
        sch = schemas(binding)
        self.channels = {k: foxglove.Channel(self.topics[k], schema=sch[k], message_encoding="json",
                                             context=live.context) for k in KINDS}
        self._cap = queue_size
        self._queue: collections.deque[Any] = collections.deque()
        self._events: collections.deque[tuple[str, dict[str, Any]]] = collections.deque(maxlen=1024)
        self._stats_source: Callable[[], Mapping[str, Any]] | None = None
        self._last_time_s = -math.inf
        self._anchor_ns: int | None = None
        self.offered = self.dropped = self.sent = 0

    # -- loop thread ------------------------------------------------------------------------------
    def offer(self, record: Any) -> bool:
        """Queue one loop ``Record``; False (counted in ``dropped``) when the queue is full."""
        self.offered += 1
        if len(self._queue) >= self._cap:
            self.dropped += 1
            return False
        self._queue.append(record)
        return True

    def close(self) -> None:
        """Nothing to do per rig: the server's owner closes ``FoxgloveLive``."""

    # -- any thread -------------------------------------------------------------------------------
    def event(self, time_s: float, kind: str, detail: str = "") -> None:
        """Publish a safety or link event on ``<prefix>/event`` (as the recorder writes it)."""
        self._events.append(("event", {"time_s": time_s if math.isfinite(time_s) else None, "kind": kind,
                                       "detail": detail}))

    def stats(self, msg: Mapping[str, Any]) -> None:
        """Publish a stats message (the zenoh ``stats`` body) on ``<prefix>/stats``."""
        self._events.append(("stats", dict(msg)))

    def set_stats_source(self, source: Callable[[], Mapping[str, Any]] | None) -> None:
        """A callable the worker asks once per second for the loop and link figures."""
        self._stats_source = source

    # -- worker thread ----------------------------------------------------------------------------
    def _log_time(self, host_time_s: float) -> int:
        # anchored on the first record: keeps the rig's own spacing of records, on this machine's clock
        if self._anchor_ns is None:
            self._anchor_ns = time.time_ns() - int(host_time_s * 1e9)
        return self._anchor_ns + int(host_time_s * 1e9)

    def _drain(self, ask_stats: bool) -> None:
        q = self._queue
        ch_sample, ch_cmd = self.channels["sample"], self.channels["command"]
        watched = ch_sample.has_sinks() or ch_cmd.has_sinks()
        while q:
            rec = q.popleft()
            if rec.sample is None:
                if watched:
                    ch_cmd.log(json.dumps(command_message(rec)).encode(), log_time=self._log_time(rec.host_time_s))
                    self.sent += 1
                continue
            if rec.state is None or rec.time_s <= self._last_time_s:
                continue  # what the recorder skips too
            self._last_time_s = rec.time_s
            if watched:
                msg = sample_message(self.binding, rec)
                ch_sample.log(json.dumps(msg).encode(), log_time=self._log_time(rec.host_time_s))
                self.sent += 1
            time.sleep(0)  # let the loop thread have the interpreter
        if ask_stats and self._stats_source is not None:
            try:
                body = dict(self._stats_source())
            except Exception as e:  # a stats bug must not stop the live view
                body = {"error": f"{type(e).__name__}: {e}"}
            self._events.append(("stats", {"time_s": time.time(), "loop": body,
                                           "telemetry": {"offered": self.offered, "dropped": self.dropped,
                                                         "sent": self.sent}}))
        while self._events:
            kind, body = self._events.popleft()
            with contextlib.suppress(Exception):
                self.channels[kind].log(json.dumps(body, default=str).encode())


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
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="foxglove", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def add_rig(self, binding: DeviceBinding, prefix: str = "/rig", queue_size: int = 20_000) -> RigFeed:
        """Advertise one rig's four channels under ``prefix`` and return its feed."""
        feed = RigFeed(self, binding, prefix, queue_size)
        with self._lock:
            self.feeds.append(feed)
        return feed

    def _run(self) -> None:
        next_stats = time.monotonic() + 1.0
        while True:
            stopping = self._stop.is_set()
            now = time.monotonic()
            ask = now >= next_stats
            if ask:
                next_stats = now + 1.0
            with self._lock:
                feeds = list(self.feeds)
            for feed in feeds:
                feed._drain(ask)
            if stopping:
                return
            self._stop.wait(0.005)

    def close(self) -> None:
        """Send what is queued, then stop the server; idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(5.0)
        self.front.close()
        with contextlib.suppress(Exception):
            self.server.stop()

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LiveView:
    """What ``rehab-hil run --foxglove`` hands the loop: the Foxglove feed, tee'd with the zenoh
    publisher when ``--telemetry`` is on too (same ``sink``/``watch``/``on_trip`` as ``RigTelemetry``)."""

    def __init__(self, live: FoxgloveLive, feed: RigFeed, zenoh_telemetry: Any = None) -> None:
        self.live, self.feed, self.zenoh = live, feed, zenoh_telemetry
        self.sink: Any = feed if zenoh_telemetry is None else Tee(zenoh_telemetry.sink, feed)

    def watch(self, service: Any, hw: Any) -> None:
        """Loop progress and link figures on ``/rig/stats`` once per second (and on zenoh, if on)."""
        if self.zenoh is not None:
            self.zenoh.watch(service, hw)
        self.feed.set_stats_source(loop_stats(service, hw))

    def on_trip(self, event: Any) -> None:
        """``LoopService.run(on_trip=...)``: the supervisor's event on ``/rig/event`` (and zenoh)."""
        if self.zenoh is not None:
            self.zenoh.on_trip(event)
        self.feed.event(float(getattr(event, "t_s", math.nan)), str(getattr(event, "reason", event)),
                        str(getattr(event, "detail", "")))

    def close(self) -> None:
        """Stop the Foxglove server (the zenoh side is closed by its own owner)."""
        self.live.close()


class Tee:
    """A telemetry sink that offers each record to several sinks; ``dropped`` adds theirs up."""

    def __init__(self, *sinks: Any) -> None:
        self.sinks = sinks

    def offer(self, record: Any) -> bool:
        ok = True
        for s in self.sinks:
            ok = s.offer(record) and ok
        return ok

    def wake(self) -> None:
        """The loop's once-per-cycle wake, to each sink that takes one."""
        for s in self.sinks:
            wake = getattr(s, "wake", None)
            if wake is not None:
                wake()

    @property
    def dropped(self) -> int:
        return sum(int(getattr(s, "dropped", 0)) for s in self.sinks)

    def close(self) -> None:
        for s in self.sinks:
            s.close()
