"""The model's thermal part as an observer: the plant parts between the actuator and its temperature.

An SMA wire or a TCP coil only heats; how hot it is decides what it does next and whether it is
safe. The rig measures no temperature, so a controller carries the actuator's one thermal model
(``plants/thermal.py``: the parts of the composed, possibly augmented, plant that lead from the
actuator input to the temperature signal) copied under new names, run on the effort it applies
offline and, on the rig, following the safety supervisor's estimate of the same model
(``loop/controllers.py``). A fitted convection effect or corrected h1 changes the observer by itself.
A plant whose temperature depends on more than the actuator and config constants (a mechanical
state) has no such slice: ``thermal_slice`` is None.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from rehab_hil.models.system import Part
from rehab_hil.plants.thermal import temperature_signal
from rehab_hil.plants.thermal import thermal_slice as plant_slice

__all__ = ["OBSERVER", "temperature_signal", "thermal_slice"]

OBSERVER = "observer_"  # prefix of the observer's parts and signals


def thermal_slice(parts: Sequence[Part], effort: str, temperature: str, constants: Mapping[str, float],
                  mechanical: Sequence[str] = ()) -> list[Part] | None:
    """The plant's thermal slice (``plants.thermal.thermal_slice``) as the observer's parts: signals
    prefixed ``observer_`` (the observer's temperature is ``observer_<temperature>``)."""
    return plant_slice(parts, effort, temperature, constants, mechanical, prefix=OBSERVER)
