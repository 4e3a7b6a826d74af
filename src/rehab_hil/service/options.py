"""How a session runs, beside its config and device: ``SessionOptions``, grouped by what they are about.

``open_session`` takes the options as flat keywords (``record=..., twin=True``: the CLI's names) and
puts each in its group: the rig (``RigOptions``), a simulated rig's plant and patient
(``SimulationOptions``), what the session learns and keeps (``LearningOptions``), what it shows and
records (``ViewOptions``), and the overrides only tests of the loop use (``TestOverrides``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from rehab_hil.hardware import HardwareInterface
from rehab_hil.protocol import Configure

__all__ = ["FoxgloveOptions", "LearningOptions", "RigOptions", "SessionOptions", "SimulationOptions",
           "TelemetryOptions", "TestOverrides", "ViewOptions"]


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


@dataclass(frozen=True)
class RigOptions:
    """The rig: its name, the encoder's zero, and an already connected rig (the caller closes it)."""

    rig_id: str | None = None  # the rig's name in run directories, stores and metadata
    home: str = "none"  # "current", "hard-stop" or "none" (the CLI's default is "current")
    confirm: Any = None  # homing "current": asks the user before zeroing (None: no question)
    hw: HardwareInterface | None = None  # an already connected rig instead of ``device``


@dataclass(frozen=True)
class SimulationOptions:
    """A simulated rig's own plant (maybe with effects the host's model lacks) and its patient."""

    sim_plant: Path | None = None  # the plant config the simulated device runs
    sim_patient: Path | None = None  # a simulated patient on the plant (profiles/sim/*.toml)


@dataclass(frozen=True)
class LearningOptions:
    """What the session learns and keeps for the next one."""

    rig_learning: bool | None = None  # learn the feedforward on the rig (None: [controllers.model_based])
    learning_store: Path | None = None  # where learned tables are kept (None: ~/.cache/rehab-hil/rig_learning)
    assistance_store: Path | None = None  # where learned assistance is kept (None: service.assist_store's default)
    fresh_assistance: bool = False  # assist-as-needed starts from the config, not the patient's stored assistance
    thermal_replan: bool = True  # re-plan the learned feedforward on the twin's thermal estimates


@dataclass(frozen=True)
class ViewOptions:
    """What the session records and shows."""

    record: Path | None = None  # a folder: each run writes a new run directory in it
    twin: bool = False  # the live twin beside the rig (also on with [twin] enabled)
    telemetry: TelemetryOptions | None = None  # publish over zenoh
    foxglove: FoxgloveOptions | None = None  # serve the session live to Foxglove


@dataclass(frozen=True)
class TestOverrides:
    """What only tests of the loop and the link set."""

    supervisor: Any = None  # a ``Supervisor`` instead of the config's limits
    configure: Configure | None = None  # a CONFIGURE instead of the config's
    sinks: tuple[Any, ...] = ()  # more sinks after the loop's write (``loop.sinks.Sink``)
    sample_timeout_s: float | None = None  # how long a cycle waits for its sample (None: a period; lockstep 5 s)
    loop_process: bool | None = None  # the loop in a process of its own (None: every real-time session)
    ring_s: float | None = None  # the loop process's ring, in seconds of records (None: loop.ring.RING_S)
    features: tuple[Any, ...] = ()  # more session features (``service.features.base.Feature``), opened last


_GROUPS = {"rig": RigOptions, "sim": SimulationOptions, "learning": LearningOptions, "views": ViewOptions,
           "test": TestOverrides}


@dataclass(frozen=True)
class SessionOptions:
    """How a session runs (every option has the CLI's meaning, ``rehab-hil run --help``). ``controller``:
    a controller's name (``rehab_hil.controllers``), or an object the loop can step
    (``loop.controllers.LoopController``)."""

    controller: Any = None  # None: [rig.session] controller
    reference: str = "session"  # "session" (open-close cycles) or "step" ([rig.session] step_deg)
    profile: Path | None = None  # a patient profile (profiles/*.toml): the session and tighter limits
    pacing: str = "device"  # react to the sample stream, or wake on host deadlines (docs/loop.md)
    lockstep: bool = False  # sim/avr: virtual time (the in-process device always is)
    realtime: bool | None = None  # the loop's real-time setup (scheduler, GC); None: unless lockstep
    rig: RigOptions = field(default_factory=RigOptions)
    sim: SimulationOptions = field(default_factory=SimulationOptions)
    learning: LearningOptions = field(default_factory=LearningOptions)
    views: ViewOptions = field(default_factory=ViewOptions)
    test: TestOverrides = field(default_factory=TestOverrides)

    @classmethod
    def of(cls, **flat: Any) -> SessionOptions:
        """From flat keywords (``record=..., rig_learning=False``), each put in its group; a keyword no
        group knows raises ``TypeError`` naming every option."""
        top = {f.name for f in fields(cls)} - set(_GROUPS)
        grouped: dict[str, dict[str, Any]] = {g: {} for g in _GROUPS}
        mine: dict[str, Any] = {}
        for key, value in flat.items():
            group = next((g for g, c in _GROUPS.items() if key in {f.name for f in fields(c)}), None)
            if key in top:
                mine[key] = value
            elif group is not None:
                grouped[group][key] = value
            else:
                raise TypeError(f"open_session() got an unexpected keyword argument {key!r}; "
                                f"the options are: {', '.join(option_names())}")
        return cls(**mine, **{g: _GROUPS[g](**kw) for g, kw in grouped.items()})


def option_names() -> list[str]:
    """Every flat option ``open_session`` takes."""
    top = [f.name for f in fields(SessionOptions) if f.name not in _GROUPS]
    return top + [f.name for c in _GROUPS.values() for f in fields(c)]
