"""The recording: a new run directory, its metadata written first (a killed run still says what it ran
against), the recorder as a sink, and at the end the metadata completed with every feature's part."""

from __future__ import annotations

from typing import Any

from rehab_hil.calibration import calibration_summary
from rehab_hil.loop.recorder import Recorder
from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.loop.run_dir import (
    METADATA_FILE,
    config_identity,
    new_run_dir,
    reference_metadata,
    result_metadata,
    session_metadata,
    write_metadata,
)
from rehab_hil.loop.sinks import Overflow, Sink
from rehab_hil.patient.truth import TRUTH_FILE
from rehab_hil.service.errors import SessionError
from rehab_hil.service.features.base import Feature, SessionParts

__all__ = ["Recording"]


class Recording(Feature):
    """``record``: run.csv, run.mcap and metadata.json in a new folder of the given one."""

    name = "recording"
    finishes_last = True  # the metadata's end holds every other feature's part

    def __init__(self) -> None:
        self.recorder: Recorder | None = None
        self.parts: SessionParts | None = None

    def open(self, parts: SessionParts) -> None:
        opts, rig_id = parts.options, parts.rig_id
        assert opts.views.record is not None
        try:
            parts.run_dir = new_run_dir(opts.views.record, rig_id)
        except OSError as e:
            raise SessionError("record", f"{opts.views.record}: cannot make the run folder: {e}") from None
        parts.metadata = session_metadata(
            plant=parts.cfg.plant, config_path=parts.config_path, device=parts.device, rig_id=rig_id,
            binding=parts.binding, hello=parts.hw.info, controller=_controller_name(parts.controller),
            pacing=opts.pacing, sim_plant=opts.sim.sim_plant,
            calibration={"force": calibration_summary(parts.cfg, parts.binding)},
            reference=reference_metadata(parts.reference))
        parts.metadata["identity"] = parts.identity.metadata()
        if opts.sim.sim_patient is not None:
            parts.metadata["sim_patient"] = {**config_identity(opts.sim.sim_patient), "truth": TRUTH_FILE}
        write_metadata(parts.run_dir, parts.metadata)
        self.recorder = Recorder(parts.run_dir, parts.binding, metadata=parts.metadata)
        self.parts = parts

    def in_process(self, separate: bool) -> None:
        """While the loop runs in its own process, the recorder waits for room (the ring holds what
        comes meanwhile) instead of dropping: a recording loses nothing the loop wrote."""
        if separate and self.recorder is not None:
            self.recorder.overflow = Overflow.WAIT

    def sinks(self) -> list[Sink]:
        return [self.recorder] if self.recorder is not None else []

    def finish(self, result: RunResult) -> FeatureResult | None:
        """Every queued row counted, the metadata completed (a full disk: what was written stays readable)."""
        rec, parts = self.recorder, self.parts
        if rec is None or parts is None or parts.run_dir is None:
            return None
        rec.drain()  # rows still queued when the loop stopped (Ctrl-C on a busy machine) are counted
        end = result_metadata(result, rec.rows)
        for got in result.features.values():
            end.update(got.metadata)
        result.files[:0] = rec.files
        try:
            rec.close(summary=end)
            write_metadata(parts.run_dir, {**parts.metadata, **end})
            result.files.append(str(parts.run_dir / METADATA_FILE))
        except OSError as e:
            report = result.sinks.setdefault("recorder", {"dropped": 0, "error": None})
            text = f"the recording's end not written: {type(e).__name__}: {e}"
            report["error"] = f"{report['error']}; {text}" if report.get("error") else text
        return None

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()


def _controller_name(controller: Any) -> str:
    return getattr(controller, "name", None) or type(controller).__name__  # a test's own: its class
