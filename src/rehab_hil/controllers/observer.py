"""The model's thermal part as an observer: the plant parts between the actuator and its temperature.

An SMA wire or a TCP coil only heats; how hot it is decides what it does next and whether it is
safe. The rig measures no temperature, so a controller runs the model's own thermal part on the
effort it applies: the parts of the composed (possibly augmented) plant that lead from the
actuator input to the temperature signal, copied under new names. A fitted convection effect or
corrected h1 changes the observer by itself. A plant whose temperature depends on more than the
actuator and config constants (a mechanical state) has no such slice: ``thermal_slice`` is None.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence

from rehab_hil.models.ports import Ports
from rehab_hil.models.system import Part

__all__ = ["OBSERVER", "temperature_signal", "thermal_slice"]

OBSERVER = "observer_"  # prefix of the observer's parts and signals


def temperature_signal(ports: Ports) -> str | None:
    """The actuator temperature the plant models (what its material law or heat port sees)."""
    if ports.transformation_temperature:
        return ports.transformation_temperature[0].wire.signal
    if ports.heat:
        return ports.heat[0].temperature
    return None


def thermal_slice(parts: Sequence[Part], effort: str, temperature: str, constants: Mapping[str, float],
                  mechanical: Sequence[str] = ()) -> list[Part] | None:
    """Copies of the parts that compute ``temperature`` from ``effort`` and ``constants`` only,
    their signals prefixed ``observer_`` (the observer's temperature is ``observer_<temperature>``);
    None when the temperature depends on anything else (an unknown input, or one of the
    ``mechanical`` signals: a joint's angle, velocity or torque)."""
    producers: dict[str, list[Part]] = {}
    for p in parts:
        for s in p.signal_names:
            producers.setdefault(s, []).append(p)
    needed: dict[str, Part] = {}
    todo = [temperature]
    seen: set[str] = set()
    while todo:
        sig = todo.pop()
        if sig in seen or sig == effort or sig in constants:
            continue
        seen.add(sig)
        if sig not in producers or sig in mechanical:
            return None  # not computable from the effort alone
        for p in producers[sig]:
            if p.name in needed:
                continue
            needed[p.name] = p
            for terms in p.connections.values():
                todo.extend(s for s, _ in terms)
    if not any(p.states for p in needed.values()):
        return None
    inside = {s for p in needed.values() for s in p.signal_names}
    out: list[Part] = []
    for p in parts:  # the plant's order
        if p.name not in needed:
            continue
        q = copy.deepcopy(p)
        q.name = OBSERVER + p.name
        q.signal_names = tuple(OBSERVER + s for s in p.signal_names)
        q.connections = {port: [((OBSERVER + s) if s in inside else s, w) for s, w in terms]
                         for port, terms in p.connections.items()}
        out.append(q)
    return out
