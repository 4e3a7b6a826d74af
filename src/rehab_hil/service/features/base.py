"""The seam a session grows by: a ``Feature`` declares what it needs, opens, takes records, contributes its
part of the result, and closes.

A session (``service.session``) opens its features in order before the loop (after the rig is homed),
gives the loop their sinks and feeds, tells each the loop's handle once it exists (``started``: stop
requests, learned tables), and after the loop asks each, in order, for its ``FeatureResult`` (its part
of metadata.json and of the summary). ``close`` runs whatever happened (the session's exit stack).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from rehab_hil.loop.records import CommandRecord
from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.loop.sinks import Sink
from rehab_hil.service.identity import SessionIdentity
from rehab_hil.service.options import SessionOptions

__all__ = ["Feature", "LoopHandle", "SessionParts"]


class LoopHandle(Protocol):
    """What a feature may ask of the running loop (in this process, or in a loop process of its own)."""

    def request_stop(self, reason: str, kind: str = "stop_request") -> None: ...

    def offer_table(self, table: Any, retune: Any = None) -> bool: ...

    def tighten_thermal(self, change: Any) -> bool: ...

    separate: bool  # the loop runs in a process of its own (``LoopProcess``): any thread may post to it


@dataclass
class SessionParts:
    """What the session has loaded and opened, once, for its features."""

    cfg: Any  # the validated plant config (the profile applied)
    config_path: Path
    binding: Any  # the plant's device binding
    period_s: float
    device: str
    hw: Any  # the connected rig
    controller: Any  # the loop's controller (a ``ControllerRuntime``, or a test's own)
    options: SessionOptions
    rig_id: str  # the rig's name in run directories and metadata
    identity: SessionIdentity  # rig and patient, as every store keys them
    lockstep: bool
    run_dir: Path | None = None  # set by the recording feature
    metadata: dict[str, Any] = field(default_factory=dict)  # the run's metadata at its start (recording)
    features: dict[str, Feature] = field(default_factory=dict)  # those opened so far, by name

    @property
    def reference(self) -> Any:
        return getattr(self.controller, "reference", None)


class Feature:
    """A session feature; every method has a do-nothing default. ``needs``: the names of features that
    must be open before this one (it reads them from ``SessionParts.features``)."""

    name = ""
    needs: tuple[str, ...] = ()

    def open(self, parts: SessionParts) -> None:
        """Before the loop (the rig is homed): open what the feature holds."""

    def sinks(self) -> list[Sink]:
        """The sinks that take the loop's records after each write."""
        return []

    def feeds(self) -> list[Callable[[CommandRecord], None]]:
        """Callables that take each command record at once (in lockstep: before the next sample)."""
        return []

    def started(self, loop: LoopHandle) -> None:
        """The loop exists: the feature may now ask it to stop, or offer it tables."""

    def finish(self, result: RunResult) -> FeatureResult | None:
        """After the loop, in the features' order: the feature's part of the result (None: nothing)."""
        return None

    def close(self) -> None:
        """Release what the feature holds (always; idempotent)."""
