"""Recording of every sample and command to the interchange CSV and to MCAP, off the loop thread.

``Recorder`` is the loop's critical sink (``loop.sinks.ThreadedSink``): the loop offers its
records after the command is out and wakes the writer once per cycle; the writer then works while
the loop waits for its next sample, and otherwise every ``flush_s`` (a producer that never calls
``wake`` gets its records written in batches). It turns records into CSV rows (plant signal names +
raw columns) and MCAP messages on JSON-schema channels (``/rig/sample``, ``/rig/command``,
``/rig/event``, ``/rig/cycle``, and extra channels such as the twin's ``/twin/prediction``; Foxglove
and PlotJuggler open them), and flushes both files at least every ``flush_s``: a killed run leaves
files that hold everything up to the last flush. A row's reference is that of the command in force
when its sample arrived; a row with none (before the first command, the stop's rows) leaves it
empty in the CSV and null in MCAP, never 0. ``read_mcap`` reads such a file even without its
footer. The session's metadata (``loop/run_dir.py``) goes into MCAP metadata records at the
start and the end. A write that fails (a full disk) stops the writer with its error kept; the loop,
told so, stops the session: a session must not go on unrecorded.
"""

from __future__ import annotations

import json
import math
import operator
import os
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson
from mcap.exceptions import McapError
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loop.records import CommandRecord, CycleRecord, EventRecord, MessageRecord, SampleRecord
from rehab_hil.loop.sinks import Overflow, ThreadedSink
from rehab_hil.protocol import DUTY_FULL
from rehab_hil.session_metrics import CycleMetrics

__all__ = ["GENERIC_FIELDS", "Recorder", "csv_columns", "generic_fields", "read_mcap"]

RAW_COLUMNS = (
    "host_time_s", "device_time_s", "sample_index", "raw_encoder_counts", "raw_adc0_counts",
    "raw_adc1_counts", "applied_duty0_ratio", "applied_duty1_ratio", "direction_bits", "status_bits",
    "fault_bits", "cmd_seq_echo", "device_rx_bad_frames", "command_duty0_ratio", "command_duty1_ratio",
    "command_direction_bits", "command_enable_bool", "command_seq", "estimated_velocity_rad_s",
    "estimated_temperature_c",
)


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


def generic_fields(r: SampleRecord) -> dict[str, float]:
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


