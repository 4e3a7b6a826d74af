"""Plant definitions: config schema, diagram builder and scenarios for each seed system.

Importing this package registers every plant's config schema with ``rehab_hil.config``.
"""

from rehab_hil.plants import (
    finger_extensor,  # noqa: F401  (registers)
    sma_exoskeleton,  # noqa: F401  (registers)
    tcp_finger,  # noqa: F401  (registers)
)
from rehab_hil.plants.base import PLANTS, PlantSpec, Scenario, get_plant

__all__ = ["PLANTS", "PlantSpec", "Scenario", "get_plant"]
