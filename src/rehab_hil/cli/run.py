"""``rehab-hil run``: a session on a rig (simulated or real) with a live display and a summary.

``--device sim`` spawns the Python simulated device, ``avr`` the firmware in simavr, ``inprocess``
runs the device logic and the plant in this process (lockstep), anything else is a serial path
(``rehab_hil.hardware.open_rig``). The device's HELLO and the controller's claims are checked
against the plant's binding before anything moves. Ctrl-C and SIGTERM trip the supervisor: PWM 0
and ESTOP before the exit.
"""

from __future__ import annotations

import argparse
import signal
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from rehab_hil.calibration import calibration_summary
from rehab_hil.cli import UserError, writable_folder
from rehab_hil.hardware import RIG_KINDS, HardwareError, HardwareInterface, on_configure, open_rig
from rehab_hil.plants import get_plant, load_config
from rehab_hil.service import assembly
from rehab_hil.service.recorder import Recorder
from rehab_hil.service.run_dir import METADATA_FILE, new_run_dir, result_metadata, session_metadata, write_metadata
from rehab_hil.service.runner import LoopService, Progress, RunResult

# virtual time: a sample that takes this long in wall time is missing (a starved machine pauses a
# lockstep device without losing anything; link loss there is link_loss_periods such waits in a row)
LOCKSTEP_SAMPLE_TIMEOUT_S = 5.0


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("run", help="run a session on the rig (sim, avr, inprocess or a serial port) and summarise it")
    p.add_argument("--config", required=True, type=Path, help="plant config (configs/*.toml)")
    p.add_argument("--profile", type=Path, default=None, help="per-patient profile (profiles/*.toml): session "
                   "and tighter limits (rehab_hil.profiles)")
    p.add_argument("--device", default=None,
                   help=f"{', '.join(repr(k) for k in RIG_KINDS)} or a serial path (default: [rig].port)")
    p.add_argument("--duration", type=float, default=30.0, help="session length [s]")
    p.add_argument("--record", type=Path, default=None, metavar="DIR",
                   help="record the session: each run writes a new DIR/<UTC time>-<rig id>/ with run.csv, "
                        "run.mcap and metadata.json (never overwriting an earlier run)")
    p.add_argument("--rig-id", default=None,
                   help="the rig's name in run directories and metadata (default: --telemetry RIG, else the plant)")
    p.add_argument("--sim-plant", type=Path, default=None, metavar="DEVICE.toml",
                   help="simulated devices: the plant config the device runs (default: --config), e.g. one with "
                        "[[effects]] the host's model lacks")
    p.add_argument("--controller", default=None, metavar="NAME",
                   help="the controller (rehab_hil.controllers: model_based, pid, open_loop_map, pulsed; settings in "
                        "[controllers.NAME]); default: [rig.session] controller")
    p.add_argument("--reference", choices=assembly.REFERENCES, default="session",
                   help="what it tracks: the session's open-close cycles, or a step to [rig.session] step_deg")
    p.add_argument("--pacing", choices=("device", "host"), default="device",
                   help="react to the sample stream, or wake on host deadlines (docs/loop.md)")
    p.add_argument("--lockstep", action="store_true",
                   help="sim or avr device: virtual time, one sample period per command (deterministic)")
    p.add_argument("--twin", action="store_true",
                   help="run the plant model beside the rig: predictions, residuals, model-mismatch events and the "
                        "patient's interaction estimate (docs/twin.md; [twin] in the config)")
    p.add_argument("--no-display", action="store_true", help="no live display (logs and CI)")
    p.add_argument("--telemetry", metavar="RIG", default=None,
                   help="publish telemetry over zenoh as rig RIG on loopback (docs/telemetry.md)")
    p.add_argument("--telemetry-port", type=int, default=7447, help="loopback zenoh hub port (default 7447)")
    p.add_argument("--telemetry-connect", action="append", default=None, metavar="ENDPOINT",
                   help="publish as a client of the lab's zenoh router, e.g. tcp/10.0.0.2:7447 (repeatable)")
    p.add_argument("--telemetry-user", default=None,
                   help="zenoh user for the lab router (password from REHAB_ZENOH_PASSWORD)")
    p.add_argument("--foxglove", metavar="PORT", type=int, nargs="?", const=8765, default=None,
                   help="serve the session live to Foxglove over its WebSocket protocol (default port 8765)")
    p.add_argument("--foxglove-host", default="127.0.0.1", help="address the Foxglove server binds (default 127.0.0.1)")
    p.add_argument("--home", choices=("current", "hard-stop", "none"), default="current",
                   help="encoder zero at start: 'current' gives the present pose [encoder] home_angle_deg (asks "
                        "first on a terminal), 'hard-stop' drives slowly to the closed stop ([encoder] hard_stop_deg, "
                        "homing_duty; a motor behind an H-bridge), 'none' keeps the device's count")
    return p


