"""``RigDeclarations``: the zenoh entities one rig's ``TelemetryPublisher`` declares, and their end.

The state publisher (zenoh's ``AdvancedPublisher``: it keeps the last ``cache_batches`` puts for
subscribers that join late or miss one in transit, and numbers its puts so that a subscriber detects
and names a miss), a plain publisher on the same key only asked whether anyone subscribes, the
liveliness token, the ``info`` queryable and, when commands are enabled, the command subscriber.
Undeclared in reverse order, the liveliness token last: a rig is seen alive until everything else
is gone.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

import zenoh
from zenoh import ext

from rehab_hil.telemetry.keys import RigKeys

__all__ = ["HEARTBEAT_S", "RigDeclarations"]

HEARTBEAT_S = 0.1  # the last put's number, sent when it changed: a subscriber recovers a lost tail


class RigDeclarations:
    """Declare the rig's entities on ``session`` under ``keys`` (undeclaring those already declared if
    one fails); ``answer_info`` answers ``info`` queries, ``on_command`` (None: no command subscriber)
    takes what arrives on the command key. Both run on zenoh's threads."""

    def __init__(self, session: zenoh.Session, keys: RigKeys, cache_batches: int,
                 answer_info: Callable[[zenoh.Query], None],
                 on_command: Callable[[zenoh.Sample], None] | None) -> None:
        self.state: Any = None
        self._matching: Any = None
        self._token: Any = None
        self._queryable: Any = None
        self._cmd_sub: Any = None
        try:
            # reliable and blocking: a subscriber (a recording) that falls behind slows the worker
            # down, which the bounded queue absorbs (and counts, if it ever overflows)
            self.state = _advanced_publisher(session, keys.state, cache_batches)
            # never put on: only asked whether anyone subscribes (an AdvancedPublisher cannot say)
            self._matching = session.declare_publisher(keys.state)
            self._token = session.liveliness().declare_token(keys.alive)
            self._queryable = session.declare_queryable(keys.info, answer_info)
            if on_command is not None:
                self._cmd_sub = session.declare_subscriber(keys.command, on_command)
        except zenoh.ZError:
            self.undeclare()
            raise

    def has_subscribers(self) -> bool:
        """Whether any subscriber currently matches the state key (zenoh matching status)."""
        status = self._matching.matching_status
        return bool(getattr(status, "matching", status))

    def undeclare(self) -> None:
        """Undeclare everything declared, the liveliness token last."""
        for entity in (self._cmd_sub, self._queryable, self._matching, self.state, self._token):  # the token last
            if entity is not None:
                with contextlib.suppress(zenoh.ZError):
                    entity.undeclare()


def _advanced_publisher(session: zenoh.Session, key: str, cache_batches: int) -> ext.AdvancedPublisher:
    """The state publisher: reliable, blocking, its last ``cache_batches`` puts kept for history and
    recovery (replies blocking too), its puts numbered and announced (miss detection, heartbeat)."""
    block = zenoh.CongestionControl.BLOCK
    return ext.declare_advanced_publisher(
        session, key, reliability=zenoh.Reliability.RELIABLE, congestion_control=block,
        cache=ext.CacheConfig(cache_batches, replies_config=ext.RepliesConfig(congestion_control=block)),
        sample_miss_detection=ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S),
        publisher_detection=True)
