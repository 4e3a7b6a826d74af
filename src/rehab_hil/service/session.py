"""One session on one rig, built one way: ``open_session(config, device, ...)``.

The builder loads the plant config (and a patient profile, and a simulated patient) once, opens the rig
and checks its HELLO against the plant and the controller's claims, homes it, and opens the session's
features (``service.features``: recording, telemetry, Foxglove, the live twin, the learning on the rig,
kept assistance, a simulated patient's truth). ``RigSession.run(duration_s)`` runs the loop, in a
process of its own for every real-time session (``loop.process``) or in this one in lockstep, and
returns the ``RunResult``; leaving the ``with`` block closes everything, in reverse order. The CLI
(``rehab-hil run``), the tests, the benches and a lab's own CI all build sessions here::

    with open_session("configs/finger_extensor.toml", "inprocess", controller="pid") as s:
        result = s.run(5.0)
    assert result.pwm_off_at_end

Errors a user can fix (a config the controller cannot run on, a device that does not answer or
does not match, a homing that fails) raise ``SessionError`` with one line.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from types import TracebackType
from typing import Any

from rehab_hil import metrics, shipped
from rehab_hil.hardware import HardwareError, on_configure
from rehab_hil.loop.dispatch import Dispatch
from rehab_hil.loop.figures import Progress, SessionFigures
from rehab_hil.loop.result import RunResult
from rehab_hil.loop.runner import PACINGS
from rehab_hil.service import assembly
from rehab_hil.service.errors import SessionError
from rehab_hil.service.features.base import Feature, SessionParts
from rehab_hil.service.homing import HomingResult, home
from rehab_hil.service.loop_handle import LOCKSTEP_SAMPLE_TIMEOUT_S, start_loop
from rehab_hil.service.opening import Loaded, load_session, open_hardware, session_features
from rehab_hil.service.options import FoxgloveOptions, SessionOptions, TelemetryOptions, option_names

__all__ = ["HOMING_MODES", "LOCKSTEP_SAMPLE_TIMEOUT_S", "FoxgloveOptions", "RigSession", "SessionError",
           "SessionOptions", "TelemetryOptions", "open_session"]

HOMING_MODES = ("current", "hard-stop", "none")
MAX_DURATION_S = 24 * 3600.0


class RigSession:
    """A built session: ``run(duration_s)`` once, inside ``with``. ``progress`` for a live display,
    ``request_stop`` for a signal handler; ``feature(name)`` a feature it opened (or None)."""

    def __init__(self, stack: ExitStack, loaded: Loaded, parts: SessionParts, features: list[Feature]) -> None:
        self.stack, self.loaded, self.parts, self.features = stack, loaded, parts, features
        self.homed: HomingResult | None = None
        self.loop: Any = None  # the loop's handle while it runs (LocalLoop or LoopProcess)
        self.result: RunResult | None = None
        self._progress = Progress()
        self._stop: tuple[str, str] | None = None
        self.sink_failures: list[str] = []  # one line per sink that stopped working, in the order they did

    # what a caller reads of it
    cfg = property(lambda self: self.parts.cfg)
    config_path = property(lambda self: self.parts.config_path)
    device = property(lambda self: self.parts.device)
    hw = property(lambda self: self.parts.hw)
    controller = property(lambda self: self.parts.controller)
    options = property(lambda self: self.parts.options)
    binding = property(lambda self: self.parts.binding)
    period_s = property(lambda self: self.parts.period_s)
    lockstep = property(lambda self: self.parts.lockstep)
    run_dir = property(lambda self: self.parts.run_dir)
    identity = property(lambda self: self.parts.identity)

    def feature(self, name: str) -> Any:
        """The feature ``name`` if the session opened it, else None."""
        return self.parts.features.get(name)

    @property
    def twin(self) -> Any:
        """The live twin's run (``twin.session.TwinRun``), or None: its hooks may be set before ``run``."""
        f = self.feature("twin")
        return f.run if f is not None else None

    @property
    def progress(self) -> Progress:
        return self.loop.progress if self.loop is not None else self._progress

    @property
    def rig_id(self) -> str:
        return self.parts.rig_id

    def request_stop(self, reason: str, kind: str = "stop_request") -> None:
        """Stop at the next cycle through the safe state (a signal handler's call; any thread)."""
        self._stop = (reason, kind)
        if self.loop is not None:
            self.loop.request_stop(reason, kind)

    def __enter__(self) -> RigSession:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stack.close()

    def close(self) -> None:
        """Close everything the session opened (the rig, the features), in reverse order; idempotent."""
        self.stack.close()

    def run(self, duration_s: float) -> RunResult:
        """Loop for ``duration_s`` of device time (or until a trip or a stop request), leave the rig
        in the safe state, finish the features and the run's metadata; returns the result."""
        if not 0 < duration_s <= MAX_DURATION_S:
            raise SessionError("duration", f"must be in (0, {MAX_DURATION_S:.0f}] s, got {duration_s}")
        if self.result is not None or self.loop is not None:
            raise SessionError(None, "a session runs once, after open_session; open a new one")
        parts, opts = self.parts, self.parts.options
        figures = self._figures(duration_s)
        dispatch = Dispatch(figures, [s for f in self.features for s in f.sinks()] + list(opts.test.sinks),
                            [feed for f in self.features for feed in f.feeds()])
        self.loop = loop = start_loop(parts, dispatch, self.stack)
        for sink in dispatch.sinks:  # a sink that stops working: a critical one (the recorder) stops the session
            sink.on_failure = _failure_route(loop, sink.critical, self.sink_failures)
        for f in self.features:
            if hasattr(f, "in_process"):
                f.in_process(loop.separate)
            f.started(loop)
        if self._stop is not None:
            loop.request_stop(*self._stop)
        realtime = opts.realtime if opts.realtime is not None else not parts.lockstep
        timeout = opts.test.sample_timeout_s or (LOCKSTEP_SAMPLE_TIMEOUT_S if parts.lockstep else None)
        try:
            report = loop.run(duration_s=duration_s, pacing=opts.pacing, realtime=realtime, sample_timeout_s=timeout,
                              lockstep=parts.lockstep)
        except BaseException as e:  # what was learned so far is kept
            for f in self.features:
                if hasattr(f, "failed"):
                    f.failed(e)
            raise
        result = RunResult.of(report, tracking=figures.tracking(), sinks={**dispatch.reports(), **loop.reports()},
                              step=self._step_figures(figures))
        result.session, result.session_cycles = figures.session()
        self.result = self._finish(result)
        return self.result

    def _figures(self, duration_s: float) -> SessionFigures:
        """The records' figures: rows for the tracking, and the per-cycle meter of a session's cycles."""
        parts, controller = self.parts, self.parts.controller
        meter = assembly.build_meter(parts.cfg, controller, duration_s) if hasattr(controller, "controller") else None
        actuator = getattr(controller, "actuator", None)
        n = round(duration_s / parts.period_s) + 128
        return SessionFigures(n, duration_s, meter, actuator.effort if actuator is not None else None)

    def _step_figures(self, figures: SessionFigures) -> dict[str, float]:
        """A step run's overshoot, rise and settling time over the recorded rows (``metrics.recorded_step``:
        the same function an analysis of run.csv calls); {} for a session's cycles."""
        ref = self.parts.reference
        if ref is None or ref.kind != "step":
            return {}
        return metrics.recorded_step(*figures.recorded_rows(), start=ref.start_deg)

    def _finish(self, result: RunResult) -> RunResult:
        """Each feature's part, in order; the recording's last (its metadata holds every other's)."""
        for f in sorted(self.features, key=lambda f: getattr(f, "finishes_last", False)):
            got = f.finish(result)
            if got is not None:
                result.features[got.name] = got
                result.files += list(got.files)
        return result

    def open(self) -> None:
        """Before anything moves: the contract check, the homing; then the features, in order."""
        parts = self.parts
        try:
            on_configure(parts.binding, parts.hw.info, parts.controller.claims)
        except HardwareError as e:
            raise SessionError("device", f"{parts.device}: {e}") from None
        self._home()
        for f in self.features:
            missing = [n for n in f.needs if n not in parts.features]
            if missing:
                raise SessionError(None, f"the {f.name} feature needs {', '.join(missing)}")
            f.open(parts)
            parts.features[f.name] = f
            self.stack.callback(f.close)

    def _home(self) -> None:
        """The encoder's zero at a confirmed pose or the closed hard stop (``service.homing``)."""
        rig, parts = self.parts.options.rig, self.parts
        if rig.home not in HOMING_MODES:
            raise SessionError("home", f"must be one of {list(HOMING_MODES)}, got {rig.home!r}")
        try:
            self.homed = home(rig.home, parts.hw, parts.cfg, parts.binding, self.loaded.configure,
                              confirm=rig.confirm)
        except HardwareError as e:
            raise SessionError("home", f"{rig.home}: {e}") from None


