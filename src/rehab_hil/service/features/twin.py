"""The live twin beside the rig (``twin.session.TwinRun``) and what it estimates of the patient's torque
per move: its predictions and model events go to the recording, Foxglove and zenoh; a mismatch may stop
the loop; at the end its summary, model events and the patient's estimate join the result."""

from __future__ import annotations

import math
from typing import Any

from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.loop.sinks import Sink
from rehab_hil.service.errors import SessionError
from rehab_hil.service.features.base import Feature, LoopHandle, SessionParts

__all__ = ["PatientTorque", "Twin", "twin_lines"]


class Twin(Feature):
    """``twin`` (or ``[twin] enabled``): the plant model run beside the rig (docs/twin.md)."""

    name = "twin"

    def __init__(self) -> None:
        self.run: Any = None  # the TwinRun

    def open(self, parts: SessionParts) -> None:
        from rehab_hil.twin.model import TwinSetupError
        from rehab_hil.twin.session import start_twin

        found = parts.features
        outputs = [s for name in ("recording", "foxglove") if name in found for s in found[name].sinks()]
        publisher = found["telemetry"].sink if "telemetry" in found else None
        ref = parts.reference
        cycle_s = ref.period_s if ref is not None and ref.kind == "session" else None
        try:
            self.run = start_twin(parts.cfg, parts.binding, parts.period_s, parts.run_dir, outputs, publisher,
                                  cycle_s, parts.lockstep)
        except TwinSetupError as e:
            raise SessionError(None, f"{parts.config_path}: [twin] {e}") from None

    def sinks(self) -> list[Sink]:
        return [self.run.live]

    def started(self, loop: LoopHandle) -> None:
        self.run.on_stop = lambda text: loop.request_stop(text, "model_mismatch")

    def finish(self, result: RunResult) -> FeatureResult | None:
        meta = self.run.close()
        csv = self.run.twin.csv_path
        return FeatureResult(self.name, meta, meta, twin_lines(meta), (str(csv),) if csv is not None else ())

    def close(self) -> None:
        if self.run is not None:
            self.run.live.close()  # the twin's thread, if the session never ran (idempotent)


def twin_lines(meta: dict[str, Any]) -> tuple[tuple[str, str], ...]:
    """The live twin's lines of the run summary: its normal residual, the model events, the thermal
    estimates and the patient's estimate."""
    from rehab_hil.twin.live import normal_residual_text
    from rehab_hil.twin.thermal import thermal_event_text

    out: list[tuple[str, str]] = []
    tw = meta["twin"]
    normal = normal_residual_text(tw.get("normal_residual", {}))
    out.append(("twin: normal residual / CPU per sample", f"{normal} / {tw.get('cpu_per_sample_us', 0):.1f} us"))
    if tw.get("error"):
        out.append(("[red]twin stopped", tw["error"]))
    for ev in meta.get("model_events", []):
        out.append((f"[yellow]model_mismatch {ev['channel']}",
                    f"t={ev['t_s']:.2f} s (seen {ev['detected_s']:.2f} s), {ev['size_counts']:.1f} counts; "
                    f"{ev['cause'] or 'no cause named'}"))
    if not meta.get("model_events"):
        out.append(("model events", "none"))
    thermal = tw.get("thermal") or {}
    for ev in thermal.get("events", []):  # the thermal quantities first: they move the bend, the contact barely
        out.append((f"[yellow]thermal_change {ev['label']}", thermal_event_text(ev, label=False)))
    for key, est in thermal.get("estimates", {}).items():
        out.append((f"thermal {est['label']}", f"{key} = {est['value']:.4g} +/- {est['ci95']:.2g} "
                    f"(config {est['config']:.4g})"))
    for name, est in meta.get("patient", {}).get("session", {}).items():
        since = f"; fitted from {est['since_s']:.2f} s, after a change" if est.get("since_s") else ""
        if est["ci95"] > 0.5 * abs(est["value"]):
            since += "; not determined by this session"
        out.append((f"patient {name.split('.')[-1]}", f"{est['value']:.4g} +/- {est['ci95']:.2g} "
                    f"(config {est['nominal']:.4g}; at the end {est['final']:.4g}{since})"))
    return tuple(out)


class PatientTorque(Feature):
    """The twin's estimate of the patient's torque per move (``twin/patient_torque.py``) into each cycle's
    figures and, averaged, the session's (``patient_torque_open_model_nm``, ``..._close_...``)."""

    name = "patient_torque"
    needs = ("twin",)

    def __init__(self) -> None:
        self.twin: Twin | None = None
        self.reference: Any = None

    def open(self, parts: SessionParts) -> None:
        self.twin = parts.features["twin"]  # type: ignore[assignment]
        self.reference = parts.reference

    def finish(self, result: RunResult) -> FeatureResult | None:
        from rehab_hil.twin.patient_torque import move_torques

        assert self.twin is not None
        est, ref = self.twin.run.twin.patient_torque, self.reference
        if est is None or ref is None or ref.kind != "session" or not result.session_cycles:
            return None
        direction = 1.0 if ref.open_deg >= ref.closed_deg else -1.0
        result.session_cycles = move_torques(est, result.session_cycles, ref.period_s, ref.move_s, direction)
        for key in ("patient_torque_open_model_nm", "patient_torque_close_model_nm"):
            v = [c[key] for c in result.session_cycles if math.isfinite(c[key])]
            if v:
                result.session[key] = sum(v) / len(v)
        return None
