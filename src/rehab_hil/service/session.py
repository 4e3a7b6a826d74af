"""One session on one rig, built one way: ``open_session(config, device, ...)``.

The builder turns a plant config (and a patient profile), a device and a few options into a
``RigSession``: the rig opened and its HELLO checked against the plant and the controller's
claims, the homing, the run directory and its metadata, the sinks (recording, zenoh telemetry,
Foxglove, the live twin) and the loop. ``RigSession`` is a context manager whose ``run(duration_s)``
returns the ``RunResult``; leaving it closes everything it opened, in reverse order. The CLI
(``rehab-hil run``), the tests, the benches and a lab's own CI all build sessions here::

    with open_session("configs/finger_extensor.toml", "inprocess", controller="pid") as s:
        result = s.run(5.0)
    assert result.pwm_off_at_end

Errors a user can fix (a config the controller cannot run on, a device that does not answer or
does not match, a homing that fails) raise ``SessionError`` with one line.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, fields
from pathlib import Path
from types import TracebackType
from typing import Any

from rehab_hil import metrics, shipped
from rehab_hil.calibration import calibration_summary
from rehab_hil.config import ConfigError
from rehab_hil.controllers.assist_as_needed import learned_directions
from rehab_hil.controllers.build import Sources, settings_for
from rehab_hil.hardware import RIG_KINDS, HardwareError, HardwareInterface, on_configure, open_rig
from rehab_hil.loading import load_config
from rehab_hil.patient.profile import load_patient
from rehab_hil.patient.truth import TRUTH_FILE, SimTruth
from rehab_hil.plants import get_plant
from rehab_hil.profiles import apply_profile, load_profile, profile_rig_keys
from rehab_hil.protocol import Configure
from rehab_hil.service import assembly
from rehab_hil.service.assist_store import AssistanceStore, KeptAssistance, default_assistance_dir
from rehab_hil.service.controllers import ControllerRuntime
from rehab_hil.service.errors import SessionError
from rehab_hil.service.homing import HomingResult, home
from rehab_hil.service.recorder import Recorder
from rehab_hil.service.replan import ThermalReplan
from rehab_hil.service.rig_learning import LOCKSTEP_REPLAN_WAIT_S, RigLearning, TableStore, default_store_dir
from rehab_hil.service.run_dir import (
    METADATA_FILE,
    config_identity,
    new_run_dir,
    reference_metadata,
    result_metadata,
    session_metadata,
    write_metadata,
)
from rehab_hil.service.runner import PACINGS, LoopService, Progress, RunResult
from rehab_hil.service.session_sinks import FoxgloveOptions, TelemetryOptions, foxglove_view, live_twin, zenoh_telemetry

__all__ = ["HOMING_MODES", "LOCKSTEP_SAMPLE_TIMEOUT_S", "FoxgloveOptions", "RigSession", "SessionError",
           "SessionOptions", "TelemetryOptions", "open_session"]

# virtual time: a sample that takes this long in wall time is missing (a starved machine pauses a
# lockstep device without losing anything; link loss there is link_loss_periods such waits in a row)
LOCKSTEP_SAMPLE_TIMEOUT_S = 5.0
HOMING_MODES = ("current", "hard-stop", "none")
MAX_DURATION_S = 24 * 3600.0


@dataclass(frozen=True)
class SessionOptions:
    """How a session runs, beside its config and device (every field has the CLI's meaning, ``rehab-hil
    run --help``). ``controller``: a controller's name (``rehab_hil.controllers``), or an object the
    loop can step (``service.controllers.LoopController``: ``claims``, ``reset``, ``__call__``)."""

    controller: Any = None  # None: [rig.session] controller
    reference: str = "session"  # "session" (open-close cycles) or "step" ([rig.session] step_deg)
    profile: Path | None = None  # a patient profile (profiles/*.toml): the session and tighter limits
    pacing: str = "device"  # react to the sample stream, or wake on host deadlines (docs/loop.md)
    lockstep: bool = False  # sim/avr: virtual time (the in-process device always is)
    realtime: bool | None = None  # the loop's real-time setup (scheduler, GC); None: unless lockstep
    home: str = "none"  # "current", "hard-stop" or "none" (the CLI's default is "current")
    confirm: Any = None  # homing "current": asks the user before zeroing (None: no question)
    record: Path | None = None  # a folder: each run writes a new run directory in it
    rig_id: str | None = None  # the rig's name in run directories and metadata
    sim_plant: Path | None = None  # simulated devices: the plant config the device runs
    sim_patient: Path | None = None  # simulated devices: a simulated patient on the plant (profiles/sim/*.toml)
    twin: bool = False  # the live twin beside the rig (also on with [twin] enabled)
    telemetry: TelemetryOptions | None = None  # publish over zenoh (loopback hub or the lab's router)
    foxglove: FoxgloveOptions | None = None  # serve the session live to Foxglove
    hw: HardwareInterface | None = None  # an already connected rig (the caller closes it) instead of ``device``
    supervisor: Any = None  # a ``Supervisor`` instead of the config's limits (tests of the loop only)
    configure: Configure | None = None  # a CONFIGURE instead of the config's (tests of the link only)
    sinks: tuple[Any, ...] = ()  # more sinks after the loop's write (``service.sinks.Sink``), beside the above
    sample_timeout_s: float | None = None  # how long a cycle waits for its sample (None: a period; lockstep 5 s)
    rig_learning: bool | None = None  # learn the feedforward on the rig (None: [controllers.model_based] rig_learning)
    learning_store: Path | None = None  # where learned tables are kept (None: ~/.cache/rehab-hil/rig_learning)
    assistance_store: Path | None = None  # where learned assistance is kept (None: service.assist_store's default)
    fresh_assistance: bool = False  # assist-as-needed starts from the config, not the patient's stored assistance
    thermal_replan: bool = True  # re-plan the learned feedforward on the twin's thermal estimates (service/replan.py)


class RigSession:
    """A built session: ``run(duration_s)`` once, inside ``with``. ``loop`` is the ``LoopService``
    (``progress`` for a live display, ``request_stop`` for a signal handler)."""

    def __init__(self, stack: ExitStack, cfg: Any, config_path: Path, device: str, options: SessionOptions,
                 hw: HardwareInterface, controller: Any, configure: Configure) -> None:
        self.stack, self.cfg, self.config_path, self.device, self.options = stack, cfg, config_path, device, options
        self.hw, self.controller, self.configure = hw, controller, configure
        self.binding = get_plant(cfg.plant).device(cfg)
        self.period_s = assembly.period_s(cfg)
        self.lockstep = options.lockstep or device == "inprocess"  # the in-process device is lockstep by nature
        self.homed: HomingResult | None = None
        self.run_dir: Path | None = None
        self.metadata: dict[str, Any] = {}
        self.recorder: Recorder | None = None
        self.telemetry: Any = None  # the zenoh publisher's owner (RigTelemetry), or None
        self.foxglove: Any = None  # the Foxglove live view (LiveView), or None
        self.twin: Any = None  # the live twin's run (TwinRun), or None
        self.replan: ThermalReplan | None = None  # the re-plan on the twin's thermal estimates, or None
        self.loop: LoopService | None = None
        self.result: RunResult | None = None
        self.truth: SimTruth | None = None  # a simulated patient's sim_truth.csv, moved into the run directory
        self.assistance: KeptAssistance | None = None  # assist-as-needed's assistance kept across sessions

    @property
    def progress(self) -> Progress:
        assert self.loop is not None
        return self.loop.progress

    @property
    def rig_id(self) -> str:
        """The rig's name in the run directory and metadata: the option, the telemetry name, the plant."""
        tel = self.options.telemetry
        return self.options.rig_id or (tel.rig_id if tel is not None else None) or self.cfg.plant

    @property
    def controller_name(self) -> str:
        return getattr(self.controller, "name", None) or type(self.controller).__name__  # a test's own: its class

    def request_stop(self, reason: str, kind: str = "stop_request") -> None:
        """Stop at the next cycle through the safe state (a signal handler's call; any thread)."""
        if self.loop is not None:
            self.loop.request_stop(reason, kind)

    def __enter__(self) -> RigSession:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stack.close()

    def close(self) -> None:
        """Close everything the session opened (the rig, the sinks), in reverse order; idempotent."""
        self.stack.close()

    def run(self, duration_s: float) -> RunResult:
        """Loop for ``duration_s`` of device time (or until a trip or a stop request), leave the rig
        in the safe state, finish the sinks and the run's metadata; returns the result."""
        if not 0 < duration_s <= MAX_DURATION_S:
            raise SessionError("duration", f"must be in (0, {MAX_DURATION_S:.0f}] s, got {duration_s}")
        if self.result is not None or self.loop is None:
            raise SessionError(None, "a session runs once, after open_session; open a new one")
        learning = None
        if isinstance(self.controller, ControllerRuntime):  # per-cycle figures of a session's open-close cycles
            self.loop.meter = assembly.build_meter(self.cfg, self.controller, duration_s)
            learning = self._learning(self.controller)
        realtime = self.options.realtime if self.options.realtime is not None else not self.lockstep
        try:
            result = self.loop.run(duration_s, pacing=self.options.pacing, realtime=realtime,
                                   sample_timeout_s=self.options.sample_timeout_s or (
                                       LOCKSTEP_SAMPLE_TIMEOUT_S if self.lockstep else None),
                                   lockstep=self.lockstep)
        except BaseException as e:  # what was learned so far is kept
            if self.assistance is not None:
                self.assistance.finish(f"error: {type(e).__name__}")
            raise
        if self.assistance is not None:
            ended = f"{result.events[0].reason}: {result.stop_reason}" if result.events else result.stop_reason
            result.assistance = self.assistance.finish(ended)
        if learning is not None:
            if self.replan is not None:
                self.replan.close()
            learning.close()
            if result.events:  # a session that ended in a safety trip teaches the next one nothing
                learning.forget_session()
            result.learning = learning.summary()
            result.session_cycles = per_cycle_learning(result.session_cycles, learning.log,
                                                       self.controller.reference.period_s)
        result.step = self._step_figures()
        self.result = result
        self._finish(result)
        return result

    def _step_figures(self) -> dict[str, float]:
        """A step run's overshoot, rise and settling time over the recorded rows (``metrics.recorded_step``:
        the same function an analysis of run.csv calls); {} for a session's cycles."""
        ref = getattr(self.controller, "reference", None)
        if ref is None or ref.kind != "step" or self.loop is None:
            return {}
        return metrics.recorded_step(*self.loop.run_state.recorded_rows(), start=ref.start_deg)

    def _learning(self, runtime: ControllerRuntime) -> RigLearning | None:
        """The learning on the rig, when the controller plans a periodic table and it is on
        (``[controllers.model_based] rig_learning``, or the ``rig_learning`` option); its table
        kept per rig id, patient profile and plan (``TableStore``)."""
        spec = runtime.controller.rig_learning
        plan = runtime.controller.plan
        on = self.options.rig_learning
        if spec is None and on:
            raise SessionError("rig_learning", f"controller {runtime.name!r} has no periodic plan to learn on the rig")
        if on is None:
            on = spec is not None and spec.enabled
        if spec is None or plan is None or not on or runtime.reference.kind != "session":
            return None
        profile = load_profile(self.options.profile).patient_id if self.options.profile is not None else None
        rig = self.rig_id
        if self.options.sim_plant is not None:  # a simulated rig is its plant file: another file, another rig
            rig += "-sim-" + config_identity(self.options.sim_plant)["config_sha256"][:12]
        store = TableStore(self.options.learning_store or default_store_dir(), rig, profile, spec.plan_key)
        learning = RigLearning(spec, next(iter(plan.signals.values())), store, lockstep=self.lockstep)
        runtime.learn_on_rig(learning)
        self.stack.callback(learning.close)
        if self.options.thermal_replan and self.twin is not None and self.twin.twin.thermal is not None:
            self.replan = ThermalReplan(self.cfg, self.controller_name, runtime.reference, learning,
                                        str(self.config_path))
            self.twin.on_thermal_change = _chained(self.twin.on_thermal_change, self.replan.request)
            live = self.twin.live
            learning.catch_up = lambda: live.catch_up(LOCKSTEP_REPLAN_WAIT_S)
            self.stack.callback(self.replan.close)
        return learning

    def _kept_assistance(self) -> None:
        """An assist-as-needed controller's assistance starts where this patient's last session on
        this rig and config ended (``service/assist_store.py``); a store that cannot be used is one
        note (the CLI's warning line) and the config's start."""
        runtime = self.controller
        if not isinstance(runtime, ControllerRuntime) or runtime.reference.kind != "session":
            return
        directions = learned_directions(runtime.controller)
        if not directions:
            return
        opts = self.options
        patient = load_profile(opts.profile).patient_id if opts.profile is not None else (
            load_patient(opts.sim_patient).patient_id if opts.sim_patient is not None else None)
        rig = self.rig_id
        if opts.sim_plant is not None:  # a simulated rig is its plant file (as the rig learning's store)
            rig += "-sim-" + config_identity(opts.sim_plant)["config_sha256"][:12]
        gains = settings_for(self.cfg, runtime.name, str(self.config_path))
        key = {"plant": self.cfg.plant, "controller": runtime.name, "directions": sorted(directions),
               "feedback": {k: getattr(gains, k) for k in ("kp_per_deg", "ki_per_deg_s", "kd_s_per_deg")}}
        store = AssistanceStore(opts.assistance_store or default_assistance_dir(), rig, patient,
                                self.config_path.stem, key)
        self.assistance = KeptAssistance(store, runtime, directions, opts.fresh_assistance)
        if self.assistance.problem:
            runtime.notes.append(self.assistance.problem)

    # ---- building, in the order things must happen ------------------------------------------------
    def _open(self) -> None:
        """Before anything moves: the contract check, the homing; then the run directory, the sinks
        and the loop."""
        try:
            on_configure(self.binding, self.hw.info, self.controller.claims)
        except HardwareError as e:
            raise SessionError("device", f"{self.device}: {e}") from None
        self._home()
        self._kept_assistance()
        if self.options.record is not None:
            self._recording()
        opts = self.options
        if opts.telemetry is not None:
            self.telemetry = zenoh_telemetry(opts.telemetry, self.cfg.plant, self.config_path, self.binding,
                                             self.period_s, self.hw.info)
            self.stack.callback(self.telemetry.close)
        if opts.foxglove is not None:
            self.foxglove = foxglove_view(opts.foxglove, self.binding)
            self.stack.callback(self.foxglove.close)
        if opts.twin or (self.cfg.twin is not None and self.cfg.twin.enabled):
            outputs = [x for x in (self.recorder, self.foxglove and self.foxglove.sink) if x is not None]
            self.twin = live_twin(self.cfg, self.binding, self.run_dir, outputs, self.telemetry and self.telemetry.sink,
                                  getattr(self.controller, "reference", None), self.lockstep, str(self.config_path))
            self.stack.callback(self.twin.live.close)  # the twin's thread, if the session never ran (idempotent)
        self._loop()

    def _home(self) -> None:
        """The encoder's zero at a confirmed pose or the closed hard stop (``service.homing``)."""
        mode = self.options.home
        if mode not in HOMING_MODES:
            raise SessionError("home", f"must be one of {list(HOMING_MODES)}, got {mode!r}")
        try:
            self.homed = home(mode, self.hw, self.cfg, self.binding, self.configure, confirm=self.options.confirm)
        except HardwareError as e:
            raise SessionError("home", f"{mode}: {e}") from None

    def _recording(self) -> None:
        """A new run directory, its metadata (written first: a killed run still says what it ran
        against) and the recorder."""
        opts = self.options
        try:
            self.run_dir = new_run_dir(opts.record, self.rig_id)
        except OSError as e:
            raise SessionError("record", f"{opts.record}: cannot make the run folder: {e}") from None
        self.metadata = session_metadata(
            plant=self.cfg.plant, config_path=self.config_path, device=self.device, rig_id=self.rig_id,
            binding=self.binding, hello=self.hw.info, controller=self.controller_name, pacing=opts.pacing,
            sim_plant=opts.sim_plant, calibration={"force": calibration_summary(self.cfg, self.binding)},
            reference=reference_metadata(getattr(self.controller, "reference", None)))
        if opts.sim_patient is not None:
            self.metadata["sim_patient"] = {**config_identity(opts.sim_patient), "truth": TRUTH_FILE}
        if self.truth is not None:
            self.truth.run_dir = self.run_dir
        write_metadata(self.run_dir, self.metadata)
        self.recorder = Recorder(self.run_dir, self.binding, metadata=self.metadata)
        self.stack.callback(self.recorder.close)

    def _loop(self) -> None:
        """The loop on the rig, with the sinks after its write."""
        supervisor = self.options.supervisor or assembly.build_supervisor(self.cfg, self.binding)
        views = [v for v in (self.telemetry, self.foxglove) if v is not None]
        sinks = [self.recorder, *(v.sink for v in views), self.twin.live if self.twin is not None else None]
        self.loop = loop = LoopService(
            self.hw, self.configure, self.controller, assembly.build_estimator(self.cfg, self.binding), supervisor,
            self.period_s, sinks=[*(x for x in sinks if x is not None), *self.options.sinks])
        if self.twin is not None:
            self.twin.on_stop = lambda text: loop.request_stop(text, "model_mismatch")
        for view in views:
            view.watch(loop, self.hw)

    def _finish(self, result: RunResult) -> None:
        """The twin's summary and the recording's end: every queued row counted, metadata completed."""
        twin_meta = self.twin.close() if self.twin is not None else {}
        self._model_torques(result)
        if twin_meta:
            result.twin = twin_meta
            if self.twin.twin.csv_path is not None:
                result.files.append(str(self.twin.twin.csv_path))
        if self.recorder is not None and self.run_dir is not None:
            self.recorder.drain()  # rows still queued when the loop stopped (Ctrl-C on a busy machine) are counted
            end = {**result_metadata(result, self.recorder.rows), **twin_meta}
            try:  # a full disk: what was written stays readable (read_mcap reads a file without its footer)
                self.recorder.close(summary=end)
                write_metadata(self.run_dir, {**self.metadata, **end})
                result.files.append(str(self.run_dir / METADATA_FILE))
            except OSError as e:
                _recorder_error(result, f"the recording's end not written: {type(e).__name__}: {e}")

    def _model_torques(self, result: RunResult) -> None:
        """The twin's estimate of the patient's torque per move (``twin/patient_torque.py``) into each
        cycle's figures and, averaged, the session's."""
        est = self.twin.twin.patient_torque if self.twin is not None else None
        ref = getattr(self.controller, "reference", None)
        if est is None or ref is None or ref.kind != "session" or not result.session_cycles:
            return
        from rehab_hil.twin.patient_torque import move_torques  # the twin's modules load with the twin only

        direction = 1.0 if ref.open_deg >= ref.closed_deg else -1.0
        result.session_cycles = move_torques(est, result.session_cycles, ref.period_s, ref.move_s, direction)
        for key in ("patient_torque_open_model_nm", "patient_torque_close_model_nm"):
            v = [c[key] for c in result.session_cycles if math.isfinite(c[key])]
            if v:
                result.session[key] = sum(v) / len(v)


