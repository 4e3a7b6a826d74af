"""The library of model effects: what each is, its bounded parameters, and the port kind it needs.

An effect is a model part that attaches to a plant through a typed port (``models/ports.py``):
friction and contact to a joint axis, a delay to the actuator input, backlash to the encoder's
wire, hysteresis to the temperature an SMA's material law sees, convection to a heat input.
Which effects apply to a plant is computed from its ports; no plant or part name appears here.
``attach`` returns a plant's parts with effect parts added (copies: the caller's parts are never
rewired): used for the ``[[effects]]`` of a config (``plants.compose``, every command and the
simulated rig) and by the discrepancy workflow, which attaches every applicable effect disabled
and enables them by editing the parameter vector.
Parameter bounds live here with the effect (documented in docs/discrepancy.md).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from rehab_hil.models.axis_parts import ConstantLoad
from rehab_hil.models.effect_parts import (
    DELAY_SLOTS,
    ActuatorDeadZone,
    Backlash,
    ContactSpringDamper,
    DirectionalCoulombFriction,
    DirectionalViscousFriction,
    NonlinearConvection,
    PassiveMuscle,
    SensorCreepHysteresis,
    SensorGainOffset,
    SmaHysteresis,
    TransportDelay,
)
from rehab_hil.models.mechanics import CoulombFriction, ViscousFriction
from rehab_hil.models.ports import ActuatorPort, AxisPort, HeatPort, MeasuredPort, Ports, TemperatureWire, Wire
from rehab_hil.models.system import DiagramError, Part

__all__ = ["EFFECTS", "Attachment", "Effect", "EffectParam", "applicable", "attach", "check_spec", "nested",
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
    axis_scaled: bool = False  # a force or torque (or a damping): scales with the axis's ``force_scale``


@dataclass(frozen=True)
class Attachment:
    """Where an effect part sits in a diagram, computed from the port it attaches to.

    connect: the effect's inputs from plant signals; output_to: plant signal its output is summed
    onto (None: a signal of its own); insert: the effect goes on this wire (its consumers read the
    effect's output, the effect reads the wire's signal); sum_into: (part, port) pairs the effect's
    own output is added to; fixed: part parameters that are not fitted; xd0: discrete state;
    sense: a measured signal the effect takes over (a sensor's calibration): the plant's producers
    of it are renamed ``<signal>_true`` (and every reader follows), the effect reads that and
    produces the signal under its own name, so the recorded column carries the effect."""

    connect: Mapping[str, Any] = field(default_factory=dict)
    output_to: str | None = None
    insert: Wire | None = None
    sum_into: tuple[tuple[str, str], ...] = ()
    fixed: Mapping[str, float] = field(default_factory=dict)
    xd0: Sequence[float] | None = None
    sense: str | None = None


TRUE_SUFFIX = "_true"  # a sensed signal's true value, once a sensor effect takes the name over
# a force-valued parameter (``EffectParam.axis_scaled``) scales with its axis's ``force_scale`` (a finger
# joint: 1, tenths of a newton metre; a 350 N prismatic drive: 350); a config may give it up to this
# many times its library bound (the fits use the bound times the axis's own scale)
AXIS_SCALE_LIMIT = 1.0e4


@dataclass(frozen=True)
class Effect:
    """A candidate missing effect: its part, fitted parameters, seed, the port kind it needs and how
    it wires onto a port of that kind (``wire(port, step_s) -> Attachment``)."""

    name: str
    part: type[Part]
    params: tuple[EffectParam, ...]
    seed: str
    description: str
    needs: str
    wire: Callable[[Any, float], Attachment]
    # the library effect this one generalises (a level per direction of a Coulomb friction): equal
    # parameters make it that effect, so the two are nested models, never aliases, and the simpler
    # one is named when the two explain the data alike (``nested``)
    refines: str = ""

    def describe(self, vocabulary: Mapping[str, str]) -> tuple[str, str]:
        """(description, source) in a plant's words (``Plant.vocabulary``): a generic drive or axis gets
        the general law and a general reference instead of the finger rigs' seed papers and words."""
        if vocabulary.get("sources", "seed") == "seed" or self.name not in GENERAL:
            return self.description, self.seed
        text, source = GENERAL[self.name]
        return text.format(**vocabulary), source

    def param(self, name: str) -> EffectParam:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)

    def port(self, ports: Ports) -> Any:
        """The port this effect attaches to (the primary one of its kind), or None."""
        found = ports.of_kind(self.needs)
        return found[0] if found else None

    def params_for(self, ports: Ports) -> tuple[EffectParam, ...]:
        """The parameters with the typical magnitudes of the port they attach to (an axis says how
        large its torques are)."""
        port = self.port(ports)
        over = port.typical if isinstance(port, AxisPort) else {}
        k = port.force_scale if isinstance(port, AxisPort) else 1.0
        scaled = [replace(p, lower=p.lower * k, upper=p.upper * k, typical=p.typical * k) if p.axis_scaled and k != 1.0
                  else p for p in self.params]
        return tuple(replace(p, typical=over.get(f"{self.name}.{p.name}", p.typical)) for p in scaled)

    def defaults(self) -> dict[str, float]:
        return {p.name: p.typical for p in self.params}

    def disabled(self) -> dict[str, float]:
        """Parameter values that switch the effect off (shape parameters at their typical value)."""
        return {p.name: (p.off if p.off is not None else p.typical) for p in self.params}


