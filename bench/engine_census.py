"""How many distinct model compilations a run made, and what makes them distinct.

Run the suite (or any command) with an empty ``REHAB_HIL_CACHE_DIR``, then point this script at that
folder: each ``rehab_hil_engine_*.py`` there is one compiled engine (one numba compilation of a whole
diagram). The script also counts how many would remain if a difference were removed: the wire gains
(numbers in the generated source), the part wiring and flat-array slices (only which part classes, in
order), and the order of the parts (only which part classes). The figures say which differences are
the avoidable ones. Prints the figures; writes nothing.

    python bench/engine_census.py /tmp/cold/rh            # the REHAB_HIL_CACHE_DIR of the run
"""

from __future__ import annotations

import argparse
import re
from collections import Counter
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cache", type=Path, help="the REHAB_HIL_CACHE_DIR (or its engines/ folder) of a run")
    ap.add_argument("--top", type=int, default=15, help="list the part classes used by the most engines")
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


if __name__ == "__main__":
    main()
