"""``rehab-hil monitor [RIG]``: live terminal view of a rig's zenoh telemetry; without RIG, a compact
table of every live rig of the lab (docs/telemetry.md)."""

from __future__ import annotations

import argparse
import time

from rich.console import Console
from rich.live import Live

from rehab_hil.cli import UserError
from rehab_hil.telemetry.cliargs import add_network_args, network_from_args
from rehab_hil.telemetry.keys import RigIdError, validate_rig_id
from rehab_hil.telemetry.lab_view import LabView, render_lab
from rehab_hil.telemetry.monitor_view import MonitorState, render
from rehab_hil.telemetry.session import TelemetryConfigError, open_session
from rehab_hil.telemetry.subscriber import list_rigs, query_info, subscribe, watch_alive


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("monitor", help="live view of a rig's telemetry over zenoh")
    p.add_argument("rig", nargs="?", default=None, help="rig id (default: a table of every live rig)")
    p.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    p.add_argument("--no-live", action="store_true", help="no live screen: print one snapshot at exit (logs, CI)")
    add_network_args(p)
    return p


def _lab(session: object, args: argparse.Namespace, console: Console) -> int:
    """The lab table: every rig whose liveliness token is present, with its latest values."""
    view = LabView(session)  # type: ignore[arg-type]
    try:
        give_up = time.monotonic() + 2.0
        rigs = view.live()  # the liveliness subscriber's history, or a liveliness query (either may lag)
        while not rigs and time.monotonic() < give_up:
            time.sleep(0.1)
            rigs = view.live() or list_rigs(session, timeout_s=0.5)  # type: ignore[arg-type]
        if not rigs:
            raise UserError("no running rig found (is `rehab-hil run --telemetry RIG` running?); "
                            "name one to wait for it")
        asked: set[str] = set()
        end = time.monotonic() + args.duration if args.duration else float("inf")

        def refresh() -> None:
            for rig in view.live():
                if rig not in asked:  # plant name once per rig, from the main thread
                    asked.add(rig)
                    view.set_plant(rig, (query_info(session, rig, timeout_s=0.5) or {}).get("plant"))  # type: ignore[arg-type]

        if args.no_live:
            while time.monotonic() < end:
                refresh()
                time.sleep(0.1)
            wide = console if console.is_terminal else Console(width=160)  # logs: never cut a rig's row
            wide.print(render_lab(view.snapshot()))
        else:
            with Live(render_lab(view.snapshot()), console=console, refresh_per_second=4) as live:
                while time.monotonic() < end:
                    refresh()
                    time.sleep(0.25)
                    live.update(render_lab(view.snapshot()))
    finally:
        view.close()
    return 0


def run(args: argparse.Namespace) -> int:
    if args.duration is not None and not 0 < args.duration <= 7 * 24 * 3600:
        raise UserError(f"--duration must be positive (and at most a week), got {args.duration}")
    try:
        net = network_from_args(args)
        session = open_session(net)
    except (TelemetryConfigError, RigIdError) as e:
        raise UserError(str(e)) from None
    console = Console()
    try:
        if args.rig is None:
            return _lab(session, args, console)
        try:
            rig = validate_rig_id(args.rig)
        except RigIdError as e:
            raise UserError(str(e)) from None
        state = MonitorState(rig)
        watcher = watch_alive(session, state.on_alive, rig=rig)
        sub = subscribe(rig, state.on_sample, on_stats=state.on_stats, on_safety=state.on_safety, session=session)
        try:
            state.set_info(query_info(session, rig, timeout_s=1.0))
            end = time.monotonic() + args.duration if args.duration else float("inf")
            if args.no_live:
                while time.monotonic() < end:
                    time.sleep(0.1)
            else:
                with Live(render(state), console=console, refresh_per_second=4) as live:
                    next_info = time.monotonic() + 5.0
                    while time.monotonic() < end:
                        time.sleep(0.25)
                        if not state.info and time.monotonic() >= next_info:  # a rig started after us
                            state.set_info(query_info(session, rig, timeout_s=0.5))
                            next_info = time.monotonic() + 5.0
                        live.update(render(state))
        finally:
            sub.close()
            watcher.undeclare()
        if args.no_live:
            console.print(render(state))
    finally:
        session.close()
    return 0
