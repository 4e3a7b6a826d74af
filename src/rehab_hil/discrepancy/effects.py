"""The library of candidate effects: what each is, its bounded parameters, where it attaches.

An effect is a model part plus, per plant it applies to, an attachment: which signals it reads,
where its output goes (summed onto a torque or heat signal, or inserted on a wire such as the
actuator input or the measured angle), and the part parameters that come from the plant config
rather than the fit. Parameter bounds live here with the effect (documented in docs/discrepancy.md).
``attach`` appends effect parts to a plant's parts; it is used for the ``effects`` list of a
config (every command) and by the discrepancy workflow, which attaches every applicable effect
disabled and enables them by editing the parameter vector.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from rehab_hil.discrepancy.parts import (
    DELAY_SLOTS,
    Backlash,
    ContactSpringDamper,
    NonlinearConvection,
    PassiveMuscle,
    SmaHysteresis,
    TransportDelay,
)
from rehab_hil.models.mechanics import CoulombFriction, ViscousFriction
from rehab_hil.models.system import DiagramError, Part

__all__ = ["EFFECTS", "Attachment", "Effect", "EffectParam", "applicable", "attach", "check_spec",
           "parse_effect_option"]


@dataclass(frozen=True)
class EffectParam:
    """A fitted parameter: SI unit in the name, bounds, a typical magnitude (start and scale).

    ``linear`` marks parameters the output responds to about linearly near zero (fitted first by
    regression on the residual); the others are scanned over ``grid`` values. ``off`` is the
    value at which the effect does nothing (only magnitude parameters have one)."""

    name: str
    lower: float
    upper: float
    typical: float
    linear: bool = True
    off: float | None = 0.0
    grid: tuple[float, ...] = ()


@dataclass(frozen=True)
class Attachment:
    """Where an effect part sits in one plant's diagram.

    connect: the effect's inputs from plant signals; output_to: plant signal its output is summed
    onto (None: a signal of its own); insert: (part, port, effect input) puts the effect on the
    wire feeding that port; sum_into: (part, port) adds the effect's own output signal to that
    port; fixed: config -> part parameters that are not fitted; xd0: config -> discrete state."""

    connect: Mapping[str, Any] = field(default_factory=dict)
    output_to: str | None = None
    insert: tuple[Any, ...] | None = None
    sum_into: tuple[Any, ...] | None = None
    fixed: Callable[[Any], dict[str, float]] = lambda cfg: {}
    xd0: Callable[[Any], Sequence[float]] | None = None
    typical: Mapping[str, float] = field(default_factory=dict)  # per-plant typical magnitudes


@dataclass(frozen=True)
class Effect:
    """A candidate missing effect: its part, fitted parameters, seed, and plant attachments."""

    name: str
    part: type[Part]
    params: tuple[EffectParam, ...]
    seed: str
    description: str
    attachments: Mapping[str, Attachment]

    def param(self, name: str) -> EffectParam:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)

    def params_for(self, plant: str) -> tuple[EffectParam, ...]:
        """The parameters with this plant's typical magnitudes (a finger's joint torques are
        milli-newton-metres where the Finger Extensor's are tenths)."""
        over = self.attachments[plant].typical if plant in self.attachments else {}
        return tuple(replace(p, typical=over.get(p.name, p.typical)) for p in self.params)

    def defaults(self) -> dict[str, float]:
        return {p.name: p.typical for p in self.params}

    def disabled(self) -> dict[str, float]:
        """Parameter values that switch the effect off (shape parameters at their typical value)."""
        return {p.name: (p.off if p.off is not None else p.typical) for p in self.params}


# Finger Extensor (plants/finger_extensor.py): part names iris, motor, encoder; torques on
# drive_torque_nm, nominal Coulomb friction on friction_torque_nm.
def _fe_stick(cfg: Any) -> dict[str, float]:
    return {"stick_velocity_rad_s": cfg.iris.stick_velocity_rad_s,
            "stick_damping_nm_s_per_rad": cfg.iris.stick_damping_nm_s_per_rad}


def _fe_step(cfg: Any) -> dict[str, float]:
    return {"step_s": cfg.simulation.step_s}


_FE_COULOMB = Attachment(
    # Reads the nominal friction too: inside the stick band the nominal part already holds what it
    # can, and this one holds only the remainder, so the two never double the holding torque.
    connect={"velocity_rad_s": "iris_velocity_rad_s", "other_torque_nm": ["drive_torque_nm", "friction_torque_nm"]},
    sum_into=("iris", "torque_nm"), fixed=_fe_stick)
_FE_VISCOUS = Attachment(connect={"velocity_rad_s": "iris_velocity_rad_s"}, output_to="drive_torque_nm")
_FE_BACKLASH = Attachment(insert=("encoder", "angle_rad", "angle_rad"))
_FE_DELAY = Attachment(insert=("motor", "voltage_v", "u"), fixed=_fe_step)
_FE_CONTACT = Attachment(connect={"angle_rad": "iris_angle_rad", "velocity_rad_s": "iris_velocity_rad_s"},
                         output_to="drive_torque_nm")

