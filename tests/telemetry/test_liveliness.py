"""Liveliness token ``rehab/<rig>/alive`` and the ``info`` queryable, over a real loopback hub."""

from __future__ import annotations

from collections.abc import Callable

import zenoh

from rehab_hil.telemetry import TelemetryPublisher, list_rigs, query_info, watch_alive


def test_liveliness_appears_with_the_publisher_and_disappears_when_it_closes(
        client: Callable[..., zenoh.Session], wait) -> None:
    viewer = client()
    changes: list[tuple[str, bool]] = []
    watcher = watch_alive(viewer, lambda rig, alive: changes.append((rig, alive)))
    try:
        pub = TelemetryPublisher(client(), "rig-7")
        assert wait(lambda: ("rig-7", True) in changes)
        assert wait(lambda: list_rigs(viewer) == ["rig-7"])
        pub.close()
        assert wait(lambda: ("rig-7", False) in changes)
        assert wait(lambda: list_rigs(viewer) == [])
    finally:
        watcher.undeclare()


def test_liveliness_disappears_when_the_rig_session_dies_without_closing_the_publisher(
        client: Callable[..., zenoh.Session], wait) -> None:
    viewer = client()
    changes: list[tuple[str, bool]] = []
    watcher = watch_alive(viewer, lambda rig, alive: changes.append((rig, alive)), rig="crash")
    try:
        rig = client()
        pub = TelemetryPublisher(rig, "crash")
        assert wait(lambda: ("crash", True) in changes)
        rig.close()  # the process's session goes; the token goes with it
        assert wait(lambda: ("crash", False) in changes)
        pub.close()
    finally:
        watcher.undeclare()


def test_a_viewer_started_after_the_rig_sees_it_alive(client: Callable[..., zenoh.Session], wait) -> None:
    with TelemetryPublisher(client(), "early"):
        viewer = client()
        changes: list[tuple[str, bool]] = []
        watcher = watch_alive(viewer, lambda rig, alive: changes.append((rig, alive)))
        try:
            assert wait(lambda: ("early", True) in changes)
        finally:
            watcher.undeclare()


def test_the_info_queryable_answers_with_plant_config_and_versions(client: Callable[..., zenoh.Session]) -> None:
    info = {"plant": "finger_extensor", "config_path": "configs/finger_extensor.toml", "config_toml": "plant = 1",
            "firmware_version": "1.0.0", "protocol_version": 1, "telemetry_state_version": 1,
            "analog_names": ["torque_nm"]}
    with TelemetryPublisher(client(), "q1", info=info):
        got = query_info(client(), "q1")
    assert got is not None
    assert {k: got[k] for k in info} == info
    assert got["rig"] == "q1" and got["kind"] == "info" and "dropped" in got["telemetry"]


def test_querying_a_rig_that_is_not_running_returns_none(client: Callable[..., zenoh.Session]) -> None:
    assert query_info(client(), "absent", timeout_s=0.5) is None