def _failure_route(loop: Any, critical: bool, failures: list[str]) -> Any:
    """A sink's one-line failure, kept; a critical sink's stops the loop (a session must not go on unrecorded)."""
    def failed(text: str) -> None:
        failures.append(text)
        if critical:
            loop.request_stop(text, "sink_failure")
    return failed


def open_session(config: str | Path, device: str | None = None, **options: Any) -> RigSession:
    """Build a session on ``device`` ("sim", "avr", "inprocess", a serial path or "auto"; default
    ``[rig].port``) for the plant config at ``config``; ``options``: those of ``SessionOptions`` by their
    flat names (``record=..., twin=True``). Raises ``SessionError`` (one line) for what the user can fix."""
    try:
        opts = SessionOptions.of(**options)
    except TypeError as e:
        raise SessionError(None, str(e) if "options are" in str(e) else f"{e}; the options are: "
                           f"{', '.join(option_names())}") from None
    if opts.pacing not in PACINGS:
        raise SessionError("pacing", f"must be one of {list(PACINGS)}, got {opts.pacing!r}")
    loaded = load_session(shipped.resolve(config), device, opts)
    stack = ExitStack()
    try:
        parts = open_hardware(stack, loaded)
        session = RigSession(stack, loaded, parts, session_features(loaded, parts))
        session.open()
    except BaseException:
        stack.close()
        raise
    return session
