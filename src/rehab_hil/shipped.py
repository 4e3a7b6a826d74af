"""The plant configs and patient profiles shipped with rehab-hil: the repository's ``configs/`` and
``profiles/`` in a checkout (and an editable install), the package's own copies in an installed
wheel (``pyproject.toml``: hatch's ``force-include`` puts them in ``rehab_hil/shipped_data/``; not
``rehab_hil/profiles``, the name of a module).

``resolve`` lets the docs' commands (``--config configs/finger_extensor.toml``) run from any folder
once the package is installed: a relative ``configs/NAME`` or ``profiles/NAME`` that does not exist
where the user stands is the shipped file of that name.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["CONFIGS", "FOXGLOVE_LAYOUT", "PROFILES", "resolve"]

_PACKAGE = Path(__file__).resolve().parent


def _shipped(name: str) -> Path:
    packaged = _PACKAGE / "shipped_data" / name  # an installed wheel
    return packaged if packaged.is_dir() else _PACKAGE.parents[1] / name  # a checkout: src/rehab_hil -> root


CONFIGS = _shipped("configs")
PROFILES = _shipped("profiles")
FOXGLOVE_LAYOUT = (_PACKAGE / "shipped_data" / "foxglove_layout.json"
                   if (_PACKAGE / "shipped_data" / "foxglove_layout.json").is_file()
                   else _PACKAGE.parents[1] / "docs" / "foxglove_layout.json")  # the layout `run --foxglove` names
_FOLDERS = {"configs": CONFIGS, "profiles": PROFILES}


def resolve(path: str | Path) -> Path:
    """``path`` when it exists (or is not a ``configs/NAME`` / ``profiles/NAME``); else the shipped
    file it names, when there is one. A missing path stays as given, for the reader to name."""
    p = Path(path)
    if p.exists() or p.is_absolute() or len(p.parts) != 2 or p.parts[0] not in _FOLDERS:
        return p
    shipped = _FOLDERS[p.parts[0]] / p.parts[1]
    return shipped if shipped.is_file() else p