def _coulomb(axis: AxisPort, step_s: float) -> Attachment:
    # Reads the axis's net torque (nominal friction included): inside the stick band a nominal
    # friction already holds what it can, and this one holds only the remainder, so the two never
    # double the holding torque. Its torque goes straight to the integrating port (no loop).
    return Attachment(connect={"velocity_rad_s": axis.velocity, "other_torque_nm": "@applied"},
                      sum_into=(axis.applied,),
                      fixed={"stick_velocity_rad_s": axis.stick_velocity_rad_s,
                             "stick_damping_nm_s_per_rad": axis.stick_damping_nm_s_per_rad})


def _viscous(axis: AxisPort, step_s: float) -> Attachment:
    return Attachment(connect={"velocity_rad_s": axis.velocity}, output_to=axis.torque)


def _viscous_like_load(axis: AxisPort, step_s: float) -> Attachment:
    return Attachment(output_to=axis.torque)


def _joint(axis: AxisPort, step_s: float) -> Attachment:
    return Attachment(connect={"angle_rad": axis.angle, "velocity_rad_s": axis.velocity}, output_to=axis.torque)


def _on_sensor(port: MeasuredPort, step_s: float) -> Attachment:
    assert port.wire is not None
    return Attachment(insert=port.wire)


def _delay(port: ActuatorPort, step_s: float) -> Attachment:
    return Attachment(insert=port.wire, fixed={"step_s": step_s})


def _dead_zone(port: ActuatorPort, step_s: float) -> Attachment:
    return Attachment(insert=port.wire, fixed={"scale": port.duty_scale})


def _sensor_gain(port: MeasuredPort, step_s: float) -> Attachment:
    assert port.wire is not None
    return Attachment(sense=port.wire.signal, fixed={"counts_per_unit": port.counts_per_unit or 1.0})


def _sensor_creep(port: MeasuredPort, step_s: float) -> Attachment:
    assert port.wire is not None
    return Attachment(sense=port.wire.signal, fixed={"counts_per_unit": port.counts_per_unit or 1.0}, xd0=[0.0])


def _hysteresis(port: TemperatureWire, step_s: float) -> Attachment:
    return Attachment(insert=port.wire, xd0=[port.initial_c])


