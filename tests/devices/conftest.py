"""Simulated devices for the device tests: started once per test session and worker (startup
costs seconds), always terminated at teardown, also when a test fails. The device test modules
share one xdist group so one worker starts them."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "finger_extensor.toml"


def avr_skip_reason() -> str | None:
    """Why the firmware-in-simavr backend cannot run here (None when it can)."""
    try:
        from rehab_hil.devices import avr_device
    except ImportError:
        return "rehab_hil.devices.avr_device does not exist yet (issue 5 part B)"
    if not hasattr(avr_device, "spawn_avr_device"):
        return "rehab_hil.devices.avr_device has no spawn_avr_device yet (issue 5 part B)"
    reason = getattr(avr_device, "unavailable_reason", None)
    return reason() if callable(reason) else None


_RUNNING: dict[tuple[str, str], tuple[Any, Any]] = {}  # the pool's devices: (kind, clock) -> (device, hardware)
HERE = Path(__file__).resolve().parent


def _close_pool() -> None:
    while _RUNNING:
        dev, hw = _RUNNING.popitem()[1]
        hw.close()
        dev.close()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Stop the pool's devices once this worker leaves the device tests (after the test's own
    fixtures are torn down): a real-time firmware in simavr spins a quarter of a core while it
    lives, and the rest of the suite needs that core."""
    try:
        return (yield)
    finally:
        if nextitem is None or HERE not in Path(nextitem.path).resolve().parents:
            _close_pool()


@pytest.fixture(scope="session")
def device_pool() -> Iterator[Callable[..., Any]]:
    """``get(kind, clock)`` -> (running device, connected ``SerialHardware``), shared
    by the tests; one connection per device keeps the host's sequence numbers unique. A device
    stopped since (``pytest_runtest_teardown``) is started again when asked for."""
    from rehab_hil.devices import spawn_device
    from rehab_hil.hardware import SerialHardware

    running = _RUNNING

    def get(kind: str, clock: str = "realtime") -> tuple[Any, SerialHardware]:
        key = (kind, clock)
        if key not in running or not running[key][0].alive():
            if key in running:
                running.pop(key)[1].close()
            dev = spawn_device(kind, CONFIG, clock=clock)
            # a loaded CI machine can pause a device; in virtual time a resend would cost device time
            hw = SerialHardware(dev.port, write_timeout_s=2.0, **({"resend_s": None} if clock == "lockstep" else {}))
            running[key] = (dev, hw)
            hw.connect(timeout=10.0)
        return running[key]

    try:
        yield get
    finally:
        _close_pool()
