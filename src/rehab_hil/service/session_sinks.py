"""The live sinks a session can have beside its recording, built from its options: zenoh telemetry,
the Foxglove live view and the live twin. Each refuses a bad setting with one ``SessionError`` line
naming its option. zenoh and Foxglove load only when asked for (their imports take a while)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from rehab_hil.service import assembly
from rehab_hil.service.errors import SessionError

if TYPE_CHECKING:  # the session module imports this one; these names are for the type checker only
    from rehab_hil.service.session import RigSession

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


def zenoh_telemetry(session: RigSession) -> Any:
    """The zenoh publisher (``telemetry.rig.RigTelemetry``) for the session's ``telemetry`` option."""
    from rehab_hil.telemetry import NetworkConfig, RigIdError, TelemetryConfigError
    from rehab_hil.telemetry.rig import RigTelemetry, rig_info

    opts = session.options.telemetry
    assert opts is not None
    info = rig_info(session.cfg.plant, session.config_path, session.binding, session.period_s, session.hw.info)
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


def foxglove_view(session: RigSession) -> Any:
    """The Foxglove live view (``telemetry.foxglove.LiveView``): the server and the rig's feed."""
    from rehab_hil.telemetry.foxglove import FoxgloveError, FoxgloveLive, LiveView

    opts = session.options.foxglove
    assert opts is not None
    try:
        live = FoxgloveLive(opts.host, opts.port)
    except FoxgloveError as e:
        raise SessionError("foxglove", str(e)) from None
    return LiveView(live, live.add_rig(session.binding))


def live_twin(session: RigSession) -> Any:
    """The live twin (``twin.session.TwinRun``) for the ``twin`` option or ``[twin] enabled``; None when off."""
    cfg = session.cfg
    if not (session.options.twin or (cfg.twin is not None and cfg.twin.enabled)):
        return None
    from rehab_hil.twin.model import TwinSetupError
    from rehab_hil.twin.session import start_twin

    declared = getattr(session.controller, "controller", session.controller)  # a built controller's declaration
    ref = getattr(declared, "reference", None)
    cycle_s = ref.period_s if ref is not None and ref.kind == "session" else None
    # its predictions and model events go to the recording and Foxglove as records, to zenoh on .../twin
    feed = session.foxglove.sink if session.foxglove is not None else None
    outputs = [x for x in (session.recorder, feed) if x is not None]
    publisher = session.telemetry.sink if session.telemetry is not None else None
    try:
        twin = start_twin(cfg, session.binding, assembly.period_s(cfg), session.run_dir, outputs, publisher,
                          cycle_s, session.lockstep)
    except TwinSetupError as e:
        raise SessionError(None, f"{session.config_path}: [twin] {e}") from None
    session.stack.callback(twin.live.close)  # the twin's thread, if the session never ran (idempotent)
    return twin
