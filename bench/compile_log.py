"""What a run compiled, for how long, and what it compiled more than once.

Run any command (the suite, a session) with ``REHAB_HIL_COMPILE_LOG=/some/file`` and an empty
``REHAB_HIL_CACHE_DIR``: every process appends one JSON line per numba compilation (a cache miss) there
(``rehab_hil.progress``). This script sums them: compilations, their CPU, how many functions were
compiled by more than one process (each one of those is work a shared cache should have saved), and the
modules that cost the most. Prints the figures; writes nothing.

    REHAB_HIL_CACHE_DIR=/tmp/cold REHAB_HIL_COMPILE_LOG=/tmp/compiles.jsonl make test
    python bench/compile_log.py /tmp/compiles.jsonl
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path


def read(path: Path) -> list[dict]:
    """The log's lines (a line cut short by a killed process is skipped)."""
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows


def kind(module: str) -> str:
    """Which sort of code a compiled function is: a generated engine, a part module, or the package."""
    for prefix in ("rehab_hil_engine", "rehab_hil_part"):
        if module.startswith(prefix):
            return prefix
    return "package"


def summary(rows: list[dict]) -> dict[str, float]:
    """Compilations, their CPU, and the repeats: functions compiled in more than one process."""
    by_fn: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in rows:  # a test that compiles into a cache of its own (its file is elsewhere) is not a repeat
        by_fn[(r.get("file", r["module"]), r["function"])].append(r)
    repeats = [rs[1:] for rs in by_fn.values() if len({r["pid"] for r in rs}) > 1]
    return {
        "compilations": len(rows),
        "distinct functions": len(by_fn),
        "processes that compiled": len({r["pid"] for r in rows}),
        "CPU compiling [s]": sum(r["cpu_s"] for r in rows),
        "wall compiling, summed over processes [s]": sum(r["wall_s"] for r in rows),
        "functions compiled in more than one process": len(repeats),
        "CPU of those repeats [s]": sum(r["cpu_s"] for rs in repeats for r in rs),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path, help="the REHAB_HIL_COMPILE_LOG file of a run")
    ap.add_argument("--top", type=int, default=10, help="list the modules that took the most CPU")
    args = ap.parse_args()
    rows = read(args.log)
    for name, value in summary(rows).items():
        print(f"{name:<48} {value:10.1f}" if isinstance(value, float) else f"{name:<48} {value:10d}")
    per_kind: dict[str, float] = defaultdict(float)
    per_module: dict[str, float] = defaultdict(float)
    for r in rows:
        per_kind[kind(r["module"])] += r["cpu_s"]
        per_module[r["module"]] += r["cpu_s"]
    print("CPU by kind: " + ", ".join(f"{k} {v:.0f} s" for k, v in sorted(per_kind.items())))
    for module, cpu in sorted(per_module.items(), key=lambda kv: -kv[1])[: args.top]:
        print(f"  {cpu:7.1f} s  {module}")


if __name__ == "__main__":
    main()