def per_cycle_learning(cycles: list[dict[str, float]], log: list[dict[str, Any]],
                       period_s: float) -> list[dict[str, Any]]:
    """Each cycle's figures with what the learning did: ``learn_trial``, the table in force when
    the cycle started (0: the model's, or the stored one's count), and the update made from it
    (swapped in during its closed hold: the share kept, the change, the predicted peak)."""
    out = []
    for c in cycles:
        start = c["start_s"]
        before = [e for e in log if e["t_s"] <= start]
        row: dict[str, Any] = {**c, "learn_trial": before[-1]["trial"] if before else (log[0]["trial"] - 1 if log
                                                                                         else 0.0)}
        for made in (e for e in log if start < e["t_s"] <= start + period_s):  # an update, a re-plan
            row.update({k: v for k, v in made.items() if k.startswith("learn_") and k != "learn_error_rmse_deg"})
        out.append(row)
    return out


def _chained(first: Callable[[dict[str, float]], Any] | None, then: Callable[[dict[str, float]], str]
             ) -> Callable[[dict[str, float]], str]:
    """A thermal-change hook that calls a user's own hook (set before ``run``) and then the re-plan."""
    if first is None:
        return then

    def hook(updates: dict[str, float]) -> str:
        first(updates)
        return then(updates)
    return hook