# SMA exoskeleton (plants/sma_exoskeleton.py): sma_thermal (duty, voltage_v) -> sma_temperature_c ->
# sma_active (Tanaka wire); joint torques on tau_<joint>_nm. The MCP joint carries the joint effects.
_SMA_DELAY = Attachment(insert=("sma_thermal", "duty", "u"), fixed=_fe_step)
_SMA_HYST = Attachment(insert=("sma_active", "temperature_c", "temperature_c"),
                       xd0=lambda cfg: [cfg.sma.ambient_c])
_SMA_MCP = {"angle_rad": "theta_mcp_rad", "velocity_rad_s": "omega_mcp_rad_s"}
_SMA_VISCOUS = Attachment(connect={"velocity_rad_s": "omega_mcp_rad_s"}, output_to="tau_mcp_nm",
                          typical={"damping_nm_s_per_rad": 0.005})
_SMA_JOINT = Attachment(connect=_SMA_MCP, output_to="tau_mcp_nm",
                        typical={"stiffness_nm_per_rad": 0.05, "damping_nm_s_per_rad": 0.002, "scale_nm": 0.002})

# TCP finger (plants/tcp_finger.py): power_w -> thermal model ("tf1" transfer function, or "thermal"
# lumped) -> tcp_temperature_c -> tf2 -> tcp_force_n -> tendon; joint torques on tau<i>_nm.
_TCP_THERMAL_IN = (("tf1", "u"), ("thermal", "power_w"))
_TCP_DELAY = Attachment(insert=(("tf1", "u", "u"), ("thermal", "power_w", "u")), fixed=_fe_step)
_TCP_CONVECTION = Attachment(connect={"temperature_c": "tcp_temperature_c"}, sum_into=_TCP_THERMAL_IN,
                             fixed=lambda cfg: {"ambient_c": cfg.muscle.ambient_c},
                             xd0=lambda cfg: [cfg.muscle.ambient_c])
_TCP_MCP = {"angle_rad": "theta_mcp_rad", "velocity_rad_s": "omega_mcp_rad_s"}
_TCP_VISCOUS = Attachment(connect={"velocity_rad_s": "omega_mcp_rad_s"}, output_to="tau1_nm",
                          typical={"damping_nm_s_per_rad": 0.0005})
_TCP_JOINT = Attachment(connect=_TCP_MCP, output_to="tau1_nm",
                        typical={"scale_nm": 0.001, "damping_nm_s_per_rad": 0.0002})

EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect(
            "coulomb_friction", CoulombFriction,
            (EffectParam("level_nm", 0.0, 1.0, 0.02),),
            "seed 002 eq 6 (F_c sgn(theta')); seed 001 blames friction",
            "extra Coulomb friction with stiction on the joint axis",
            {"finger_extensor": _FE_COULOMB},
        ),
        Effect(
            "viscous_friction", ViscousFriction,
            (EffectParam("damping_nm_s_per_rad", 0.0, 0.5, 0.02),),
            "seed 002 eq 6-8 (V_c, B_v)",
            "extra viscous friction on the joint axis",
            {"finger_extensor": _FE_VISCOUS, "sma_exoskeleton": _SMA_VISCOUS, "tcp_finger": _TCP_VISCOUS},
        ),
        Effect(
            "backlash", Backlash,
            (EffectParam("width_rad", 0.0, 0.2, 0.02),),
            "seed 002 sec 2 (chain and sprocket between gearbox and iris)",
            "play between the drive and the measured angle: a dead zone at every reversal",
            {"finger_extensor": _FE_BACKLASH},
        ),
        Effect(
            "time_delay", TransportDelay,
            (EffectParam("delay_s", 0.0, 0.05, 0.01, linear=False,
                         grid=(0.002, 0.005, 0.01, 0.02, 0.035)),),
            "seed 002 sec 4.2 (the hardware lags the simulation)",
            f"transport delay on the actuator input (FIFO of {DELAY_SLOTS - 1} steps)",
            {"finger_extensor": _FE_DELAY, "sma_exoskeleton": _SMA_DELAY, "tcp_finger": _TCP_DELAY},
        ),
        Effect(
            "contact_spring_damper", ContactSpringDamper,
            (EffectParam("stiffness_nm_per_rad", 0.0, 20.0, 0.5),
             EffectParam("damping_nm_s_per_rad", 0.0, 2.0, 0.02),
             EffectParam("contact_angle_rad", -0.5, 3.0, 0.5, linear=False, off=None,
                         grid=(0.0, 0.4, 0.8, 1.2, 1.6))),
            "seed 000 eq 18-28 and Table 4 (contact force k dx + c dx', k and c by regression)",
            "one-sided spring-damper of the patient's finger beyond a contact angle",
            {"finger_extensor": _FE_CONTACT, "sma_exoskeleton": _SMA_JOINT},
        ),
        Effect(
            "passive_muscle", PassiveMuscle,
            (EffectParam("scale_nm", 0.0, 1.0, 0.005),
             EffectParam("shape_per_rad", 0.1, 10.0, 2.0, linear=False, off=None, grid=(1.0, 2.0, 4.0)),
             EffectParam("damping_nm_s_per_rad", 0.0, 0.1, 0.001)),
            "seed 000 eq 1-3, Table 1 (Hill passive muscle force)",
            "exponential passive joint torque of the finger's muscles and tendons (MCP joint)",
            {"sma_exoskeleton": _SMA_JOINT, "tcp_finger": _TCP_JOINT},
        ),
        Effect(
            "sma_hysteresis", SmaHysteresis,
            (EffectParam("width_c", 0.0, 40.0, 5.0),),
            "seed 000 eq 14-17, Table 2 (A_s, A_f, M_s, M_f)",
            "transformation hysteresis: heating and cooling see temperatures width_c apart",
            {"sma_exoskeleton": _SMA_HYST},
        ),
        Effect(
            "nonlinear_convection", NonlinearConvection,
            (EffectParam("coefficient_w_per_k3", 0.0, 1e-3, 1e-5),),
            "seed 000 eq 13 (h = h1 + h2 T^2); seed 001 sec 4 (error grows with power)",
            "heat loss growing with the cube of the temperature rise",
            {"tcp_finger": _TCP_CONVECTION},
        ),
    ]
}


