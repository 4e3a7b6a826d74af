"""Recording of every sample and command to the interchange CSV and to MCAP, off the loop thread.

The loop calls ``offer`` after its command is out (never blocks, wakes nothing: a full queue drops
and counts the record) and ``wake`` once per cycle when all of the cycle's records are there; the
writer thread then works while the loop waits for its next sample, and otherwise every ``flush_s``
(a producer that never calls ``wake`` gets its records written in batches). It turns records into
CSV rows (plant signal names + raw columns) and MCAP messages on JSON-schema
channels (``/rig/sample``, ``/rig/command``, ``/rig/event``; Foxglove and PlotJuggler open them),
and flushes both files at least every ``flush_s``: a killed run leaves files that hold everything
up to the last flush. ``read_mcap`` reads such a file even without its footer. The session's
metadata (``service/run_dir.py``) goes into MCAP metadata records at the start and the end.
"""

from __future__ import annotations

import json
import math
import operator
import os
import struct
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson
from mcap.exceptions import McapError
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.protocol import DUTY_FULL, Sample
from rehab_hil.service.controllers import Command
from rehab_hil.service.estimation import State
from rehab_hil.session_metrics import CycleMetrics

__all__ = ["GENERIC_FIELDS", "Record", "Recorder", "csv_columns", "generic_fields", "read_mcap"]

RAW_COLUMNS = (
    "host_time_s", "device_time_s", "sample_index", "raw_encoder_counts", "raw_adc0_counts",
    "raw_adc1_counts", "applied_duty0_ratio", "applied_duty1_ratio", "direction_bits", "status_bits",
    "fault_bits", "cmd_seq_echo", "device_rx_bad_frames", "command_duty0_ratio", "command_duty1_ratio",
    "command_direction_bits", "command_enable_bool", "command_seq", "estimated_velocity_rad_s",
    "estimated_temperature_c",
)


@dataclass(frozen=True)
class Record:
    """What the loop hands over per cycle: the sample it consumed (or None) and the command sent."""

    host_time_s: float
    time_s: float  # position on the recording's time axis (continued sample index x period)
    sample: Sample | None
    state: State | None
    command: Command
    command_seq: int
    temperature_c: float


CYCLE_FIELDS = tuple(CycleMetrics.__dataclass_fields__)


def csv_columns(binding: DeviceBinding) -> list[str]:
    """Plant signal names first (angle in rad and deg, reference, calibrated ADC, PWM-driven inputs),
    then the raw columns."""
    plant = [binding.encoder_signal, binding.angle_output, binding.reference_column,
             *(ch.signal for ch in binding.adc), *binding.duty_inputs]
    return list(dict.fromkeys([*plant, *RAW_COLUMNS]))


# plant-independent names in every MCAP sample message, so that one Foxglove layout
# (docs/foxglove_layout.json) plots every plant; the plant's own names stay alongside
GENERIC_FIELDS = ("angle_deg", "reference_deg", "analog0", "analog1")


def generic_fields(r: Record) -> dict[str, float]:
    """The plant-independent fields of a sample record: angle, reference, first two calibrated ADC signals."""
    assert r.state is not None
    a = [*r.state.analog.values(), math.nan, math.nan]
    return {"angle_deg": r.state.angle_deg, "reference_deg": r.command.reference_deg, "analog0": a[0], "analog1": a[1]}


def _schema(title: str, fields: list[str]) -> bytes:
    return json.dumps({"title": title, "type": "object",
                       "properties": {f: {"type": "number"} for f in fields}}).encode()


def _metadata_strings(meta: dict[str, Any]) -> dict[str, str]:
    """MCAP metadata values are strings: nested values become JSON."""
    return {str(k): v if isinstance(v, str) else json.dumps(v, default=str) for k, v in meta.items()}


def _json(body: dict[str, Any]) -> bytes:
    """One message's JSON (orjson: a non-finite float becomes null, numpy scalars are numbers)."""
    return orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY)


