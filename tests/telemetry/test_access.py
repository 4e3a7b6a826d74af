"""Remote commands protected by zenoh access control on the hub (user/password + default-deny rules)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from rehab_hil.protocol import Sample
from rehab_hil.telemetry import (
    TelemetryConfigError,
    TelemetryPublisher,
    open_session,
    query_info,
    send_command,
    subscribe,
)
from rehab_hil.telemetry.access import command_access_control
from rehab_hil.telemetry.codec import StateSample
from rehab_hil.telemetry.session import NetworkConfig

USERS = {"rig": "rig-secret", "alice": "op-secret", "victor": "view-secret"}


@pytest.fixture
def secured(tmp_path: Path, hub_factory) -> Iterator[Callable[[str, str], zenoh.Session]]:
    """A hub with a password dictionary and the command ACL; yields a factory of authenticated clients."""
    dictionary = tmp_path / "users.txt"
    dictionary.write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
    acl = command_access_control(rig_users=["rig"], operators=["alice"], viewers=["victor"])
    hub, port = hub_factory(usrpwd_dictionary=dictionary, access_control=acl)
    opened: list[zenoh.Session] = []

    def make(user: str, password: str) -> zenoh.Session:
        s = open_session(NetworkConfig(port=port, user=user, password=password))
        opened.append(s)
        return s

    yield make
    for s in reversed(opened):
        s.close()
    hub.close()


def test_an_unauthorised_put_on_command_is_refused_while_its_telemetry_subscription_works(
        secured: Callable[[str, str], zenoh.Session], wait) -> None:
    rig, viewer, operator = secured("rig", USERS["rig"]), secured("victor", USERS["victor"]), \
        secured("alice", USERS["alice"])
    commands: list[dict] = []
    seen: list[StateSample] = []
    with TelemetryPublisher(rig, "lab1", batch=1, commands_enabled=True, on_command=commands.append) as pub, \
            subscribe("lab1", seen.append, session=viewer):
        assert wait(pub.has_subscribers)
        send_command(viewer, "lab1", "setpoint", 45.0)  # refused by the hub
        send_command(operator, "lab1", "stop")  # allowed; arrives after the viewer's put would have
        assert wait(lambda: len(commands) >= 1)
        pub.offer(Sample(1, 42, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
        assert wait(lambda: len(seen) == 1)
    assert [c["op"] for c in commands] == ["stop"]
    assert seen[0].sample_index == 42


def test_a_wrong_password_cannot_open_a_session(secured: Callable[[str, str], zenoh.Session]) -> None:
    with pytest.raises(TelemetryConfigError, match="cannot connect"):
        secured("victor", "guess")


def test_a_rig_listens_for_commands_only_when_enabled(client: Callable[..., zenoh.Session], wait) -> None:
    sender = client()
    probe_off = sender.declare_publisher("rehab/plain/command")
    probe_on = sender.declare_publisher("rehab/armed/command")
    try:
        with TelemetryPublisher(client(), "plain"), \
                TelemetryPublisher(client(), "armed", commands_enabled=True, on_command=lambda c: None):
            assert wait(lambda: probe_on.matching_status.matching)  # the probe does see a command listener
            assert query_info(sender, "plain") is not None  # the plain rig's declarations have propagated
            assert not probe_off.matching_status.matching
    finally:
        probe_off.undeclare()
        probe_on.undeclare()


def test_malformed_commands_are_counted_and_not_delivered(client: Callable[..., zenoh.Session], wait) -> None:
    got: list[dict] = []
    sender = client()
    with TelemetryPublisher(client(), "c1", commands_enabled=True, on_command=got.append) as pub:
        assert wait(lambda: (sender.put("rehab/c1/command", b'{"v":1,"kind":"command","op":"explode"}'),
                             pub.commands_rejected >= 1)[1])
        sender.put("rehab/c1/command", b'{"v":1,"kind":"command","op":"setpoint","value":"high"}')
        send_command(sender, "c1", "setpoint", 10.0)
        assert wait(lambda: len(got) == 1)
    assert got[0]["value"] == 10.0 and pub.commands_rejected >= 2


def test_the_acl_builder_refuses_ambiguous_users() -> None:
    with pytest.raises(ValueError, match="both a rig"):
        command_access_control(rig_users=["a"], operators=["a"])
    with pytest.raises(ValueError, match="at least one rig user"):
        command_access_control(rig_users=[])
    with pytest.raises(ValueError, match="without ':'"):
        command_access_control(rig_users=["r:x"])


def test_a_viewer_that_joins_late_gets_the_history_through_the_access_control(
        secured: Callable[[str, str], zenoh.Session], wait) -> None:
    rig, viewer = secured("rig", USERS["rig"]), secured("victor", USERS["victor"])
    seen: list[int] = []
    with TelemetryPublisher(rig, "lab2", batch=1) as pub:
        for i in range(20):
            pub.offer(Sample(1, i, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
        assert wait(lambda: pub.published_batches == 20)  # before the viewer subscribes
        with subscribe("lab2", lambda s: seen.append(s.sample_index), session=viewer):
            assert wait(lambda: len(seen) == 20)
            pub.offer(Sample(1, 20, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
            assert wait(lambda: len(seen) == 21)
    assert seen == list(range(21))
