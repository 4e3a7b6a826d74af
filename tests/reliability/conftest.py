"""Fixtures for the reliability suites: real simulated devices (real-time clock, so the firmware
watchdog runs in device time while the host is stalled), a fault-injecting link proxy per test,
and the host connected through it. Every process and descriptor is closed, also on failure."""

from __future__ import annotations

import os
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from rehab_hil.hardware import SerialHardware
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

from .link_proxy import LinkProxy

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "finger_extensor.toml"


def avr_skip_reason() -> str | None:
    """Why the firmware-in-simavr backend cannot run here (None when it can)."""
    try:
        from rehab_hil.devices import avr_device
    except ImportError:
        return "rehab_hil.devices.avr_device is not available"
    reason = getattr(avr_device, "unavailable_reason", None)
    return reason() if callable(reason) else None


@pytest.fixture(scope="module")
def cfg() -> Any:
    return load_config(CONFIG)


@pytest.fixture(scope="module")
def binding(cfg: Any) -> Any:
    return get_plant(cfg.plant).device(cfg)


# The Python device's emulated bootloader behind the bridge model: silent this long after every open
# (each case opens the port: a fresh proxy), shorter than optiboot's ~1 s as in tests/devices/test_usb_bridge.py.
# The cases inject their faults into a running session; the silence's length is not what they test
# (tests/devices/test_usb_bridge.py does). The firmware in simavr runs the real optiboot either way.
BRIDGE_BOOT_MS = 300.0


@pytest.fixture(scope="module")
def device_pool(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[[str], Any]]:
    """``get(kind)`` -> a running real-time device, shared by a module's tests (a start costs
    seconds); respawned when a test ended it. All are closed at module teardown."""
    from rehab_hil.devices import spawn_device

    running: dict[str, Any] = {}
    text = CONFIG.read_text()
    assert "bootloader_ms = 1000.0" in text
    bridged = tmp_path_factory.mktemp("bridge") / CONFIG.name
    bridged.write_text(text.replace("bootloader_ms = 1000.0", f"bootloader_ms = {BRIDGE_BOOT_MS}"))

    def get(kind: str) -> Any:
        """``kind``: "python" or "avr", "+bridge" puts the Uno's USB bridge model (devices/usb_bridge.py)
        between (batching, DTR auto-reset and bootloader silence on every open)."""
        dev = running.get(kind)
        if dev is None or not dev.alive() or not os.path.exists(dev.port):  # ended by a test (disconnect)
            if dev is not None:
                dev.close()
            base, _, bridge = kind.partition("+")
            config = bridged if kind == "python+bridge" else CONFIG
            running[kind] = dev = spawn_device(base, config, clock="realtime", usb_bridge=bridge == "bridge")
        return dev

    try:
        yield get
    finally:
        for dev in running.values():
            dev.close()


@pytest.fixture
def link(device_pool: Callable[[str], Any], request: pytest.FixtureRequest) -> Iterator[tuple[Any, LinkProxy,
                                                                                                SerialHardware]]:
    """(device, proxy, host) for the backend named by the test's ``backend`` parameter (default
    python): a fresh proxy on the shared device (seeded from the test's name: reproducible), the
    host connected through it."""
    callspec = getattr(request.node, "callspec", None)
    kind = callspec.params.get("backend", "python") if callspec is not None else "python"
    if kind.startswith("avr") and (reason := avr_skip_reason()):
        pytest.skip(reason)
    dev = device_pool(kind)
    proxy = LinkProxy(dev.port, seed=zlib.crc32(request.node.name.encode()))
    hw = SerialHardware(proxy.port)
    try:
        hw.connect(timeout=15.0)  # behind the bridge: the bootloader's silence first
        yield dev, proxy, hw
    finally:
        hw.close()
        proxy.close()
