"""Every command in README.md and docs/*.md, checked on a fresh clone.

Without options (what ``tests/test_docs.py`` does on every ``make test``, in a second): each
``rehab-hil`` command parses (argparse, the real parser), each file it reads from the repository
exists (configs, profiles, docs/examples), each file or folder it writes is under ``out/``, and each
other program line (a Python module, a bench script, mkdir/cp/printf, make) names what exists.

``--run`` (minutes): clones the repository (``git clone``, the committed tree) into a temporary
folder and runs every command there in document order, shell lines included, with sessions cut to
``--max-duration`` seconds (12) and trials to two patients of one session; ``<run>`` placeholders
become the newest run directory. Commands that need a board, a lab network or a second live process
are listed with the reason and the test that covers them. Prints one line per command and exits 1 if
any failed.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHELL_LANGS = ("", "sh", "bash", "shell", "console")
PROGRAMS = ("rehab-hil", ".venv/bin/rehab-hil", "python", ".venv/bin/python", "mkdir", "cp", "printf", "make")
OUTPUT_OPTIONS = ("--out", "--record", "--html", "--layout-out", "--out-dir")
READ_FOLDERS = ("configs/", "profiles/", "docs/")

# commands not run by --run, and who runs them instead (matched on the command line)
NOT_RUN = (
    ("/dev/tty", "a real board (tests/hardware/test_serial_hw.py runs the serial path on a pty)"),
    ("--device auto", "a real board (`--device auto` finds the Uno; tests/hardware/test_discovery.py)"),
    ("tcp/10.0.0.2", "the lab's network (tests/telemetry/test_lab.py runs the same on loopback)"),
    ("rehab-hil router", "binds the default port 7447 (tests/telemetry/test_lab_examples.py runs it on a free one)"),
    ("rehab-hil monitor", "waits for a live rig (tests/telemetry/test_lab.py and test_cli.py run it beside rigs)"),
    ("rehab-hil record --from-zenoh", "waits for a live rig (tests/telemetry/test_lab.py)"),
    ("rehab-hil foxglove", "waits for a live rig (tests/telemetry/test_lab.py)"),
    ("make ", "make test is the suite itself; make run is the README's `run ... --duration 30 --record out/`"),
    ("bench/", "a benchmark, not a check (make bench)"),
    ("python_device", "waits on stdin for the host (tests/devices/test_conformance.py)"),
    ("--scheduler", "a Dask cluster started beside it (tests/trial/test_trial.py starts one on 127.0.0.1)"),
)
TRIAL_CUT = {"--patients": 2, "--sessions": 1}  # --run: a trial's size cut to this (and its sessions' duration)


@dataclass
class DocCommand:
    """One command line of a document: where it is, its text (continuations joined, comment cut)."""

    file: str
    line: int
    text: str

    @property
    def argv(self) -> list[str]:
        return shlex.split(self.text)

    @property
    def where(self) -> str:
        return f"{self.file}:{self.line}"

    def rehab_args(self) -> list[str] | None:
        """The arguments after ``rehab-hil``, or None for another program."""
        argv = self.argv
        return argv[1:] if argv and argv[0] in ("rehab-hil", ".venv/bin/rehab-hil") else None


def _strip_comment(line: str) -> str:
    """The line without its shell comment (a # outside quotes that starts a word)."""
    out, quote = [], None
    for i, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            break
        out.append(ch)
    return "".join(out).strip()


def doc_commands(root: Path = ROOT) -> list[DocCommand]:
    """Every program line of the shell blocks of README.md and docs/*.md, in document order."""
    found = []
    for path in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        for block in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
            if block.group(1) not in SHELL_LANGS:
                continue
            first = text.count("\n", 0, block.start(2)) + 1
            lines = block.group(2).split("\n")
            i = 0
            while i < len(lines):
                start, cur = i, lines[i]
                while cur.rstrip().endswith("\\") and i + 1 < len(lines):
                    i += 1
                    cur = cur.rstrip()[:-1] + " " + lines[i].strip()
                i += 1
                cmd = _strip_comment(cur)
                if cmd.split(" ", 1)[0] in PROGRAMS:
                    for part in cmd.split(" && "):
                        found.append(DocCommand(str(path.relative_to(root)), first + start, part.strip()))
    return found


def parse_problem(args: list[str]) -> str | None:
    """What argparse says about ``rehab-hil ARGS`` (None: it parses). Placeholders are filled first."""
    from rehab_hil.cli import build_parser

    args = [re.sub(r"<[a-z0-9_]+>", "PLACEHOLDER", a) for a in args]
    command = next((a for a in args if not a.startswith("-")), None)
    names = {"import": "import_data"}
    parser = build_parser(names.get(command, command))
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            parser.parse_args(args)
    except SystemExit as e:
        return err.getvalue().strip().splitlines()[-1] if e.code else None
    except Exception as e:  # an argument's own check (--device simm)
        return str(e)
    return None


FILE_LIKE = re.compile(r"\.(toml|json|csv|txt|pw|mat|mcap|html|py|pem)$")


def read_files(cmd: DocCommand) -> list[str]:
    """Files the command reads from the repository (configs, profiles, docs/examples, an access-control
    file): they must be shipped. Not: what earlier commands wrote (out/), data beside the repository
    (../shared), absolute paths, placeholders, outputs."""
    out = []
    argv = cmd.argv
    for i, a in enumerate(argv[1:], 1):
        if argv[i - 1] in OUTPUT_OPTIONS or argv[i - 1] in (">", ">>") or (argv[0] == "cp" and i == len(argv) - 1):
            continue
        if a.startswith(("out/", "../", "/", "-")) or "<" in a or a.startswith(("tcp/", "tls/")):
            continue
        if a.startswith(READ_FOLDERS) or FILE_LIKE.search(a):
            out.append(a)
    return out


def written(cmd: DocCommand) -> list[str]:
    """What the command writes: option values, a shell redirection, cp's target."""
    argv = cmd.argv
    out = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in OUTPUT_OPTIONS]
    out += [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in (">", ">>")]
    if argv and argv[0] == "cp":
        out.append(argv[-1])
    if argv and argv[0] == "mkdir":
        out += [a for a in argv[1:] if not a.startswith("-")]
    return out


