"""TelemetryPublisher against real zenoh sessions: one loopback hub, the rig and the viewers are clients."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import zenoh

from rehab_hil.protocol import Sample
from rehab_hil.telemetry import TelemetryPublisher, decode_json, subscribe
from rehab_hil.telemetry.codec import StateSample


def raw(i: int) -> Sample:
    return Sample(i * 1000, i, i - 500, i % 1024, 1023 - i % 1024, i % 10_001, 0, i & 1, 3, 0, i & 0xFFFF, 0)


def test_samples_published_arrive_complete_and_in_order(client: Callable[..., zenoh.Session], wait) -> None:
    rig, viewer = client(), client()
    got: list[StateSample] = []
    with subscribe("r1", got.append, session=viewer) as sub, TelemetryPublisher(rig, "r1", batch=10) as pub:
        assert wait(pub.has_subscribers)
        for i in range(2005):  # not a multiple of the batch: the tail leaves after max_delay_s
            assert pub.offer(raw(i))
            if i % 50 == 49:
                time.sleep(0.005)  # about 10 kHz: above the loop's rate, not a flood
        assert wait(lambda: len(got) == 2005)
        assert sub.missing_batches == 0 and sub.bad_payloads == 0
    assert [s.sample_index for s in got] == list(range(2005))
    assert [(s.device_time_us, s.encoder_count, s.adc0, s.adc1, s.duty0, s.cmd_seq_echo) for s in got] == [
        (r.device_time_us, r.encoder_count, r.adc0, r.adc1, r.duty0, r.cmd_seq_echo) for r in map(raw, range(2005))]
    assert pub.dropped == 0 and pub.published_samples == 2005


def test_a_full_queue_drops_and_counts_without_blocking_and_stats_report_it(
        client: Callable[..., zenoh.Session], wait) -> None:
    rig, viewer = client(), client()
    stats: list[dict] = []
    release = threading.Event()
    with subscribe("r2", None, on_stats=stats.append, session=viewer), \
            TelemetryPublisher(rig, "r2", batch=10, queue_size=20, stats_period_s=0.05) as pub:
        real_put = pub._put_batch

        def stalled_put(*batch: object) -> None:  # a publisher thread stuck in the network
            release.wait(10)
            real_put(*batch)

        pub._put_batch = stalled_put  # type: ignore[method-assign]
        accepted = [pub.offer(raw(i)) for i in range(200)]
        assert accepted.count(False) == pub.dropped > 0
        assert pub.offered == 200
        release.set()
        assert wait(lambda: any(m["telemetry"]["dropped"] == pub.dropped for m in stats))


def test_a_closed_publisher_refuses_samples(client: Callable[..., zenoh.Session]) -> None:
    pub = TelemetryPublisher(client(), "r3")
    pub.close()
    assert pub.offer(raw(0)) is False and pub.dropped == 1


def test_safety_events_and_stats_arrive_as_versioned_json(client: Callable[..., zenoh.Session], wait) -> None:
    rig, viewer = client(), client()
    events: list[dict] = []
    stats: list[dict] = []
    with subscribe("r4", None, on_safety=events.append, on_stats=stats.append, session=viewer), \
            TelemetryPublisher(rig, "r4", stats_period_s=0.05) as pub:
        pub.update_stats({"lateness_p99_us": 21.5, "link": {"rx_bad_frames": 0}})
        assert wait(lambda: any(m["loop"].get("lateness_p99_us") == 21.5 for m in stats))
        pub.offer_safety({"state": "tripped", "reason": "force", "detail": "41 N > 40 N"})
        assert wait(lambda: len(events) == 1)
    assert events[0]["v"] == 1 and events[0]["kind"] == "safety" and events[0]["reason"] == "force"
    assert events[0]["rig"] == "r4"
    assert decode_json(b'{"v":1,"kind":"stats"}')["kind"] == "stats"


def test_two_rigs_on_one_hub_do_not_see_each_others_samples(client: Callable[..., zenoh.Session], wait) -> None:
    got_a: list[StateSample] = []
    got_b: list[StateSample] = []
    viewer = client()
    with subscribe("a", got_a.append, session=viewer), subscribe("b", got_b.append, session=viewer), \
            TelemetryPublisher(client(), "a", batch=1) as pa, TelemetryPublisher(client(), "b", batch=1) as pb:
        assert wait(pa.has_subscribers) and wait(pb.has_subscribers)
        pa.offer(raw(1))
        pb.offer(raw(2))
        pb.offer(raw(3))
        assert wait(lambda: len(got_a) == 1 and len(got_b) == 2)
    assert [s.sample_index for s in got_a] == [1] and [s.sample_index for s in got_b] == [2, 3]


def test_an_unpublishable_offer_is_counted_and_the_stream_goes_on(client: Callable[..., zenoh.Session],
                                                                  wait) -> None:
    got: list[StateSample] = []
    viewer = client()
    with subscribe("g1", got.append, session=viewer), TelemetryPublisher(client(), "g1", batch=2) as pub:
        assert wait(pub.has_subscribers)
        pub.offer(raw(1))
        pub.offer(object())  # not a sample: refused by the codec on the worker thread
        pub.offer(Sample(0, 2, 0, 70_000, 0, 0, 0, 0, 0, 0, 0, 0))  # adc0 out of u16 range
        pub.offer(raw(3))
        assert wait(lambda: len(got) == 2)
    assert [s.sample_index for s in got] == [1, 3] and pub.publish_errors == 2


def test_the_publisher_is_a_loop_telemetry_sink(client: Callable[..., zenoh.Session]) -> None:
    from rehab_hil.loop.stats import TelemetrySink

    with TelemetryPublisher(client(), "sink1") as pub:
        assert isinstance(pub, TelemetrySink)
