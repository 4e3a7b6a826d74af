"""The live views beside a session: zenoh telemetry and the Foxglove live view. Each is a sink of the
loop's records and publishes the loop's progress and link figures once a second; each refuses a bad
setting with one ``SessionError`` line naming its option. zenoh and Foxglove load only when asked for."""

from __future__ import annotations

from typing import Any

from rehab_hil.loop.sinks import Sink
from rehab_hil.service.errors import SessionError
from rehab_hil.service.features.base import Feature, LoopHandle, SessionParts
from rehab_hil.service.options import FoxgloveOptions, TelemetryOptions

__all__ = ["Foxglove", "Telemetry"]


class Telemetry(Feature):
    """``telemetry``: publish over zenoh as the rig (``telemetry.rig.RigTelemetry``)."""

    name = "telemetry"

    def __init__(self, opts: TelemetryOptions) -> None:
        self.opts = opts
        self.rig: Any = None

    def open(self, parts: SessionParts) -> None:
        from rehab_hil.telemetry import NetworkConfig, RigIdError, TelemetryConfigError
        from rehab_hil.telemetry.rig import RigTelemetry, rig_info

        opts = self.opts
        info = rig_info(parts.cfg.plant, parts.config_path, parts.binding, parts.period_s, parts.hw.info)
        try:
            if opts.connect:
                if opts.user and opts.password is None:
                    raise TelemetryConfigError("a lab router user needs a password (REHAB_ZENOH_PASSWORD)")
                net = NetworkConfig(mode="lab", router=tuple(opts.connect), user=opts.user, password=opts.password)
            else:
                net = NetworkConfig(port=opts.port)
            self.rig = RigTelemetry(opts.rig_id, info, net, queue_size=20_000)
        except (RigIdError, TelemetryConfigError, ValueError) as e:
            raise SessionError("telemetry", str(e)) from None

    @property
    def sink(self) -> Any:
        return self.rig.sink if self.rig is not None else None

    def sinks(self) -> list[Sink]:
        return [self.rig.sink] if self.rig is not None else []

    def started(self, loop: LoopHandle) -> None:
        self.rig.watch(loop, loop.link)  # type: ignore[attr-defined]

    def close(self) -> None:
        if self.rig is not None:
            self.rig.close()


class Foxglove(Feature):
    """``foxglove``: serve the session live to Foxglove (``telemetry.foxglove.LiveView``)."""

    name = "foxglove"

    def __init__(self, opts: FoxgloveOptions) -> None:
        self.opts = opts
        self.view: Any = None

    def open(self, parts: SessionParts) -> None:
        from rehab_hil.telemetry.foxglove import FoxgloveError, FoxgloveLive, LiveView

        try:
            live = FoxgloveLive(self.opts.host, self.opts.port)
        except FoxgloveError as e:
            raise SessionError("foxglove", str(e)) from None
        self.view = LiveView(live, live.add_rig(parts.binding))

    @property
    def sink(self) -> Any:
        return self.view.sink if self.view is not None else None

    @property
    def url(self) -> str:
        return self.view.live.url

    def sinks(self) -> list[Sink]:
        return [self.view.sink] if self.view is not None else []

    def started(self, loop: LoopHandle) -> None:
        self.view.watch(loop, loop.link)  # type: ignore[attr-defined]

    def close(self) -> None:
        if self.view is not None:
            self.view.close()
