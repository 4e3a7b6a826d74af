"""``TelemetryPublisher``: the loop's telemetry sink. ``offer`` never blocks; a worker thread publishes.

The loop thread only appends to a bounded queue (a full queue drops the sample and counts it) and,
once per cycle after its command is out, calls ``wake``; the worker (woken so, or every 2 ms)
batches samples into the binary state encoding, publishes stats at 1 Hz and safety events as
they come, holds the rig's liveliness token and answers ``info`` queries.
"""

from __future__ import annotations

import collections
import contextlib
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import zenoh

from rehab_hil.protocol import Sample
from rehab_hil.telemetry.codec import PayloadError, StateSample, decode_json, encode_json, join_records, pack_record
from rehab_hil.telemetry.keys import RigKeys

__all__ = ["COMMAND_OPS", "CommandHandler", "TelemetryPublisher"]

CommandHandler = Callable[[dict[str, Any]], None]


def _carries_sample(x: Any) -> bool:
    """Whether an offered record holds a device SAMPLE (a loop ``Record`` with one, a bare
    ``protocol.Sample``, a ``StateSample`` with ``has_sample``): what a recording counts."""
    if getattr(x, "sample", None) is not None:
        return True
    t = type(x)
    return (t is StateSample and x.has_sample) or t is Sample


COMMAND_OPS = ("setpoint", "start", "stop")