def _recorder_error(result: RunResult, text: str) -> None:
    """Add ``text`` to the recorder's line in ``result.sinks`` (the summary shows it)."""
    report = result.sinks.setdefault("recorder", {"dropped": 0, "error": None})
    report["error"] = f"{report['error']}; {text}" if report.get("error") else text


def open_session(config: str | Path, device: str | None = None, **options: Any) -> RigSession:
    """Build a session on ``device`` ("sim", "avr", "inprocess", a serial path or "auto"; default
    ``[rig].port``) for the plant config at ``config``; ``options``: the fields of ``SessionOptions``.
    Raises ``SessionError`` (one line) for what the user can fix."""
    try:
        opts = SessionOptions(**options)
    except TypeError as e:
        known = ", ".join(f.name for f in fields(SessionOptions))
        raise SessionError(None, f"{e}; the options are: {known}") from None
    config = shipped.resolve(config)  # "configs/NAME.toml" from any folder once the package is installed
    cfg = _load(config, opts.profile)
    if opts.pacing not in PACINGS:
        raise SessionError("pacing", f"must be one of {list(PACINGS)}, got {opts.pacing!r}")
    binding = get_plant(cfg.plant).device(cfg)
    controller = _controller(cfg, config, opts)
    device = device or cfg.rig.port
    configure = opts.configure or assembly.firmware_configure(cfg, binding)
    stack = ExitStack()
    try:
        truth = _sim_truth(stack, config, device, opts)  # its callback first: it runs after the rig has closed
        hw = opts.hw if opts.hw is not None else _rig(stack, cfg, config, device, opts, truth)
        session = RigSession(stack, cfg, config, device, opts, hw, controller, configure)
        session.truth = truth
        session._open()
    except BaseException:
        stack.close()
        raise
    return session


