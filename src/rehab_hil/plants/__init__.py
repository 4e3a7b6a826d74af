"""Plant definitions: one module per plant, each declaring one ``Plant`` (schema, parts, ports,
scenarios). ``plants()`` finds them by scanning this package: no import list to keep."""

from rehab_hil.plants.base import (
    DeviceBinding,
    Plant,
    PlantConfig,
    Scenario,
    compose,
    get_plant,
    plant_names,
    plants,
    run_scenario,
)

__all__ = ["DeviceBinding", "Plant", "PlantConfig", "Scenario", "compose", "get_plant",
           "plant_names", "plants", "run_scenario"]
