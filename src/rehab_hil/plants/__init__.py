"""Plant definitions: one module per plant, each declaring one ``Plant`` (schema, parts, ports,
scenarios). ``plants()`` finds them by scanning this package: no import list to keep."""

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.plants.experiments import Scenario
from rehab_hil.plants.registry import Plant, compose, get_plant, plant_names, plants, run_scenario
from rehab_hil.plants.sections import PlantConfig

__all__ = ["DeviceBinding", "Plant", "PlantConfig", "Scenario", "compose", "get_plant",
           "plant_names", "plants", "run_scenario"]