def _convection(port: HeatPort, step_s: float) -> Attachment:
    return Attachment(connect={"temperature_c": port.temperature}, sum_into=(port.into,),
                      fixed={"ambient_c": port.ambient_c}, xd0=[port.ambient_c])


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect(
            "coulomb_friction", CoulombFriction,
            (EffectParam("level_nm", 0.0, 1.0, 0.02, axis_scaled=True),),
            "seed 002 eq 6 (F_c sgn(theta')); seed 001 blames friction",
            "extra Coulomb friction with stiction on the joint axis",
            "axis", _coulomb,
        ),
        Effect(
            "viscous_friction", ViscousFriction,
            (EffectParam("damping_nm_s_per_rad", 0.0, 0.5, 0.02, axis_scaled=True),),
            "seed 002 eq 6-8 (V_c, B_v)",
            "extra viscous friction on the joint axis",
            "axis", _viscous,
        ),
        Effect(
            "coulomb_friction_directional", DirectionalCoulombFriction,
            (EffectParam("level_pos_nm", 0.0, 1.0, 0.02, axis_scaled=True),
             EffectParam("level_neg_nm", 0.0, 1.0, 0.02, axis_scaled=True)),
            "Olsson et al. 1998, Friction models and friction compensation (asymmetric Coulomb levels); issue 38",
            "Coulomb friction with a level per direction of motion (turning +, turning -)",
            "axis", _coulomb, refines="coulomb_friction",
        ),
        Effect(
            "viscous_friction_directional", DirectionalViscousFriction,
            (EffectParam("damping_pos_nm_s_per_rad", 0.0, 0.5, 0.02, axis_scaled=True),
             EffectParam("damping_neg_nm_s_per_rad", 0.0, 0.5, 0.02, axis_scaled=True)),
            "Olsson et al. 1998 (direction-dependent viscous friction); issue 38",
            "viscous friction with a damping per direction of motion",
            "axis", _viscous, refines="viscous_friction",
        ),
        Effect(
            "constant_load", ConstantLoad,
            (EffectParam("level_nm", -1.0, 1.0, 0.01, axis_scaled=True),),
            "Janot, Gautier and Brunot 2019, EMPS eq 1 (the offset)",
            "a constant force or torque against the axis (gravity on a tilted axis, a cable's pull, a drive offset)",
            "axis", _viscous_like_load,
        ),
        Effect(
            "backlash", Backlash,
            (EffectParam("width_rad", 0.0, 0.2, 0.02),),
            "seed 002 sec 2 (chain and sprocket between gearbox and iris)",
            "play between the drive and the measured angle: a dead zone at every reversal",
            "encoder", _on_sensor,
        ),
        Effect(
            "time_delay", TransportDelay,
            (EffectParam("delay_s", 0.0, 0.05, 0.01, linear=False,
                         grid=tuple(round(0.0025 * k, 4) for k in range(1, 20))),),
            "seed 002 sec 4.2 (the hardware lags the simulation)",
            f"transport delay on the actuator input (FIFO of {DELAY_SLOTS - 1} steps)",
            "actuator", _delay,
        ),
        Effect(
            "contact_spring_damper", ContactSpringDamper,
            (EffectParam("stiffness_nm_per_rad", 0.0, 20.0, 0.5, axis_scaled=True),
             EffectParam("damping_nm_s_per_rad", 0.0, 2.0, 0.02, axis_scaled=True),
             EffectParam("contact_angle_rad", -0.5, 3.0, 0.5, linear=False, off=None,
                         grid=(0.0, 0.4, 0.8, 1.2, 1.6))),
            "seed 000 eq 18-28 and Table 4 (contact force k dx + c dx', k and c by regression)",
            "one-sided spring-damper of the patient's finger beyond a contact angle",
            "axis", _joint,
        ),
        Effect(
            "passive_muscle", PassiveMuscle,
            (EffectParam("scale_nm", 0.0, 1.0, 0.005),
             EffectParam("shape_per_rad", 0.1, 10.0, 2.0, linear=False, off=None, grid=(1.0, 2.0, 4.0)),
             EffectParam("damping_nm_s_per_rad", 0.0, 0.1, 0.001)),
            "seed 000 eq 1-3, Table 1 (Hill passive muscle force)",
            "exponential passive joint torque of the finger's muscles and tendons (MCP joint)",
            "finger_axis", _joint,
        ),
        Effect(
            "sma_hysteresis", SmaHysteresis,
            (EffectParam("width_c", 0.0, 40.0, 5.0),),
            "seed 000 eq 14-17, Table 2 (A_s, A_f, M_s, M_f)",
            "transformation hysteresis: heating and cooling see temperatures width_c apart",
            "transformation_temperature", _hysteresis,
        ),
        Effect(
            "nonlinear_convection", NonlinearConvection,
            (EffectParam("coefficient_w_per_k3", 0.0, 1e-3, 1e-5),),
            "seed 000 eq 13 (h = h1 + h2 T^2); seed 001 sec 4 (error grows with power)",
            "heat loss growing with the cube of the temperature rise",
            "heat", _convection,
        ),
        Effect(
            "actuator_dead_zone", ActuatorDeadZone,
            (EffectParam("width_duty", 0.0, 0.3, 0.02),),
            "Tao & Kokotovic 1996 (dead-zone model); H-bridge dead time and MOSFET threshold of the PWM driver",
            "dead zone of the PWM power stage, both signs: |command| below width x full scale gives nothing",
            "actuator", _dead_zone,
        ),
        Effect(
            "sensor_gain_offset", SensorGainOffset,
            (EffectParam("gain_error_fraction", -0.5, 0.5, 0.05),
             EffectParam("offset_counts", -300.0, 300.0, 5.0)),
            "Tekscan FlexiForce manual (sensitivity drift, zero offset); seed 000 sec III.A (Flexiforce A201)",
            "calibration drift of the ADC sensor: gain error and zero offset (in ADC counts)",
            "adc", _sensor_gain,
        ),
        Effect(
            "sensor_creep_hysteresis", SensorCreepHysteresis,
            (EffectParam("creep_fraction", 0.0, 0.3, 0.03),
             EffectParam("creep_time_s", 0.2, 60.0, 5.0, linear=False, off=None, grid=(1.0, 3.0, 6.0, 15.0)),
             EffectParam("hysteresis_counts", 0.0, 300.0, 10.0)),
            "Dickmann et al. 2021 (FlexiForce A201 dead-weight staircases: ~3 % creep in 5 s, loading/unloading "
            "hysteresis); Tekscan FlexiForce manual (drift, hysteresis)",
            "force sensor creep (the reading drifts by a fraction of the load with a time constant) and "
            "loading/unloading hysteresis (unloading reads higher, in ADC counts)",
            "adc", _sensor_creep,
        ),
    ]
}


