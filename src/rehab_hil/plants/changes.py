"""Changes during a session on a simulated rig: effects that start or ramp in (``start_s``,
``ramp_s``) and plant parameters that move (``[[changes]]``); the rig binding at the session's
start and the schedule that moves it (``models/schedule.py``). Checked when a config loads."""

from __future__ import annotations

import difflib
from collections.abc import Callable, Sequence
from typing import Any

from pydantic import BaseModel, ValidationError

from rehab_hil.effects import EFFECTS, check_spec
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.models.schedule import ScheduleError, build_schedule
from rehab_hil.plants.sections import EffectSpec, PlantConfig

__all__ = ["NOT_CHANGEABLE", "changeable_keys", "scheduled", "scheduled_binding", "with_change", "with_values"]

# the shared tables: not the plant's model, so no [[changes]] key points into them
NOT_CHANGEABLE = ("plant", "simulation", "rig", "effects", "changes", "controllers", "recorded_controller", "import",
                  "twin")


def scheduled(cfg: PlantConfig) -> bool:
    """Whether ``cfg`` schedules anything mid-session (an effect with start_s or ramp_s, a change)."""
    return bool(getattr(cfg, "changes", ())) or any(e.timing.scheduled for e in getattr(cfg, "effects", ()))


def changeable_keys(cfg: PlantConfig) -> dict[str, Any]:
    """Every leaf of the plant's own tables by dotted TOML key -> its value (what a change may name)."""
    out: dict[str, Any] = {}

    def walk(obj: Any, prefix: str) -> None:
        if isinstance(obj, BaseModel):
            for name, f in type(obj).model_fields.items():
                walk(getattr(obj, name), prefix + (f.alias or name) + ".")
        elif isinstance(obj, dict):
            for k, v in obj.items():
                walk(v, f"{prefix}{k}.")
        else:
            out[prefix[:-1]] = obj

    for name, f in type(cfg).model_fields.items():
        if (f.alias or name) not in NOT_CHANGEABLE:
            walk(getattr(cfg, name), (f.alias or name) + ".")
    return out


def _replaced(obj: Any, parts: Sequence[str], value: float) -> Any:
    """``obj`` with the dotted key ``parts`` set to ``value``, every table on the way validated again."""
    head, rest = parts[0], parts[1:]
    if isinstance(obj, dict):
        return {**obj, head: value if not rest else _replaced(obj[head], rest, value)}
    fields = {(f.alias or k): k for k, f in type(obj).model_fields.items()}
    data = {a: getattr(obj, k) for a, k in fields.items()}
    data[head] = value if not rest else _replaced(data[head], rest, value)
    return type(obj).model_validate(data)


def with_values(cfg: PlantConfig, values: dict[str, float]) -> PlantConfig:
    """``cfg`` with each dotted key of ``values`` set (every table on the way validated again): a
    model updated on estimates, such as the twin's thermal quantities."""
    for key, value in values.items():
        cfg = _replaced(cfg, key.split("."), float(value))
    return cfg


def with_change(cfg: PlantConfig, i: int) -> PlantConfig:
    """``cfg`` with its change ``i`` (``[[changes]]`` entry) at its end value; ScheduleError names the
    entry's key when the key is unknown, not a real number, or its new value is refused."""
    ch = cfg.changes[i]
    known = changeable_keys(cfg)
    where = f"changes.{i}.key"
    if ch.key.split(".")[0] in NOT_CHANGEABLE:
        raise ScheduleError(where, f"{ch.key!r} is in a shared table ({ch.key.split('.')[0]}), not the plant's "
                            "model; a change names a key of the plant's own tables")
    if ch.key not in known:
        near = difflib.get_close_matches(ch.key, [k for k, v in known.items() if type(v) is float], n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise ScheduleError(where, f"unknown key {ch.key!r}{hint}")
    old = known[ch.key]
    if type(old) is not float:
        raise ScheduleError(where, f"{ch.key} is {old!r}, not a real number: only real-valued keys can change")
    new = ch.value if ch.value is not None else old * ch.scale
    try:
        return _replaced(cfg, ch.key.split("."), new)
    except ValidationError as e:
        err = e.errors()[0]
        raise ScheduleError(f"changes.{i}.{'value' if ch.value is not None else 'scale'}",
                            f"{ch.key} = {new:g} is refused: {err['msg'].lower()}") from None


def scheduled_binding(bind: Callable[[PlantConfig], DeviceBinding], cfg: PlantConfig) -> DeviceBinding:
    """The rig binding at the session's start (scheduled effects off, changed keys at their config
    values) with the schedule that moves them to their end values. ``bind`` binds a config as
    written, every effect acting from the start (the plant's ``Plant._binding``)."""
    eff = [i for i, e in enumerate(cfg.effects) if e.timing.scheduled]
    n_ch = len(cfg.changes)
    keys = [f"effects.{i}" for i in eff] + [f"changes.{j}.key" for j in range(n_ch)]
    timings = [cfg.effects[i].timing for i in eff] + [c.timing for c in cfg.changes]
    ends_cfg = [with_change(cfg, j) for j in range(n_ch)]

    def off(e: EffectSpec) -> EffectSpec:
        full = check_spec(e.name, e.params)
        return e.model_copy(update={"params": {p.name: (p.off if p.off is not None else full[p.name])
                                               for p in EFFECTS[e.name].params}})

    def binding_with(ends: frozenset[int]) -> DeviceBinding:
        c = cfg
        for j in range(n_ch):
            if len(eff) + j in ends:
                c = ends_cfg[j]  # one item at its end value at a time (build_schedule asks for no more)
        effects = [off(e) if i in eff and eff.index(i) not in ends else e for i, e in enumerate(cfg.effects)]
        return bind(c.model_copy(update={"effects": effects, "changes": []}))

    schedule = build_schedule(keys, timings, binding_with)
    binding = binding_with(frozenset())
    binding.schedule = schedule
    return binding
