"""The ``rehab-hil`` command line. Each subcommand lives in its own module and registers here.

Errors that are the user's (bad config, malformed CSV, bad arguments) print one line naming
the file and key or line, and exit with status 2; no traceback.
"""

from __future__ import annotations

import _thread
import argparse
import importlib
import os
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

# One BLAS thread per process, unless the user says otherwise: the matrices here are small, and a
# BLAS pool's idle workers spin on the second core beside the real-time loop (a 100 x 100 solve took
# 4 ms in the twin's thread with the default pool on 2 busy cores). Set before numpy is first loaded.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__all__ = ["SUBCOMMANDS", "UserError", "config_file", "device_arg", "interrupted", "keep_ctrl_c", "main",
           "writable_folder"]

# module names under rehab_hil.cli; each defines add_parser(subparsers) and run(args) -> int
SUBCOMMANDS = ["simulate", "run", "tune", "identify", "sensitivity", "discrepancy", "replay", "monitor", "record",
               "ports", "flash", "router", "foxglove", "doctor", "calibrate", "report", "import_data", "twin", "trial"]


class UserError(Exception):
    """An error in what the user asked for; printed as one line."""


def writable_folder(path: Path, flag: str, why: str) -> None:
    """``flag path`` must be a folder this process can write (made now if missing); checked before
    any work whose result would be lost. ``why`` says why a file will not do."""
    if path.exists() and not path.is_dir():
        raise UserError(f"{flag} {path}: a file, not a folder ({why})")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"{flag} {path}: cannot create: {e.strerror}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise UserError(f"{flag} {path}: not writable")


def config_file(text: str) -> Path:
    """``--config`` / ``--profile`` / ``--sim-plant``: the file as typed; a ``configs/NAME`` or
    ``profiles/NAME`` that is not where the user stands is the shipped one (an installed package run
    from any folder), said on standard error."""
    from rehab_hil.shipped import resolve

    path = resolve(text)
    if path != Path(text):
        print(f"rehab-hil: {text}: not in {Path.cwd()}; using the one shipped with rehab-hil, {path}", file=sys.stderr)
    return path


def device_arg(text: str) -> str:
    """``--device``: a near-miss of sim, avr, inprocess or auto (``simm``) is refused with the name
    meant, at once, instead of being opened as a serial path after the model is built."""
    from rehab_hil.hardware import HardwareError
    from rehab_hil.hardware.discovery import check_device_name

    try:
        return check_device_name(text)
    except HardwareError as e:
        raise UserError(f"--device: {e}") from None


def _user_errors() -> tuple[type[BaseException], ...]:
    from rehab_hil.calibration import ForceLimitError
    from rehab_hil.config import ConfigError
    from rehab_hil.controllers.base import ControllerError
    from rehab_hil.interchange import CsvError
    from rehab_hil.models.system import DiagramError

    return (UserError, ConfigError, ControllerError, CsvError, DiagramError, ForceLimitError)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; with ``command``, only that subcommand's module is imported (the
    others stay names): ``rehab-hil run`` does not pay for python-control and matplotlib."""
    parser = argparse.ArgumentParser(prog="rehab-hil", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in SUBCOMMANDS:
        if command is not None and name != command:
            sub.add_parser(name.replace("_data", ""), add_help=False)
            continue
        mod = importlib.import_module(f"rehab_hil.cli.{name}")
        p = mod.add_parser(sub)
        p.set_defaults(_run=mod.run)
    return parser


STDIN_CLOSED = ("standard input closed while waiting for an answer: answer on a terminal, or pass --yes "
                "(doctor, calibrate) or --home none (run)")


def interrupted(exc: BaseException) -> bool:
    """Ctrl-C, also when a library wrapped it: numba's compiler turns a KeyboardInterrupt raised in
    its callbacks into a ``SystemError`` whose cause or context is the interrupt."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def keep_ctrl_c(unraisable: Any) -> None:
    """A ``sys.unraisablehook`` that does not lose Ctrl-C: an interrupt raised where Python cannot
    propagate it (the import lock's weakref callback, a ``__del__``) is printed "Exception ignored" and
    dropped, and the command would run on; it is raised again at the main thread's next safe point."""
    if issubclass(unraisable.exc_type, KeyboardInterrupt):
        # from another thread 50 ms on, once this hook has returned (an interrupt raised in the hook is dropped for
        # good); it calls the SIGINT handler as a new Ctrl-C would, and does nothing when SIGINT is ignored
        again = threading.Timer(0.05, _thread.interrupt_main)
        again.daemon = True
        again.start()
        return
    sys.__unraisablehook__(unraisable)


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: 0 done, 1 a session that tripped, 2 a user error (one line), 130 Ctrl-C
    (one line, wherever it came: while importing, compiling the model or fitting)."""
    words = list(sys.argv[1:] if argv is None else argv)
    command = next((w for w in words if not w.startswith("-")), "")
    previous_hook, sys.unraisablehook = sys.unraisablehook, keep_ctrl_c
    try:
        return _main(words)
    except BaseException as e:
        if not interrupted(e):
            raise
        print(f"\nrehab-hil {command}: interrupted", file=sys.stderr)
        return 130
    finally:
        sys.unraisablehook = previous_hook


def _main(words: list[str]) -> int:
    from rehab_hil import progress

    progress.set_sink(lambda line: print(f"rehab-hil: {line}", file=sys.stderr, flush=True))  # slow steps say so
    named = {name.replace("_data", ""): name for name in SUBCOMMANDS}
    first = next((w for w in words if not w.startswith("-")), None)
    parser = build_parser(named.get(first) if first is not None else None)
    try:
        args = parser.parse_args(words)
    except _user_errors() as e:  # an argument's own check (argparse type=) said what is wrong
        command = next((a for a in words if a in named), "")
        print(f"rehab-hil {command}: error: {e}".replace("  ", " "), file=sys.stderr)
        return 2
    try:
        return int(args._run(args) or 0)
    except _user_errors() as e:
        print(f"rehab-hil {args.command}: error: {e}", file=sys.stderr)
        return 2
    except EOFError:  # input() on a closed standard input, or Ctrl-D at a prompt
        print(f"\nrehab-hil {args.command}: error: {STDIN_CLOSED}", file=sys.stderr)
        return 2
    except OSError as e:  # a file the command reads or writes, not worded by the command itself: still one line
        if e.filename is None:
            raise
        print(f"rehab-hil {args.command}: error: {e.filename}: {e.strerror}", file=sys.stderr)
        return 2
    finally:
        progress.set_sink(None)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
