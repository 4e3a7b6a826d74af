"""``rehab-hil ports``: list the serial ports with their USB ids and name the likely Arduino.

The suggested path is the ``/dev/serial/by-id`` link (stable across re-plugging); put it in
``[rig].port`` or pass it as ``--device``. ``--device auto`` picks the same board
(``rehab_hil.hardware.discovery``).
"""

from __future__ import annotations

import argparse

from rich.console import Console
from rich.table import Table

from rehab_hil.hardware.discovery import PortCandidate, candidates


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("ports", help="list serial ports with USB ids and name the likely Arduino")
    p.add_argument("--likely", action="store_true", help="only ports that look like an Arduino")
    return p


def ports_table(found: list[PortCandidate]) -> Table:
    """One row per port: path, by-id link, USB id, serial number, description, verdict."""
    t = Table(title="serial ports")
    for col in ("port", "by-id link (use this)", "USB vid:pid", "serial", "description", "looks like"):
        t.add_column(col)
    for c in found:
        verdict = f"[green]{c.kind}" if c.likely_arduino else "-"
        t.add_row(c.device, c.by_id or "-", c.usb_id, c.serial_number or "-", c.description, verdict)
    return t


def run(args: argparse.Namespace) -> int:
    console = Console()
    found = candidates()
    if args.likely:
        found = [c for c in found if c.likely_arduino]
    if not found:
        console.print("no serial ports found" + (" that look like an Arduino" if args.likely else "")
                      + ": is the board plugged in (and is this user in the dialout group)?")
        return 1
    console.print(ports_table(found))
    best = [c for c in found if c.likely_arduino]
    if best:
        console.print(f"likely Arduino: {best[0].suggested}  (--device auto picks it when it is the only one)")
    return 0
