"""From a config to a checked controller: settings validated at load, a pre-flight run on the model.

``validate_controllers`` checks every ``[controllers.<name>]`` table against its controller's
schema and ``[rig.session] controller`` against the registry when a config loads, naming the
file and key. ``build_controller`` builds one for the config's plant and reference and refuses,
in one line, a controller that does not apply: one the plant cannot carry (``refuse``), or one
that on the model would trip the rig's own limits (range of motion, heating time, temperature)
before anything moves.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rehab_hil.config import ConfigError, validate
from rehab_hil.control.thermal import thermal_from_config
from rehab_hil.controllers.base import (
    ControlContext,
    Controller,
    ControllerError,
    Reference,
    closed_loop,
    get_controller,
)
from rehab_hil.plants.sections import PlantConfig

__all__ = ["PREFLIGHT_MAX_S", "build_controller", "preflight", "settings_for", "validate_controllers"]

PREFLIGHT_MAX_S = 120.0  # the pre-flight run covers the rest and one reference period, at most this long [s]


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


def build_controller(cfg: PlantConfig, name: str | None = None, reference: Reference | None = None,
                     source: str = "<config>", check: bool = True) -> Controller:
    """The controller ``name`` (default: ``[rig.session] controller``) for the config's plant and
    ``reference`` (default: the session's cycles), refused if it does not apply."""
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
        preflight(controller)
    return controller


def preflight(controller: Controller) -> None:
    """Run the controller on the model for one reference period and refuse it, naming the rig limit
    it would trip first and when, if it would trip one (the supervisor's checks, on the model)."""
    ctx = controller.ctx
    lim = ctx.cfg.rig.limits
    duration = min(controller.reference.first_open_s + controller.reference.period_s, PREFLIGHT_MAX_S)
    res = closed_loop(controller, duration)
    t = res.t
    trips: list[tuple[float, str]] = []
    lo, hi = ctx.angle_limits_deg
    angle = res[ctx.angle]
    out = np.flatnonzero((angle < lo) | (angle > hi))
    if out.size:
        k = int(out[0])
        trips.append((t[k], f"leaves the range of motion ({ctx.angle} {angle[k]:.1f} deg outside {lo:g}..{hi:g} deg)"))
    scale = ctx.ports.actuators[0].duty_scale
    duty = np.minimum(np.abs(res[ctx.effort]) / scale, lim.max_duty)
    heating_limit = ctx.cfg.rig.host_limits().max_heating_s  # as the supervisor has it: at least one period
    on = duty > 0.0
    run_start = None
    for k in range(len(t)):
        if not on[k]:
            run_start = None
            continue
        run_start = t[k] if run_start is None else run_start
        if t[k] - run_start + ctx.step_s >= heating_limit:
            trips.append((t[k], f"heats continuously for {heating_limit:g} s (rig.limits.max_heating_s less the "
                                "host margin)"))
            break
    th = ctx.cfg.rig.thermal
    if th is not None:
        model = thermal_from_config(th)
        est = np.array([model.step(d, ctx.step_s) for d in duty])
        over = np.flatnonzero(est > lim.max_temperature_c)
        if over.size:
            trips.append((t[int(over[0])], f"heats the actuator past {lim.max_temperature_c:g} C (the host's "
                                           "temperature estimate)"))
    if trips:
        when, what = min(trips)
        raise ControllerError(f"controller {controller.name!r} does not apply to plant {ctx.cfg.plant!r}: run on the "
                              f"model it {what} at {when:.2f} s, a safety trip on the rig")