class Recorder:
    """Writes ``<out_dir>/<name>.csv`` and ``<out_dir>/<name>.mcap`` from a bounded queue."""

    def __init__(self, out_dir: str | Path, binding: DeviceBinding, name: str = "run",
                 queue_size: int = 20_000, flush_s: float = 0.1, metadata: dict[str, Any] | None = None) -> None:
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.csv_path = self.out_dir / f"{name}.csv"
        self.mcap_path = self.out_dir / f"{name}.mcap"
        self.binding = binding
        self.columns = csv_columns(binding)
        keys = ["time_s", *self.columns]
        self._csv_values = operator.itemgetter(*keys)  # a row dict -> its CSV values in column order
        self._csv_line = ",".join(["%.10g"] * len(keys)) + "\n"
        self.flush_s = flush_s
        self.dropped = 0
        self.rows = 0
        self.messages = 0
        self._cap = queue_size
        self._q: deque[Record | tuple[str, Any]] = deque()  # appended by the loop, taken by the writer
        self._kick = threading.Event()
        self._closing = False
        self._csv_fd = os.open(self.csv_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.write(self._csv_fd, (",".join(["time_s", *self.columns]) + "\n").encode())
        self._mcap_fh = open(self.mcap_path, "wb")
        self._mcap = Writer(self._mcap_fh, compression=CompressionType.NONE)
        self._mcap.start(profile="", library="rehab-hil")
        sample_fields = ["time_s", *self.columns, *GENERIC_FIELDS]
        cmd_fields = ["host_time_s", "duty0_ratio", "duty1_ratio", "direction_bits", "enable_bool", "seq",
                      "reference_deg"]
        self._ch_sample = self._channel("/rig/sample", "rehab_hil.Sample", sample_fields)
        self._ch_cmd = self._channel("/rig/command", "rehab_hil.Command", cmd_fields)
        ev_schema = self._mcap.register_schema(
            "rehab_hil.Event", "jsonschema",
            json.dumps({"title": "rehab_hil.Event", "type": "object",
                        "properties": {"time_s": {"type": "number"}, "kind": {"type": "string"},
                                       "detail": {"type": "string"}}}).encode())
        self._ch_event = self._mcap.register_channel("/rig/event", "json", ev_schema)
        self._ch_cycle = self._channel("/rig/cycle", "rehab_hil.Cycle", list(CYCLE_FIELDS))
        self._extra: dict[str, int] = {}  # topic -> channel of ``message``
        if metadata:
            self._mcap.add_metadata("rehab_hil.session", _metadata_strings(metadata))
        self._mcap.flush()
        self._wall0_ns = time.time_ns() - int(time.perf_counter() * 1e9)
        self._last_time_s = -math.inf
        self._pending: list[str] = []
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._closed = False
        self._thread.start()

    def _channel(self, topic: str, name: str, fields: list[str]) -> int:
        sid = self._mcap.register_schema(name, "jsonschema", _schema(name, fields))
        return self._mcap.register_channel(topic, "json", sid)

    # -- loop side -------------------------------------------------------------------------
    def offer(self, record: Record, block: bool = False) -> bool:
        """Queue one record without blocking or waking the writer; False (and counted) if the queue
        is full. ``block``: wait for room instead (a zenoh recording: back-pressure, not loss)."""
        if len(self._q) >= self._cap:
            if not block:
                self.dropped += 1
                return False
            while len(self._q) >= self._cap and not self._closing:
                self._kick.set()
                time.sleep(0.001)
        self._q.append(record)
        return True

    def wake(self) -> None:
        """Let the writer take what is queued now (the loop: once per cycle, after its write)."""
        self._kick.set()

    def event(self, time_s: float, kind: str, detail: str = "") -> None:
        """Log a safety or link event (from the loop thread, outside the timed section)."""
        if len(self._q) >= self._cap:
            self.dropped += 1
            return
        self._q.append(("event", (time_s, kind, detail)))
        self._kick.set()

    def cycle(self, metrics: dict[str, float]) -> None:
        """One finished open-close cycle's figures (``session_metrics.CycleMetrics``), outside the
        timed section."""
        if len(self._q) >= self._cap:
            self.dropped += 1
            return
        self._q.append(("cycle", metrics))

    def message(self, topic: str, schema: str, body: dict[str, Any]) -> None:
        """One message on an extra JSON channel (the live twin's ``/twin/prediction``), registered at
        its first message with the fields of that message; from any thread, never blocks."""
        if len(self._q) >= self._cap:
            self.dropped += 1
            return
        self._q.append(("message", (topic, schema, body)))

    def drain(self) -> None:
        """Write everything queued so far and stop the writer: ``rows`` is final from here on (what
        the run's metadata reports), the files still open for ``close``'s summary."""
        self._closing = True
        self._kick.set()
        self._thread.join()

    def close(self, summary: dict[str, Any] | None = None) -> None:
        """Drain the queue, add ``summary`` as an MCAP metadata record (``rehab_hil.summary``: the
        run's figures and safety events), write the MCAP summary and close both files; idempotent."""
        if self._closed:
            return
        self._closed = True
        self.drain()
        if summary:
            self._mcap.add_metadata("rehab_hil.summary", _metadata_strings(summary))
        self._mcap.finish()
        self._mcap_fh.close()
        os.close(self._csv_fd)

    # -- writer thread ---------------------------------------------------------------------
    def _run(self) -> None:
        q = self._q
        next_flush = time.perf_counter() + self.flush_s
        while True:
            self._kick.wait(max(0.0, next_flush - time.perf_counter()))
            self._kick.clear()
            closing = self._closing  # read before draining: whatever came before close() is written
            while q:
                self._write(q.popleft())
            if closing:
                self._flush()
                return
            if time.perf_counter() >= next_flush:
                self._flush()
                next_flush = time.perf_counter() + self.flush_s

    def _flush(self) -> None:
        if self._pending:
            os.write(self._csv_fd, "".join(self._pending).encode())  # whole lines in one write
            self._pending.clear()
        self._mcap.flush()

    def _log_time(self, host_time_s: float) -> int:
        return self._wall0_ns + int(host_time_s * 1e9)

    def _write(self, item: Record | tuple[str, Any]) -> None:
        if type(item) is Record:
            self._write_record(item)
        elif item[0] == "message":
            topic, schema, body = item[1]
            ch = self._extra.get(topic)
            if ch is None:
                ch = self._extra[topic] = self._channel(topic, schema, list(body))
            now = self._log_time(time.perf_counter())
            self._mcap.add_message(ch, log_time=now, publish_time=now, sequence=0, data=_json(body))
            self.messages += 1
        elif item[0] == "cycle":
            now = self._log_time(time.perf_counter())
            self._mcap.add_message(self._ch_cycle, log_time=now, publish_time=now, sequence=int(item[1]["index"]),
                                   data=_json({k: float(v) for k, v in item[1].items()}))
            self.messages += 1
        else:
            t, kind, detail = item[1]
            now = self._log_time(time.perf_counter())
            self._mcap.add_message(self._ch_event, log_time=now, publish_time=now, sequence=0,
                                   data=_json({"time_s": t, "kind": kind, "detail": detail}))
            self.messages += 1

    def _write_record(self, item: Record) -> None:
        lt = self._log_time(item.host_time_s)
        if item.sample is None:  # a command the loop sent
            self._write_command(item, lt)
            return
        if item.state is None or item.time_s <= self._last_time_s:
            return
        self._last_time_s = item.time_s
        row = self._row(item)
        self._mcap.add_message(self._ch_sample, log_time=lt, publish_time=lt,
                               sequence=item.sample.sample_index & 0xFFFFFFFF,
                               data=_json({**row, **generic_fields(item)}))
        self.messages += 1
        self._pending.append(self._csv_line % self._csv_values(row))
        self.rows += 1

    def _write_command(self, item: Record, lt: int) -> None:
        c = item.command
        cmd = {"host_time_s": item.host_time_s, "duty0_ratio": c.duty[0], "duty1_ratio": c.duty[1],
               "direction_bits": c.direction, "enable_bool": int(c.enable), "seq": item.command_seq,
               "reference_deg": c.reference_deg}
        self._mcap.add_message(self._ch_cmd, log_time=lt, publish_time=lt, sequence=item.command_seq, data=_json(cmd))
        self.messages += 1

    def _row(self, r: Record) -> dict[str, float]:
        s, st, c, b = r.sample, r.state, r.command, self.binding
        assert s is not None and st is not None
        row: dict[str, float] = {"time_s": r.time_s, b.encoder_signal: st.angle_rad, b.angle_output: st.angle_deg,
                                 b.reference_column: c.reference_deg if math.isfinite(c.reference_deg) else 0.0}
        row.update(st.analog)
        applied = (s.duty0 / DUTY_FULL, s.duty1 / DUTY_FULL)
        for name, inp in b.duty_inputs.items():
            row[name] = inp.effort(applied[inp.channel], s.direction)
        row.update({
            "host_time_s": r.host_time_s, "device_time_s": st.t_s, "sample_index": s.sample_index,
            "raw_encoder_counts": s.encoder_count, "raw_adc0_counts": s.adc0, "raw_adc1_counts": s.adc1,
            "applied_duty0_ratio": applied[0], "applied_duty1_ratio": applied[1], "direction_bits": s.direction,
            "status_bits": s.status, "fault_bits": s.faults, "cmd_seq_echo": s.cmd_seq_echo,
            "device_rx_bad_frames": s.rx_bad_frames, "command_duty0_ratio": c.duty[0],
            "command_duty1_ratio": c.duty[1], "command_direction_bits": c.direction,
            "command_enable_bool": float(c.enable), "command_seq": r.command_seq,
            "estimated_velocity_rad_s": st.velocity_rad_s,
            "estimated_temperature_c": r.temperature_c if math.isfinite(r.temperature_c) else 0.0,
        })
        return row


def read_mcap(path: str | Path) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """(topic, log_time_ns, decoded JSON) of every message in file order, also from a file cut short
    by a kill (no summary or footer): records are read sequentially until the data ends."""
    with open(path, "rb") as fh:
        topics: dict[int, str] = {}
        try:
            for rec in StreamReader(fh).records:
                if isinstance(rec, Channel):
                    topics[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    yield topics.get(rec.channel_id, "?"), rec.log_time, json.loads(rec.data)
        except (McapError, EOFError, struct.error, ValueError):  # the unfinished tail of a killed run
            return
