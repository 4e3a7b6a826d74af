from __future__ import annotations

import json
from pathlib import Path

import pytest

from rehab_hil.telemetry.session import NetworkConfig, TelemetryConfigError, build_zenoh_config, open_session


def get(cfg, key: str):  # type: ignore[no-untyped-def]
    return json.loads(cfg.get_json(key))


def test_default_client_is_loopback_only_with_scouting_and_gossip_off() -> None:
    cfg = build_zenoh_config(NetworkConfig())
    assert get(cfg, "mode") == "client"
    assert get(cfg, "connect/endpoints") == ["tcp/127.0.0.1:7447"]
    assert get(cfg, "listen/endpoints") == []
    assert get(cfg, "scouting/multicast/enabled") is False
    assert get(cfg, "scouting/gossip/enabled") is False


def test_a_hub_listens_on_loopback_only() -> None:
    cfg = build_zenoh_config(NetworkConfig(role="hub", port=17447))
    assert get(cfg, "mode") == "router"
    assert get(cfg, "listen/endpoints") == ["tcp/127.0.0.1:17447"]
    assert get(cfg, "scouting/multicast/enabled") is False and get(cfg, "scouting/gossip/enabled") is False
    assert get(cfg, "connect/endpoints") == []


def test_lab_mode_connects_to_the_router_endpoint() -> None:
    cfg = build_zenoh_config(NetworkConfig(mode="lab", router=("tcp/10.1.2.3:7447",)))
    assert get(cfg, "connect/endpoints") == ["tcp/10.1.2.3:7447"]
    assert get(cfg, "scouting/gossip/enabled") is False


def test_user_password_and_tls_files_are_passed_through(tmp_path: Path) -> None:
    ca, cert, key = (tmp_path / n for n in ("ca.pem", "c.pem", "k.pem"))
    for p in (ca, cert, key):
        p.write_text("x")
    cfg = build_zenoh_config(NetworkConfig(mode="lab", router=("tls/lab-router:7447",), user="viewer",
                                           password="pw", tls_root_ca=ca, tls_certificate=cert, tls_private_key=key))
    assert get(cfg, "transport/auth/usrpwd/user") == "viewer"
    assert get(cfg, "transport/auth/usrpwd/password") == "pw"
    assert get(cfg, "transport/link/tls/root_ca_certificate") == str(ca)
    assert get(cfg, "transport/link/tls/connect_certificate") == str(cert)
    assert get(cfg, "transport/link/tls/connect_private_key") == str(key)
    assert get(cfg, "transport/link/tls/enable_mtls") is True


@pytest.mark.parametrize(("kw", "msg"), [
    ({"mode": "wan"}, "mode"),
    ({"role": "peer"}, "role"),
    ({"port": 0}, "port"),
    ({"port": True}, "port"),
    ({"router": ("tcp/10.0.0.1:7447",)}, "mode='lab'"),
    ({"mode": "lab"}, "at least one router"),
    ({"mode": "lab", "router": ("10.0.0.1:7447",)}, "must look like"),
    ({"mode": "lab", "router": ("tcp/10.0.0.1:99999",)}, "must look like"),
    ({"mode": "lab", "router": ("tls/r:7447",)}, "tls_root_ca"),
    ({"mode": "lab", "role": "hub", "router": ("tcp/r:7447",)}, "lab router needs at least one listen endpoint"),
    ({"mode": "lab", "role": "hub", "listen": ("tcp/0.0.0.0:7447",), "router": ("r:7447",)}, "must look like"),
    ({"mode": "lab", "role": "hub", "listen": ("tls/0.0.0.0:7447",)}, "tls_certificate"),
    ({"listen": ("tcp/127.0.0.1:7447",)}, "listen endpoints are for the lab router"),
    ({"user": "u"}, "together"),
    ({"tls_root_ca": Path("/nonexistent/ca.pem")}, "file not found"),
    ({"access_control": {"enabled": True}}, "hub settings"),
])
def test_settings_that_cannot_work_are_refused_with_the_setting_named(kw: dict, msg: str) -> None:
    with pytest.raises(TelemetryConfigError, match=msg):
        build_zenoh_config(NetworkConfig(**kw))


def test_a_client_without_a_hub_fails_fast_with_a_clear_error(unused_port: int) -> None:
    with pytest.raises(TelemetryConfigError, match=r"cannot connect to tcp/127\.0\.0\.1"):
        open_session(NetworkConfig(port=unused_port))


def test_a_lab_router_listens_where_told_and_connects_to_its_mesh() -> None:
    cfg = build_zenoh_config(NetworkConfig(mode="lab", role="hub", listen=("tcp/10.0.0.2:7447",),
                                           router=("tcp/10.0.0.3:7447",)))
    assert json.loads(cfg.get_json("mode")) == "router"
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/10.0.0.2:7447"]
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/10.0.0.3:7447"]
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
