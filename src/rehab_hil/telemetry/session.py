"""Build zenoh session configs for telemetry: loopback-only by default, a lab router, TLS and user/password.

Every config turns multicast scouting and gossip off and names its endpoints explicitly, because
zenoh's defaults listen on all interfaces and scout the LAN (docs/telemetry.md, "Network").
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import zenoh

__all__ = ["DEFAULT_PORT", "NetworkConfig", "TelemetryConfigError", "build_zenoh_config", "open_session"]

DEFAULT_PORT = 7447
_ENDPOINT = re.compile(r"^(tcp|tls|quic|udp)/(\[[0-9a-fA-F:]+\]|[A-Za-z0-9.\-]+):(\d{1,5})$")
_LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "[::1]"}


class TelemetryConfigError(ValueError):
    """A telemetry network setting that cannot work; the message names the setting."""


@dataclass(frozen=True)
class NetworkConfig:
    """Where a telemetry session listens or connects, and how it authenticates.

    ``mode="loopback"`` (default): only 127.0.0.1; a ``hub`` listens on ``port``, a ``client`` connects
    to it, over TLS when ``tls`` (hub: certificate and key; client: root CA). ``mode="lab"``: a client
    that connects to ``router`` endpoints (e.g. ``tls/lab-router:7447``), or the lab's router itself
    (``role="hub"``) listening on ``listen`` endpoints and connecting to the other routers of a mesh
    in ``router`` (``rehab-hil router``).
    ``user``/``password`` and the TLS files are passed through to zenoh unchanged.
    """

    mode: Literal["loopback", "lab"] = "loopback"
    role: Literal["hub", "client"] = "client"
    port: int = DEFAULT_PORT
    tls: bool = False
    router: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()  # lab router (mode="lab", role="hub"): the endpoints it listens on
    user: str | None = None
    password: str | None = None
    tls_root_ca: Path | None = None
    tls_certificate: Path | None = None
    tls_private_key: Path | None = None
    # hub only: user/password dictionary file ("user:password" lines) and zenoh access_control object
    usrpwd_dictionary: Path | None = None
    access_control: dict[str, Any] | None = field(default=None, hash=False, compare=False)

    def endpoints(self) -> list[str]:
        """The endpoints this session listens on (hub) or connects to (client)."""
        if self.mode == "loopback":
            return [f"{'tls' if self.tls else 'tcp'}/127.0.0.1:{self.port}"]
        return list(self.listen if self.role == "hub" else self.router)

    def validate(self) -> NetworkConfig:
        """Raise ``TelemetryConfigError`` naming the first setting that cannot work."""
        if self.mode not in ("loopback", "lab"):
            raise TelemetryConfigError(f"mode must be 'loopback' or 'lab', got {self.mode!r}")
        if self.role not in ("hub", "client"):
            raise TelemetryConfigError(f"role must be 'hub' or 'client', got {self.role!r}")
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 1 <= self.port <= 65535:
            raise TelemetryConfigError(f"port must be an integer in 1..65535, got {self.port!r}")
        if self.mode == "loopback" and self.router:
            raise TelemetryConfigError("router endpoints need mode='lab' (loopback mode only uses 127.0.0.1)")
        if self.tls and self.mode != "loopback":
            raise TelemetryConfigError("tls=True is for loopback; in lab mode use tls/HOST:PORT router endpoints")
        if self.tls and self.role == "hub" and self.tls_certificate is None:
            raise TelemetryConfigError("a TLS hub needs tls_certificate and tls_private_key")
        if self.tls and self.role == "client" and self.tls_root_ca is None:
            raise TelemetryConfigError("a TLS client needs tls_root_ca to check the hub's certificate")
        if self.mode == "loopback" and self.listen:
            raise TelemetryConfigError("listen endpoints are for the lab router (mode='lab', role='hub')")
        if self.mode == "lab" and self.role == "hub":
            if not self.listen:
                raise TelemetryConfigError("the lab router needs at least one listen endpoint, e.g. tcp/0.0.0.0:7447")
            for ep in self.listen:
                m = _ENDPOINT.match(ep) if isinstance(ep, str) else None
                if not m or not 0 <= int(m.group(3)) <= 65535:
                    raise TelemetryConfigError(f"listen endpoint {ep!r} must look like tcp/HOST:PORT or tls/HOST:PORT")
                if m.group(1) == "tls" and self.tls_certificate is None:
                    raise TelemetryConfigError(f"listen endpoint {ep!r} uses TLS: set tls_certificate and key")
            for ep in self.router:  # other routers of a mesh
                m = _ENDPOINT.match(ep) if isinstance(ep, str) else None
                if not m or not 1 <= int(m.group(3)) <= 65535:
                    raise TelemetryConfigError(f"router endpoint {ep!r} must look like tcp/HOST:PORT or tls/HOST:PORT")
        elif self.mode == "lab":
            if self.listen:
                raise TelemetryConfigError("listen endpoints are for the lab router (role='hub')")
            if not self.router:
                raise TelemetryConfigError("mode='lab' needs at least one router endpoint, e.g. tcp/10.0.0.2:7447")
            for ep in self.router:
                m = _ENDPOINT.match(ep) if isinstance(ep, str) else None
                if not m or not 1 <= int(m.group(3)) <= 65535:
                    raise TelemetryConfigError(f"router endpoint {ep!r} must look like tcp/HOST:PORT or tls/HOST:PORT")
                if m.group(1) == "tls" and self.tls_root_ca is None:
                    raise TelemetryConfigError(f"router endpoint {ep!r} uses TLS: set tls_root_ca")
        if (self.user is None) != (self.password is None):
            raise TelemetryConfigError("user and password go together: set both or neither")
        if (self.tls_certificate is None) != (self.tls_private_key is None):
            raise TelemetryConfigError("tls_certificate and tls_private_key go together: set both or neither")
        for name in ("tls_root_ca", "tls_certificate", "tls_private_key", "usrpwd_dictionary"):
            p = getattr(self, name)
            if p is not None and not Path(p).is_file():
                raise TelemetryConfigError(f"{name}: file not found: {p}")
        if self.role != "hub" and (self.usrpwd_dictionary is not None or self.access_control is not None):
            raise TelemetryConfigError("usrpwd_dictionary and access_control are hub settings (role='hub')")
        return self


def _put(cfg: zenoh.Config, key: str, value: Any) -> None:
    # zenoh's insert_json5 wants the value as JSON5 text, not a Python object
    cfg.insert_json5(key, json.dumps(value))


def build_zenoh_config(net: NetworkConfig) -> zenoh.Config:
    """The zenoh ``Config`` for ``net``: scouting off, explicit endpoints, auth and TLS passed through."""
    net.validate()
    cfg = zenoh.Config()
    _put(cfg, "scouting/multicast/enabled", False)
    _put(cfg, "scouting/gossip/enabled", False)
    if net.role == "hub":
        _put(cfg, "mode", "router")
        _put(cfg, "scouting/delay", 0)  # nothing to scout for with scouting off; saves 500 ms at open
        _put(cfg, "listen/endpoints", net.endpoints())
        _put(cfg, "connect/endpoints", list(net.router) if net.mode == "lab" else [])  # a lab router's mesh
    else:
        _put(cfg, "mode", "client")
        _put(cfg, "listen/endpoints", [])
        _put(cfg, "connect/endpoints", net.endpoints())
    if net.user is not None:
        _put(cfg, "transport/auth/usrpwd/user", net.user)
        _put(cfg, "transport/auth/usrpwd/password", net.password)
    if net.usrpwd_dictionary is not None:
        _put(cfg, "transport/auth/usrpwd/dictionary_file", str(net.usrpwd_dictionary))
    if net.tls_root_ca is not None:
        _put(cfg, "transport/link/tls/root_ca_certificate", str(net.tls_root_ca))
    if net.tls_certificate is not None:
        side = "listen" if net.role == "hub" else "connect"
        _put(cfg, f"transport/link/tls/{side}_certificate", str(net.tls_certificate))
        _put(cfg, f"transport/link/tls/{side}_private_key", str(net.tls_private_key))
        if net.tls_root_ca is not None:
            _put(cfg, "transport/link/tls/enable_mtls", True)
    if net.access_control is not None:
        _put(cfg, "access_control", net.access_control)
    return cfg


def open_session(net: NetworkConfig, wait_s: float | None = 0.0) -> zenoh.Session:
    """Open a zenoh session for ``net``; an unreachable hub/router becomes ``TelemetryConfigError``.

    A client tries again every 0.1 s for up to ``wait_s`` (None: until it connects; Ctrl-C ends the
    wait), so a subscriber started before its rig waits for the rig's hub or the lab's router."""
    cfg = build_zenoh_config(net)
    end = None if wait_s is None else time.monotonic() + max(0.0, wait_s)
    while True:
        try:
            return zenoh.open(cfg)
        except zenoh.ZError as e:
            if net.role == "hub" or (end is not None and time.monotonic() >= end):
                raise _unreachable(net, e, wait_s) from None
        time.sleep(0.1)
        cfg = build_zenoh_config(net)  # zenoh.open takes the config


def _unreachable(net: NetworkConfig, e: zenoh.ZError, wait_s: float | None) -> TelemetryConfigError:
    where = ", ".join(net.endpoints())
    verb = "listen on" if net.role == "hub" else "connect to"
    why = re.sub(r"\s+at \S+\.rs:\d+\.?\s*$", "", str(e)).strip()  # no Rust source path for a user
    waited = f" within {wait_s:g} s" if net.role != "hub" and wait_s else ""
    hint = ""
    if net.role != "hub" and net.mode != "lab":
        hint = (": no hub there; start the rig with `rehab-hil run ... --telemetry RIG` (it hosts the loopback "
                "hub) or `rehab-hil router`, or give the port it uses (--port), or the lab router (--connect ENDPOINT)")
    elif net.role != "hub":
        hint = ": is the lab router running and reachable (`rehab-hil router`)?"
    return TelemetryConfigError(f"cannot {verb} {where}{waited} ({why}){hint}")