def _load(config: Path, profile: Path | None) -> Any:
    """The validated config, with the patient's profile over the rig's session and limits (tighten only)."""
    cfg = load_config(config)
    if profile is not None:
        cfg = apply_profile(cfg, load_profile(profile), config, profile)
    return cfg


def _controller(cfg: Any, config: Path, opts: SessionOptions) -> Any:
    """The controller the loop steps: a declared one built by name for this plant, or the object given."""
    if opts.controller is not None and not isinstance(opts.controller, str):
        return opts.controller
    try:
        return assembly.build_controller(cfg, opts.controller, opts.reference, source=str(config),
                                         sources=_sources(config, opts.profile))
    except assembly.ServiceSetupError as e:
        raise SessionError(None, f"{config}: {e}") from None


def _sources(config: Path, profile: Path | None) -> Sources:
    """Where the session's settings come from: the config, and the keys the profile overrides."""
    if profile is None:
        return Sources(str(config))
    return Sources(str(config), str(profile), profile_rig_keys(load_profile(profile)))


def _rig(stack: ExitStack, cfg: Any, config: Path, device: str, opts: SessionOptions,
         truth: SimTruth | None = None) -> HardwareInterface:
    """Open and connect the rig (its process, for a simulated one, stops with the stack)."""
    device_config = _device_config(cfg, config, device, opts.sim_plant)
    try:
        return stack.enter_context(open_rig(device, device_config, lockstep=opts.lockstep, baud=cfg.rig.baud,
                                            write_timeout_s=cfg.rig.write_timeout_ms / 1000.0,
                                            sim_patient=opts.sim_patient, sim_truth=truth and truth.path))
    except HardwareError as e:
        raise SessionError("device", f"{device}: {e}") from None


