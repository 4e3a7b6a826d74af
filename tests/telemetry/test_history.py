"""A recording has the whole session: zenoh's publisher history for late joiners, recovery of what is
lost in transit, and every sample it still lacks named where it went (``telemetry.history``,
``telemetry.zrecord``). Real zenoh sessions on loopback; loss is injected by the hub's own
downsampling interceptor, which drops puts in transit."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest
import zenoh

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv
from rehab_hil.loading import load_config
from rehab_hil.loop.records import SampleRecord
from rehab_hil.plants import get_plant
from rehab_hil.telemetry import NetworkConfig, TelemetryPublisher, decode_state, subscribe
from rehab_hil.telemetry.history import BATCH_ATTACHMENT, BatchLedger
from rehab_hil.telemetry.rig import RigTelemetry
from rehab_hil.telemetry.session import TelemetryConfigError, open_session
from rehab_hil.telemetry.zrecord import ZenohRecorder

from .conftest import open_lossy_hub
from .test_cli import CONFIG, info, records


def _att(records_before: int, samples_before: int) -> bytes:
    return BATCH_ATTACHMENT.pack(records_before, samples_before)


def test_the_ledger_counts_the_samples_of_batches_it_never_received() -> None:
    led = BatchLedger()
    led.add(3, 4, _att(60, 30))  # joined at batch 3: batches 0-2 held 30 samples
    led.add(4, 5, _att(70, 34))
    led.add(7, 5, _att(100, 50))  # batches 5 and 6 lost: 50 - 39 = 11 samples
    assert (led.batches_before_first, led.samples_before_first) == (3, 30)
    assert (led.batches_lost, led.samples_lost) == (2, 11)
    assert led.tail(10, 70) == (2, 15)  # batches 8 and 9 after the last one: 70 - 55
    assert led.batches == 3 and led.samples == 14


def test_the_ledger_takes_a_step_back_for_a_new_publisher_and_knows_batches_without_attachments() -> None:
    led = BatchLedger()
    led.add(0, 10, _att(0, 0))
    led.add(1, 10, _att(10, 10))
    led.add(0, 10, _att(0, 0))  # the rig restarted: counting starts over, nothing lost
    assert led.restarts == 1 and led.batches_lost == 0 and led.samples_lost == 0
    foreign = BatchLedger()
    foreign.add(2, 10, None)
    foreign.add(5, 10, None)
    assert foreign.batches_before_first == 2 and foreign.samples_before_first is None
    assert foreign.batches_lost == 2 and foreign.samples_lost is None


def _binding():  # type: ignore[no-untyped-def]
    cfg = load_config(CONFIG)
    return get_plant(cfg.plant).device(cfg)


def _offer(pub: TelemetryPublisher, recs: Iterable[SampleRecord], every_s: float = 0.0) -> None:
    """Offer records as a loop does (``wake`` after each), ``every_s`` apart."""
    for r in recs:
        assert pub.offer(r)
        pub.wake()
        if every_s:
            time.sleep(every_s)


def _finish(pub: TelemetryPublisher, *zrecs: ZenohRecorder) -> None:
    pub.close(timeout_s=30)
    for z in zrecs:
        assert z.wait_finished(30), "the rig's final word and last batch did not arrive"
        z.close()


def _indices(path: Path) -> list[int]:
    return [int(i) for i in read_csv(path / "run.csv")["sample_index"]]


def test_a_recorder_that_joins_late_gets_the_session_from_its_first_sample(
        client: Callable[..., zenoh.Session], wait, tmp_path: Path) -> None:
    recs = records(600)
    pub = TelemetryPublisher(client(), "late1", info=info())
    _offer(pub, recs[:300])
    assert wait(lambda: pub.published_samples == 300)  # these went out before anyone subscribed
    zrec = ZenohRecorder(client(), "late1", tmp_path / "history", _binding())
    plain = ZenohRecorder(client(), "late1", tmp_path / "plain", _binding(), history=False)
    assert wait(lambda: zrec.samples_received == 300)  # the history arrived before the live samples
    _offer(pub, recs[300:])
    _finish(pub, zrec, plain)
    want = [r.sample.sample_index for r in recs]
    assert _indices(tmp_path / "history") == want
    acc = zrec.accounting()
    assert acc["complete"] and acc["samples_not_received"] == 0
    assert acc["lost"] == {"at_publisher": 0, "before_joining": 0, "in_transit": 0, "in_writer": 0, "unexplained": 0}
    # without the history, the same recorder lacks the first 300 and says where they went
    assert _indices(tmp_path / "plain") == want[300:]
    lost = plain.accounting()["lost"]
    assert lost == {"at_publisher": 0, "before_joining": 300, "in_transit": 0, "in_writer": 0, "unexplained": 0}


def test_samples_older_than_the_publishers_history_are_named_as_such(
        client: Callable[..., zenoh.Session], wait, tmp_path: Path) -> None:
    recs = records(400)
    pub = TelemetryPublisher(client(), "short1", info=info(), cache_batches=5)  # keeps 5 batches of 10
    _offer(pub, recs[:300])
    assert wait(lambda: pub.published_batches == 30)
    zrec = ZenohRecorder(client(), "short1", tmp_path, _binding())
    assert wait(lambda: zrec.samples_received == 50)
    _offer(pub, recs[300:])
    _finish(pub, zrec)
    assert _indices(tmp_path) == [r.sample.sample_index for r in recs[250:]]
    acc = zrec.accounting()
    assert acc["lost"] == {"at_publisher": 0, "before_joining": 250, "in_transit": 0, "in_writer": 0,
                           "unexplained": 0}
    assert acc["samples_not_received"] == 250 and acc["batches"]["before_joining"] == 25 and not acc["complete"]


@pytest.mark.parametrize(("recovery", "cache_batches"), [(True, 12_000), (True, 1), (False, 12_000)],
                         ids=["recovered", "past_the_cache", "no_recovery"])
def test_a_loss_in_transit_is_recovered_or_named_in_transit(recovery: bool, cache_batches: int, wait,
                                                            tmp_path: Path) -> None:
    """The hub lets 40 puts/s of the rig's state through to each subscriber; the rig puts about 100/s.
    A plain subscriber sees the gaps. With recovery and the shipped cache the recording recovers every
    batch; with a cache of one batch, or without recovery, it names each lost sample in transit."""
    hub, port = open_lossy_hub("rehab/lossy1/state", 40.0)
    opened = [open_session(NetworkConfig(port=port)) for _ in range(3)]
    try:
        plain_seqs: list[int] = []
        plain = opened[0].declare_subscriber(
            "rehab/lossy1/state", lambda s: plain_seqs.append(decode_state(s.payload.to_bytes()).batch_seq))
        zrec = ZenohRecorder(opened[1], "lossy1", tmp_path, _binding(), recovery=recovery)
        pub = TelemetryPublisher(opened[2], "lossy1", info=info(), cache_batches=cache_batches)
        assert wait(pub.has_subscribers)
        recs = records(800)
        _offer(pub, recs, every_s=0.001)
        pub.close(timeout_s=30)
        zrec.wait_finished(30)  # False if the last batch was lost for good: the accounting names it
        assert zrec.rig_final is not None
        zrec.close()
        plain.undeclare()
    finally:
        for s in opened:
            s.close()
        hub.close()
    assert len(plain_seqs) < pub.published_batches * 0.8  # the hub did drop puts in transit
    got, want = _indices(tmp_path), [r.sample.sample_index for r in recs]
    acc = zrec.accounting()
    lost = acc["lost"]
    assert lost["at_publisher"] == 0 and lost["before_joining"] == 0 and lost["unexplained"] == 0
    if recovery and cache_batches > 1:
        assert got == want and acc["complete"] and lost["in_transit"] == 0
    else:
        assert set(got) < set(want) and got == sorted(got)
        assert lost["in_transit"] == len(want) - len(got) == acc["samples_not_received"] > 0
        assert acc["batches"]["lost_in_transit"] > 0 and acc["batches"]["zenoh_reported_missed"] > 0


def test_a_subscriber_started_before_its_rig_waits_for_the_rigs_hub(unused_port: int, wait) -> None:
    got: list[int] = []
    subs: list[object] = []
    th = threading.Thread(target=lambda: subs.append(subscribe(
        "first1", lambda s: got.append(s.sample_index), net=NetworkConfig(port=unused_port), wait_s=30)))
    th.start()
    time.sleep(0.5)  # the subscriber is waiting: nothing listens on the port yet
    assert th.is_alive()
    recs = records(300)
    with RigTelemetry("first1", info(), NetworkConfig(port=unused_port)) as rig:  # hosts the hub
        assert rig.role == "hub"
        th.join(30)
        assert subs, "the subscriber did not connect to the rig's hub"
        _offer(rig.sink, recs)
        assert wait(lambda: len(got) == len(recs))
    subs[0].close()  # type: ignore[attr-defined]
    assert got == [r.sample.sample_index for r in recs]


def test_a_subscriber_that_waits_in_vain_says_so_in_one_line(unused_port: int) -> None:
    with pytest.raises(TelemetryConfigError, match=r"cannot connect to tcp/127.0.0.1:\d+ within 0.3 s"):
        subscribe("nobody", lambda s: None, net=NetworkConfig(port=unused_port), wait_s=0.3)


@pytest.mark.parametrize("start", ["before", "after"])
def test_record_from_zenoh_started_before_or_after_the_rig_gets_every_sample(
        start: str, unused_port: int, wait, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The rig hosts the hub. Started before, the recorder waits for the hub and the rig; started
    0.5 s into the session, it gets the part it missed from the publisher's history."""
    recs = records(1500)
    codes: list[int] = []
    cmd = ["record", "--from-zenoh", "whole1", "--out", str(tmp_path), "--port", str(unused_port), "--wait", "30"]
    recorder = threading.Thread(target=lambda: codes.append(main(cmd)))
    if start == "before":
        recorder.start()
        time.sleep(0.5)
    with RigTelemetry("whole1", info(), NetworkConfig(port=unused_port)) as rig:
        feed = threading.Thread(target=_offer, args=(rig.sink, recs, 0.001))
        feed.start()
        if start == "after":
            time.sleep(0.5)
            recorder.start()
        feed.join()
        if start == "before":
            assert wait(lambda: any(tmp_path.iterdir()))  # it is recording
    recorder.join(60)
    assert codes == [0]
    (run_dir,) = tmp_path.iterdir()
    assert _indices(run_dir) == [r.sample.sample_index for r in recs]
    out = capsys.readouterr().out
    assert ("1500 of the rig's 1500 samples received, 0 missing: 0 dropped at the rig's publisher, 0 from before "
            "it joined, not in the publisher's history, 0 lost in transit, 0 refused by the writer") in out