# the effects that attach to a generic drive or axis, in general words ({axis}, {actuator}: Plant.vocabulary)
GENERAL: dict[str, tuple[str, str]] = {
    "coulomb_friction": ("extra Coulomb friction with stiction on the {axis}",
                         "Coulomb friction F_c sgn(v) with a Karnopp stick band (Karnopp 1985; EMPS eq 1: F_c)"),
    "viscous_friction": ("extra viscous friction on the {axis}", "viscous friction F_v v (EMPS eq 1: F_v)"),
    "constant_load": ("a constant force or torque against the {axis} (gravity on a tilted axis, a cable, a "
                      "drive offset)", "Janot, Gautier and Brunot 2019, EMPS eq 1 (the offset)"),
    "contact_spring_damper": ("one-sided spring-damper beyond a contact position of the {axis} (an end stop, "
                              "a load met on the way)", "one-sided Kelvin-Voigt contact k dx + c dx'"),
    "time_delay": ("transport delay on the {actuator}'s input", "transport delay (dead time) of the command"),
    "actuator_dead_zone": ("dead zone of the {actuator}, both signs: a command below width x full scale gives "
                           "nothing", "Tao & Kokotovic 1996 (dead-zone model)"),
    "backlash": ("play between the drive and the measured position: a dead zone at every reversal",
                 "play (backlash) operator, Tao & Kokotovic 1996"),
}


def nested(a: str, b: str) -> bool:
    """Does one of the two effects generalise the other (``Effect.refines``)?"""
    ea, eb = EFFECTS.get(a), EFFECTS.get(b)
    return bool((ea is not None and ea.refines == b) or (eb is not None and eb.refines == a))


def applicable(ports: Ports) -> list[Effect]:
    """Library effects that attach to a plant with these ports."""
    kinds = ports.kinds()
    return [e for e in EFFECTS.values() if e.needs in kinds]


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
        lo, hi = (p.lower * AXIS_SCALE_LIMIT, p.upper * AXIS_SCALE_LIMIT) if p.axis_scaled else (p.lower, p.upper)
        if not (lo <= v <= hi):
            raise ValueError(f"effect {name!r}: {k} = {v} is outside [{lo:g}, {hi:g}]")
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


def not_applicable_message(name: str, plant: str, ports: Ports) -> str:
    """The one-line refusal of an effect a plant has no port for."""
    ok = sorted(e.name for e in applicable(ports))
    return (f"effect {name!r} does not apply to plant {plant!r} (it needs a {EFFECTS[name].needs!r} port); "
            f"applicable: {ok}")


