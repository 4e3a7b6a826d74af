"""Shipped sessions stay inside their rig's limits (issue 16 item 6): each plant's default session
(``rehab-hil run`` with its session controller) runs 60 s on the simulated rig (the firmware's
logic and the plant in process, one sample per command: deterministic) without a single trip. The
TCP finger's session is model-based tracking of one slow cycle a minute."""

from __future__ import annotations

import pytest

from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.service import assembly
from rehab_hil.service.runner import LoopService
from rehab_hil.testing import CONFIGS, inprocess_rig

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


@pytest.mark.parametrize("plant", ["finger_extensor", "sma_exoskeleton", "tcp_finger"])
def test_the_default_session_runs_60_s_on_the_simulated_rig_without_a_trip(plant: str) -> None:
    path = CONFIGS / f"{plant}.toml"
    cfg = load_config(path)
    binding = get_plant(cfg.plant).device(cfg)
    hw = inprocess_rig(path, configured=False)
    controller = assembly.build_controller(cfg)
    duties: list[float] = []

    def recording(t_s, state):  # the session's own commands, to check that it really drives
        cmd = controller(t_s, state)
        duties.append(max(cmd.duty))
        return cmd

    recording.reset = controller.reset  # type: ignore[attr-defined]
    try:
        svc = LoopService(hw, assembly.firmware_configure(cfg, binding), recording,
                          assembly.build_estimator(cfg, binding),
                          assembly.build_supervisor(cfg, binding), assembly.period_s(cfg))
        res = svc.run(60.0, realtime=False)
    finally:
        hw.close()
    assert res.events == [], res.events
    assert res.stop_reason == "duration reached" and res.cycles >= 59_000
    assert max(duties) > 0.05  # the session drives: not trivially inside its limits
