"""Python API for custom subscribers: ``subscribe(rig, on_sample)``, ``query_info``, ``watch_alive``.

Callbacks run on zenoh's threads (keep them short; hand work to your own queue). Each returned
handle undeclares on ``close()`` - zenoh keeps callbacks alive until then (docs/telemetry.md).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

import zenoh

from rehab_hil.telemetry.codec import PayloadError, StateSample, decode_json, decode_state
from rehab_hil.telemetry.keys import PREFIX, RigKeys, rig_from_key
from rehab_hil.telemetry.session import NetworkConfig, open_session

__all__ = ["Subscription", "list_rigs", "query_info", "send_command", "subscribe", "watch_alive"]

SampleCallback = Callable[[StateSample], None]
JsonCallback = Callable[[dict[str, Any]], None]


class Subscription:
    """Live subscription to one rig; counts batches, samples, gaps and undecodable payloads."""

    def __init__(self, session: zenoh.Session, rig_id: str, on_sample: SampleCallback | None,
                 on_stats: JsonCallback | None, on_safety: JsonCallback | None, owns_session: bool) -> None:
        self.keys = RigKeys(rig_id)
        self.session = session
        self._owns = owns_session
        self.batches = self.samples = self.missing_batches = self.bad_payloads = 0
        self.publisher_dropped = 0
        self._next_batch: int | None = None
        self._on_sample, self._on_stats, self._on_safety = on_sample, on_stats, on_safety
        self._subs: list[zenoh.Subscriber[None]] = []
        try:
            if on_sample is not None:
                self._subs.append(session.declare_subscriber(self.keys.state, self._state))
            if on_stats is not None:
                self._subs.append(session.declare_subscriber(self.keys.stats, self._json("stats", on_stats)))
            if on_safety is not None:
                self._subs.append(session.declare_subscriber(self.keys.safety, self._json("safety", on_safety)))
        except Exception:
            self.close()
            raise

    def _state(self, zsample: zenoh.Sample) -> None:
        try:
            batch = decode_state(zsample.payload.to_bytes())
        except PayloadError:
            self.bad_payloads += 1
            return
        if self._next_batch is not None and batch.batch_seq != self._next_batch:
            self.missing_batches += (batch.batch_seq - self._next_batch) & 0xFFFFFFFF
        self.batches += 1
        self.samples += len(batch.samples)
        self.publisher_dropped = batch.dropped_total
        assert self._on_sample is not None
        for s in batch.samples:
            self._on_sample(s)
        self._next_batch = (batch.batch_seq + 1) & 0xFFFFFFFF  # after its samples: the batch is in

    def batches_seen_up_to(self, published_batches: int) -> bool:
        """Whether the batch numbered ``published_batches - 1`` (the publisher's last) has arrived."""
        if published_batches <= 0:
            return True
        return self._next_batch == published_batches & 0xFFFFFFFF

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
        for s in self._subs:
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
              net: NetworkConfig | None = None) -> Subscription:
    """Call ``on_sample(StateSample)`` for every sample rig ``rig`` publishes, in order.

    Uses ``session`` if given, else opens a client session from ``net`` (default: loopback port 7447)
    that the returned ``Subscription`` closes."""
    RigKeys(rig)  # validate before opening anything
    owns = session is None
    if session is None:
        session = open_session(net or NetworkConfig())
    return Subscription(session, rig, on_sample, on_stats, on_safety, owns)


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
