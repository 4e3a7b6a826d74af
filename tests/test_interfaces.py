"""The rig's interface types: importable without the rig, and the very types the contract checks."""

from __future__ import annotations

import json
import subprocess
import sys

from rehab_hil import interfaces
from rehab_hil.hardware import contract

_PROBE = """
import json, sys
before = set(sys.modules)
import rehab_hil.interfaces
print(json.dumps(sorted(set(sys.modules) - before)))
"""


def test_the_interfaces_module_imports_only_the_standard_library():
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    ours = {m for m in loaded if m.split(".")[0] == "rehab_hil"}
    assert ours == {"rehab_hil", "rehab_hil.interfaces"}
    third_party = {m.split(".")[0] for m in loaded} - set(sys.stdlib_module_names) - {"rehab_hil"}
    assert third_party == set()


def test_the_contract_re_exports_the_same_interface_types():
    assert contract.StateInterface is interfaces.StateInterface
    assert contract.CommandInterface is interfaces.CommandInterface
    assert contract.Claims is interfaces.Claims
    assert {"Claims", "CommandInterface", "StateInterface"} <= set(contract.__all__)
    from rehab_hil.hardware import Claims, CommandInterface, StateInterface

    assert (Claims, CommandInterface, StateInterface) == (interfaces.Claims, interfaces.CommandInterface,
                                                          interfaces.StateInterface)


def test_a_command_interface_converts_effort_and_duty_both_ways():
    bridge = interfaces.CommandInterface("motor_voltage_v", "v", channel=1, scale=24.0, signed=True)
    assert bridge.duty(-12.0) == (0.5, True) and bridge.duty(48.0) == (1.0, False)
    assert bridge.effort(0.5, direction_bits=0b10) == -12.0 and bridge.effort(0.5, direction_bits=0b01) == 12.0
    heater = interfaces.CommandInterface("power_w", "w", channel=0, scale=2.0)
    assert heater.duty(-1.0) == (0.0, False)  # an unsigned input applies no negative effort
    assert heater.effort(0.25, direction_bits=0b1) == 0.5  # and ignores the direction pin
