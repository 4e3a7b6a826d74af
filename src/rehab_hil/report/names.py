"""Names a person reads for the recorder's column names (``<quantity>_<unit>``): "contact force [N]"
for ``contact_force_n``, "applied duty, channel 0 [0-1]" for ``applied_duty0_ratio``; and units
for a twin estimate's name (``..._nm_per_rad`` -> "N m/rad")."""

from __future__ import annotations

import re

__all__ = ["label", "quantity", "unit"]

# a column's unit suffix -> how the report writes it (SI symbols; a ratio is a share of full scale)
UNITS = {"deg": "deg", "rad": "rad", "n": "N", "nm": "N m", "c": "°C", "k": "K", "v": "V", "a": "A", "w": "W",
         "s": "s", "j": "J", "m": "m", "mm": "mm", "ratio": "0-1", "duty": "0-1", "counts": "counts", "pct": "%",
         "rad_s": "rad/s", "n_per_m": "N/m", "nm_per_rad": "N m/rad", "nms_per_rad": "N m s/rad"}
# whole names worth more than their parts
SPECIAL = {"estimated_temperature_c": "estimated actuator temperature",
           "estimated_velocity_rad_s": "estimated velocity", "pwm_duty": "PWM duty"}
_DUTY = re.compile(r"^(applied|command)_duty(\d)_ratio$")
_JOINT = re.compile(r"^theta_(mcp|pip|dip)")  # seed 000's joint angles
ACRONYMS = {"mcp", "pip", "dip", "tcp", "sma", "pwm", "adc"}


def _split(name: str) -> tuple[str, str]:
    """(quantity, unit key) of ``name``: the longest known unit suffix."""
    base = name.rsplit(".", 1)[-1]
    for key in sorted(UNITS, key=len, reverse=True):
        if base.endswith("_" + key) and len(base) > len(key) + 1:
            return base[: -len(key) - 1], key
    return base, ""


def unit(name: str) -> str:
    """The unit of a column or parameter name as the report writes it ("" when none is known)."""
    return UNITS.get(_split(name)[1], "")


def quantity(name: str) -> str:
    """What the column holds, in words, without its unit."""
    m = _DUTY.match(name)
    if m:
        return f"{m.group(1)} duty, channel {m.group(2)}"
    if name in SPECIAL:
        return SPECIAL[name]
    words = _JOINT.sub(lambda m: f"{m.group(1)}_joint_angle", _split(name)[0]).split("_")
    return " ".join(w.upper() if w in ACRONYMS else w for w in words)


def label(name: str) -> str:
    """``quantity [unit]``, e.g. "iris angle [deg]"; the quantity alone when no unit is known."""
    u = unit(name)
    return f"{quantity(name)} [{u}]" if u else quantity(name)
