"""The session builder (``service.session.open_session``): what it refuses in one line, what a
recorded session leaves behind, and the safe state when the loop's own code fails."""

from __future__ import annotations

import json
import math

import pytest

from rehab_hil.loop.controllers import SAFE_COMMAND
from rehab_hil.protocol import Fault
from rehab_hil.service.session import SessionError, open_session
from rehab_hil.testing import CONFIGS

FE = CONFIGS / "finger_extensor.toml"


def test_an_unknown_option_is_refused_naming_the_known_ones():
    with pytest.raises(SessionError, match=r"unexpected keyword argument 'recrod'.*the options are: .*record"):
        open_session(FE, "inprocess", recrod="out")


@pytest.mark.parametrize(("options", "option", "text"), [
    ({"home": "sideways"}, "home", "must be one of"),
    ({"pacing": "sometimes"}, "pacing", "must be one of"),
    ({"controller": "no_such_controller"}, None, "no_such_controller"),
    ({"sim_plant": CONFIGS / "finger_extensor.toml"}, "sim_plant", "for simulated devices"),
])
def test_what_a_user_can_fix_is_one_line_naming_its_option(options, option, text):
    device = "/dev/ttyACM9" if "sim_plant" in options else "inprocess"
    with pytest.raises(SessionError) as info:
        open_session(FE, device, **options)
    assert info.value.option == option and text in str(info.value) and "\n" not in str(info.value)


def test_a_recorded_session_leaves_its_run_directory_complete(tmp_path):
    with open_session(FE, "inprocess", controller="pid", reference="step", record=tmp_path, rig_id="bench 3") as s:
        assert s.run_dir is not None and s.run_dir.parent == tmp_path and "bench-3" in s.run_dir.name
        before = json.loads((s.run_dir / "metadata.json").read_text())  # written before anything moved
        assert before["controller"] == "pid" and "rows" not in before
        result = s.run(1.0)
    meta = json.loads((s.run_dir / "metadata.json").read_text())
    assert meta["rows"] == result.samples and meta["stop_reason"] == "duration reached"
    assert meta["sinks"]["recorder"] == {"dropped": 0, "error": None}
    assert sorted(p.rsplit("/", 1)[1] for p in result.files) == ["metadata.json", "run.csv", "run.mcap"]


def test_a_session_runs_once():
    with open_session(FE, "inprocess", controller="pid", reference="step") as s:
        s.run(0.2)
        with pytest.raises(SessionError, match="runs once"):
            s.run(0.2)


class FailingController:
    """Follows nothing and fails on its 200th step (a bug in a lab's controller)."""

    claims = None

    def __init__(self, claims):
        self.claims, self.calls = claims, 0

    def reset(self):
        self.calls = 0

    def __call__(self, t_s, state):
        self.calls += 1
        if self.calls == 200:
            raise ZeroDivisionError("gain / 0")
        return SAFE_COMMAND


def test_an_exception_in_the_controller_trips_the_safe_state_and_says_why():
    from rehab_hil.controllers import build_controller
    from rehab_hil.loading import load_config

    claims = build_controller(load_config(FE), "pid").claims
    with open_session(FE, "inprocess", controller=FailingController(claims)) as s:
        result = s.run(1.0)
        s.hw.write_command(0.0, enable=False)  # the in-process device answers each command with a sample
        after = s.hw.read(1.0)
    (event,) = [e for e in result.events if e.reason == "software_fault"]
    assert "ZeroDivisionError: gain / 0" in event.detail and math.isclose(event.t_s, 0.199, abs_tol=0.002)
    assert result.pwm_off_at_end and after.sample.faults & Fault.ESTOP_COMMAND  # the ESTOP reached the device
