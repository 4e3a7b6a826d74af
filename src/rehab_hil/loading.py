"""The application's config loader: a plant config file in, a validated config out.

The file's top-level ``plant`` key picks the plant's schema (``rehab_hil.plants``); after the
schema, what only the whole application can check is checked now, not mid-session: the force
calibration a config refers to (``rehab_hil.calibration``), the effects it adds against the plant's
ports, the changes it schedules, and its controller tables (``rehab_hil.controllers``). Every error
names the file and the dotted key (``ConfigError``).
"""

from __future__ import annotations

from pathlib import Path

from rehab_hil.calibration import calibration_for
from rehab_hil.config import ConfigError, load_toml
from rehab_hil.config import validate as validate_config
from rehab_hil.controllers.build import validate_controllers
from rehab_hil.effects import applicable, not_applicable_message
from rehab_hil.models.schedule import ScheduleError
from rehab_hil.plants.changes import scheduled
from rehab_hil.plants.registry import plants
from rehab_hil.plants.sections import PlantConfig

__all__ = ["load_config"]


def load_config(path: str | Path, expect: str | None = None) -> PlantConfig:
    """Load a plant config; its top-level ``plant`` key selects the schema (a ``PlantConfig``
    subclass, the plant's ``config``), validated as above. Errors name file and key."""
    known = plants()
    data = load_toml(path)
    plant = data.get("plant")
    if plant is None:
        raise ConfigError(path, "plant", f"missing key (one of {sorted(known)})")
    if not isinstance(plant, str) or plant not in known:
        raise ConfigError(path, "plant", f"unknown plant {plant!r}; known plants: {sorted(known)}")
    if expect is not None and plant != expect:
        raise ConfigError(path, "plant", f"this command needs a {expect!r} config, the file is {plant!r}")
    cls = known[plant]
    cfg = validate_config(path, data, cls.config)
    ref = cfg.rig.force_calibration
    if ref is not None:  # resolved against the config's directory and checked now, not mid-session
        resolved = ref if Path(ref).is_absolute() else str((Path(path).parent / ref).resolve())
        cfg = cfg.model_copy(update={"rig": cfg.rig.model_copy(update={"force_calibration": resolved})})
        calibration_for(cfg, path)
    ports = cls.ports(cfg)
    ok = {e.name for e in applicable(ports)}
    for i, e in enumerate(cfg.effects):
        if e.name not in ok:
            raise ConfigError(path, f"effects.{i}.name", not_applicable_message(e.name, plant, ports))
    if scheduled(cfg):  # checked now (keys, values, structure), not when a simulated rig starts
        try:
            cls.device(cfg)
        except ScheduleError as e:
            raise ConfigError(path, e.key, e.message) from None
    check_thermal(cfg, path)
    return validate_controllers(cfg, path)


def check_thermal(cfg: PlantConfig, path: str | Path) -> None:
    """One thermal model of a heated actuator: a plant that models its actuator's heat (``plants/thermal.py``)
    takes no ``[rig.thermal]`` estimate of its own. (Its ``max_temperature_c`` may lie above what the model
    reaches at ``max_duty``: the wire cannot get that hot on this config's values, and a simulated rig's
    file, a 10 % lower supply, is such a config; the twin's stricter values can make it reachable.)"""
    from rehab_hil.plants.thermal import ActuatorThermal

    th = cfg.rig.thermal
    if th is None or not th.has_model:
        return
    model = ActuatorThermal.of(cfg)
    if model is not None:
        raise ConfigError(path, "rig.thermal.rise_at_full_duty_c", f"plant {cfg.plant!r} models its actuator's "
                          f"heat ({model.temperature}): that model is the safety's estimate, as the controllers' "
                          "and the twin's; remove ambient_c, rise_at_full_duty_c and time_constant_s from "
                          "[rig.thermal] (the room, the convection and the supply are the plant's own keys)")
