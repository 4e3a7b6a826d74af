"""``rehab-hil run``: a session on a rig (simulated or real) with a live display and a summary.

``--device sim`` spawns the Python simulated device, ``avr`` the firmware in simavr, ``inprocess``
runs the device logic and the plant in this process (lockstep), anything else is a serial path
(``rehab_hil.hardware.open_rig``). The device's HELLO and the controller's claims are checked
against the plant's binding before anything moves. Ctrl-C and SIGTERM trip the supervisor: PWM 0
and ESTOP before the exit.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from rehab_hil import launch, shipped
from rehab_hil.cli import UserError, config_file, device_arg, writable_folder
from rehab_hil.hardware import RIG_KINDS, HardwareError
from rehab_hil.loop.figures import Progress
from rehab_hil.loop.result import RunResult
from rehab_hil.service import assembly
from rehab_hil.service.errors import SessionError
from rehab_hil.service.session import FoxgloveOptions, RigSession, TelemetryOptions, open_session


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("run", help="run a session on the rig (sim, avr, inprocess or a serial port) and summarise it")
    p.add_argument("--config", required=True, type=config_file, help="plant config (configs/*.toml)")
    p.add_argument("--profile", type=config_file, default=None, help="per-patient profile (profiles/*.toml): session "
                   "and tighter limits (rehab_hil.profiles)")
    p.add_argument("--device", default=None, type=device_arg,
                   help=f"{', '.join(repr(k) for k in RIG_KINDS)} or a serial path (default: [rig].port)")
    p.add_argument("--duration", type=float, default=30.0, help="session length [s]")
    p.add_argument("--record", type=Path, default=None, metavar="DIR",
                   help="record the session: each run writes a new DIR/<UTC time>-<rig id>/ with run.csv, "
                        "run.mcap and metadata.json (never overwriting an earlier run)")
    p.add_argument("--rig-id", default=None,
                   help="the rig's name in run directories and metadata (default: --telemetry RIG, else the plant)")
    p.add_argument("--sim-patient", type=Path, default=None, metavar="PATIENT.toml",
                   help="simulated devices only: a simulated patient on the device's plant (profiles/sim/*.toml); "
                        "the host's model does not know it; the device writes sim_truth.csv beside the recording")
    p.add_argument("--sim-plant", type=config_file, default=None, metavar="DEVICE.toml",
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
    p.add_argument("--rig-learning", action=argparse.BooleanOptionalAction, default=None,
                   help="keep learning the feedforward on the rig, cycle after cycle, from the measured error "
                        "(default: [controllers.model_based] rig_learning; docs/controllers.md). The table is kept "
                        "per rig id and profile under ~/.cache/rehab-hil/rig_learning; delete its file (the summary "
                        "names it) to start again from the model")
    p.add_argument("--assistance-store", type=Path, default=None, metavar="DIR",
                   help="assist_as_needed: keep each patient's learned assistance per rig and config in DIR, "
                        "loaded at the start and saved at the end (default: REHAB_HIL_ASSISTANCE_DIR, else "
                        "~/.local/share/rehab-hil/assistance; docs/patient.md)")
    p.add_argument("--fresh-assistance", action="store_true",
                   help="assist_as_needed: start from the config's initial assistance, not the patient's stored one "
                        "(the end is still saved)")
    p.add_argument("--thermal-replan", action=argparse.BooleanOptionalAction, default=True,
                   help="with --twin and the learning on the rig: re-plan the feedforward on the twin's estimate of "
                        "the room, draft and supply when one leaves its interval (default: on; docs/twin.md)")
    p.add_argument("--twin", action="store_true",
                   help="run the plant model beside the rig: predictions, residuals, model-mismatch events, the "
                        "patient's interaction estimate and the patient's torque per move (docs/twin.md; [twin] in "
                        "the config)")
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
    if r.realtime is not None and r.realtime.process:
        t.add_row("loop runs in", r.realtime.process)
    if r.realtime is not None and r.realtime.tty_workers:
        t.add_row("kernel tty workers", r.realtime.tty_workers)
    t.add_row("ran", f"{r.ran_s:.2f} s of {r.duration_s:g} s asked")
    t.add_row("cycles / samples / gaps / reboots", f"{r.cycles} / {r.samples} / {r.sample_gaps} / {r.reboots}")
    for k, v in r.tracking.items():
        t.add_row(f"tracking {k}", f"{v:.4g}" + (" deg" if k in ("mae", "rmse", "max_abs_error") else ""))
    if r.step:
        st = r.step
        t.add_row(f"step {st['start']:g} -> {st['target']:g} deg: overshoot",
                  f"{st['overshoot']:.3g} deg ({st['overshoot_pct']:.3g} %)")
        t.add_row("step: rise (10-90 %) / settling (2 %)", f"{st['rise_time_s']:.3g} / {st['settling_time_s']:.3g} s")
    s = r.session
    if s.get("cycles"):
        t.add_row("open-close cycles", f"{s['cycles']:.0f} complete")
        t.add_row("per cycle: RMSE / max error", f"{s['rmse_deg']:.3g} / {s['max_error_deg']:.3g} deg")
        t.add_row("per cycle: range of motion", f"{s['rom_deg']:.3g} deg")
        t.add_row("per cycle: time to open / closed", f"{s['time_to_open_s']:.3g} / {s['time_to_closed_s']:.3g} s")
        t.add_row("peak est. temperature / energy per cycle",
                  f"{s['peak_temperature_c']:.4g} C / {s['energy_per_cycle_j']:.4g} J")
        _therapy_rows(t, r)
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
    for name, sink in r.sinks.items():  # each sink by name: its drops, and the error it stopped with
        t.add_row(f"{name} drops", str(sink["dropped"]))
        if sink["error"]:
            t.add_row(f"[red]{name} failed", sink["error"])
    for ev in r.events:
        t.add_row(f"[red]safety {ev.reason}", f"t={ev.t_s:.3f} s {ev.detail}")
        if ev.cause:
            t.add_row("  cause", ev.cause)
    if not r.events:
        t.add_row("safety events", "none")
    _stall_rows(t, r.stalls)
    off = r.pwm_off_at_end
    t.add_row("device PWM off at end", "yes" if off else (f"[yellow]{r.pwm_unconfirmed}" if off is None else "[red]NO"))
    for feature in r.features.values():  # each feature's own lines (the twin, the learning, the safety's temperature)
        for label, text in feature.lines:
            t.add_row(label, text)
    return t


def _stall_rows(t: Table, stalls: dict[str, Any]) -> None:
    """A simulated device's stalls of its own process: reported, never a fault (a real MCU is never
    descheduled; devices/stall.py)."""
    silences = stalls.get("device_silences_not_scheduled", [])
    rep = stalls.get("device_reported", {})
    if rep.get("not_scheduled"):
        t.add_row("simulated device not scheduled", f"{rep['not_scheduled']:.0f} times, longest "
                  f"{rep['not_scheduled_max_ms']:.1f} ms, {rep['not_scheduled_total_ms']:.0f} ms in all "
                  "(its own count; not a fault: a real MCU is never descheduled)")
    if silences:
        longest = max(silences, key=lambda x: x["silent_s"])
        t.add_row("link silent while the device could not run", f"{len(silences)} times, longest "
                  f"{longest['silent_s'] * 1e3:.1f} ms at t={longest['t_s']:.3f} s (not a link loss)")


def _therapy_rows(t: Table, r: RunResult) -> None:
    """What a therapist reads first (``therapy_measures.py``): success, the assistance ratio from the
    first cycle to the last, and the patient's torque from the twin's model when it ran."""
    s, cyc = r.session, r.session_cycles
    if "success" in s and cyc:
        rig = (f" (the moves the rig drives {100 * s['success_assisted']:.0f} %)"
               if s.get("success_assisted", s["success"]) != s["success"] else "")
        t.add_row("per cycle: success", f"{100 * s['success']:.0f} % of the moves{rig}")
    ratios = [c["assistance_ratio"] for c in cyc if math.isfinite(c.get("assistance_ratio", math.nan))]
    if ratios:
        t.add_row("per cycle: assistance ratio", f"{ratios[0]:.2f} -> {ratios[-1]:.2f} (first -> last cycle; "
                  "the robot's work over its work with a passive patient)")
    if "patient_torque_open_model_nm" in s:  # the twin's estimate of the patient's torque per move
        src = cyc[0].get("patient_torque_model_source", "model")
        t.add_row(f"per cycle: patient torque ({src})", f"opening {s['patient_torque_open_model_nm']:+.3g}, "
                  f"closing {s.get('patient_torque_close_model_nm', float('nan')):+.3g} N m toward the target")


def recorded_line(r: RunResult) -> str | None:
    """The run directory once, in full, and the files in it (outside the table: never cut short)."""
    if not r.files:
        return None
    folder = Path(r.files[0]).resolve().parent
    return f"recorded: {folder}/ ({', '.join(Path(f).name for f in r.files)})"


def _telemetry(args: argparse.Namespace) -> TelemetryOptions | None:
    """``--telemetry RIG``: the loopback hub on --telemetry-port, or a client of the lab router(s)
    given by --telemetry-connect (password from the environment)."""
    from rehab_hil.telemetry.cliargs import PASSWORD_ENV

    if not args.telemetry:
        return None
    password = os.environ.get(PASSWORD_ENV) if args.telemetry_user else None
    if args.telemetry_connect and args.telemetry_user and password is None:
        raise UserError(f"--telemetry-user needs the {PASSWORD_ENV} environment variable")
    return TelemetryOptions(args.telemetry, args.telemetry_port, tuple(args.telemetry_connect or ()),
                            args.telemetry_user, password)


def _session(args: argparse.Namespace) -> RigSession:
    """The session the arguments ask for (``service.session``); its errors as one line on the option."""
    if args.record:
        writable_folder(args.record, "--record", "each run makes a new folder inside it")
    try:
        return open_session(
            args.config, args.device, controller=args.controller, reference=args.reference, profile=args.profile,
            pacing=args.pacing, lockstep=args.lockstep, home=args.home, record=args.record, rig_id=args.rig_id,
            sim_plant=args.sim_plant, sim_patient=args.sim_patient,
            twin=args.twin, telemetry=_telemetry(args), rig_learning=args.rig_learning,
            thermal_replan=args.thermal_replan, assistance_store=args.assistance_store,
            fresh_assistance=args.fresh_assistance,
            foxglove=FoxgloveOptions(args.foxglove_host, args.foxglove) if args.foxglove is not None else None,
            confirm=(lambda text: input(f"{text} ")) if sys.stdin.isatty() else None)
    except SessionError as e:
        raise UserError(_option_error(e)) from None


def _option_error(e: SessionError) -> str:
    """A session's error as the CLI names its option (``--sim-plant: ...``)."""
    return f"--{e.option.replace('_', '-')}: {e.message}" if e.option else e.message