def _telemetry(args: argparse.Namespace, cfg: Any, binding: Any, hw: HardwareInterface) -> Any:
    """The zenoh publisher for ``--telemetry RIG`` (rehab_hil.telemetry.rig)."""
    from rehab_hil.telemetry import RigIdError, TelemetryConfigError
    from rehab_hil.telemetry.rig import RigTelemetry, rig_info

    info = rig_info(cfg.plant, args.config, binding, assembly.period_s(cfg), hw.info)
    try:
        return RigTelemetry(args.telemetry, info, _telemetry_network(args), queue_size=20_000)
    except (RigIdError, TelemetryConfigError, ValueError) as e:
        raise UserError(f"--telemetry: {e}") from None


def _telemetry_network(args: argparse.Namespace) -> Any:
    """Loopback hub on --telemetry-port, or a client of the lab router(s) given by --telemetry-connect."""
    import os

    from rehab_hil.telemetry import NetworkConfig, TelemetryConfigError
    from rehab_hil.telemetry.cliargs import PASSWORD_ENV

    if not args.telemetry_connect:
        return NetworkConfig(port=args.telemetry_port)
    password = os.environ.get(PASSWORD_ENV) if args.telemetry_user else None
    if args.telemetry_user and password is None:
        raise TelemetryConfigError(f"--telemetry-user needs the {PASSWORD_ENV} environment variable")
    return NetworkConfig(mode="lab", router=tuple(args.telemetry_connect), user=args.telemetry_user, password=password)


def _foxglove(args: argparse.Namespace, binding: Any, telemetry: Any) -> Any:
    """The Foxglove live view for ``--foxglove [PORT]``, tee'd with ``telemetry`` (rehab_hil.telemetry.foxglove)."""
    from rehab_hil.telemetry.foxglove import FoxgloveError, FoxgloveLive, LiveView

    try:
        live = FoxgloveLive(args.foxglove_host, args.foxglove)
    except FoxgloveError as e:
        raise UserError(f"--foxglove: {e}") from None
    print(f"Foxglove live view: {live.url} (layout: docs/foxglove_layout.json)")
    return LiveView(live, live.add_rig(binding), telemetry)


def _twin(args: argparse.Namespace, cfg: Any, binding: Any, run_dir: Path | None, recorder: Any,
          telemetry: Any, cycle_s: float | None, lockstep: bool) -> Any:
    """The live twin for ``--twin`` or ``[twin] enabled`` (rehab_hil.twin), refused in one line."""
    if not (args.twin or (cfg.twin is not None and cfg.twin.enabled)):
        return None
    from rehab_hil.twin.model import TwinSetupError
    from rehab_hil.twin.session import start_twin

    try:
        return start_twin(cfg, binding, assembly.period_s(cfg), run_dir, recorder, telemetry, cycle_s, lockstep)
    except TwinSetupError as e:
        raise UserError(f"{args.config}: [twin] {e}") from None


