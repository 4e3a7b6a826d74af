"""``TelemetryPublisher``: the loop's telemetry sink ("telemetry"). ``offer`` never blocks; a worker
thread publishes.

A ``loop.sinks.ThreadedSink``: the loop thread only appends to a bounded queue (a full queue
drops the record and counts it) and, once per cycle after its command is out, calls ``wake``; the
worker (woken so, or every 2 ms) batches samples and commands into the binary state encoding,
publishes the loop's safety events (``EventRecord``) on ``.../safety``, stats at 1 Hz, holds the
rig's liveliness token and answers ``info`` queries.

The state batches go through zenoh's ``AdvancedPublisher``: it keeps the last ``cache_batches`` puts
for subscribers that join late or miss one in transit (history and recovery) and numbers its puts
so that a subscriber detects and names a miss (``telemetry.history``). The zenoh entities are
declared and undeclared by ``RigDeclarations`` (declarations.py); the JSON messages beside the
batches (safety, twin, stats) are put by ``SideMessages`` (side_messages.py).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

import zenoh

from rehab_hil.loop.records import CycleRecord, EventRecord, MessageRecord, SampleRecord
from rehab_hil.loop.sinks import ThreadedSink
from rehab_hil.protocol import Sample
from rehab_hil.telemetry.codec import PayloadError, StateSample, decode_json, encode_json, join_records, pack_record
from rehab_hil.telemetry.declarations import RigDeclarations
from rehab_hil.telemetry.history import BATCH_ATTACHMENT
from rehab_hil.telemetry.keys import RigKeys
from rehab_hil.telemetry.side_messages import SideMessages

__all__ = ["CACHE_BATCHES", "COMMAND_OPS", "CommandHandler", "TelemetryPublisher"]

CommandHandler = Callable[[dict[str, Any]], None]


def _carries_sample(x: Any) -> bool:
    """Whether an offered record holds a device SAMPLE (a ``SampleRecord``, a bare ``protocol.Sample``,
    a ``StateSample`` with ``has_sample``): what a recording counts."""
    t = type(x)
    return t is SampleRecord or t is Sample or (t is StateSample and x.has_sample)


_NOT_STATE = (EventRecord, CycleRecord, MessageRecord)  # records that are not packed into state batches
TICK_S = 0.002  # the worker looks at its partial batch, side messages and stats this often


COMMAND_OPS = ("setpoint", "start", "stop")
# The publisher's history: 12 000 batches = 60 s of a 1 kHz loop (a sample and a command record per
# cycle, 10 records per batch: 200 batches/s), about 16 MB of 1.3 kB puts. A recorder that joins up to
# a minute late still gets the session from its first sample (docs/telemetry.md, "History").
CACHE_BATCHES = 12_000
LINGER_S = 0.5  # the cache stays this long after the last batch while anyone subscribes (a lost tail)


class TelemetryPublisher(ThreadedSink):
    """Publish one rig's telemetry on ``session`` (which the caller owns and closes).

    ``batch`` samples go in one put (a partial batch leaves after ``max_delay_s``); ``queue_size`` bounds
    the samples waiting for the worker. ``info`` answers ``rehab/<rig>/info`` queries. Commands on
    ``rehab/<rig>/command`` reach ``on_command`` only when ``commands_enabled`` (off by default; protect
    the channel with the hub's access control, docs/telemetry.md). ``stats_source()``, if given, is called
    on the worker thread once per stats period for the loop and link figures. ``cache_batches``: how many
    state batches zenoh keeps for late joiners and recovery."""

    def __init__(self, session: zenoh.Session, rig_id: str, *, batch: int = 10, queue_size: int = 4096,
                 max_delay_s: float = 0.02, stats_period_s: float = 1.0, info: Mapping[str, Any] | None = None,
                 commands_enabled: bool = False, on_command: CommandHandler | None = None,
                 stats_source: Callable[[], Mapping[str, Any]] | None = None,
                 cache_batches: int = CACHE_BATCHES) -> None:
        if not 1 <= batch <= 1000:
            raise ValueError(f"batch must be 1..1000 samples, got {batch}")
        if queue_size < batch:
            raise ValueError(f"queue_size ({queue_size}) must hold at least one batch ({batch})")
        if not 0 < max_delay_s <= 1.0 or not 0 < stats_period_s <= 60.0:
            raise ValueError("max_delay_s must be in (0, 1] s and stats_period_s in (0, 60] s")
        if commands_enabled and on_command is None:
            raise ValueError("commands_enabled needs an on_command handler")
        if not 1 <= cache_batches <= 1_000_000:
            raise ValueError(f"cache_batches must be 1..1000000, got {cache_batches}")
        super().__init__("telemetry", queue_size, poll_s=TICK_S, tick_s=TICK_S)
        self.keys = RigKeys(rig_id)
        self._session = session
        self._batch, self._max_delay = batch, max_delay_s
        self._stats_period = stats_period_s
        self._info = dict(info or {})
        self._side = SideMessages(session, self.keys, stats_source)  # safety, twin and stats messages
        self._on_command = on_command
        self._samples_taken = 0  # records with a device SAMPLE the worker took from the queue
        self._samples_refused = 0  # records with a device SAMPLE dropped at the full queue
        self.samples_dropped = 0  # of the dropped records, those that carry a device SAMPLE
        self.published_samples = 0
        self._published_device_samples = 0  # of those, records with a device SAMPLE
        self.published_batches = 0
        self._batch_errors = 0  # records that could not be packed, batches that could not be put
        self.commands_accepted = 0
        self.commands_rejected = 0
        self._pending: list[bytes] = []  # packed records of the batch being filled
        self._pending_samples = 0  # of those, records with a device SAMPLE
        self._first_at = 0.0
        self._next_stats = time.monotonic() + stats_period_s
        self._zenoh = RigDeclarations(session, self.keys, cache_batches, self._answer_info,
                                      self._command if commands_enabled else None)
        self._thread.name = f"telemetry-{rig_id}"
        self.start()

    @property
    def samples_offered(self) -> int:
        """Offered records that carry a device SAMPLE (what a recording counts): those taken and those
        dropped at the queue (exact once the queue is empty, as in the final stats)."""
        return self._samples_taken + self._samples_refused

    @property
    def publish_errors(self) -> int:
        """Records that could not be packed, and puts that failed (batches and side messages)."""
        return self._batch_errors + self._side.errors

    def refused(self, record: Any) -> None:
        if _carries_sample(record):
            self._samples_refused += 1
            self.samples_dropped += 1

    def offer_safety(self, event: Mapping[str, Any]) -> None:
        """Queue a safety event (e.g. ``{"state": "tripped", "reason": "force"}``) for ``.../safety``."""
        self._side.queue(self.keys.safety, "safety", {"rig": self.keys.rig_id, "time_s": time.time(), **event})

    def offer_twin(self, kind: str, body: Mapping[str, Any]) -> None:
        """Queue a live twin message (``prediction`` or ``model_mismatch``) for ``.../twin``."""
        self._side.queue(self.keys.twin, kind, {"rig": self.keys.rig_id, **body})

    def update_stats(self, stats: Mapping[str, Any]) -> None:
        """Replace the loop and link figures merged into the next 1 Hz ``.../stats`` message."""
        self._side.loop_stats = dict(stats)

    def set_stats_source(self, source: Callable[[], Mapping[str, Any]] | None) -> None:
        """Replace the callable the worker asks for loop and link figures once per stats period."""
        self._side.stats_source = source

    def set_info(self, info: Mapping[str, Any]) -> None:
        """Replace what ``.../info`` queries are answered with."""
        self._info = dict(info)

    # -- lifecycle ---------------------------------------------------------------------------------
    def close(self, timeout_s: float | None = 2.0) -> None:
        """Publish what is queued, then undeclare everything (the liveliness token goes last)."""
        super().close(timeout_s)

    def release(self) -> None:
        self._zenoh.undeclare()  # the liveliness token last

    def __enter__(self) -> TelemetryPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def has_subscribers(self) -> bool:
        """Whether any subscriber currently matches ``rehab/<rig>/state`` (zenoh matching status)."""
        return self._zenoh.has_subscribers()

    def counters(self) -> dict[str, int]:
        """Publisher counters as they appear under ``telemetry`` in the stats message."""
        return {"offered": self.offered, "samples_offered": self.samples_offered, "dropped": self.dropped,
                "samples_dropped": self.samples_dropped, "queued": len(self._q),
                "published_samples": self.published_samples, "published_batches": self.published_batches,
                "publish_errors": self.publish_errors, "commands_accepted": self.commands_accepted,
                "commands_rejected": self.commands_rejected}

    # -- worker thread -----------------------------------------------------------------------------
    def handle(self, item: Any) -> None:
        # Records are packed one at a time as they are taken, with a GIL release after each, so the
        # loop thread never waits long for the interpreter while this thread works.
        if isinstance(item, _NOT_STATE):
            if type(item) is EventRecord:  # the loop's safety events (``RigTelemetry.on_trip``'s body)
                t = item.time_s if math.isfinite(item.time_s) else None
                self._side.put(self.keys.safety, "safety", {"rig": self.keys.rig_id, "time_s": time.time(),
                               "state": "tripped", "t_s": t, "reason": item.kind, "detail": item.detail})
            return  # cycles reach zenoh in the stats; the twin's messages through ``offer_twin``
        has_sample = _carries_sample(item)
        self._samples_taken += has_sample
        try:
            rec = pack_record(item)
        except PayloadError:
            self._batch_errors += 1
            self.dropped += 1
            self.samples_dropped += has_sample
            return
        if not self._pending:
            self._first_at = time.monotonic()
        self._pending.append(rec)
        self._pending_samples += has_sample
        if len(self._pending) == self._batch:
            self._put_pending()
        time.sleep(0)

    def tick(self) -> None:
        """The partial batch once ``max_delay_s`` old, the side messages, the stats when due."""
        now = time.monotonic()
        if self._pending and now - self._first_at >= self._max_delay:
            self._put_pending()
        self._side.put_queued()
        if now >= self._next_stats:
            self._next_stats = now + self._stats_period
            self._side.put_stats(self.counters, final=False)

    def finish(self) -> None:
        """The last batch, the side messages, then the final stats (a recording's last word); the
        history is kept ``LINGER_S`` longer while anyone subscribes."""
        if self._pending:
            self._put_pending()
        self._side.put_queued()
        self._side.put_stats(self.counters, final=True)
        if self.published_batches and self.has_subscribers():
            time.sleep(LINGER_S)  # a heartbeat or two: a subscriber that missed the last batches recovers them

    def _put_pending(self) -> None:
        self._put_batch(self._pending, self._pending_samples)
        self._pending, self._pending_samples = [], 0

    def _put_batch(self, records: list[bytes], n_samples: int = 0) -> None:
        try:
            payload = join_records(records, self.published_batches, self.dropped)
            # what the earlier batches held: a subscriber counts the samples of a batch it lacks
            att = BATCH_ATTACHMENT.pack(self.published_samples, self._published_device_samples)
            self._zenoh.state.put(payload, attachment=att)
        except (PayloadError, zenoh.ZError):
            self._batch_errors += 1
            self.dropped += len(records)  # lost here: counted with the queue's drops, never silent
            self.samples_dropped += n_samples
            return
        self.published_batches += 1
        self.published_samples += len(records)
        self._published_device_samples += n_samples

    # -- zenoh threads -----------------------------------------------------------------------------
    def _answer_info(self, query: zenoh.Query) -> None:
        body = {"rig": self.keys.rig_id, **self._info, "telemetry": self.counters()}
        with contextlib.suppress(zenoh.ZError, PayloadError):
            query.reply(self.keys.info, encode_json("info", body))

    def _command(self, sample: zenoh.Sample) -> None:
        try:
            msg = _decode_command(sample.payload.to_bytes())
        except PayloadError:
            self.commands_rejected += 1
            return
        self.commands_accepted += 1
        assert self._on_command is not None
        try:
            self._on_command(msg)
        except Exception:  # the rig's handler failed: count it, keep zenoh's thread alive
            self.commands_rejected += 1


def _decode_command(payload: bytes) -> dict[str, Any]:
    """A message on ``rehab/<rig>/command``, checked: JSON of kind ``command`` whose ``op`` is one of
    ``COMMAND_OPS`` (a ``setpoint`` with a numeric ``value``); ``PayloadError`` otherwise."""
    msg = decode_json(payload, expect="command")
    if msg.get("op") not in COMMAND_OPS:
        raise PayloadError(f"unknown command op {msg.get('op')!r}; known: {COMMAND_OPS}")
    if msg["op"] == "setpoint" and not isinstance(msg.get("value"), (int, float)):
        raise PayloadError("a setpoint command needs a numeric 'value'")
    return msg
