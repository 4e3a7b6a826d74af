"""The twin's thermal estimate (issue 39, item 2) on real SMA sessions: the shipped session through
``open_session`` on the in-process rig (lockstep, ADC noise), its plant a copy of the shipped config
with one value changed. A 7 C warmer room is found within 2 C and 30 % more convection within 10 %
within two cycles, with a ``thermal_change`` event in metadata.json and the controller's hook
called; the nominal rig raises no thermal event and its estimates stay within their band. Also the
robustness bench's rigs: each a valid config that differs from the shipped one in its key only."""

from __future__ import annotations

import functools
import importlib.util
import io
import json
import sys
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from rehab_hil.cli.run import summary_table
from rehab_hil.hardware.open import inprocess_hardware
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS
from rehab_hil.twin.thermal import THERMAL_EVENT, thermal_quantities

ROOT = CONFIGS.parent
SMA = CONFIGS / "sma_exoskeleton.toml"
CYCLE_S = 12.0  # the shipped SMA session: five bends a minute


@functools.cache
def _bench() -> Any:
    """bench/robustness.py, loaded as the benchmark runs it (its dataclasses need their module known)."""
    spec = importlib.util.spec_from_file_location("bench_robustness", ROOT / "bench" / "robustness.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _session(tmp: Path, key: str, value: float | None, duration_s: float) -> tuple[Any, list[dict], Path]:
    """The shipped SMA session on a rig whose ``key`` is ``value`` (None: the shipped rig), recorded;
    (result, the hook's calls, the run folder)."""
    bench = _bench()
    sim_path = tmp / "rig.toml"
    sim_path.write_text(bench.set_key(SMA.read_text(), key, value) if value is not None else SMA.read_text())
    sim = load_config(sim_path)
    hw = inprocess_hardware(get_plant(sim.plant).device(sim), adc_noise_counts=1.0, seed=1)
    hw.connect()
    calls: list[dict] = []
    try:
        with open_session(SMA, hw=hw, twin=True, lockstep=True, realtime=False, sample_timeout_s=5.0,
                          record=tmp / "runs") as session:
            session.twin.live._cap = max(session.twin.live._cap, round(2 * duration_s / session.period_s))
            session.twin.on_thermal_change = calls.append
            res = session.run(duration_s)
    finally:
        hw.close()
    (run,) = (tmp / "runs").iterdir()
    return res, calls, run


def _estimate(res: Any, key: str) -> dict[str, float]:
    return res.twin["twin"]["thermal"]["estimates"][key]


@pytest.mark.slow
def test_warm_room_found_within_2_c_in_two_cycles(tmp_path):
    res, calls, run = _session(tmp_path, "sma.ambient_c", 30.0, 2 * CYCLE_S + 0.5)
    th = res.twin["twin"]["thermal"]
    assert len(th["windows"]) == 2
    assert abs(_estimate(res, "sma.ambient_c")["value"] - 30.0) <= 2.0
    assert any(e["key"] == "sma.ambient_c" for e in th["events"])
    assert any(abs(c.get("sma.ambient_c", 0.0) - 30.0) <= 2.0 for c in calls)  # the controller's hook
    meta = json.loads((run / "metadata.json").read_text())
    assert meta["twin"]["thermal"]["events"][0]["kind"] == THERMAL_EVENT


@pytest.mark.slow
def test_draft_found_within_10_percent_in_two_cycles(tmp_path):
    # the shipped controller trips heating_time at 11.8 s on this rig (issue 39): the estimate is made
    # on the part of the first cycle the session had
    res, calls, _ = _session(tmp_path, "sma.h1_w_per_m2_c", 390.0, 2 * CYCLE_S + 0.5)
    est = _estimate(res, "sma.h1_w_per_m2_c")
    assert abs(est["value"] - 390.0) <= 0.10 * 390.0
    assert any("sma.h1_w_per_m2_c" in c for c in calls)


@pytest.mark.slow
def test_nominal_rig_raises_no_thermal_event(tmp_path):
    res, calls, _ = _session(tmp_path, "sma.ambient_c", None, 3 * CYCLE_S + 0.5)
    th = res.twin["twin"]["thermal"]
    assert len(th["windows"]) == 3
    assert th["events"] == [] and calls == []
    floors = {q.key: q.floor for q in thermal_quantities(load_config(SMA))}
    for key, e in th["estimates"].items():
        assert abs(e["value"] - e["config"]) <= max(e["ci95"], floors[key]), key


@pytest.mark.slow
def test_a_difference_that_is_not_thermal_is_not_handed_to_the_controller(tmp_path):
    # the wire's pre-strain 15 % lower moves the bend as a thermal difference would; the fit leaves
    # 13 counts RMS where a thermal one leaves < 1: the event says so and the hook is not called
    res, calls, _ = _session(tmp_path, "sma.prestrain", 0.85 * 0.0117, CYCLE_S + 0.5)
    th = res.twin["twin"]["thermal"]
    assert th["events"] and not any(e["explained"] for e in th["events"])
    assert calls == []
    console = Console(width=400, record=True, file=io.StringIO())
    console.print(summary_table(res))
    rows = [x for x in console.export_text().splitlines() if "thermal_change" in x]
    assert rows and all("not explained by the thermal quantities alone" in x and "not told" in x for x in rows)


def _flat(obj: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(obj, dict):
        out: dict[str, Any] = {}
        for k, v in obj.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: obj}


@pytest.mark.parametrize("plant", ["sma_exoskeleton", "finger_extensor", "tcp_finger"])
def test_bench_rigs_are_valid_configs_that_differ_in_their_key_only(tmp_path, plant):
    bench = _bench()
    base = CONFIGS / f"{plant}.toml"
    flat0 = _flat(load_config(base).model_dump())
    cases = [c for c in bench.CASES if c.plant == plant]
    assert len(cases) >= 5
    for i, case in enumerate(cases):
        cfg = load_config(bench.case_config(base, case, tmp_path / f"{i}.toml"))  # load_config accepts it
        flat = _flat(cfg.model_dump())
        changed = {k for k in flat0.keys() | flat.keys() if flat0.get(k) != flat.get(k)}
        assert changed == ({case.key} if case.key else set()), case.name
        if case.key:
            assert flat[case.key] == pytest.approx(case.value(flat0[case.key]))


def test_thermal_event_goes_to_the_recording_and_zenoh():
    from rehab_hil.twin.outputs import SinkOutput, ZenohOutput
    from rehab_hil.twin.thermal import ThermalEvent

    ev = ThermalEvent(24.0, "sma.ambient_c", "ambient", 29.9, 0.1, 23.0, {"sma.ambient_c": 29.9})
    offered: list[Any] = []
    SinkOutput(type("Sink", (), {"offer": lambda self, r: offered.append(r)})()).thermal(ev)
    assert offered[0].kind == THERMAL_EVENT and "29.9" in offered[0].detail
    published: list[tuple[str, dict]] = []
    ZenohOutput(type("Pub", (), {"offer_twin": lambda self, k, b: published.append((k, b))})()).thermal(ev)
    kind, body = published[0]
    assert kind == THERMAL_EVENT and body["updates"] == {"sma.ambient_c": 29.9} and "kind" not in body


def test_an_unknown_thermal_quantity_is_refused():
    from rehab_hil.config import TwinSection
    from rehab_hil.twin.live import thermal_estimator
    from rehab_hil.twin.model import TwinSetupError

    cfg = load_config(SMA)
    with pytest.raises(TwinSetupError, match=r"sma\.length_m.*sma\.ambient_c"):
        thermal_estimator(cfg, get_plant(cfg.plant).device(cfg), 0.001, TwinSection(thermal=["sma.length_m"]), 12.0)
    fe = load_config(CONFIGS / "finger_extensor.toml")  # no thermal actuator: nothing to estimate, no error
    assert thermal_estimator(fe, get_plant(fe.plant).device(fe), 0.001, TwinSection(), None) is None
