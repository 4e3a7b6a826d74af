"""Fixtures: a real Python simulated device (lockstep clock) on a pty, and the host interface to it."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import pytest

from rehab_hil.devices.spawn import spawn_sim_device
from rehab_hil.hardware import SerialHardware
from rehab_hil.loading import load_config
from rehab_hil.loop.supervisor import Supervisor
from rehab_hil.plants import get_plant
from rehab_hil.service import assembly
from rehab_hil.service.session import open_session
from rehab_hil.testing import pid_runtime

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
    # a starved device process on a busy machine; in virtual time a request sent again would cost device time
    h = SerialHardware(device.port, write_timeout_s=2.0, resend_s=None)
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


HOME_DEG = 30.0


def home(h: SerialHardware, cfg, binding) -> None:
    """Bring the shared plant to ``HOME_DEG`` (wide limits: it may start outside the range of
    motion after an earlier test), so each test starts from the same place."""
    conf = dataclasses.replace(assembly.firmware_configure(cfg, binding), enc_min=-10**6, enc_max=10**6)
    base = assembly.build_supervisor(cfg, binding)
    wide = dataclasses.replace(base.limits, min_angle_deg=-1e6, max_angle_deg=1e6)
    ctl = pid_runtime(cfg, HOME_DEG)
    with open_session(CONFIG, hw=h, controller=ctl, configure=conf, supervisor=Supervisor(wide, base.dt_s),
                      realtime=False, sample_timeout_s=5.0, lockstep=True) as session:
        res = session.run(1.0)
    assert not res.events, res.events


@pytest.fixture
def fresh_hw(shared_device, cfg, binding) -> Iterator[SerialHardware]:
    """The shared device rebooted (fresh firmware state, no latched faults), its plant homed to
    ``HOME_DEG``, and a new host connection to it."""
    shared_device.control("reboot")
    h = SerialHardware(shared_device.port, write_timeout_s=2.0, resend_s=None)  # lockstep: no resends
    h.connect()
    try:
        home(h, cfg, binding)
        yield h
    finally:
        h.close()
