"""``rehab-hil monitor`` and ``rehab-hil record --from-zenoh`` against a real loopback hub."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv
from rehab_hil.loading import load_config
from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import Estimator
from rehab_hil.loop.records import SampleRecord
from rehab_hil.plants import get_plant
from rehab_hil.telemetry import TelemetryPublisher
from rehab_hil.telemetry.rig import rig_info

from .fake_rig import LockstepRig

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "finger_extensor.toml"


def records(n: int) -> list[SampleRecord]:
    """n loop cycles of the finger extensor through the fake rig and the real estimator."""
    cfg = load_config(CONFIG)
    binding = get_plant(cfg.plant).device(cfg)
    hw, est = LockstepRig(), Estimator(binding)
    out = []
    for i in range(n):
        cmd = Command((0.4, 0.0), 0, True, 20.0)
        hw.write_command(*cmd.duty, cmd.direction, cmd.enable)
        s = hw.read_sample()
        assert s is not None
        st = est.update(s.encoder_count, s.device_time_us, (s.adc0, s.adc1))
        out.append(SampleRecord(10.0 + i * 1e-3, i * 1e-3, s, st, cmd, i, 25.0 + i * 0.01))
    return out


def info() -> dict:
    cfg = load_config(CONFIG)
    return rig_info(cfg.plant, CONFIG, get_plant(cfg.plant).device(cfg), 0.001, LockstepRig().connect())


def test_monitor_shows_the_rig_values_safety_and_rates(client: Callable[..., zenoh.Session], hub: int,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    with TelemetryPublisher(client(), "mon1", info=info(), stats_period_s=0.1) as pub:
        pub.update_stats({"lateness_p99_us": 12.5})
        stop = threading.Event()

        def feed() -> None:  # until the monitor is done: it must not miss the stream while it starts
            for r in itertools.cycle(records(300)):
                if stop.wait(0.002):
                    return
                pub.offer(r)

        th = threading.Thread(target=feed)
        th.start()
        try:
            code = main(["monitor", "mon1", "--port", str(hub), "--duration", "1.0", "--no-live"])
        finally:
            stop.set()
            th.join()
    out = capsys.readouterr().out
    assert code == 0
    for text in ("rig mon1", "running", "finger_extensor", "firmware 1.2.3", "angle", "torque_nm",
                 "temperature est.", "safety", "ok", "loop.lateness_p99_us", "12.5", "telemetry.dropped"):
        assert text in out, text


def test_monitor_without_a_running_rig_says_so_in_one_line(hub: int, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["monitor", "--port", str(hub), "--duration", "0.1", "--no-live"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rehab-hil monitor: error: no running rig found") and "\n" not in err


def test_monitor_refuses_a_bad_rig_id_and_a_missing_hub(unused_port: int, hub: int,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["monitor", "a/b", "--port", str(hub), "--duration", "0.1", "--no-live"]) == 2
    assert "separator" in capsys.readouterr().err
    assert main(["monitor", "r1", "--port", str(unused_port), "--no-live"]) == 2
    assert "cannot connect to tcp/127.0.0.1" in capsys.readouterr().err


def test_record_from_zenoh_writes_the_rigs_samples_until_the_rig_stops(
        client: Callable[..., zenoh.Session], hub: int, wait, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    recs = records(250)
    codes: list[int] = []
    pub = TelemetryPublisher(client(), "rec1", info=info())
    th = threading.Thread(target=lambda: codes.append(
        main(["record", "--from-zenoh", "rec1", "--out", str(tmp_path), "--port", str(hub), "--wait", "10"])))
    th.start()
    try:
        assert wait(pub.has_subscribers)
        for r in recs:
            pub.offer(r)
    finally:
        pub.close()  # the rig stops: the recorder finishes on its own
        th.join(30)
    assert codes == [0]
    (run_dir,) = tmp_path.iterdir()  # one run directory: <UTC start>-rec1
    assert run_dir.name.endswith("-rec1") and (run_dir / "metadata.json").is_file()
    rec = read_csv(run_dir / "run.csv")
    assert list(rec["sample_index"]) == [r.sample.sample_index for r in recs]
    assert list(rec["host_time_s"]) == [r.host_time_s for r in recs]
    assert "rig stopped: rig rec1: 250 records, 250 CSV rows" in capsys.readouterr().out


def test_record_refuses_a_rig_that_never_answers(hub: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["record", "--from-zenoh", "ghost", "--out", str(tmp_path), "--port", str(hub), "--wait", "0.3"]) == 2
    assert "no live rig matches 'ghost' within 0.3 s" in capsys.readouterr().err


def test_user_without_a_password_source_is_refused(hub: int, tmp_path: Path, monkeypatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv("REHAB_ZENOH_PASSWORD", raising=False)
    assert main(["record", "--from-zenoh", "r", "--out", str(tmp_path), "--port", str(hub), "--user", "v"]) == 2
    assert "--password-file" in capsys.readouterr().err


def test_monitor_live_screen_runs_and_exits_after_its_duration(client: Callable[..., zenoh.Session], hub: int,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    with TelemetryPublisher(client(), "live1", info=info()) as pub:
        for r in records(20):
            pub.offer(r)
        assert main(["monitor", "live1", "--port", str(hub), "--duration", "0.6"]) == 0
    assert "rig live1" in capsys.readouterr().out
