"""From a config to a checked controller: settings validated at load, a pre-flight run on the model.

``validate_controllers`` checks every ``[controllers.<name>]`` table against its controller's
schema and ``[rig.session] controller`` against the registry when a config loads, naming the
file and key. ``build_controller`` builds one for the config's plant and reference and refuses,
in one line, a controller that does not apply: one the plant cannot carry (``refuse``), or one
that on the model would trip the rig's own limits (range of motion, heating time, temperature)
before anything moves.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.config import ConfigError, validate
from rehab_hil.controllers.base import (
    ControlContext,
    Controller,
    ControllerError,
    Reference,
    closed_loop,
    get_controller,
    safety_temperature,
)
from rehab_hil.plants.sections import PlantConfig
from rehab_hil.progress import announce

__all__ = ["PREFLIGHT_MAX_S", "Sources", "build_controller", "preflight", "preflight_duration_s", "settings_for",
           "validate_controllers"]

PREFLIGHT_MAX_S = 240.0  # the pre-flight run covers the rest, two periods and a hold, at most this long [s]


def validate_controllers(cfg: PlantConfig, path: Any) -> PlantConfig:
    """The config with each ``[controllers.<name>]`` table validated (ConfigError naming the key)."""
    validated = {}
    for name, table in cfg.controllers.items():
        spec = get_controller(name, str(path), key=f"controllers.{name}")
        if spec.settings is None:
            raise ConfigError(path, f"controllers.{name}", f"controller {name!r} takes no settings")
        validated[name] = validate(path, table, spec.settings, prefix=f"controllers.{name}.") \
            if isinstance(table, dict) else table
    ses = cfg.rig.session
    if ses is not None:
        get_controller(ses.controller, str(path))
    return cfg.model_copy(update={"controllers": validated})


def settings_for(cfg: PlantConfig, name: str, source: str = "<config>") -> Any:
    """The validated ``[controllers.<name>]`` table; a controller with settings needs its table."""
    spec = get_controller(name, source, key="--controller")
    if spec.settings is None:
        return None
    got = cfg.controllers.get(name)
    if got is None:
        raise ConfigError(source, f"controllers.{name}", f"missing table: controller {name!r} needs its settings "
                          f"({', '.join(spec.settings.model_fields)})")
    return got if not isinstance(got, dict) else validate(source, got, spec.settings, prefix=f"controllers.{name}.")


@dataclass(frozen=True)
class Sources:
    """Where a session's settings come from, for messages: the plant config's path and, when a
    patient profile is applied, its path and which rig keys it set (rig key -> the profile's key)."""

    config: str = "<config>"
    profile: str | None = None
    profile_keys: Mapping[str, str] = field(default_factory=dict)

    def where(self, rig_key: str) -> str:
        """``file: key`` of the setting behind ``rig_key`` (``rig.session.open_deg``): the profile's
        key when the profile set it, else the config's."""
        if self.profile is not None and rig_key in self.profile_keys:
            return f"{self.profile}: {self.profile_keys[rig_key]}"
        return f"{self.config}: {rig_key}"


def build_controller(cfg: PlantConfig, name: str | None = None, reference: Reference | None = None,
                     source: str = "<config>", check: bool = True, sources: Sources | None = None) -> Controller:
    """The controller ``name`` (default: ``[rig.session] controller``) for the config's plant and
    ``reference`` (default: the session's cycles), refused if it does not apply. ``sources`` (the
    config and the profile applied) name the file and key a refusal comes from."""
    if cfg.rig.session is None:
        raise ControllerError(f"{source}: the config has no [rig.session] table (what a session does)")
    name = name or cfg.rig.session.controller
    spec = get_controller(name, source, key="--controller" if name != cfg.rig.session.controller else
                          "rig.session.controller")
    ctx = ControlContext.of(cfg, source)
    why = spec.refuse(ctx)
    if why:
        raise ControllerError(f"controller {name!r} does not apply to plant {cfg.plant!r}: {why}")
    controller = spec.build(ctx, settings_for(cfg, name, source), reference or Reference.session(cfg))
    if check:
        with announce(f"pre-flight: controller {name!r} on the model over "
                      f"{preflight_duration_s(controller.reference):.0f} s, against the rig's limits"):
            preflight(controller, sources or Sources(source))
    return controller


@dataclass(frozen=True)
class Trip:
    """A limit the pre-flight run would trip: when, what, the setting behind it, what would pass."""

    t_s: float
    what: str
    key: str
    passes: str


def preflight_duration_s(reference: Reference) -> float:
    """The pre-flight run: the rest before the first move, two cycles (the second starts from the
    first's end state: a wire still warm), and the longest hold once more [s]."""
    longest_hold = max(reference.hold_open_s, reference.hold_closed_s)
    return min(reference.first_open_s + 2.0 * reference.period_s + longest_hold, PREFLIGHT_MAX_S)


def preflight(controller: Controller, sources: Sources | None = None) -> None:
    """Run the controller on the model over ``preflight_duration_s`` and refuse it, naming the rig
    limit it would trip first and when, the file and key behind it and what would pass (the
    supervisor's checks, on the model)."""
    ctx = controller.ctx
    src = sources or Sources(ctx.source)
    res = closed_loop(controller, preflight_duration_s(controller.reference))
    trips = [x for x in (_range_trip(ctx, res, src), _heating_trip(ctx, res, src),
                         _temperature_trip(ctx, res, src, controller.name)) if x is not None]
    if trips:
        first = min(trips, key=lambda x: x.t_s)
        raise ControllerError(f"controller {controller.name!r} does not apply to plant {ctx.cfg.plant!r}: run on the "
                              f"model it {first.what} at {first.t_s:.2f} s, a safety trip on the rig; cause: "
                              f"{first.key}; would pass: {first.passes}")


def _range_trip(ctx: ControlContext, res: Any, src: Sources) -> Trip | None:
    lo, hi = ctx.angle_limits_deg
    angle = res[ctx.angle]
    out = np.flatnonzero((angle < lo) | (angle > hi))
    if not out.size:
        return None
    k = int(out[0])
    side = "max" if angle[k] > hi else "min"
    extreme = float(np.max(angle) if side == "max" else np.min(angle))
    margin = ctx.cfg.rig.host.angle_margin_deg if ctx.cfg.rig.host else 0.0
    need = extreme + margin if side == "max" else extreme - margin
    return Trip(float(res.t[k]), f"leaves the range of motion ({ctx.angle} {angle[k]:.1f} deg outside {lo:g}..{hi:g} "
                f"deg)", src.where(f"rig.limits.{side}_angle_deg"),
                f"{side}_angle_deg {'>=' if side == 'max' else '<='} {need:.1f} deg (the model reaches {extreme:.1f})")


def _heating_trip(ctx: ControlContext, res: Any, src: Sources) -> Trip | None:
    duty = np.abs(res[ctx.effort]) > 0.0
    limit = ctx.cfg.rig.host_limits().max_heating_s
    runs = _runs(duty)
    longest = max((b - a for a, b in runs), default=0) * ctx.step_s
    if longest < limit:
        return None
    start = next(a for a, b in runs if (b - a) * ctx.step_s >= limit)
    t = float(res.t[start]) + limit - ctx.step_s
    margin = ctx.cfg.rig.limits.max_heating_s - limit  # the host margin
    return Trip(t, f"heats continuously for {limit:g} s (rig.limits.max_heating_s less the host margin)",
                src.where("rig.session.cycles_per_minute"),
                f"a continuous run of {longest:.2f} s needs rig.limits.max_heating_s >= {longest + margin:.2f} s, "
                "or a session whose holds are shorter")


def _runs(on: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) index pairs of each run of True in ``on``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _temperature_trip(ctx: ControlContext, res: Any, src: Sources, name: str) -> Trip | None:
    lim = ctx.cfg.rig.limits
    est = safety_temperature(ctx.cfg, res[ctx.effort], ctx.ports.actuators[0].duty_scale, ctx.step_s, lim.max_duty)
    if est is None:
        return None
    over = np.flatnonzero(est > lim.max_temperature_c)
    if not over.size:
        return None
    return Trip(float(res.t[int(over[0])]), f"heats the actuator past {lim.max_temperature_c:g} C (the host's "
                "temperature estimate)", src.where("rig.limits.max_temperature_c"),
                f"the estimate peaks at {float(np.max(est)):.1f} C: a controller that heats less "
                f"([controllers.{name}] in {src.config}, the session's pace) or a limit above it")
