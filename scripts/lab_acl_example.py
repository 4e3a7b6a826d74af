"""Write docs/examples/lab/acl.json, the access-control file the docs' ``rehab-hil router`` command
names: ``telemetry.access.command_access_control`` for the docs' users (rig ``rig``, operator
``alice``, viewer ``victor``), as the JSON the router reads, one rule per line.
``--check``: exit 1 if the shipped file differs (tests/telemetry/test_lab_examples.py checks it)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / "docs" / "examples" / "lab" / "acl.json"


def acl_text() -> str:
    from rehab_hil.telemetry.access import command_access_control

    acl = command_access_control(rig_users=["rig"], operators=["alice"], viewers=["victor"])
    lists = [k for k, v in acl.items() if isinstance(v, list)]
    head = ", ".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in acl.items() if k not in lists)
    lines = ["{", '  "access_control": {', f"    {head},"]
    for n, key in enumerate(lists):
        items = [f"      {json.dumps(item)}" for item in acl[key]]
        lines += [f'    "{key}": [', ",\n".join(items), "    ]" + ("," if n < len(lists) - 1 else "")]
    text = "\n".join([*lines, "  }", "}"]) + "\n"
    assert json.loads(text) == {"access_control": acl}
    return text


def main() -> int:
    text = acl_text()
    if "--check" in sys.argv[1:]:
        same = TARGET.read_text() == text
        state = "up to date" if same else "differs: run python scripts/lab_acl_example.py"
        print(f"{TARGET.relative_to(ROOT)}: {state}")
        return 0 if same else 1
    TARGET.write_text(text)
    print(f"wrote {TARGET.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
