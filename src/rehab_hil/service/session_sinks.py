"""The live sinks a session can have beside its recording, built from its options: zenoh telemetry,
the Foxglove live view and the live twin. Each refuses a bad setting with one ``SessionError`` line
naming its option. zenoh and Foxglove load only when asked for (their imports take a while)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rehab_hil.service import assembly
from rehab_hil.service.errors import SessionError

__all__ = ["FoxgloveOptions", "TelemetryOptions", "foxglove_view", "live_twin", "zenoh_telemetry"]


@dataclass(frozen=True)
class TelemetryOptions:
    """Publish the session over zenoh as rig ``rig_id``: the loopback hub on ``port``, or a client of
    the lab's router(s) ``connect`` (``user``/``password``: its access control; docs/telemetry.md)."""

    rig_id: str
    port: int = 7447
    connect: tuple[str, ...] = ()
    user: str | None = None
    password: str | None = None


@dataclass(frozen=True)
class FoxgloveOptions:
    """Serve the session live to Foxglove over its WebSocket protocol on ``host:port``."""

    host: str = "127.0.0.1"
    port: int = 8765


def zenoh_telemetry(opts: TelemetryOptions, plant: str, config_path: Path, binding: Any, period_s: float,
                    hello: Any) -> Any:
    """The zenoh publisher (``telemetry.rig.RigTelemetry``); its ``info`` answer names the plant,
    the config and the device's firmware (``hello``)."""
    from rehab_hil.telemetry import NetworkConfig, RigIdError, TelemetryConfigError
    from rehab_hil.telemetry.rig import RigTelemetry, rig_info

    info = rig_info(plant, config_path, binding, period_s, hello)
    try:
        if opts.connect:
            if opts.user and opts.password is None:
                raise TelemetryConfigError("a lab router user needs a password (REHAB_ZENOH_PASSWORD)")
            net = NetworkConfig(mode="lab", router=tuple(opts.connect), user=opts.user, password=opts.password)
        else:
            net = NetworkConfig(port=opts.port)
        return RigTelemetry(opts.rig_id, info, net, queue_size=20_000)
    except (RigIdError, TelemetryConfigError, ValueError) as e:
        raise SessionError("telemetry", str(e)) from None


def foxglove_view(opts: FoxgloveOptions, binding: Any) -> Any:
    """The Foxglove live view (``telemetry.foxglove.LiveView``): the server and the rig's feed."""
    from rehab_hil.telemetry.foxglove import FoxgloveError, FoxgloveLive, LiveView

    try:
        live = FoxgloveLive(opts.host, opts.port)
    except FoxgloveError as e:
        raise SessionError("foxglove", str(e)) from None
    return LiveView(live, live.add_rig(binding))


def live_twin(cfg: Any, binding: Any, run_dir: Path | None, outputs: list[Any], publisher: Any, reference: Any,
              lockstep: bool, source: str) -> Any:
    """The live twin (``twin.session.TwinRun``): its predictions and model events offered to ``outputs``
    (the recorder, the Foxglove feed) and published by ``publisher`` (zenoh's, or None) on
    ``rehab/<rig>/twin``; ``reference``: the controller's (its open-close period gives per-cycle
    interaction estimates)."""
    from rehab_hil.twin.model import TwinSetupError
    from rehab_hil.twin.session import start_twin

    cycle_s = reference.period_s if reference is not None and reference.kind == "session" else None
    try:
        return start_twin(cfg, binding, assembly.period_s(cfg), run_dir, outputs, publisher, cycle_s, lockstep)
    except TwinSetupError as e:
        raise SessionError(None, f"{source}: [twin] {e}") from None
