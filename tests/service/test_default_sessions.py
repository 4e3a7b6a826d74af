"""Shipped sessions stay inside their rig's limits (issue 16 item 6): each plant's default session
(``rehab-hil run`` with its session controller) runs 60 s on the simulated rig (the firmware's
logic and the plant in process, one sample per command: deterministic) without a single trip. The
TCP finger's session is model-based tracking of one slow cycle a minute."""

from __future__ import annotations

import pytest

from rehab_hil.loading import load_config
from rehab_hil.service import assembly
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


@pytest.mark.parametrize("plant", ["finger_extensor", "sma_exoskeleton", "tcp_finger"])
def test_the_default_session_runs_60_s_on_the_simulated_rig_without_a_trip(plant: str) -> None:
    path = CONFIGS / f"{plant}.toml"
    cfg = load_config(path)
    controller = assembly.build_controller(cfg)
    duties: list[float] = []

    def recording(t_s, state):  # the session's own commands, to check that it really drives
        cmd = controller(t_s, state)
        duties.append(max(cmd.duty))
        return cmd

    recording.reset = controller.reset  # type: ignore[attr-defined]
    recording.claims = controller.claims  # type: ignore[attr-defined]
    with open_session(path, "inprocess", controller=recording) as session:
        res = session.run(60.0)
    assert res.events == [], res.events
    assert res.stop_reason == "duration reached" and res.cycles >= 59_000
    assert max(duties) > 0.05  # the session drives: not trivially inside its limits
