"""``rehab_hil.testing``: what tests and benchmarks share."""

from __future__ import annotations

import socket

from rehab_hil.hardware import InProcessHardware, LifecycleState
from rehab_hil.testing import CONFIGS, free_port, inprocess_rig


def test_free_port_can_be_bound_on_loopback() -> None:
    port = free_port()
    assert 0 < port < 65536
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))


def test_the_inprocess_rig_is_configured_and_answers_each_command_with_a_sample() -> None:
    hw = inprocess_rig(CONFIGS / "finger_extensor.toml", hello={"fw_minor": 7})
    assert isinstance(hw, InProcessHardware) and hw.state is LifecycleState.ACTIVE
    assert hw.info is not None and hw.info.fw_minor == 7
    indices = []
    for _ in range(5):
        seq = hw.write_command(0.2)
        s = hw.read_sample()
        assert s is not None and s.cmd_seq_echo == seq
        indices.append(s.sample_index)
    assert indices == list(range(indices[0], indices[0] + 5)) and hw.read_sample() is None
    hw.close()
