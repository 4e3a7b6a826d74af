"""Every command in README.md and docs/*.md works on a fresh clone (scripts/check_docs.py): each
``rehab-hil`` line parses with the real parser, reads only files the repository ships and writes
only under out/; the cheap ones run here, in a folder of their own. ``scripts/check_docs.py --run``
runs all of them in a fresh clone (minutes: the fits and sessions)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("check_docs", ROOT / "scripts" / "check_docs.py")
assert _spec and _spec.loader
check_docs = importlib.util.module_from_spec(_spec)
sys.modules["check_docs"] = check_docs  # its dataclass looks its module up by name
_spec.loader.exec_module(check_docs)


def test_the_docs_have_commands_for_every_subcommand_they_describe():
    commands = check_docs.doc_commands()
    used = {c.rehab_args()[0] for c in commands if c.rehab_args()}
    assert len(commands) > 60
    assert {"simulate", "run", "report", "discrepancy", "replay", "router", "monitor", "calibrate"} <= used


def test_every_doc_command_parses_reads_shipped_files_and_writes_under_out():
    problems = [f"{c.where}: {c.text[:70]}: {p}" for c in check_docs.doc_commands()
                for p in check_docs.static_problems(c)]
    assert problems == []


@pytest.mark.parametrize(("line", "problem"), [
    ("rehab-hil run --config configs/finger_extensor.toml --device simm", "does not parse: --device"),
    ("rehab-hil simulate --config configs/finger_extensor.toml --scenrio step", "unrecognized arguments: --scenrio"),
    ("rehab-hil router --access-control acl.json", "names acl.json, which is not in the repository"),
    ("rehab-hil tune --config configs/finger_extensor.toml --out tuned.toml", "writes tuned.toml outside out/"),
    ("python -m rehab_hil.no_such_module", "module rehab_hil.no_such_module not in the repository"),
])
def test_the_checker_names_what_would_fail_or_litter(line, problem):
    found = check_docs.static_problems(check_docs.DocCommand("x.md", 1, line))
    assert any(problem in p for p in found), found


def _doc_line(text: str):
    return next(c for c in check_docs.doc_commands() if c.file == "README.md" and c.text.endswith(text))


@pytest.mark.slow
def test_the_readmes_first_commands_run_in_a_folder_of_their_own(tmp_path):
    """The README's first simulate line, then a session recorded into out/ (as ``make run`` does, cut to
    1 s) and ``report out/`` on that folder, which holds the simulated run.csv beside the run directory."""
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    lines = [_doc_line("--scenario step --duration 3 --out out/run.csv"),
             check_docs.DocCommand("README.md", 0, "rehab-hil run --config configs/finger_extensor.toml --device "
                                   "inprocess --controller pid --duration 1 --record out/"),  # make run's --record out/
             _doc_line("report out/")]
    for cmd in lines:
        proc = subprocess.run(check_docs._runnable(cmd, tmp_path, 1.0), cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=600)
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, f"{cmd.where}: {proc.stderr[-2000:]}"
    assert "rehab-hil report: out holds 1 run: " in proc.stderr  # the simulated out/run.csv is not one
    assert sorted(p.name for p in tmp_path.iterdir()) == ["configs", "out"]  # nothing beside out/
    (run,) = [d for d in (tmp_path / "out").iterdir() if d.is_dir()]
    assert (run / "report.html").is_file()
