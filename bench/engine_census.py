"""How many distinct model compilations a run made, and what makes them distinct.

Run the suite (or any command) with an empty ``REHAB_HIL_CACHE_DIR``, then point this script at that
folder: each ``rehab_hil_engine_*.py`` there is one compiled engine (one numba compilation of a whole
diagram). The script also counts how many would remain if a difference were removed: the wire gains
(numbers in the generated source), the part wiring and flat-array slices (only which part classes, in
order), and the order of the parts (only which part classes). The figures say which differences are
the avoidable ones. With ``--log``, the run's compile log (``REHAB_HIL_COMPILE_LOG``: every process
appends a JSON line per numba compilation, ``rehab_hil.progress``) is summed too: compilations, their
CPU, the functions compiled in more than one process (work the shared cache should have saved) and the
modules that cost the most. Prints the figures; writes nothing.

    REHAB_HIL_CACHE_DIR=/tmp/cold/rh REHAB_HIL_COMPILE_LOG=/tmp/cold/compiles.jsonl make test
    python bench/engine_census.py /tmp/cold/rh --log /tmp/cold/compiles.jsonl
"""

from __future__ import annotations

import argparse
import json
import re
from collections import Counter, defaultdict
from pathlib import Path

_NUMBER = re.compile(r"\((-?[0-9][0-9.e+-]*)\) \* ")
_IMPORT = re.compile(r"^import (rehab_hil_part_\w+) as _C\d+$", re.MULTILINE)  # an engine's part modules
_PART_CLASS = re.compile(r"^from (\S+) import (\S+) as _C$", re.MULTILINE)  # a part module's class


_CLASSES: dict[str, str] = {}  # part module name -> the part class it compiles (module.qualname)


def engine_sources(cache: Path) -> list[str]:
    """The generated engine sources under a cache folder (``engines/`` or the folder itself); the part
    modules beside them say which part class each engine imports."""
    folder = cache / "engines" if (cache / "engines").is_dir() else cache
    for p in folder.glob("rehab_hil_part_*.py"):
        found = _PART_CLASS.search(p.read_text())
        _CLASSES[p.stem] = f"{found[1]}.{found[2]}" if found else p.stem
    return [p.read_text() for p in sorted(folder.glob("rehab_hil_engine_*.py"))]


def part_classes(src: str) -> tuple[str, ...]:
    """The part classes an engine imports, in diagram order (module.qualname; a part module whose
    file is gone: its name)."""
    return tuple(_CLASSES.get(m, m) for m in _IMPORT.findall(src))


def census(sources: list[str]) -> dict[str, int]:
    """Distinct engines, and distinct ones left once each kind of difference is ignored."""
    return {
        "engine files (cache keys)": len(sources),
        "distinct generated sources": len(set(sources)),
        "ignoring wire gains": len({_NUMBER.sub("(G) * ", s) for s in sources}),
        "ignoring wiring and slices (part classes in order)": len({part_classes(s) for s in sources}),
        "ignoring part order (multiset of part classes)": len({tuple(sorted(part_classes(s))) for s in sources}),
    }


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
    ap.add_argument("cache", type=Path, help="the REHAB_HIL_CACHE_DIR (or its engines/ folder) of a run")
    ap.add_argument("--top", type=int, default=15, help="list the part classes used by the most engines")
    ap.add_argument("--log", type=Path, help="the run's REHAB_HIL_COMPILE_LOG file: sum its compilations too")
    args = ap.parse_args()
    sources = engine_sources(args.cache)
    for what, n in census(sources).items():
        print(f"{what:55s} {n:5d}")
    uses = Counter(c for s in sources for c in set(part_classes(s)))
    sizes = [len(part_classes(s)) for s in sources]
    if sizes:
        print(f"parts per engine: min {min(sizes)}, median {sorted(sizes)[len(sizes) // 2]}, max {max(sizes)}")
    print("part classes in most engines:")
    for cls, n in uses.most_common(args.top):
        print(f"  {n:5d}  {cls}")

    if args.log:
        print_log(read(args.log), args.top)


def print_log(rows: list[dict], top: int) -> None:
    """The compile log's sums, by kind of code, and the ``top`` modules by CPU."""
    for name, value in summary(rows).items():
        print(f"{name:<55} {value:7.1f}" if isinstance(value, float) else f"{name:<55} {value:5d}")
    per_kind: dict[str, float] = defaultdict(float)
    per_module: dict[str, float] = defaultdict(float)
    for r in rows:
        per_kind[kind(r["module"])] += r["cpu_s"]
        per_module[r["module"]] += r["cpu_s"]
    print("CPU by kind: " + ", ".join(f"{k} {v:.0f} s" for k, v in sorted(per_kind.items())))
    for module, cpu in sorted(per_module.items(), key=lambda kv: -kv[1])[:top]:
        print(f"  {cpu:7.1f} s  {module}")


if __name__ == "__main__":
    main()
