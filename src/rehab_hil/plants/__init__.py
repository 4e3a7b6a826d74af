"""Plant definitions: one module per plant, each declaring one ``Plant`` (schema, parts, ports,
scenarios). ``plants()`` finds them by scanning this package: no import list to keep.

Beside the plants: ``registry`` (the ``Plant`` declaration, ``compose``, the registry, a scenario's
run), ``sections`` (the config tables plant files share), ``experiments`` (scenarios and
identification helpers) and ``changes`` (what changes mid-session on a simulated rig). The rig
binding a plant derives is ``rehab_hil.interfaces.DeviceBinding``; configs load through
``rehab_hil.loading``.
"""

from rehab_hil.plants.experiments import Scenario
from rehab_hil.plants.registry import Plant, compose, get_plant, plant_names, plants, run_scenario
from rehab_hil.plants.sections import PlantConfig

__all__ = ["Plant", "PlantConfig", "Scenario", "compose", "get_plant", "plant_names", "plants", "run_scenario"]
