"""Where a session's loop runs: in a process of its own for every real-time session (``loop.process``), in
the session's own process in lockstep (its time is virtual: nothing competes with it) or where the loop
cannot cross to a process (an in-process device, a controller that does not pickle: said in a note).

Both handles answer the same calls (``service.features.base.LoopHandle``): ``run``, ``request_stop``,
``offer_table``, ``tighten_thermal``, ``progress`` and ``link`` (the link figures the live views publish).
"""

from __future__ import annotations

from contextlib import ExitStack
from typing import Any

from rehab_hil.loop.dispatch import Dispatch
from rehab_hil.loop.figures import Progress
from rehab_hil.loop.process import LoopProcess, can_cross
from rehab_hil.loop.ring import RING_S
from rehab_hil.loop.runner import LoopReport, LoopService
from rehab_hil.service import assembly
from rehab_hil.service.features.base import SessionParts

__all__ = ["LOCKSTEP_SAMPLE_TIMEOUT_S", "LocalLoop", "start_loop"]

# virtual time: a sample that takes this long in wall time is missing (a starved machine pauses a
# lockstep device without losing anything; link loss there is link_loss_periods such waits in a row)
LOCKSTEP_SAMPLE_TIMEOUT_S = 5.0


class LocalLoop:
    """The loop in the session's process: the dispatch is its outlet, a table is swapped in at once
    (the learning offers it at its swap point, between two samples of this very thread)."""

    separate = False

    def __init__(self, service: LoopService, dispatch: Dispatch, hw: Any, why: str = "") -> None:
        self.service, self.dispatch, self.link, self.why = service, dispatch, hw, why

    @property
    def progress(self) -> Progress:
        return self.dispatch.figures.progress

    def request_stop(self, reason: str, kind: str = "stop_request") -> None:
        self.service.request_stop(reason, kind)

    def offer_table(self, table: Any, retune: Any = None) -> bool:
        self.service.controller.swap_table(table, retune)  # type: ignore[attr-defined]
        return True

    def tighten_thermal(self, change: Any) -> bool:
        """Stricter values for the supervisor's temperature estimate, straight into it: called on the loop's
        own thread between two cycles (the safety feature's feed hands them over there)."""
        self.service.tighten_thermal(change)
        return True

    def run(self, **run: Any) -> LoopReport:
        return self.service.run(**run)

    def reports(self) -> dict[str, dict[str, Any]]:
        """Nothing between the loop and the sinks here."""
        return {}


def start_loop(parts: SessionParts, dispatch: Dispatch, stack: ExitStack) -> LocalLoop | LoopProcess:
    """The loop's handle for this session: a process of its own unless lockstep (or it cannot cross)."""
    opts = parts.options
    supervisor = opts.test.supervisor or assembly.build_supervisor(parts.cfg, parts.binding)
    estimator = assembly.build_estimator(parts.cfg, parts.binding)
    wanted = opts.test.loop_process if opts.test.loop_process is not None else not parts.lockstep
    why = can_cross(parts.hw, parts.controller) if wanted else ""
    if wanted and not why:
        critical = any(getattr(s, "critical", False) for s in dispatch.sinks)
        handle = LoopProcess(parts.hw, _configure(parts), parts.controller, estimator, supervisor, parts.period_s,
                             dispatch, tuple(ch.signal for ch in parts.binding.adc), ring_s=opts.test.ring_s or RING_S,
                             trip_on_overflow=critical)
        stack.callback(handle.close)
        return handle
    if why:
        notes = getattr(parts.controller, "notes", None)
        if isinstance(notes, list):
            notes.append(f"the loop runs in the session's process: {why}")
    service = LoopService(parts.hw, _configure(parts), parts.controller, estimator, supervisor, parts.period_s,
                          dispatch)
    return LocalLoop(service, dispatch, parts.hw, why)


def _configure(parts: SessionParts) -> Any:
    return parts.options.test.configure or assembly.firmware_configure(parts.cfg, parts.binding)
