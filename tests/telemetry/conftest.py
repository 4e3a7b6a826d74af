"""Real zenoh sessions on loopback: one hub listening on an ephemeral 127.0.0.1 port, clients connect to it.

Multicast scouting and gossip are off in every session (``build_zenoh_config``); nothing leaves 127.0.0.1.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from rehab_hil.telemetry.session import NetworkConfig, TelemetryConfigError, build_zenoh_config, open_session
from rehab_hil.testing import free_port

zenoh.init_log_from_env_or("off")


def open_hub(**kw: Any) -> tuple[zenoh.Session, int]:
    """A hub session on a free loopback port (retried: another worker may grab the port first)."""
    for _ in range(5):
        port = free_port()
        try:
            return open_session(NetworkConfig(role="hub", port=port, **kw)), port
        except TelemetryConfigError:
            continue
    raise RuntimeError("no free loopback port for the hub")


def open_lossy_hub(key: str, max_puts_per_s: float) -> tuple[zenoh.Session, int]:
    """A hub that drops puts on ``key`` in transit: zenoh's own downsampling interceptor on the hub's
    egress lets at most ``max_puts_per_s`` through to each subscriber and drops the rest (queries and
    replies, i.e. history and recovery, are not touched)."""
    for _ in range(5):
        port = free_port()
        cfg = build_zenoh_config(NetworkConfig(role="hub", port=port))
        cfg.insert_json5("downsampling", json.dumps([{"id": "lossy", "flows": ["egress"], "messages": ["put"],
                                                      "rules": [{"key_expr": key, "freq": max_puts_per_s}]}]))
        try:
            return zenoh.open(cfg), port
        except zenoh.ZError:
            continue
    raise RuntimeError("no free loopback port for the lossy hub")


def wait_until(pred: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Poll ``pred`` until true; a generous bound, not a timing assertion."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


@pytest.fixture
def hub() -> Iterator[int]:
    """Port of a running hub session."""
    session, port = open_hub()
    yield port
    session.close()


@pytest.fixture
def client(hub: int) -> Iterator[Callable[..., zenoh.Session]]:
    """Factory of client sessions connected to the hub; all closed at teardown."""
    opened: list[zenoh.Session] = []

    def make(**kw: Any) -> zenoh.Session:
        s = open_session(NetworkConfig(port=hub, **kw))
        opened.append(s)
        return s

    yield make
    for s in reversed(opened):
        s.close()


@pytest.fixture
def hub_factory() -> Callable[..., tuple[zenoh.Session, int]]:
    """``open_hub(**NetworkConfig fields)`` -> (session, port); the test closes the session."""
    return open_hub


@pytest.fixture
def wait() -> Callable[..., bool]:
    return wait_until


@pytest.fixture
def unused_port() -> int:
    return free_port()


@pytest.fixture
def docs_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "docs"
