"""The seam a session grows by: a feature opens after those it needs, takes every record the recorder takes
and every command at once, may stop the loop, adds its part to the result, metadata.json and the summary,
and is closed whatever happened."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rehab_hil.cli.run import summary_table
from rehab_hil.loop.records import CommandRecord, SampleRecord
from rehab_hil.loop.result import FeatureResult
from rehab_hil.service.features.base import Feature
from rehab_hil.service.identity import SessionIdentity
from rehab_hil.service.options import SessionOptions
from rehab_hil.service.session import SessionError, open_session
from rehab_hil.testing import CONFIGS

FE = CONFIGS / "finger_extensor.toml"


class Counting(Feature):
    """Counts what it is given, stops the loop after ``stop_after`` commands, and says so."""

    name = "counting"
    needs = ("recording",)

    def __init__(self, stop_after: int | None = None) -> None:
        self.stop_after, self.samples, self.commands, self.rows_seen = stop_after, 0, 0, []
        self.opened = self.closed = 0
        self.loop = None
        self.critical, self.dropped, self.error, self.on_failure = False, 0, None, None

    def open(self, parts) -> None:
        self.opened += 1
        self.run_dir = parts.run_dir  # the recording opened first: its folder exists

    def sinks(self):
        return [self]

    def offer(self, record) -> bool:
        self.samples += type(record) is SampleRecord
        return True

    def wake(self) -> None:
        pass

    def drain(self) -> None:
        pass

    def feeds(self):
        return [self._command]

    def _command(self, rec: CommandRecord) -> None:
        self.commands += 1
        if self.commands == self.stop_after:
            self.loop.request_stop("counted enough", "stop_request")

    def started(self, loop) -> None:
        self.loop = loop

    def finish(self, result) -> FeatureResult:
        figures = {"samples": self.samples, "commands": self.commands}
        return FeatureResult(self.name, figures, {"counting": figures}, (("counted", f"{self.samples} samples"),))

    def close(self) -> None:
        self.closed += 1


def test_a_feature_sees_every_record_and_adds_its_part_to_the_result_the_metadata_and_the_summary(tmp_path) -> None:
    feature = Counting()
    with open_session(FE, "inprocess", controller="pid", record=tmp_path, features=(feature,)) as s:
        result = s.run(1.0)
        assert feature.run_dir == s.run_dir and feature.closed == 0
    assert feature.opened == feature.closed == 1
    assert feature.samples == result.samples and feature.commands == result.cycles
    assert result.feature("counting") == {"samples": result.samples, "commands": result.cycles}
    meta = json.loads((Path(result.files[0]).parent / "metadata.json").read_text())
    assert meta["counting"] == {"samples": result.samples, "commands": result.cycles}
    assert meta["identity"] == {"rig": "finger_extensor", "patient": None}
    from rich.console import Console

    console = Console(width=200, record=True)
    console.print(summary_table(result))
    lines = [x for x in console.export_text().splitlines() if "counted" in x]
    assert len(lines) == 1 and f"{result.samples} samples" in lines[0]  # once: each feature's lines are added once


def test_a_feature_may_stop_the_loop_through_its_handle(tmp_path) -> None:
    feature = Counting(stop_after=300)
    with open_session(FE, "inprocess", controller="pid", record=tmp_path, features=(feature,)) as s:
        result = s.run(5.0)
    assert result.events[0].reason == "stop_request" and result.events[0].detail == "counted enough"
    assert 300 <= result.cycles < 400 and result.pwm_off_at_end


def test_a_feature_whose_need_is_missing_is_refused_in_one_line_and_nothing_stays_open() -> None:
    feature = Counting()
    with pytest.raises(SessionError, match="the counting feature needs recording"):
        open_session(FE, "inprocess", controller="pid", features=(feature,))
    assert feature.opened == 0


def test_the_options_are_grouped_and_an_unknown_one_names_them_all() -> None:
    opts = SessionOptions.of(record=Path("out"), twin=True, rig_learning=False, sim_plant=FE, rig_id="bench")
    assert opts.views.record == Path("out") and opts.views.twin and opts.learning.rig_learning is False
    assert opts.sim.sim_plant == FE and opts.rig.rig_id == "bench"
    assert len([f for f in SessionOptions.__dataclass_fields__]) <= 12
    with pytest.raises(TypeError, match=r"'recrod'.*the options are: controller, reference"):
        SessionOptions.of(recrod="out")


def test_one_identity_names_a_simulated_rig_by_its_file_and_a_simulated_patient_by_its_file(tmp_path) -> None:
    from rehab_hil.patient.profile import load_patient

    weak = CONFIGS.parent / "profiles" / "sim" / "weak.toml"
    copy = tmp_path / "weak.toml"
    copy.write_text(weak.read_text().replace("patient_id", "# a copy\npatient_id", 1))
    a = SessionIdentity.of("rig", FE, None, load_patient(weak), weak)
    b = SessionIdentity.of("rig", FE, None, load_patient(copy), copy)
    assert a.rig == b.rig and a.rig.startswith("rig-sim-")
    assert a.patient != b.patient and a.patient.startswith("sim-")  # one id, two files: two patients
    assert SessionIdentity.of("rig").patient is None and SessionIdentity.of("rig").rig == "rig"
