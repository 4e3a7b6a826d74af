"""``rehab-hil monitor [RIG]``: live terminal view of a rig's zenoh telemetry (docs/telemetry.md)."""

from __future__ import annotations

import argparse
import time

from rich.console import Console
from rich.live import Live

from rehab_hil.cli import UserError
from rehab_hil.telemetry.cliargs import add_network_args, network_from_args
from rehab_hil.telemetry.keys import RigIdError, validate_rig_id
from rehab_hil.telemetry.monitor_view import MonitorState, render
from rehab_hil.telemetry.session import TelemetryConfigError, open_session
from rehab_hil.telemetry.subscriber import list_rigs, query_info, subscribe, watch_alive


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("monitor", help="live view of a rig's telemetry over zenoh")
    p.add_argument("rig", nargs="?", default=None, help="rig id (default: the only running rig)")
    p.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    p.add_argument("--no-live", action="store_true", help="no live screen: print one snapshot at exit (logs, CI)")
    add_network_args(p)
    return p


def _pick_rig(session: object, wanted: str | None) -> str:
    if wanted is not None:
        return validate_rig_id(wanted)
    rigs = list_rigs(session)  # type: ignore[arg-type]
    if len(rigs) == 1:
        return rigs[0]
    if not rigs:
        raise UserError("no running rig found (is `rehab-hil run --telemetry RIG` running?); name one to wait for it")
    raise UserError(f"several rigs are running: {', '.join(rigs)}; name one")


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
        try:
            rig = _pick_rig(session, args.rig)
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
