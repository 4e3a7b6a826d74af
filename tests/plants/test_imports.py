"""Plants do not import the hardware layer: a plant module (and the package that scans them) loads
in a fresh interpreter without pyserial or ``rehab_hil.hardware``."""

from __future__ import annotations

import importlib.util
import json
import pkgutil
import subprocess
import sys

import pytest

_PLANTS_DIR = importlib.util.find_spec("rehab_hil.plants").submodule_search_locations  # no plant imported here
PLANT_MODULES = sorted(f"rehab_hil.plants.{m.name}" for m in pkgutil.iter_modules(_PLANTS_DIR)
                       if not m.name.startswith("_"))

# imports the module (and, for the package, scans every plant module as plants() does), then lists
# the hardware-layer modules loaded
_PROBE = """
import importlib, json, sys
mod = importlib.import_module(sys.argv[1])
if sys.argv[1] == "rehab_hil.plants":
    mod.plants()
hw = sorted(m for m in sys.modules
            if m.split(".")[0] == "serial" or m == "rehab_hil.hardware" or m.startswith("rehab_hil.hardware."))
print(json.dumps(hw))
"""


def _hardware_modules_loaded_by(module: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", _PROBE, module], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_every_plant_module_is_checked():
    assert {"rehab_hil.plants.registry", "rehab_hil.plants.finger_extensor", "rehab_hil.plants.sma_exoskeleton",
            "rehab_hil.plants.tcp_finger"} <= set(PLANT_MODULES)


@pytest.mark.parametrize("module", ["rehab_hil.plants", *PLANT_MODULES])
def test_importing_a_plant_loads_neither_pyserial_nor_the_hardware_layer(module):
    assert _hardware_modules_loaded_by(module) == []
