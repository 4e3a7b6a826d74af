"""A zenoh recording of a running loop equals the local recording, sample for sample."""

from __future__ import annotations

import subprocess
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from rehab_hil.loading import load_config
from rehab_hil.loop.recorder import Recorder, read_mcap
from rehab_hil.plants import get_plant
from rehab_hil.service import assembly
from rehab_hil.service.session import open_session
from rehab_hil.telemetry import TelemetryPublisher
from rehab_hil.telemetry.rig import rig_info
from rehab_hil.telemetry.zrecord import ZenohRecorder

from .fake_rig import LockstepRig, RampController

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "finger_extensor.toml"


def mcap_content(path: Path) -> list[tuple[str, dict]]:
    return [(topic, msg) for topic, _log_time, msg in read_mcap(path)]  # log times are per-process wall clock


def test_a_zenoh_recording_equals_the_local_recording_sample_for_sample(
        client: Callable[..., zenoh.Session], wait, tmp_path: Path) -> None:
    cfg = load_config(CONFIG)
    binding = get_plant(cfg.plant).device(cfg)
    rig_session, rec_session = client(), client()
    zrec = ZenohRecorder(rec_session, "loop1", tmp_path / "zenoh", binding)
    local = Recorder(tmp_path / "local", binding)
    hw = LockstepRig()
    hw.connect()
    info = rig_info(cfg.plant, CONFIG, binding, assembly.period_s(cfg), hw.info)
    pub = TelemetryPublisher(rig_session, "loop1", info=info, queue_size=20_000)
    try:
        assert wait(pub.has_subscribers)
        with open_session(CONFIG, hw=hw, controller=RampController(), sinks=(local, pub), realtime=False,
                          sample_timeout_s=0.5) as session:
            result = session.run(0.6)
        assert result.cycles > 500 and not result.events
    finally:
        local.close()
        pub.close()
    assert pub.dropped == 0
    assert wait(lambda: zrec.samples == pub.published_samples)
    assert wait(zrec.done.is_set)  # the rig's liveliness token went with pub.close()
    zrec.close()
    assert zrec.subscription.missing_batches == 0 and zrec.recorder.dropped == 0 and local.dropped == 0
    local_csv = (tmp_path / "local" / "run.csv").read_text()
    zenoh_csv = (tmp_path / "zenoh" / "run.csv").read_text()
    assert local_csv.count("\n") > 500
    assert zenoh_csv == local_csv
    assert mcap_content(tmp_path / "zenoh" / "run.mcap") == mcap_content(tmp_path / "local" / "run.mcap")


def _indices(csv: Path) -> list[int]:
    """The sample_index column of a recording's CSV."""
    lines = csv.read_text().splitlines()
    col = lines[0].split(",").index("sample_index")
    return [int(float(line.split(",")[col])) for line in lines[1:]]


@pytest.mark.slow
@pytest.mark.parametrize("queue_size", [20_000, 30], ids=["shipped_queue", "overflowing_queue"])
def test_a_zenoh_recording_on_a_busy_machine_states_every_sample_it_did_not_receive(
        client: Callable[..., zenoh.Session], wait, tmp_path: Path, queue_size: int) -> None:
    """Two busy processes beside the rig (one per core of the 2-core CI machine) and the loop running
    flat out on the in-process lockstep rig. The recording's own count of the samples it did not
    receive equals what its CSV lacks against the rig's local recording, and every one of them is a
    sample the rig's publisher queue dropped and counted: the path after it (reliable, blocking)
    loses none. With the shipped queue the publisher may still fall behind on a loaded machine; a
    30-record queue whose worker is held until the session ends overflows for certain."""
    cfg = load_config(CONFIG)
    binding = get_plant(cfg.plant).device(cfg)
    busy = [subprocess.Popen(["sh", "-c", "while :; do :; done"]) for _ in range(2)]
    try:
        zrec = ZenohRecorder(client(), "busy1", tmp_path / "zenoh", binding, period_s=assembly.period_s(cfg))
        local = Recorder(tmp_path / "local", binding)
        hw = LockstepRig()
        hw.connect()
        info = rig_info(cfg.plant, CONFIG, binding, assembly.period_s(cfg), hw.info)
        pub = TelemetryPublisher(client(), "busy1", info=info, queue_size=queue_size, batch=10)
        held = threading.Event()
        if queue_size < 1000:  # the worker stuck in its first put until the loop is done
            put = pub._put_batch

            def held_put(*batch: object) -> None:
                held.wait(60)
                put(*batch)

            pub._put_batch = held_put  # type: ignore[method-assign]
        try:
            assert wait(pub.has_subscribers)
            with open_session(CONFIG, hw=hw, controller=RampController(), sinks=(local, pub), realtime=False,
                              sample_timeout_s=5.0) as session:
                result = session.run(2.0)
            assert not result.events
        finally:
            held.set()
            local.close()
            pub.close(timeout_s=60)  # the final stats go out after the last batch
        assert wait(zrec.done.is_set, 60) and zrec.wait_finished(60)
        zrec.close()
    finally:
        for p in busy:
            p.kill()
            p.wait()
    rig = _indices(tmp_path / "local" / "run.csv")
    got = _indices(tmp_path / "zenoh" / "run.csv")
    missing = sorted(set(rig) - set(got))
    assert set(got) <= set(rig) and len(rig) == result.samples
    acc = zrec.accounting()
    assert acc["rig_samples"] == len(rig) and acc["samples_received"] == len(got)
    assert acc["samples_not_received"] == len(missing)  # stated = actual
    assert acc["rig_samples_dropped"] == pub.samples_dropped == len(missing)  # all at the rig's counted queue
    assert acc["lost"] == {"at_publisher": len(missing), "before_joining": 0, "in_transit": 0, "in_writer": 0,
                           "unexplained": 0}  # named where it happened, adding up to what is missing
    between = [i for i in missing if got and got[0] < i < got[-1]]
    assert acc["sample_index_gaps"] == len(between)
    assert acc["samples_before_first"] == rig.index(got[0])
    assert acc["complete"] == (not missing)
    if queue_size < 1000:
        assert missing  # the held worker's queue did overflow
