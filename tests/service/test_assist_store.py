"""The assistance an assist-as-needed session learned, kept for the patient's next session
(``service/assist_store.py``), through ``open_session`` on the in-process rig with a simulated
patient: the next session starts where the last one ended, per patient and config; a trip or a stop
keeps what was learned so far; a store that cannot be used is one line and the config's start."""

from __future__ import annotations

import json
from pathlib import Path

from rehab_hil.controllers import Reference
from rehab_hil.loading import load_config
from rehab_hil.service.assist_store import FORMAT, AssistanceStore
from rehab_hil.service.identity import store_name
from rehab_hil.service.session import open_session
from tests.conftest import ROOT

from .conftest import CONFIG
from .test_rig_learning import StopAfter

CAPABLE = ROOT / "profiles" / "sim" / "capable.toml"
WEAK = ROOT / "profiles" / "sim" / "weak.toml"
CYCLES = 3
A0 = load_config(CONFIG).controllers["assist_as_needed"].initial_assistance
START = {"open": A0, "close": A0}  # the config's initial_assistance


def run(store: Path, record: Path | None = None, patient: Path = CAPABLE, cycles: int = CYCLES, **kw):
    """An assist-as-needed session of ``cycles`` cycles on the Finger Extensor; (result, metadata, notes)."""
    ref = Reference.session(load_config(CONFIG))
    with open_session(CONFIG, "inprocess", controller="assist_as_needed", sim_patient=patient,
                      assistance_store=store, record=record, **kw) as s:
        notes = list(s.controller.notes)
        res = s.run(ref.first_open_s + cycles * ref.period_s + 0.5)
        run_dir = s.run_dir
    meta = json.loads((run_dir / "metadata.json").read_text()) if run_dir is not None else None
    return res, meta, notes


def test_the_next_session_starts_with_the_assistance_the_last_one_ended_with(tmp_path: Path) -> None:
    store = tmp_path / "store"
    first, meta, notes = run(store, record=tmp_path / "runs")
    a = first.assistance
    assert first.events == [] and notes == []
    assert not a["resumed"] and a["start"] == START
    assert a["end"]["open"] < A0 - 0.1  # a capable patient: the assistance fell
    assert meta["assistance_store"] == a and Path(a["store"]).exists()
    second, _, notes = run(store)
    b = second.assistance
    assert notes == [] and b["resumed"] and b["store"] == a["store"] and b["sessions"] == 2
    assert b["start"] == a["end"]
    assert b["end"]["open"] < a["end"]["open"]  # and it goes on learning from there
    # another patient on the same rig and config has a store of its own
    other, _, _ = run(store, patient=WEAK, cycles=1)
    assert not other.assistance["resumed"] and other.assistance["store"] != a["store"]


def test_a_fresh_start_ignores_the_store_and_still_saves_its_end(tmp_path: Path) -> None:
    store = tmp_path / "store"
    first, _, _ = run(store, cycles=2)
    fresh, _, _ = run(store, cycles=1, fresh_assistance=True)
    f = fresh.assistance
    assert f["fresh"] and not f["resumed"] and f["start"] == START
    assert json.loads(Path(f["store"]).read_text())["assistance"] == f["end"] != first.assistance["end"]


def test_a_corrupt_store_is_one_line_naming_the_file_and_the_session_starts_from_the_default(tmp_path: Path) -> None:
    store = tmp_path / "store"
    first, _, _ = run(store, cycles=1)
    path = Path(first.assistance["store"])
    path.write_text('{"format": "rehab-hil assistance 1", "key": ')  # a write cut short
    res, _, notes = run(store, cycles=1)
    assert len(notes) == 1 and str(path) in notes[0] and "unreadable" in notes[0] and "\n" not in notes[0]
    a = res.assistance
    assert not a["resumed"] and a["start"] == START and a["problem"] == notes[0]
    assert json.loads(path.read_text())["format"] == FORMAT  # the end replaced it with a readable file


def test_a_store_learned_with_other_gains_or_out_of_range_is_not_used(tmp_path: Path) -> None:
    store = tmp_path / "store"
    first, _, _ = run(store, cycles=1)
    path = Path(first.assistance["store"])
    data = json.loads(path.read_text())
    data["key"]["feedback"]["kp_per_deg"] += 1.0
    path.write_text(json.dumps(data))
    _, _, notes = run(store, cycles=1)
    assert len(notes) == 1 and str(path) in notes[0] and "learned for feedback" in notes[0]
    data = json.loads(path.read_text())
    data["assistance"]["open"] = 1.5
    path.write_text(json.dumps(data))
    res, _, notes = run(store, cycles=1)
    assert len(notes) == 1 and "'assistance.open' must be a number in 0..1, got 1.5" in notes[0]
    assert res.assistance["start"] == START


def test_a_session_stopped_part_way_keeps_what_it_learned_so_far(tmp_path: Path) -> None:
    store = tmp_path / "store"
    ref = Reference.session(load_config(CONFIG))
    stop = StopAfter(ref.first_open_s + 1.5 * ref.period_s)  # after the first cycle's moves were learned
    with open_session(CONFIG, "inprocess", controller="assist_as_needed", sim_patient=CAPABLE,
                      assistance_store=store, sinks=(stop,)) as s:
        stop.session = s
        res = s.run(ref.first_open_s + 5 * ref.period_s)
    a = res.assistance
    assert res.events and res.events[0].reason == "stop_request"
    assert a["end"]["open"] < A0 and a["ended"].startswith("stop_request")
    saved = json.loads(Path(a["store"]).read_text())
    assert saved["assistance"] == a["end"] and saved["ended"] == a["ended"]


def test_the_store_file_is_one_per_rig_patient_and_config_and_written_whole(tmp_path: Path) -> None:
    key = {"plant": "p", "controller": "assist_as_needed", "directions": ["open"], "feedback": {"kp_per_deg": 1.0}}
    s = AssistanceStore(tmp_path, "rig a", "sim-capable", "finger_extensor", key)
    assert s.path == tmp_path / store_name("rig a") / f"{store_name('sim-capable')}-finger_extensor.json"
    assert s.path.parent.name.startswith("rig-a-") and s.path.name.startswith("sim-capable-")  # readable
    assert s.load() == (None, None)
    s.save({"open": 0.25}, 3, "duration")
    stored, problem = s.load()
    assert problem is None and stored.assistance == {"open": 0.25} and stored.sessions == 3
    assert [p.name for p in s.path.parent.iterdir()] == [s.path.name]  # no temporary file left
    s.path.write_text("[1, 2]")
    assert "not an assistance store" in s.load()[1]


def test_the_store_refuses_a_file_for_other_directions(tmp_path: Path) -> None:
    key = {"plant": "p", "controller": "c", "directions": ["open", "close"], "feedback": {}}
    s = AssistanceStore(tmp_path, "r", None, "c", key)
    s.save({"open": 0.5}, 1, "duration")
    assert "'assistance' must hold ['open', 'close']" in s.load()[1]
    assert s.path.name == "no-patient-c.json"