def applicable(plant: str) -> list[Effect]:
    """Library effects that attach to ``plant``."""
    return [e for e in EFFECTS.values() if plant in e.attachments]


def check_spec(name: str, params: Mapping[str, float]) -> dict[str, float]:
    """Validate an effect name and parameters (bounds included); returns the full parameter set.

    Unnamed parameters take the effect's typical value. Raises ValueError with a clear message."""
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; the library has {sorted(EFFECTS)}")
    eff = EFFECTS[name]
    known = {p.name for p in eff.params}
    unknown = sorted(set(params) - known)
    if unknown:
        raise ValueError(f"effect {name!r} has no parameters {unknown}; its parameters are {sorted(known)}")
    out = eff.defaults()
    for k, v in params.items():
        p = eff.param(k)
        v = float(v)
        if not (p.lower <= v <= p.upper):
            raise ValueError(f"effect {name!r}: {k} = {v} is outside [{p.lower}, {p.upper}]")
        out[k] = v
    return out


def parse_effect_option(text: str) -> tuple[str, dict[str, float]]:
    """Parse ``name:key=value,key=value`` (the ``--effect`` option of ``simulate``)."""
    name, _, rest = text.partition(":")
    params: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise ValueError(f"--effect {text!r}: expected key=value, got {item!r}")
        try:
            params[key.strip()] = float(val)
        except ValueError:
            raise ValueError(f"--effect {text!r}: {key.strip()} is not a number: {val!r}") from None
    check_spec(name.strip(), params)
    return name.strip(), params


def attach(plant: str, cfg: Any, parts: list[Part], effects: Sequence[tuple[str, Mapping[str, float]]],
           prefix: str = "effect") -> list[Part]:
    """Append one part per (effect name, parameters) to ``parts``, rewiring as each attachment says.

    Parts are named ``<prefix>_<effect>`` (``_<i>`` added for repeats). Raises DiagramError when an
    effect does not apply to the plant."""
    parts = list(parts)
    by_name = {p.name: p for p in parts}
    used: set[str] = set(by_name)
    for name, given in effects:
        try:
            values = check_spec(name, given)
        except ValueError as e:
            raise DiagramError(str(e)) from None
        eff = EFFECTS[name]
        att = eff.attachments.get(plant)
        if att is None:
            ok = [e.name for e in applicable(plant)]
            raise DiagramError(f"effect {name!r} does not apply to plant {plant!r}; applicable: {ok}")
        pname = f"{prefix}_{name}"
        i = 1
        while pname in used:
            i += 1
            pname = f"{prefix}_{name}_{i}"
        used.add(pname)
        own_out = f"{pname}_{eff.part.outputs[0]}"
        connect = dict(att.connect)
        if att.insert is not None:
            target, port, inport = _pick(by_name, att.insert, name)
            tp = by_name[target]
            connect[inport] = list(tp.connections[port])
            tp.connections[port] = [(own_out, 1.0)]
        rename = {eff.part.outputs[0]: att.output_to or own_out}
        if att.sum_into is not None:
            target, port = _pick(by_name, att.sum_into, name)
            by_name[target].connections[port].append((own_out, 1.0))
        xd0 = att.xd0(cfg) if att.xd0 else None
        part = eff.part(pname, connect=connect, rename=rename, xd0=xd0, **att.fixed(cfg), **values)
        parts.append(part)
        by_name[pname] = part
    return parts


def _pick(by_name: Mapping[str, Part], where: tuple[Any, ...], effect: str) -> tuple[str, ...]:
    """The first alternative whose part exists: ``where`` is (part, port, ...) or a tuple of them
    (a plant whose parts depend on its config, e.g. the TCP finger's thermal model)."""
    options = where if isinstance(where[0], tuple) else (where,)
    for opt in options:
        if opt[0] in by_name:
            return opt
    raise DiagramError(f"effect {effect!r} attaches to part {options[0][0]!r}, which the plant does not have")