def _sim_truth(stack: ExitStack, config: Path, device: str, opts: SessionOptions) -> SimTruth | None:
    """Where a simulated patient's device writes ``sim_truth.csv`` (None: no patient); refuses a
    patient on a real board and a patient file that does not validate, in one line."""
    if opts.sim_patient is None:
        return None
    if device not in RIG_KINDS or opts.hw is not None:
        raise SessionError("sim_patient", f"for simulated devices ({', '.join(RIG_KINDS)}); device {device} is a "
                           "real board, whose patient is a person")
    try:
        load_patient(opts.sim_patient)
    except (ConfigError, OSError) as e:
        raise SessionError("sim_patient", str(e)) from None
    truth = SimTruth()
    stack.callback(truth.finish)
    return truth


def _device_config(cfg: Any, config: Path, device: str, sim_plant: Path | None) -> Path:
    """The plant config a simulated device runs: ``sim_plant`` (the same plant, maybe with effects
    the host's model lacks) or the host's own."""
    if sim_plant is None:
        return config
    if device not in RIG_KINDS:
        raise SessionError("sim_plant", f"for simulated devices ({', '.join(RIG_KINDS)}); device {device} is a "
                           "real board, whose plant is the physical one")
    dev = load_config(sim_plant)
    if dev.plant != cfg.plant:
        raise SessionError("sim_plant", f"{sim_plant}: a {dev.plant!r} plant; the host's config {config} is a "
                           f"{cfg.plant!r} plant")
    return sim_plant
