"""The nominal model's own parameters as candidates, and the corrected config they imply.

Each plant declares which of its parameters may be off (``Plant.fit_parameters``: the config key,
the diagram parameters and inputs it scales). A candidate here has one fitted value, the relative
error ``error_fraction`` (the model's value times 1 + error), so a torque constant 15 % low is
found as "motor.kt_nm_per_a is off by -15 %" instead of being explained by a new effect; the
corrected value goes into ``augmented.toml`` in place of the config's (the config key's line
keeps its comment and says what it was).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from rehab_hil.effects import EffectParam
from rehab_hil.plants.experiments import FitParameter

if TYPE_CHECKING:
    from rehab_hil.discrepancy.replay import Replay

__all__ = ["ERROR_PARAM", "ParameterTerm", "config_value", "corrected_config_text", "parameter_terms"]

ERROR_PARAM = EffectParam("error_fraction", -0.5, 1.0, 0.1)  # factor 0.5 .. 2 of the config's value


@dataclass(frozen=True)
class ParameterTerm:
    """A declared nominal parameter bound to a replay's parameter vector."""

    fp: FitParameter
    indices: tuple[int, ...]
    nominal: tuple[float, ...]

    @property
    def name(self) -> str:
        return self.fp.name

    def apply(self, P: np.ndarray, values: Mapping[str, float]) -> np.ndarray:
        """``P`` with the parameter's entries at nominal x (1 + error_fraction)."""
        out = np.array(P, float)
        f = 1.0 + float(values[ERROR_PARAM.name])
        for i, v in zip(self.indices, self.nominal, strict=True):
            out[i] = v * f
        return out


def parameter_terms(replay: Replay) -> list[ParameterTerm]:
    """The plant's declared fit parameters that this replay's diagram and inputs carry."""
    out = []
    P = replay.nominal_params()
    for fp in replay.spec.fit_parameters:
        if _value_or_none(replay.cfg, fp.config_key) is None:  # a key this config does not use (a rotary
            continue                                           # axis's inertia on a linear one)
        idx = [replay.system.diagram.param_index(q) for q in fp.diagram]
        idx += [replay.input_scale_index(u) for u in fp.inputs if u in replay.system.input_names]
        nominal = tuple(float(P[i]) for i in idx)
        if idx and any(v != 0.0 for v in nominal):  # a relative error of zero is nothing to fit
            out.append(ParameterTerm(fp, tuple(idx), nominal))
    return out


def _value_or_none(cfg: Any, key: str) -> Any:
    obj = cfg
    for part in key.split("."):
        obj = getattr(obj, part, None)
    return obj


def config_value(cfg: Any, key: str) -> float:
    """The config's value at a dotted key."""
    obj = cfg
    for part in key.split("."):
        obj = getattr(obj, part)
    return float(obj)


def corrected_config_text(text: str, cfg: Any, fixes: Mapping[FitParameter, float]) -> str:
    """The config text with each fit parameter's key set to its corrected value (factor given)."""
    for fp, factor in fixes.items():
        old = config_value(cfg, fp.config_key)
        new = fp.to_config(cfg, factor) if fp.to_config else old * factor
        section, _, key = fp.config_key.rpartition(".")
        text = _set_key(text, section, key, new, old)
        for other in fp.also:  # the rest of a coupled group, by the same factor
            section, _, key = other.rpartition(".")
            text = _set_key(text, section, key, config_value(cfg, other) * factor, config_value(cfg, other))
    return text


def _set_key(text: str, section: str, key: str, value: float, old: float) -> str:
    lines = text.split("\n")
    current = ""
    header = re.compile(r"^\s*\[\s*([A-Za-z0-9_.]+)\s*\]")
    for i, line in enumerate(lines):
        m = header.match(line)
        if m:
            current = m.group(1)
            continue
        km = re.match(rf"^(\s*{re.escape(key)}\s*=\s*)([^#]*?)(\s*#.*)?$", line)
        if km and current == section:
            note = f"  # corrected by rehab-hil discrepancy (was {old:.6g})"
            lines[i] = f"{km.group(1)}{value!r}{note}{(' ' + km.group(3).strip()) if km.group(3) else ''}"
            return "\n".join(lines)
    raise KeyError(f"config key {section}.{key} not found in the config text")