def _progress_table(p: Progress) -> Table:
    t = Table(show_header=False, box=None)
    t.add_row("time", f"{p.t_s:7.2f} / {p.duration_s:.1f} s")
    t.add_row("angle / reference", f"{p.angle_deg:7.2f} / {p.reference_deg:7.2f} deg")
    t.add_row("duty", f"{p.duty:5.3f}")
    t.add_row("est. temperature", f"{p.temperature_c:6.1f} C")
    t.add_row("samples (gaps)", f"{p.samples} ({p.sample_gaps})")
    if p.tripped:
        t.add_row("[red]SAFE STATE", p.tripped)
    return t


def summary_table(r: RunResult) -> Table:
    """The final summary: tracking, loop timing, link and safety."""
    t = Table(title=f"rehab-hil run: {r.stop_reason}", show_header=False)
    t.add_row("pacing / scheduler", f"{r.pacing} / {r.realtime.scheduler if r.realtime else 'not real-time'}")
    t.add_row("cycles / samples / gaps / reboots", f"{r.cycles} / {r.samples} / {r.sample_gaps} / {r.reboots}")
    for k, v in r.tracking.items():
        t.add_row(f"tracking {k}", f"{v:.4g}" + (" deg" if k in ("mae", "rmse", "max_abs_error") else ""))
    s = r.session
    if s.get("cycles"):
        t.add_row("open-close cycles", f"{s['cycles']:.0f} complete")
        t.add_row("per cycle: RMSE / max error", f"{s['rmse_deg']:.3g} / {s['max_error_deg']:.3g} deg")
        t.add_row("per cycle: range of motion", f"{s['rom_deg']:.3g} deg")
        t.add_row("per cycle: time to open / closed", f"{s['time_to_open_s']:.3g} / {s['time_to_closed_s']:.3g} s")
        t.add_row("peak est. temperature / energy per cycle",
                  f"{s['peak_temperature_c']:.4g} C / {s['energy_per_cycle_j']:.4g} J")
    tm = r.timing
    label = "lateness" if r.pacing == "host" else "reaction (sample in -> command out)"
    t.add_row(f"{label} p50/p99/p99.9/max",
              " / ".join(f"{tm.get(f'lateness_{q}_us', float('nan')):.1f}" for q in ("p50", "p99", "p99_9", "max"))
              + " us")
    t.add_row("missed cycles", f"{tm.get('missed_cycles', 0):.0f} ({tm.get('missed_pct', 0):.3f} %)")
    if tm.get("wall_s"):
        t.add_row("device time / host time", f"{tm['device_s']:.2f} / {tm['wall_s']:.2f} s "
                  f"({tm['speed_x']:.2f}x real time)")
    ln = r.link
    t.add_row("link frames rx / tx", f"{ln['frames_rx']} / {ln['frames_tx']}")
    t.add_row("link bad frames host / device", f"{sum(ln['bad_frames'].values())} {dict(ln['bad_frames'])} / "
              f"{ln['device_rx_bad_frames']}")
    t.add_row("link dropped samples", str(ln["dropped_samples"]))
    t.add_row("command->echo latency p50/p99",
              f"{1e6 * ln['latency_p50_s']:.0f} / {1e6 * ln['latency_p99_s']:.0f} us")
    t.add_row("recorder / telemetry / twin drops", f"{r.recorder_dropped} / {r.telemetry_dropped} / {r.twin_dropped}")
    for ev in r.events:
        t.add_row(f"[red]safety {ev.reason}", f"t={ev.t_s:.3f} s {ev.detail}")
    if not r.events:
        t.add_row("safety events", "none")
    t.add_row("device PWM off at end", "yes" if r.pwm_off_at_end else "[red]NO")
    _twin_rows(t, r.twin)
    return t


