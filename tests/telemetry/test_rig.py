"""RigTelemetry (what ``run --telemetry`` uses) and the shared network CLI options."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import pytest
import zenoh

from rehab_hil.hardware.interface import LinkStats
from rehab_hil.loading import load_config
from rehab_hil.loop.supervisor import SafetyEvent
from rehab_hil.plants import get_plant
from rehab_hil.telemetry import NetworkConfig, TelemetryConfigError, open_session, query_info, subscribe
from rehab_hil.telemetry.cliargs import PASSWORD_ENV, add_network_args, network_from_args
from rehab_hil.telemetry.rig import RigTelemetry, rig_info

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "finger_extensor.toml"


def info() -> dict:
    cfg = load_config(CONFIG)
    return rig_info(cfg.plant, CONFIG, get_plant(cfg.plant).device(cfg), 0.001)


def test_the_rig_hosts_the_loopback_hub_when_none_runs(unused_port: int, wait) -> None:
    with RigTelemetry("solo", info(), NetworkConfig(port=unused_port)) as rt:
        assert rt.role == "hub"
        viewer = open_session(NetworkConfig(port=unused_port))
        try:
            got = query_info(viewer, "solo")
        finally:
            viewer.close()
    assert got is not None and got["plant"] == "finger_extensor" and "[rig]" in got["config_toml"]
    assert got["analog_names"] == [ch.signal for ch in get_plant("finger_extensor").device(
        load_config(CONFIG)).adc]


def test_the_rig_joins_an_existing_hub_as_a_client(hub: int, client: Callable[..., zenoh.Session], wait) -> None:
    events: list[dict] = []
    stats: list[dict] = []
    with subscribe("joined", None, on_safety=events.append, on_stats=stats.append, session=client()), \
            RigTelemetry("joined", info(), NetworkConfig(port=hub), stats_period_s=0.05) as rt:
        assert rt.role == "client"
        link = LinkStats(frames_rx=5)
        progress = SimpleNamespace(t_s=1.0, duration_s=2.0, samples=5, sample_gaps=0, tripped="")
        rt.watch(SimpleNamespace(progress=progress), SimpleNamespace(stats=link))
        assert wait(lambda: any(m["loop"].get("link", {}).get("frames_rx") == 5 for m in stats))
        rt.on_trip(SafetyEvent(0.5, "force", "41 N > 40 N"))
        assert wait(lambda: len(events) == 1)
    assert events[0]["reason"] == "force" and events[0]["t_s"] == 0.5 and events[0]["state"] == "tripped"


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_network_args(p)
    return p.parse_args(argv)


def test_network_options_default_to_loopback_and_switch_to_lab_with_connect() -> None:
    assert network_from_args(parse([])) == NetworkConfig()
    net = network_from_args(parse(["--connect", "tcp/10.0.0.2:7447", "--connect", "tcp/10.0.0.3:7447"]))
    assert net.mode == "lab" and net.router == ("tcp/10.0.0.2:7447", "tcp/10.0.0.3:7447")


def test_passwords_come_from_a_file_or_the_environment(tmp_path: Path, monkeypatch) -> None:
    pw = tmp_path / "pw"
    pw.write_text("s3cret\n")
    assert network_from_args(parse(["--user", "v", "--password-file", str(pw)])).password == "s3cret"
    monkeypatch.setenv(PASSWORD_ENV, "from-env")
    assert network_from_args(parse(["--user", "v"])).password == "from-env"
    monkeypatch.delenv(PASSWORD_ENV)
    with pytest.raises(TelemetryConfigError, match="--password-file"):
        network_from_args(parse(["--user", "v"]))
    with pytest.raises(TelemetryConfigError, match="No such file"):
        network_from_args(parse(["--user", "v", "--password-file", str(tmp_path / "missing")]))