def _run_in_thread(session: RigSession, duration_s: float, display: bool, console: Console,
                   signals: list[int]) -> RunResult:
    """Run the loop on its own thread, so the main thread stays free for signals and the live display;
    Ctrl-C and SIGTERM stop it through the safe state (``signals`` collects them, for the exit code)."""
    result: list[RunResult] = []
    errors: list[BaseException] = []

    def stop(n: int, frame: Any) -> None:
        signals.append(n)
        session.request_stop(signal.Signals(n).name)

    def work() -> None:
        try:
            result.append(session.run(duration_s))
        except BaseException as e:  # reported on the main thread
            errors.append(e)

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        th = threading.Thread(target=work, name="loop")
        th.start()
        if not display:
            while th.is_alive():
                th.join(0.1)
        else:
            with Live(_progress_table(session.progress), console=console, refresh_per_second=4) as live:
                while th.is_alive():
                    th.join(0.25)
                    live.update(_progress_table(session.progress))
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    if errors:
        if isinstance(errors[0], HardwareError):
            raise UserError(f"device: {errors[0]}")
        if isinstance(errors[0], SessionError):
            raise UserError(_option_error(errors[0]))
        raise errors[0]
    return result[0]


def run(args: argparse.Namespace) -> int:
    if not 0 < args.duration <= 24 * 3600:
        raise UserError(f"--duration must be in (0, 86400] s, got {args.duration}")
    if args.device != "inprocess":  # the device's and the loop's processes: the zygote imports while this builds
        launch.warm()
    console = Console()
    with _session(args) as session:
        for note in getattr(session.controller, "notes", ()):  # a declared controller's warnings
            print(f"warning: {note}")
        if session.homed is not None:
            print(f"homed ({session.homed.mode}): encoder count {session.homed.count} at the home pose")
        if (fox := session.feature("foxglove")) is not None:
            print(f"Foxglove live view: {fox.url} (layout: {shipped.FOXGLOVE_LAYOUT})")
        signals: list[int] = []
        result = _run_in_thread(session, args.duration, not args.no_display, console, signals)
    console.print(summary_table(result))
    if (line := recorded_line(result)) is not None:
        print(line)
    if signals:  # stopped by Ctrl-C or SIGTERM: the shell's convention, 128 + the signal
        print(f"rehab-hil run: interrupted ({signal.Signals(signals[0]).name}); the rig was left in the safe state",
              file=sys.stderr)
        return 128 + signals[0]
    return 1 if result.events and result.events[0].reason != "stop_request" else 0