def _twin_rows(t: Table, meta: dict[str, Any]) -> None:
    """The live twin's lines: its normal residual, the model events and the patient's estimate."""
    from rehab_hil.twin.live import normal_residual_text

    if not meta:
        return
    tw = meta["twin"]
    normal = normal_residual_text(tw.get("normal_residual", {}))
    t.add_row("twin: normal residual / CPU per sample", f"{normal} / {tw.get('cpu_per_sample_us', 0):.1f} us")
    if tw.get("error"):
        t.add_row("[red]twin stopped", tw["error"])
    for ev in meta.get("model_events", []):
        t.add_row(f"[yellow]model_mismatch {ev['channel']}",
                  f"t={ev['t_s']:.2f} s (seen {ev['detected_s']:.2f} s), {ev['size_counts']:.1f} counts; "
                  f"{ev['cause'] or 'no cause named'}")
    if not meta.get("model_events"):
        t.add_row("model events", "none")
    for name, est in meta.get("patient", {}).get("session", {}).items():
        since = f"; fitted from {est['since_s']:.2f} s, after a change" if est.get("since_s") else ""
        if est["ci95"] > 0.5 * abs(est["value"]):
            since += "; not determined by this session"
        t.add_row(f"patient {name.split('.')[-1]}", f"{est['value']:.4g} +/- {est['ci95']:.2g} "
                  f"(config {est['nominal']:.4g}; at the end {est['final']:.4g}{since})")


def recorded_line(r: RunResult) -> str | None:
    """The run directory once, in full, and the files in it (outside the table: never cut short)."""
    if not r.files:
        return None
    folder = Path(r.files[0]).resolve().parent
    return f"recorded: {folder}/ ({', '.join(Path(f).name for f in r.files)})"