class TelemetryPublisher:
    """Publish one rig's telemetry on ``session`` (which the caller owns and closes).

    ``batch`` samples go in one put (a partial batch leaves after ``max_delay_s``); ``queue_size`` bounds
    the samples waiting for the worker. ``info`` answers ``rehab/<rig>/info`` queries. Commands on
    ``rehab/<rig>/command`` reach ``on_command`` only when ``commands_enabled`` (off by default; protect
    the channel with the hub's access control, docs/telemetry.md). ``stats_source()``, if given, is called
    on the worker thread once per stats period for the loop and link figures."""

    def __init__(self, session: zenoh.Session, rig_id: str, *, batch: int = 10, queue_size: int = 4096,
                 max_delay_s: float = 0.02, stats_period_s: float = 1.0, info: Mapping[str, Any] | None = None,
                 commands_enabled: bool = False, on_command: CommandHandler | None = None,
                 stats_source: Callable[[], Mapping[str, Any]] | None = None) -> None:
        if not 1 <= batch <= 1000:
            raise ValueError(f"batch must be 1..1000 samples, got {batch}")
        if queue_size < batch:
            raise ValueError(f"queue_size ({queue_size}) must hold at least one batch ({batch})")
        if not 0 < max_delay_s <= 1.0 or not 0 < stats_period_s <= 60.0:
            raise ValueError("max_delay_s must be in (0, 1] s and stats_period_s in (0, 60] s")
        if commands_enabled and on_command is None:
            raise ValueError("commands_enabled needs an on_command handler")
        self.keys = RigKeys(rig_id)
        self._session = session
        self._batch, self._cap, self._max_delay = batch, queue_size, max_delay_s
        self._stats_period = stats_period_s
        self._info = dict(info or {})
        self._queue: collections.deque[Any] = collections.deque()
        # (key, kind, JSON body) for the worker to put: safety events, the twin's predictions and events
        self._events: collections.deque[tuple[str, str, dict[str, Any]]] = collections.deque(maxlen=4096)
        self._loop_stats: dict[str, Any] = {}
        self._on_command = on_command
        self._stats_source = stats_source
        self.offered = 0
        self.samples_offered = 0  # offered records that carry a device SAMPLE (what a recording counts)
        self.dropped = 0
        self.samples_dropped = 0  # of the dropped records, those that carry a device SAMPLE
        self.published_samples = 0
        self.published_batches = 0
        self.publish_errors = 0
        self.commands_accepted = 0
        self.commands_rejected = 0
        self._closed = False
        self._stop = threading.Event()
        self._kick = threading.Event()
        self._pub = self._token = self._queryable = self._cmd_sub = None
        try:
            # reliable and blocking: a subscriber (a recording) that falls behind slows the worker
            # down, which the bounded queue absorbs (and counts, if it ever overflows)
            self._pub = session.declare_publisher(self.keys.state, reliability=zenoh.Reliability.RELIABLE,
                                                  congestion_control=zenoh.CongestionControl.BLOCK)
            self._token = session.liveliness().declare_token(self.keys.alive)
            self._queryable = session.declare_queryable(self.keys.info, self._answer_info)
            if commands_enabled:
                self._cmd_sub = session.declare_subscriber(self.keys.command, self._command)
        except zenoh.ZError:
            self._undeclare()
            raise
        self._thread = threading.Thread(target=self._run, name=f"telemetry-{rig_id}", daemon=True)
        self._thread.start()

    # -- called from the loop thread: O(1), never blocks ------------------------------------------
    def offer(self, sample: Any) -> bool:
        """Queue one sample for publishing; False (and counted in ``dropped``) when the queue is full."""
        self.offered += 1
        has_sample = _carries_sample(sample)
        self.samples_offered += has_sample
        if self._closed or len(self._queue) >= self._cap:
            self.dropped += 1
            self.samples_dropped += has_sample
            return False
        self._queue.append(sample)
        return True

    def wake(self) -> None:
        """Let the worker take what is queued now (the loop: once per cycle, after its write)."""
        self._kick.set()

    def offer_safety(self, event: Mapping[str, Any]) -> None:
        """Queue a safety event (e.g. ``{"state": "tripped", "reason": "force"}``) for ``.../safety``."""
        self._events.append((self.keys.safety, "safety", {"rig": self.keys.rig_id, "time_s": time.time(), **event}))

    def offer_twin(self, kind: str, body: Mapping[str, Any]) -> None:
        """Queue a live twin message (``prediction`` or ``model_mismatch``) for ``.../twin``."""
        self._events.append((self.keys.twin, kind, {"rig": self.keys.rig_id, **body}))

    def update_stats(self, stats: Mapping[str, Any]) -> None:
        """Replace the loop and link figures merged into the next 1 Hz ``.../stats`` message."""
        self._loop_stats = dict(stats)

    def set_stats_source(self, source: Callable[[], Mapping[str, Any]] | None) -> None:
        """Replace the callable the worker asks for loop and link figures once per stats period."""
        self._stats_source = source

    def set_info(self, info: Mapping[str, Any]) -> None:
        """Replace what ``.../info`` queries are answered with."""
        self._info = dict(info)

    # -- lifecycle ---------------------------------------------------------------------------------
    def close(self, timeout_s: float = 2.0) -> None:
        """Publish what is queued, then undeclare everything (the liveliness token goes last)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._kick.set()
        self._thread.join(timeout_s)
        self._undeclare()

    def _undeclare(self) -> None:
        for entity in (self._cmd_sub, self._queryable, self._pub, self._token):  # the token last
            if entity is not None:
                with contextlib.suppress(zenoh.ZError):
                    entity.undeclare()

    def __enter__(self) -> TelemetryPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def has_subscribers(self) -> bool:
        """Whether any subscriber currently matches ``rehab/<rig>/state`` (zenoh matching status)."""
        status = self._pub.matching_status
        return bool(getattr(status, "matching", status))

    def counters(self) -> dict[str, int]:
        """Publisher counters as they appear under ``telemetry`` in the stats message."""
        return {"offered": self.offered, "samples_offered": self.samples_offered, "dropped": self.dropped,
                "samples_dropped": self.samples_dropped, "queued": len(self._queue),
                "published_samples": self.published_samples, "published_batches": self.published_batches,
                "publish_errors": self.publish_errors, "commands_accepted": self.commands_accepted,
                "commands_rejected": self.commands_rejected}

    # -- worker thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        # Records are packed one at a time as they are taken, with a GIL release after each, so the
        # loop thread never waits long for the interpreter while this thread works.
        pending: list[bytes] = []
        pending_samples = 0  # of the pending records, those with a device SAMPLE
        first_at = 0.0
        next_stats = time.monotonic() + self._stats_period
        while True:
            stopping = self._stop.is_set()
            q = self._queue
            while q:
                item = q.popleft()
                try:
                    rec = pack_record(item)
                except PayloadError:
                    self.publish_errors += 1
                    self.dropped += 1
                    self.samples_dropped += _carries_sample(item)
                    continue
                if not pending:
                    first_at = time.monotonic()
                pending.append(rec)
                pending_samples += _carries_sample(item)
                if len(pending) == self._batch:
                    self._put_batch(pending, pending_samples)
                    pending, pending_samples = [], 0
                time.sleep(0)
            now = time.monotonic()
            if pending and (stopping or now - first_at >= self._max_delay):
                self._put_batch(pending, pending_samples)
                pending, pending_samples = [], 0
            while self._events:
                key, kind, body = self._events.popleft()
                self._put_json(key, kind, body)
            if now >= next_stats or stopping:
                next_stats = now + self._stats_period
                if self._stats_source is not None:
                    try:
                        self._loop_stats = dict(self._stats_source())
                    except Exception as e:  # a stats bug must not stop telemetry
                        self._loop_stats = {"error": f"{type(e).__name__}: {e}"}
                body = {"rig": self.keys.rig_id, "time_s": time.time(), "loop": self._loop_stats,
                        "telemetry": self.counters()}
                if stopping:  # the last word, after the last batch on the same path: a recording
                    body["final"] = True  # knows from it how many samples it should have received
                self._put_json(self.keys.stats, "stats", body, final=stopping)
            if stopping:
                return
            self._kick.wait(0.002)
            self._kick.clear()

    def _put_batch(self, records: list[bytes], n_samples: int = 0) -> None:
        try:
            payload = join_records(records, self.published_batches, self.dropped)
            self._pub.put(payload)
        except (PayloadError, zenoh.ZError):
            self.publish_errors += 1
            self.dropped += len(records)  # lost here: counted with the queue's drops, never silent
            self.samples_dropped += n_samples
            return
        self.published_batches += 1
        self.published_samples += len(records)

    def _put_json(self, key: str, kind: str, body: dict[str, Any], final: bool = False) -> None:
        try:
            if final:  # reliable and blocking like the state batches, so it arrives, and after them
                self._session.put(key, encode_json(kind, body), congestion_control=zenoh.CongestionControl.BLOCK)
            else:
                self._session.put(key, encode_json(kind, body))
        except (PayloadError, zenoh.ZError):
            self.publish_errors += 1

    # -- zenoh threads -----------------------------------------------------------------------------
    def _answer_info(self, query: zenoh.Query) -> None:
        body = {"rig": self.keys.rig_id, **self._info, "telemetry": self.counters()}
        with contextlib.suppress(zenoh.ZError, PayloadError):
            query.reply(self.keys.info, encode_json("info", body))

    def _command(self, sample: zenoh.Sample) -> None:
        try:
            msg = decode_json(sample.payload.to_bytes(), expect="command")
            if msg.get("op") not in COMMAND_OPS:
                raise PayloadError(f"unknown command op {msg.get('op')!r}; known: {COMMAND_OPS}")
            if msg["op"] == "setpoint" and not isinstance(msg.get("value"), (int, float)):
                raise PayloadError("a setpoint command needs a numeric 'value'")
        except PayloadError:
            self.commands_rejected += 1
            return
        self.commands_accepted += 1
        assert self._on_command is not None
        try:
            self._on_command(msg)
        except Exception:  # the rig's handler failed: count it, keep zenoh's thread alive
            self.commands_rejected += 1
