"""How a report speaks of a plant and its figures: an effect's words and source in the plant's own
vocabulary (a drive, an axis, a finger rig: ``Plant.vocabulary``), the unit of each effect
parameter on the axis it attaches to (N on a linear axis, N m on a rotary one: a linear axis carries
forces on the framework's ``*_nm`` names, ``models/axis_parts``), and a change of an error as what
it is ("cut by 81.5 %", "worse by 92.5 %": a negative cut was printed as "-92.5 % cut")."""

from __future__ import annotations

from typing import Any

import numpy as np

from rehab_hil.effects import EFFECTS

__all__ = ["change_words", "effect_words", "is_linear", "param_label", "param_unit"]

# parameter-name suffix -> (unit on a rotary axis, unit on a linear axis); longest suffixes first
_SUFFIX_UNITS: tuple[tuple[str, str, str], ...] = (
    ("_nm_s_per_rad", "N m s/rad", "N s/m"), ("_nm_per_rad", "N m/rad", "N/m"), ("_per_rad", "1/rad", "1/m"),
    ("_w_per_k3", "W/K^3", "W/K^3"), ("_nm", "N m", "N"), ("_rad", "rad", "m"), ("_counts", "counts", "counts"),
    ("_duty", "of full scale", "of full scale"), ("_fraction", "", ""), ("_s", "s", "s"), ("_c", "C", "C"),
)


def param_unit(name: str, linear: bool = False) -> str:
    """The unit of an effect parameter on its axis: ``level_nm`` is N m on a rotary axis, N on a linear one."""
    for suffix, rotary, lin in _SUFFIX_UNITS:
        if name.endswith(suffix):
            return lin if linear else rotary
    return ""


def param_label(name: str) -> str:
    """A parameter's name without its unit suffix: ``level_nm`` -> ``level``."""
    for suffix, _, _ in _SUFFIX_UNITS:
        if name.endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)]
    return name


def is_linear(replay: Any) -> bool:
    """Does the replay's plant move a linear axis (its effects' forces are newtons)?"""
    axes = getattr(getattr(replay, "ports", None), "axes", ()) or ()
    return bool(axes) and bool(getattr(axes[0], "linear", False))


def effect_words(effect: str, plant: str) -> tuple[str, str]:
    """(description, source) of a library effect in the plant's words."""
    from rehab_hil.plants import get_plant

    return EFFECTS[effect].describe(get_plant(plant).vocabulary)


def change_words(cut_pct: float | None) -> str:
    """A relative cut of an error (100 (1 - after / before), in percent) in words: "cut by 81.5 %" when
    the error fell, "worse by 92.5 %" when it rose, "unchanged" when it rounds to 0.0 %. A signed
    "-92.5 % cut" reads as a cut at a glance (issue 47: a validation record made worse was printed so)."""
    if cut_pct is None or not np.isfinite(cut_pct):  # an error that became infinite or NaN (null in JSON)
        return "worse (the model diverged)"
    if round(cut_pct, 1) == 0.0:
        return "unchanged"
    return f"cut by {cut_pct:.1f} %" if cut_pct > 0 else f"worse by {-cut_pct:.1f} %"