def attach(plant: str, ports: Ports, step_s: float, parts: list[Part],
           effects: Sequence[tuple[str, Mapping[str, float]]], prefix: str = "effect") -> list[Part]:
    """A new part list: copies of ``parts`` plus one part per (effect name, parameters), wired onto
    the plant's ports. The caller's parts are left as they were (an effect rewires the copies'
    connections and signal names), so the nominal list can be kept or attached to again.

    Parts are named ``<prefix>_<effect>`` (``_<i>`` added for repeats). Raises DiagramError when the
    plant has no port of the kind an effect needs."""
    parts = copy.deepcopy(list(parts))  # parts hold names and numpy arrays; their kernels are class attributes
    by_name = {p.name: p for p in parts}
    used: set[str] = set(by_name)
    # sensor effects take a signal's name over: everything that sums onto it must be in place first
    effects = sorted(effects, key=lambda e: e[0] in EFFECTS and EFFECTS[e[0]].wire in (_sensor_gain, _sensor_creep))
    for name, given in effects:
        try:
            values = check_spec(name, given)
        except ValueError as e:
            raise DiagramError(str(e)) from None
        eff = EFFECTS[name]
        port = eff.port(ports)
        if port is None:
            raise DiagramError(not_applicable_message(name, plant, ports))
        att = eff.wire(port, step_s)
        pname = f"{prefix}_{name}"
        i = 1
        while pname in used:
            i += 1
            pname = f"{prefix}_{name}_{i}"
        used.add(pname)
        own_out = f"{pname}_{eff.part.outputs[0]}"
        sensed = _sensed(parts)  # signals a sensor effect took over: plant terms go to the true value
        connect: dict[str, Any] = {}
        for k, v in att.connect.items():  # "@applied": the terms that feed the axis's integrating port
            connect[k] = list(_port(by_name, att.sum_into[0], name)) if v == "@applied" else sensed.get(v, v)
        fixed = dict(att.fixed)
        if att.sense is not None:
            produced = any(att.sense in p.signal_names for p in parts)
            fixed["invert"] = 0.0 if produced else 1.0
            if produced:  # the model computes the true value: the effect makes the recorded one
                connect[eff.part.inputs[0]] = _take_over(parts, att.sense)
            else:  # a recorded input: the model's readers see the true value the effect recovers
                connect[eff.part.inputs[0]] = att.sense
                for p in parts:
                    for terms in p.connections.values():
                        terms[:] = [(own_out if s == att.sense else s, w) for s, w in terms]
        if att.insert is not None:
            feeds = [_port(by_name, c, name) for c in att.insert.consumers]
            connect[eff.part.inputs[0]] = list(feeds[0])
            for terms in feeds:
                terms[:] = [(own_out, 1.0)]
        out = (att.sense if fixed.get("invert") == 0.0 else None) or \
            (sensed.get(att.output_to, att.output_to) if att.output_to else None)
        rename = {eff.part.outputs[0]: out or own_out}
        for target in att.sum_into:
            _port(by_name, target, name).append((own_out, 1.0))
        part = eff.part(pname, connect=connect, rename=rename, xd0=att.xd0, **fixed, **values)
        parts.append(part)
        by_name[pname] = part
    return parts


def _sensed(parts: Sequence[Part]) -> dict[str, str]:
    """Signals already taken over by a sensor effect -> the name their true value now has."""
    return {p.signal_names[0]: p.connections["u"][0][0] for p in parts
            if getattr(p, "sensor_effect", False) and p.param_values[p.params.index("invert")] < 0.5}


def _take_over(parts: Sequence[Part], signal: str) -> str:
    """Rename every producer and reader of ``signal`` to ``<signal>_true``; returns that name."""
    true = signal + TRUE_SUFFIX
    k = 1
    while any(true in p.signal_names for p in parts):  # a second sensor effect on the same signal
        k += 1
        true = f"{signal}{TRUE_SUFFIX}{k}"
    for p in parts:
        p.signal_names = tuple(true if s == signal else s for s in p.signal_names)
        for terms in p.connections.values():
            terms[:] = [(true if s == signal else s, w) for s, w in terms]
    return true


def _port(by_name: Mapping[str, Part], where: tuple[str, str], effect: str) -> list[tuple[str, float]]:
    """The connection list of a (part, input) a port names."""
    part, port = where
    if part not in by_name or port not in by_name[part].connections:
        raise DiagramError(f"effect {effect!r}: the plant's port names {part}.{port}, which its parts lack")
    return by_name[part].connections[port]
