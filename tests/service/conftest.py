"""Fixtures: a real Python simulated device (lockstep clock) on a pty, and the host interface to it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from rehab_hil.config import load_config
from rehab_hil.devices.spawn import spawn_sim_device
from rehab_hil.hardware import SerialHardware
from rehab_hil.plants import get_plant

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "finger_extensor.toml"


@pytest.fixture
def cfg():
    return load_config(CONFIG)


@pytest.fixture
def binding(cfg):
    return get_plant(cfg.plant).device(cfg)


@pytest.fixture
def device() -> Iterator:
    """The simulated Finger Extensor in lockstep mode; killed after the test, also on failure."""
    dev = spawn_sim_device(CONFIG, clock="lockstep")
    try:
        yield dev
    finally:
        dev.close()


@pytest.fixture
def hw(device) -> Iterator[SerialHardware]:
    h = SerialHardware(device.port)
    h.connect()
    try:
        yield h
    finally:
        h.close()


@pytest.fixture(scope="module")
def shared_device() -> Iterator:
    """One lockstep device for a module's trip tests (a spawn costs seconds of numba loading)."""
    dev = spawn_sim_device(CONFIG, clock="lockstep")
    try:
        yield dev
    finally:
        dev.close()


@pytest.fixture
def fresh_hw(shared_device) -> Iterator[SerialHardware]:
    """The shared device rebooted (fresh firmware state, no latched faults; the plant keeps its
    angle, as a real finger would) and a new host connection to it."""
    shared_device.control("reboot")
    h = SerialHardware(shared_device.port)
    h.connect()
    try:
        yield h
    finally:
        h.close()
