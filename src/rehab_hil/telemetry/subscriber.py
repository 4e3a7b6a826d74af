"""Python API for custom subscribers: ``subscribe(rig, on_sample)``, ``query_info``, ``watch_alive``.

Callbacks run on zenoh's threads (keep them short; hand work to your own queue). Each returned
handle undeclares on ``close()`` - zenoh keeps callbacks alive until then (docs/telemetry.md).
Samples come through zenoh's ``AdvancedSubscriber``: the rig publisher's history first (a late
subscriber gets the session from its start, as far as the publisher keeps it), and every miss
counted (``telemetry.history``); ``recovery=True`` also asks the publisher's cache for misses.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

import zenoh
from zenoh import ext

from rehab_hil.telemetry.codec import PayloadError, StateSample, decode_json, decode_state
from rehab_hil.telemetry.history import BatchLedger
from rehab_hil.telemetry.keys import PREFIX, RigKeys, rig_from_key
from rehab_hil.telemetry.session import NetworkConfig, open_session

__all__ = ["Subscription", "list_rigs", "query_info", "send_command", "subscribe", "watch_alive"]

SampleCallback = Callable[[StateSample], None]
# How many of the publisher's cached batches the history asks for (all it may hold). zenoh (1.10)
# also holds live batches back until this many arrived or the history query is answered; unset, it
# delivers the first batch to arrive at once, and a live one that overtakes the history makes it drop
# the history. Any other query of the same publisher still open when the history query ends (late
# publisher detection, a recovery query) reopens that race, so the history goes alone by default.
HISTORY_BATCHES = 1_000_000
JsonCallback = Callable[[dict[str, Any]], None]


class Subscription:
    """Live subscription to one rig; counts batches, samples, misses and undecodable payloads.

    ``history`` (default): an ``AdvancedSubscriber`` that first asks the rig publisher's cache for
    what it holds; ``recovery``: asks it again for each miss (see ``HISTORY_BATCHES`` for the race this
    may cost a late joiner in zenoh 1.10); ``ledger`` says what arrived and what is missing where.
    """

    def __init__(self, session: zenoh.Session, rig_id: str, on_sample: SampleCallback | None,
                 on_stats: JsonCallback | None, on_safety: JsonCallback | None, owns_session: bool,
                 history: bool = True, recovery: bool = False) -> None:
        self.keys = RigKeys(rig_id)
        self.session = session
        self._owns = owns_session
        self.bad_payloads = 0
        self._records = 0
        self.publisher_dropped = 0
        self.zenoh_missed = 0  # batches zenoh reported missed for good (its sample-miss detection)
        self.ledger = BatchLedger()
        self._on_sample, self._on_stats, self._on_safety = on_sample, on_stats, on_safety
        self._subs: list[Any] = []
        try:
            if on_sample is not None:
                self._subs.append(self._declare_state(history, recovery))
            if on_stats is not None:
                self._subs.append(session.declare_subscriber(self.keys.stats, self._json("stats", on_stats)))
            if on_safety is not None:
                self._subs.append(session.declare_subscriber(self.keys.safety, self._json("safety", on_safety)))
        except Exception:
            self.close()
            raise

    def _declare_state(self, history: bool, recovery: bool) -> Any:
        if not history and not recovery:
            return self.session.declare_subscriber(self.keys.state, self._state)
        sub = ext.declare_advanced_subscriber(
            self.session, self.keys.state, self._state,
            history=ext.HistoryConfig(max_samples=HISTORY_BATCHES) if history else None,
            recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True) if recovery else None)
        self._subs.append(sub)  # undeclared after its miss listener (close() goes in reverse)
        return sub.sample_miss_listener(self._missed)

    def _missed(self, miss: Any) -> None:
        self.zenoh_missed += int(miss.nb)

    @property
    def batches(self) -> int:
        return self.ledger.batches

    @property
    def samples(self) -> int:
        """Records received (device samples and commands)."""
        return self._records

    @property
    def missing_batches(self) -> int:
        """Batches missing between received ones: lost in transit and not recovered."""
        return self.ledger.batches_lost

    def _state(self, zsample: zenoh.Sample) -> None:
        try:
            batch = decode_state(zsample.payload.to_bytes())
        except PayloadError:
            self.bad_payloads += 1
            return
        att = zsample.attachment
        n_samples = sum(1 for s in batch.samples if s.has_sample)
        self.publisher_dropped = batch.dropped_total
        assert self._on_sample is not None
        for s in batch.samples:
            self._on_sample(s)
        self._records += len(batch.samples)
        # after its samples: the batch is in
        self.ledger.add(batch.batch_seq, n_samples, None if att is None else att.to_bytes())

    def batches_seen_up_to(self, published_batches: int) -> bool:
        """Whether the batch numbered ``published_batches - 1`` (the publisher's last) has arrived."""
        if published_batches <= 0:
            return True
        return self.ledger.next_batch == published_batches & 0xFFFFFFFF

    def _json(self, kind: str, cb: JsonCallback) -> Callable[[zenoh.Sample], None]:
        def handle(zsample: zenoh.Sample) -> None:
            try:
                msg = decode_json(zsample.payload.to_bytes(), expect=kind)
            except PayloadError:
                self.bad_payloads += 1
                return
            cb(msg)

        return handle

    def close(self) -> None:
        """Undeclare the subscribers (and close the session if this subscription opened it)."""
        for s in reversed(self._subs):
            with contextlib.suppress(zenoh.ZError):
                s.undeclare()
        self._subs.clear()
        if self._owns:
            with contextlib.suppress(zenoh.ZError):
                self.session.close()
            self._owns = False

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def subscribe(rig: str, on_sample: SampleCallback | None, *, on_stats: JsonCallback | None = None,
              on_safety: JsonCallback | None = None, session: zenoh.Session | None = None,
              net: NetworkConfig | None = None, history: bool = True, recovery: bool = False,
              wait_s: float | None = 60.0) -> Subscription:
    """Call ``on_sample(StateSample)`` for every sample rig ``rig`` publishes, in order.

    Uses ``session`` if given, else opens a client session from ``net`` (default: loopback port 7447)
    that the returned ``Subscription`` closes; with no hub there yet it waits for one up to ``wait_s``
    (None: until there is one), so a subscriber may start before its rig. ``history``: begin with what
    the rig's publisher keeps of the session; ``recovery``: ask its cache for misses (both zenoh's
    AdvancedSubscriber; every miss is counted either way)."""
    RigKeys(rig)  # validate before opening anything
    owns = session is None
    if session is None:
        session = open_session(net or NetworkConfig(), wait_s=wait_s)
    return Subscription(session, rig, on_sample, on_stats, on_safety, owns, history=history, recovery=recovery)


def query_info(session: zenoh.Session, rig: str, timeout_s: float = 2.0) -> dict[str, Any] | None:
    """Ask ``rehab/<rig>/info``: the rig's plant, config and versions, or None if no rig answered."""
    for reply in session.get(RigKeys(rig).info, timeout=timeout_s):
        if reply.ok is not None:
            with contextlib.suppress(PayloadError):
                return decode_json(reply.ok.payload.to_bytes(), expect="info")
    return None


def list_rigs(session: zenoh.Session, timeout_s: float = 2.0) -> list[str]:
    """Rig ids whose liveliness token is present (rigs running now), sorted."""
    rigs = set()
    for reply in session.liveliness().get(RigKeys.any_alive(), timeout=timeout_s):
        if reply.ok is not None:
            with contextlib.suppress(ValueError):
                rigs.add(rig_from_key(str(reply.ok.key_expr)))
    return sorted(rigs)


def watch_alive(session: zenoh.Session, on_change: Callable[[str, bool], None],
                rig: str | None = None) -> zenoh.Subscriber[None]:
    """Call ``on_change(rig_id, alive)`` when a rig's token appears or goes (present ones reported first).

    Undeclare the returned subscriber when done."""
    key = RigKeys(rig).alive if rig is not None else f"{PREFIX}/*/alive"

    def handle(s: zenoh.Sample) -> None:
        with contextlib.suppress(ValueError):
            on_change(rig_from_key(str(s.key_expr)), s.kind == zenoh.SampleKind.PUT)

    return session.liveliness().declare_subscriber(key, handle, history=True)


def send_command(session: zenoh.Session, rig: str, op: str, value: float | None = None) -> None:
    """Put a command (``setpoint``/``start``/``stop``) on ``rehab/<rig>/command``.

    Whether it arrives is up to the rig (commands are off by default) and the hub's access control;
    zenoh does not report a refused put to the sender."""
    from rehab_hil.telemetry.codec import encode_json
    from rehab_hil.telemetry.publisher import COMMAND_OPS

    if op not in COMMAND_OPS:
        raise ValueError(f"unknown command op {op!r}; known: {COMMAND_OPS}")
    body: dict[str, Any] = {"op": op}
    if value is not None:
        body["value"] = float(value)
    session.put(RigKeys(rig).command, encode_json("command", body))
