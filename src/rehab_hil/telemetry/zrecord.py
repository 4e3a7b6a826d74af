"""Record a rig from zenoh into the same CSV and MCAP files a local recording writes.

Decoded ``StateSample`` s are turned back into the loop's ``Record`` objects and handed to the
loop engineer's ``Recorder`` unchanged, so both paths share one writer (docs/telemetry.md).
"""

from __future__ import annotations

import contextlib
import math
import threading
from pathlib import Path
from typing import Any

import zenoh

from rehab_hil.plants.base import DeviceBinding
from rehab_hil.protocol import Sample
from rehab_hil.service.controllers import Command
from rehab_hil.service.estimation import State
from rehab_hil.service.recorder import Record, Recorder
from rehab_hil.telemetry.codec import StateSample
from rehab_hil.telemetry.subscriber import Subscription, subscribe, watch_alive

__all__ = ["ZenohRecorder", "to_record"]

_RAW = ("device_time_us", "sample_index", "encoder_count", "adc0", "adc1", "duty0", "duty1",
        "direction", "status", "faults", "cmd_seq_echo", "rx_bad_frames")


def to_record(s: StateSample, analog_names: list[str] | tuple[str, ...]) -> Record:
    """The loop ``Record`` a ``StateSample`` was encoded from (exact: the wire carries f64 values)."""
    sample = Sample(*(getattr(s, f) for f in _RAW)) if s.has_sample else None
    state = None
    if s.has_state:
        if len(s.analog) > len(analog_names):
            raise ValueError(f"sample has {len(s.analog)} analog values but only names {list(analog_names)}")
        state = State(s.state_t_s, s.angle_rad, s.velocity_rad_s, dict(zip(analog_names, s.analog, strict=False)))
    cmd = Command((s.command_duty0, s.command_duty1), s.command_direction, s.command_enable, s.reference_deg)
    return Record(s.host_time_s, s.time_s, sample, state, cmd, s.command_seq, s.temperature_c)


class ZenohRecorder:
    """Subscribe to a rig's samples and safety events and write them with a ``Recorder``.

    ``done`` is set when the rig's liveliness token goes away (its run ended)."""

    def __init__(self, session: zenoh.Session, rig: str, out_dir: str | Path, binding: DeviceBinding,
                 name: str = "run", metadata: dict[str, Any] | None = None) -> None:
        self.recorder = Recorder(out_dir, binding, name=name, metadata=metadata)
        self._names = [ch.signal for ch in binding.adc]
        self.samples = 0
        self.bad = 0
        self.done = threading.Event()
        self.seen_alive = threading.Event()
        self._closed = False
        self._lock = threading.Lock()
        self._watch = watch_alive(session, self._alive, rig=rig)
        self.subscription: Subscription = subscribe(rig, self._on_sample, on_safety=self._on_safety, session=session)

    def _alive(self, rig: str, alive: bool) -> None:
        (self.seen_alive if alive else self.done).set()

    def _on_sample(self, s: StateSample) -> None:
        try:
            rec = to_record(s, self._names)
        except ValueError:
            self.bad += 1
            return
        with self._lock:
            if not self._closed:
                self.recorder.offer(rec)
                self.samples += 1

    def _on_safety(self, msg: dict[str, Any]) -> None:
        t = msg.get("t_s")
        with self._lock:
            if not self._closed:
                self.recorder.event(float(t) if isinstance(t, (int, float)) else math.nan,
                                    str(msg.get("reason", msg.get("state", "?"))), str(msg.get("detail", "")))

    @property
    def dropped(self) -> int:
        """Samples lost on the way: publisher drops, missing batches (as reported) and recorder drops."""
        return self.subscription.publisher_dropped + self.subscription.missing_batches + self.recorder.dropped

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