def static_problems(cmd: DocCommand, root: Path = ROOT) -> list[str]:
    """Why the line would fail or litter on a fresh clone, without running it."""
    problems = []
    args = cmd.rehab_args()
    if args is not None and "..." not in args and (why := parse_problem(args)):
        problems.append(f"does not parse: {why}")
    problems += [f"names {f}, which is not in the repository" for f in read_files(cmd) if not (root / f).exists()]
    problems += [f"writes {w} outside out/" for w in written(cmd) if not w.startswith("out/") and w != "out"]
    argv = cmd.argv
    if argv[0].endswith("python"):
        target = argv[2] if argv[1:2] == ["-m"] else argv[1]
        if argv[1:2] == ["-m"]:
            mod = target.replace(".", "/")
            if not any((root / base / f"{mod}{suffix}").exists() for base in ("src", ".")
                       for suffix in (".py", "/__main__.py")):
                problems.append(f"module {target} not in the repository")
        elif not (root / target).exists():
            problems.append(f"script {target} not in the repository")
    return problems


# -- --run --------------------------------------------------------------------------------------


def _not_run(cmd: DocCommand) -> str | None:
    if "..." in cmd.argv:
        return "an elided command (`...`): its options are checked on the full lines"
    if "../shared/" in cmd.text:
        return "data outside the repository (../shared/data); run when it is present" \
            if not (ROOT.parent / "shared").exists() else None
    return next((why for key, why in NOT_RUN if key in cmd.text), None)


