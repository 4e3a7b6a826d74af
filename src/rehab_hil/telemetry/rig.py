"""Telemetry for a running rig: the session (hub or client), the ``info`` body and the publisher.

``rehab-hil run --telemetry RIG`` uses this; on one machine the rig hosts the loopback hub so that
``monitor`` and ``record --from-zenoh`` can connect to it as clients.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import zenoh

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loop.records import EventRecord
from rehab_hil.loop.stats import loop_stats
from rehab_hil.protocol import PROTOCOL_VERSION
from rehab_hil.telemetry.codec import JSON_VERSION, STATE_VERSION
from rehab_hil.telemetry.publisher import TelemetryPublisher
from rehab_hil.telemetry.session import NetworkConfig, TelemetryConfigError, open_session

__all__ = ["RigTelemetry", "rig_info"]


def rig_info(plant: str, config_path: str | Path, binding: DeviceBinding, period_s: float,
             hello: Any = None) -> dict[str, Any]:
    """What ``rehab/<rig>/info`` answers: plant, config (path and full TOML text), versions, signal names."""
    path = Path(config_path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError:
        text = None
    fw = None
    if hello is not None:
        fw = f"{hello.fw_major}.{hello.fw_minor}.{hello.fw_patch}"
    return {
        "plant": plant, "config_path": str(path), "config_toml": text, "period_s": period_s,
        "firmware_version": fw, "device_protocol_version": getattr(hello, "protocol_version", None),
        "host_protocol_version": PROTOCOL_VERSION, "telemetry_state_version": STATE_VERSION,
        "telemetry_json_version": JSON_VERSION, "analog_names": [ch.signal for ch in binding.adc],
        "encoder_signal": binding.encoder_signal,
    }


class RigTelemetry:
    """Session + ``TelemetryPublisher`` for one rig; ``sink`` (the publisher) is one of the loop's sinks.

    In loopback mode the rig first tries to be the hub (listen on 127.0.0.1:port) and becomes a
    client of an existing hub if the port is taken; ``role`` says which it got."""

    def __init__(self, rig_id: str, info: Mapping[str, Any], net: NetworkConfig | None = None,
                 stats_source: Callable[[], Mapping[str, Any]] | None = None, **publisher_kw: Any) -> None:
        net = net or NetworkConfig()
        if net.mode == "loopback" and net.role == "client":
            try:
                self.session = open_session(replace(net, role="hub"))
                self.role = "hub"
            except TelemetryConfigError:
                self.session = open_session(net)
                self.role = "client"
        else:
            self.session = open_session(net)
            self.role = net.role
        try:
            self.sink = TelemetryPublisher(self.session, rig_id, info=info, stats_source=stats_source, **publisher_kw)
        except BaseException:
            self.session.close()
            raise

    def watch(self, service: Any, hw: Any) -> None:
        """Publish ``service.progress`` and ``hw.stats`` in the 1 Hz stats message (read off the loop thread)."""
        self.sink.set_stats_source(loop_stats(service, hw))

    def on_trip(self, event: Any) -> None:
        """Publish a supervisor's ``SafetyEvent`` on ``.../safety`` now (the loop itself offers its
        events to the publisher as ``EventRecord`` s at the end of a session)."""
        self.sink.offer(EventRecord(float(getattr(event, "t_s", math.nan)), str(getattr(event, "reason", event)),
                                    str(getattr(event, "detail", ""))))
        self.sink.wake()

    def close(self) -> None:
        """Flush and undeclare the publisher, then close the session; idempotent."""
        self.sink.close()
        with contextlib.suppress(zenoh.ZError):
            self.session.close()

    def __enter__(self) -> RigTelemetry:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

