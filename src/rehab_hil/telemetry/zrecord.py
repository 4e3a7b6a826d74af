"""Record a rig from zenoh into the same CSV and MCAP files a local recording writes.

Decoded ``StateSample`` s are turned back into the loop's records (``loop.records``) and handed
to the loop's ``Recorder`` unchanged, so both paths share one writer (docs/telemetry.md).

Nothing is lost silently. The rig publishes reliably with congestion control BLOCK and the
recorder's queue blocks instead of dropping, so a busy recorder slows the rig's publisher thread
(whose own queue counts any overflow) rather than losing samples on the way; the subscription
begins with the publisher's history (a recorder that joins late gets the session from its first
sample) and recovers misses from its cache. What still goes missing is named where it went, once
the rig's last ``stats`` message (``final``, sent after its last batch) has arrived: dropped at the
rig's publisher, older than the publisher's history when the recorder joined, lost in transit, or
refused by the writer; the four add up to what the recording lacks (``accounting()``; run metadata
and MCAP summary).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.recorder import Recorder
from rehab_hil.loop.records import CommandRecord, EventRecord, SampleRecord
from rehab_hil.loop.sinks import Overflow
from rehab_hil.protocol import Sample
from rehab_hil.telemetry.codec import StateSample
from rehab_hil.telemetry.subscriber import Subscription, subscribe, watch_alive

__all__ = ["ZenohRecorder", "to_record"]

_RAW = ("device_time_us", "sample_index", "encoder_count", "adc0", "adc1", "duty0", "duty1",
        "direction", "status", "faults", "cmd_seq_echo", "rx_bad_frames")


def to_record(s: StateSample, analog_names: list[str] | tuple[str, ...]) -> SampleRecord | CommandRecord:
    """The loop record a ``StateSample`` was encoded from (exact: the wire carries f64 values): a
    ``SampleRecord`` when it carries a device SAMPLE, else a ``CommandRecord``."""
    cmd = Command((s.command_duty0, s.command_duty1), s.command_direction, s.command_enable, s.reference_deg)
    if not s.has_sample:
        return CommandRecord(s.host_time_s, s.time_s, cmd, s.command_seq, s.temperature_c)
    sample = Sample(*(getattr(s, f) for f in _RAW))
    state = None
    if s.has_state:
        if len(s.analog) > len(analog_names):
            raise ValueError(f"sample has {len(s.analog)} analog values but only names {list(analog_names)}")
        state = State(s.state_t_s, s.angle_rad, s.velocity_rad_s, dict(zip(analog_names, s.analog, strict=False)))
    return SampleRecord(s.host_time_s, s.time_s, sample, state, cmd, s.command_seq, s.temperature_c)


class ZenohRecorder:
    """Subscribe to a rig's samples, safety events and stats and write them with a ``Recorder``.

    ``done`` is set when the rig's liveliness token goes away (its run ended); ``finished`` when the
    rig's final stats message arrived (nothing more will come); ``period_s`` (the rig's ``info``)
    lets the accounting say how many samples came before the first one received. ``history=False``:
    records from the moment it subscribes; ``recovery``: asks the publisher's cache for misses."""

    def __init__(self, session: zenoh.Session, rig: str, out_dir: str | Path, binding: DeviceBinding,
                 name: str = "run", metadata: dict[str, Any] | None = None, period_s: float | None = None,
                 history: bool = True, recovery: bool = False) -> None:
        # a full queue waits: back-pressure to zenoh, and so to the rig's publisher, instead of loss
        self.recorder = Recorder(out_dir, binding, name=name, metadata=metadata, overflow=Overflow.WAIT)
        self._names = [ch.signal for ch in binding.adc]
        self.period_s = period_s
        self.samples = 0  # records received and written (samples and commands)
        self.samples_received = 0  # of those, records that carry a device SAMPLE
        self.writer_refused = 0  # device samples received that the writer did not take
        self.sample_index_gaps = 0  # samples missing between received ones (sample_index steps > 1)
        self.first_time_s: float | None = None  # session time of the first sample received
        self.rig_final: dict[str, Any] | None = None  # the publisher's counters in its final stats
        self.bad = 0
        self.done = threading.Event()
        self.seen_alive = threading.Event()
        self.finished = threading.Event()
        self._last_index: int | None = None
        self._closed = False
        self._lock = threading.Lock()
        self._watch = watch_alive(session, self._alive, rig=rig)
        self.subscription: Subscription = subscribe(rig, self._on_sample, on_safety=self._on_safety,
                                                    on_stats=self._on_stats, session=session, history=history,
                                                    recovery=recovery)

    def _alive(self, rig: str, alive: bool) -> None:
        (self.seen_alive if alive else self.done).set()

    def _on_sample(self, s: StateSample) -> None:
        try:
            rec = to_record(s, self._names)
        except ValueError:
            self.bad += 1
            return
        with self._lock:
            if self._closed:
                return
            if s.has_sample:
                self._count(s)
            if not self.recorder.offer(rec) and s.has_sample:
                self.writer_refused += 1
            self.samples += 1

    def _count(self, s: StateSample) -> None:
        self.samples_received += 1
        if self.first_time_s is None:
            self.first_time_s = s.time_s
        last, self._last_index = self._last_index, s.sample_index
        if last is not None:
            step = (s.sample_index - last) & 0xFFFFFFFF
            if 1 < step < 0x80000000:  # a step back is the device restarting: a new sequence
                self.sample_index_gaps += step - 1

    def _on_safety(self, msg: dict[str, Any]) -> None:
        t = msg.get("t_s")
        with self._lock:
            if not self._closed:
                self.recorder.offer(EventRecord(float(t) if isinstance(t, (int, float)) else math.nan,
                                                str(msg.get("reason", msg.get("state", "?"))),
                                                str(msg.get("detail", ""))))

    def _on_stats(self, msg: dict[str, Any]) -> None:
        if msg.get("final") and isinstance(msg.get("telemetry"), dict):
            self.rig_final = dict(msg["telemetry"])
            self.finished.set()

    def wait_finished(self, timeout_s: float, tail_s: float = 2.0) -> bool:
        """Wait until the rig's final stats and its last batch have arrived (the final word comes after
        the last batch; a batch lost in transit is recovered behind it); False if they did not within
        ``timeout_s``, or if the last batch is still missing ``tail_s`` after the final word (lost for
        good: the accounting names it). A rig that was killed says no final word: the tail of its
        recording is then unknown."""
        deadline = time.monotonic() + timeout_s
        tail_end = None
        while time.monotonic() < deadline:
            final = self.rig_final
            if final is not None:
                if self.subscription.batches_seen_up_to(int(final.get("published_batches", 0))):
                    return True
                tail_end = tail_end or time.monotonic() + tail_s
                if time.monotonic() >= tail_end:
                    return False
            time.sleep(0.01)
        return False

    @property
    def samples_not_received(self) -> int | None:
        """Samples the rig published (offered to its publisher) that this recording did not receive;
        None until the rig's final stats have arrived."""
        final = self.rig_final
        if final is None or "samples_offered" not in final:
            return None
        return int(final["samples_offered"]) - self.samples_received

    def losses(self) -> dict[str, int | None]:
        """The rig's device samples this recording lacks, by where they went (None: not known, e.g.
        before the rig's final word): ``at_publisher`` (its queue was full, counted by the rig),
        ``before_joining`` (published before this recorder joined and not in the publisher's history it got),
        ``in_transit`` (missed on the way and not recovered from the publisher's cache),
        ``in_writer`` (received, refused by the writer), ``unexplained`` (what the four leave over:
        0 when the accounting is whole)."""
        final, ledger = self.rig_final, self.subscription.ledger
        at_pub = int(final["samples_dropped"]) if final and "samples_dropped" in final else None
        rig = int(final["samples_offered"]) if final and "samples_offered" in final else None
        tail = None
        if final is not None and rig is not None and at_pub is not None:
            tail = ledger.tail(int(final.get("published_batches", 0)), rig - at_pub)[1]
        in_transit = None if tail is None or ledger.samples_lost is None else ledger.samples_lost + tail
        out: dict[str, int | None] = {"at_publisher": at_pub, "before_joining": ledger.samples_before_first,
                                      "in_transit": in_transit, "in_writer": self.writer_refused}
        parts = list(out.values())
        written = self.samples_received - self.writer_refused
        out["unexplained"] = None if rig is None or None in parts else rig - written - sum(parts)  # type: ignore[arg-type]
        return out

    def accounting(self) -> dict[str, Any]:
        """What this recording holds and what it lacks, in samples (for its metadata and summary)."""
        before = None
        if self.first_time_s is not None and self.period_s:
            before = round(self.first_time_s / self.period_s)
        final = self.rig_final
        missing = self.samples_not_received
        lost = self.losses()
        return {
            "samples_received": self.samples_received,
            "rig_samples": int(final["samples_offered"]) if final and "samples_offered" in final else None,
            "samples_not_received": missing,
            # of those, dropped at the rig's own publisher queue (the rest went missing on the way)
            "rig_samples_dropped": lost["at_publisher"],
            "lost": lost,
            "samples_before_first": before,
            "sample_index_gaps": self.sample_index_gaps,
            "batches": {"received": self.subscription.ledger.batches,
                        "before_joining": self.subscription.ledger.batches_before_first,
                        "lost_in_transit": self.subscription.ledger.batches_lost,
                        "zenoh_reported_missed": self.subscription.zenoh_missed},
            "rig_final_word": final is not None,
            "complete": missing == 0 and self.writer_refused == 0,
        }

    @property
    def dropped(self) -> int:
        """Device samples lost on the way, as far as known now: at the rig's publisher, before its
        history, in transit and at the writer."""
        return sum(v for k, v in self.losses().items() if k != "unexplained" and v)

    def close(self, summary: dict[str, Any] | None = None) -> None:
        """Stop listening and finish both files (``summary``: an MCAP metadata record); idempotent."""
        self.subscription.close()
        with contextlib.suppress(zenoh.ZError):
            self._watch.undeclare()
        with self._lock:
            self._closed = True
        self.recorder.close(summary)

    def __enter__(self) -> ZenohRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