def _device_config(args: argparse.Namespace, cfg: Any, device: str) -> Path:
    """The plant config the simulated device runs: ``--sim-plant`` (same plant, maybe other effects)
    or the host's own."""
    if args.sim_plant is None:
        return args.config
    if device not in RIG_KINDS:
        raise UserError(f"--sim-plant is for simulated devices ({', '.join(RIG_KINDS)}); --device {device} is a "
                        "real board, whose plant is the physical one")
    dev = load_config(args.sim_plant)
    if dev.plant != cfg.plant:
        raise UserError(f"--sim-plant {args.sim_plant}: a {dev.plant!r} plant; the host's config "
                        f"{args.config} is a {cfg.plant!r} plant")
    return args.sim_plant


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    if args.profile is not None:  # the patient's session and limits over the rig's (tighten only)
        from rehab_hil.profiles import apply_profile, load_profile

        cfg = apply_profile(cfg, load_profile(args.profile), args.config, args.profile)
    if not 0 < args.duration <= 24 * 3600:
        raise UserError(f"--duration must be in (0, 86400] s, got {args.duration}")
    binding = get_plant(cfg.plant).device(cfg)
    try:
        controller = assembly.build_controller(cfg, args.controller, args.reference, source=str(args.config))
    except assembly.ServiceSetupError as e:
        raise UserError(f"{args.config}: {e}") from None
    for note in controller.controller.notes:
        print(f"warning: {note}")
    device = args.device or cfg.rig.port
    device_config = _device_config(args, cfg, device)
    if args.record:
        writable_folder(args.record, "--record", "each run makes a new folder inside it")
    console = Console()
    lockstep = args.lockstep or device == "inprocess"  # the in-process device is lockstep by nature
    with ExitStack() as stack:
        try:
            hw = stack.enter_context(open_rig(device, device_config, lockstep=args.lockstep, baud=cfg.rig.baud,
                                                write_timeout_s=cfg.rig.write_timeout_ms / 1000.0))
            on_configure(binding, hw.info, controller.claims)  # refuse a mismatch before anything moves
        except HardwareError as e:
            raise UserError(f"--device {device}: {e}") from None
        # homing (issue 15): the encoder's zero at a confirmed pose or the closed hard stop
        import sys

        from rehab_hil.service.homing import home

        try:
            homed = home(args.home, hw, cfg, binding, assembly.firmware_configure(cfg, binding),
                         confirm=(lambda text: input(f"{text} ")) if sys.stdin.isatty() else None)
        except HardwareError as e:
            raise UserError(f"--home {args.home}: {e}") from None
        if homed is not None:
            print(f"homed ({homed.mode}): encoder count {homed.count} at the home pose")
        recorder = None
        if args.record:
            rig_id = args.rig_id or args.telemetry or cfg.plant
            try:
                run_dir = new_run_dir(args.record, rig_id)
            except OSError as e:
                raise UserError(f"--record {args.record}: cannot make the run folder: {e}") from None
            meta = session_metadata(plant=cfg.plant, config_path=args.config, device=device, rig_id=rig_id,
                                    binding=binding, hello=hw.info, controller=controller.controller.name,
                                    pacing=args.pacing, sim_plant=args.sim_plant,
                                    calibration={"force": calibration_summary(cfg)})
            write_metadata(run_dir, meta)  # first now: a killed run still says what it ran against
            recorder = Recorder(run_dir, binding, metadata=meta)
            stack.callback(recorder.close)
        telemetry = _telemetry(args, cfg, binding, hw) if args.telemetry else None
        if telemetry is not None:
            stack.callback(telemetry.close)
        if args.foxglove is not None:  # the Foxglove live view, tee'd with zenoh telemetry when that is on
            telemetry = _foxglove(args, binding, telemetry)
            stack.callback(telemetry.close)
        ref = controller.controller.reference
        twin = _twin(args, cfg, binding, run_dir if recorder is not None else None, recorder, telemetry,
                     ref.period_s if ref.kind == "session" else None, lockstep)
        svc = LoopService(hw, assembly.firmware_configure(cfg, binding), controller,
                          assembly.build_estimator(cfg, binding), assembly.build_supervisor(cfg, binding),
                          assembly.period_s(cfg), recorder=recorder, telemetry=telemetry and telemetry.sink,
                          meter=assembly.build_meter(cfg, controller, args.duration),
                          twin=twin.live if twin is not None else None)
        if twin is not None:
            twin.on_stop = lambda text: svc.request_stop(text, "model_mismatch")
        if telemetry is not None:
            telemetry.watch(svc, hw)
        previous = {s: signal.signal(s, lambda n, f: svc.request_stop(signal.Signals(n).name))
                    for s in (signal.SIGINT, signal.SIGTERM)}
        stack.callback(lambda: [signal.signal(s, h) for s, h in previous.items()])
        result: list[RunResult] = []
        errors: list[BaseException] = []

        def work() -> None:
            try:
                result.append(svc.run(args.duration, pacing=args.pacing, realtime=not lockstep,
                                      sample_timeout_s=LOCKSTEP_SAMPLE_TIMEOUT_S if lockstep else None,
                                      lockstep=lockstep,
                                      on_trip=telemetry.on_trip if telemetry else None))
            except BaseException as e:  # reported on the main thread
                errors.append(e)

        # the loop runs on its own thread so the main thread stays free for signals and the display
        th = threading.Thread(target=work, name="loop")
        th.start()
        if args.no_display:
            while th.is_alive():
                th.join(0.1)
        else:
            with Live(_progress_table(svc.progress), console=console, refresh_per_second=4) as live:
                while th.is_alive():
                    th.join(0.25)
                    live.update(_progress_table(svc.progress))
        if errors:
            if isinstance(errors[0], HardwareError):
                raise UserError(f"device: {errors[0]}")
            raise errors[0]
        twin_meta = twin.close() if twin is not None else {}
        if twin_meta:
            result[0].twin = twin_meta
            if twin.twin.csv_path is not None:
                result[0].files.append(str(twin.twin.csv_path))
        if recorder is not None:
            recorder.drain()  # rows still queued when the loop stopped (Ctrl-C on a busy machine) are counted
            end = {**result_metadata(result[0], recorder.rows), **twin_meta}
            recorder.close(summary=end)
            write_metadata(run_dir, {**meta, **end})
            result[0].files.append(str(run_dir / METADATA_FILE))
    time.sleep(0)
    console.print(summary_table(result[0]))
    if (line := recorded_line(result[0])) is not None:
        print(line)
    return 1 if result[0].events and result[0].events[0].reason != "stop_request" else 0