def _runnable(cmd: DocCommand, work: Path, max_duration_s: float) -> list[str]:
    """The line as run in the clone: the project's interpreter, durations cut, placeholders filled."""
    argv = cmd.argv
    for i, a in enumerate(argv):
        m = re.search(r"<run(\d?)>", a)
        if m:  # <run>, <run2>: the newest run there; <run1>: the one before it
            runs = sorted(d for d in (work / a[:m.start()]).iterdir() if (d / "metadata.json").is_file())
            argv[i] = str(runs[-2] if m.group(1) == "1" and len(runs) > 1 else runs[-1])
    if argv[0] in ("rehab-hil", ".venv/bin/rehab-hil"):
        argv = [sys.executable, "-m", "rehab_hil.cli", *argv[1:]]
        if argv[3] == "run":
            if "--duration" in argv:
                k = argv.index("--duration") + 1
                argv[k] = str(min(float(argv[k]), max_duration_s))
            else:
                argv += ["--duration", str(max_duration_s)]
            if "--no-display" not in argv:
                argv.append("--no-display")
            argv += ["--home", "none"] if "--home" not in argv else []
        if argv[3] == "trial":
            for flag, most in {**TRIAL_CUT, "--duration": max_duration_s}.items():
                if flag in argv:
                    k = argv.index(flag) + 1
                    argv[k] = str(min(type(most)(argv[k]), most))
                else:
                    argv += [flag, str(most)]
    elif argv[0].endswith("python"):
        argv = [sys.executable, *argv[1:]]
    return argv


def run_all(work: Path, max_duration_s: float) -> int:
    """Run every document command in ``work`` (a clone); one line each; 1 if any failed."""
    env = {**os.environ, "PYTHONPATH": str(work / "src"), "PYTHONUNBUFFERED": "1"}
    failed = 0
    for cmd in doc_commands(work):
        why = _not_run(cmd)
        if why:
            print(f"skip  {cmd.where}: {cmd.text[:90]}  ({why})")
            continue
        t0 = time.monotonic()
        if cmd.argv[0] == "printf" or ">>" in cmd.text:
            proc = subprocess.run(cmd.text, shell=True, cwd=work, env=env, capture_output=True, text=True)
        else:
            proc = subprocess.run(_runnable(cmd, work, max_duration_s), cwd=work, env=env, capture_output=True,
                                  text=True, timeout=1800)
        ok = proc.returncode == 0 and "Traceback" not in proc.stderr
        failed += not ok
        print(f"{'ok  ' if ok else 'FAIL'}  {cmd.where}: {cmd.text[:90]}  ({time.monotonic() - t0:.0f} s)", flush=True)
        if not ok:
            print("      " + (proc.stderr.strip() or proc.stdout.strip())[-600:].replace("\n", "\n      "))
    litter = [p.name for p in work.iterdir() if p.name not in _tracked(work) and p.name not in ("out", ".git")]
    if litter:
        failed += 1
        print(f"FAIL  left in the repository root: {', '.join(sorted(litter))}")
    return 1 if failed else 0


def _tracked(work: Path) -> set[str]:
    out = subprocess.run(["git", "-C", str(work), "ls-files"], capture_output=True, text=True, check=True).stdout
    return {line.split("/", 1)[0] for line in out.splitlines()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", action="store_true", help="clone the repository and run every command in it")
    ap.add_argument("--max-duration", type=float, default=12.0,
                    help="cut sessions to this many seconds (--run; default 12: one SMA open-close cycle)")
    ap.add_argument("--keep", action="store_true", help="keep the clone (--run)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    bad = 0
    for cmd in doc_commands():
        for problem in static_problems(cmd):
            bad += 1
            print(f"{cmd.where}: {cmd.text[:80]}: {problem}")
    print(f"{len(doc_commands())} commands in README.md and docs/*.md; {bad} problems")
    if not args.run:
        return 1 if bad else 0
    tmp = Path(tempfile.mkdtemp(prefix="rehab-hil-docs-"))
    work = tmp / "clone"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(work)], check=True)
    if (ROOT.parent / "shared").is_dir():  # the data beside the repository (../shared/data), as beside a clone
        (tmp / "shared").symlink_to(ROOT.parent / "shared")
    print(f"running them in a fresh clone, {work}")
    code = run_all(work, args.max_duration)
    if not args.keep:
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)
    return max(code, 1 if bad else 0)


if __name__ == "__main__":
    sys.exit(main())