class Recorder(ThreadedSink):
    """Writes ``<out_dir>/<name>.csv`` and ``<out_dir>/<name>.mcap`` from a bounded queue; the sink
    named "recorder", critical. ``overflow``: ``Overflow.WAIT`` for a zenoh recording (back-pressure
    to the network instead of loss)."""

    def __init__(self, out_dir: str | Path, binding: DeviceBinding, name: str = "run",
                 queue_size: int = 20_000, flush_s: float = 0.1, metadata: dict[str, Any] | None = None,
                 overflow: Overflow = Overflow.DROP) -> None:
        super().__init__("recorder", queue_size, overflow, critical=True, poll_s=flush_s, tick_s=flush_s)
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.csv_path = self.out_dir / f"{name}.csv"
        self.mcap_path = self.out_dir / f"{name}.mcap"
        self.binding = binding
        self.columns = csv_columns(binding)
        keys = ["time_s", *self.columns]
        self._csv_values = operator.itemgetter(*keys)  # a row dict -> its CSV values in column order
        self._csv_line = ",".join(["%.10g"] * len(keys)) + "\n"
        # a row with no reference (before the first command, after the stop) leaves that cell empty
        self._csv_values_noref = operator.itemgetter(*(k for k in keys if k != binding.reference_column))
        self._csv_line_noref = ",".join("" if k == binding.reference_column else "%.10g" for k in keys) + "\n"
        self.flush_s = flush_s
        self.rows = 0  # rows handed to the CSV (those of a failed write taken back)
        self.messages = 0
        self._summary: dict[str, Any] | None = None
        self._csv_fd = os.open(self.csv_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.write(self._csv_fd, (",".join(["time_s", *self.columns]) + "\n").encode())
        self._mcap_fh = open(self.mcap_path, "wb")
        self._mcap = Writer(self._mcap_fh, compression=CompressionType.NONE)
        self._mcap.start(profile="", library="rehab-hil")
        self._register_channels()
        if metadata:
            self._mcap.add_metadata("rehab_hil.session", _metadata_strings(metadata))
        self._mcap.flush()
        self._wall0_ns = time.time_ns() - int(time.perf_counter() * 1e9)
        self._last_time_s = -math.inf
        self._pending: list[str] = []
        self.start()

    def _register_channels(self) -> None:
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
        self._extra: dict[str, int] = {}  # topic -> channel of a ``MessageRecord``

    def _channel(self, topic: str, name: str, fields: list[str]) -> int:
        sid = self._mcap.register_schema(name, "jsonschema", _schema(name, fields))
        return self._mcap.register_channel(topic, "json", sid)

    @property
    def files(self) -> list[str]:
        """The recording's two files (what the run's result lists)."""
        return [str(self.csv_path), str(self.mcap_path)]

    def close(self, summary: dict[str, Any] | None = None) -> None:
        """Drain the queue, add ``summary`` as an MCAP metadata record (``rehab_hil.summary``: the
        run's figures and safety events), write the MCAP summary and close both files; idempotent.
        ``drain`` before it makes ``rows`` final (what the run's metadata reports)."""
        if not self._closed:
            self._summary = summary
        super().close()

    def release(self) -> None:
        """Finish the MCAP (after a failed writer too: what was written stays readable), close both files."""
        try:
            if self._summary:
                self._mcap.add_metadata("rehab_hil.summary", _metadata_strings(self._summary))
            self._mcap.finish()
        except OSError:
            if self.error is None:
                raise
        finally:
            self._mcap_fh.close()
            os.close(self._csv_fd)

    # -- writer thread ---------------------------------------------------------------------
    def tick(self) -> None:
        self._flush()

    def finish(self) -> None:
        self._flush()

    def _flush(self) -> None:
        if self._pending:
            try:
                os.write(self._csv_fd, "".join(self._pending).encode())  # whole lines in one write
            except OSError:
                self.rows -= len(self._pending)  # rows counts what the CSV holds
                self._pending.clear()
                raise
            self._pending.clear()
        self._mcap.flush()

    def _log_time(self, host_time_s: float) -> int:
        return self._wall0_ns + int(host_time_s * 1e9)

    def handle(self, item: Any) -> None:
        t = type(item)
        if t is SampleRecord:
            self._write_sample(item)
        elif t is CommandRecord:
            self._write_command(item)
        elif t is MessageRecord:
            ch = self._extra.get(item.topic)
            if ch is None:
                ch = self._extra[item.topic] = self._channel(item.topic, item.schema, list(item.body))
            self._add(ch, self._log_time(time.perf_counter()), 0, item.body)
        elif t is CycleRecord:
            self._add(self._ch_cycle, self._log_time(time.perf_counter()), int(item.metrics["index"]),
                      {k: float(v) for k, v in item.metrics.items()})
        elif t is EventRecord:
            self._add(self._ch_event, self._log_time(time.perf_counter()), 0,
                      {"time_s": item.time_s, "kind": item.kind, "detail": item.detail})

    def _add(self, channel: int, log_time: int, sequence: int, body: dict[str, Any]) -> None:
        self._mcap.add_message(channel, log_time=log_time, publish_time=log_time, sequence=sequence, data=_json(body))
        self.messages += 1

    def _write_sample(self, item: SampleRecord) -> None:
        if item.state is None or item.time_s <= self._last_time_s:
            return
        self._last_time_s = item.time_s
        row = self._row(item)
        self._add(self._ch_sample, self._log_time(item.host_time_s), item.sample.sample_index & 0xFFFFFFFF,
                  {**row, **generic_fields(item)})
        if math.isnan(row[self.binding.reference_column]):
            self._pending.append(self._csv_line_noref % self._csv_values_noref(row))
        else:
            self._pending.append(self._csv_line % self._csv_values(row))
        self.rows += 1

    def _write_command(self, item: CommandRecord) -> None:
        c = item.command
        cmd = {"host_time_s": item.host_time_s, "duty0_ratio": c.duty[0], "duty1_ratio": c.duty[1],
               "direction_bits": c.direction, "enable_bool": int(c.enable), "seq": item.command_seq,
               "reference_deg": c.reference_deg}
        self._add(self._ch_cmd, self._log_time(item.host_time_s), item.command_seq, cmd)

    def _row(self, r: SampleRecord) -> dict[str, float]:
        s, st, c, b = r.sample, r.state, r.command, self.binding
        assert st is not None
        row: dict[str, float] = {"time_s": r.time_s, b.encoder_signal: st.angle_rad, b.angle_output: st.angle_deg,
                                 b.reference_column: c.reference_deg if math.isfinite(c.reference_deg) else math.nan}
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
