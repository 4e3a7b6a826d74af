"""What the report says: one run (identity, session plot, per-cycle plot and table) or several
(progress across sessions, then the newest run in full)."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.report import figures
from rehab_hil.report.names import label, unit
from rehab_hil.report.page import Page, table
from rehab_hil.report.runs import ReportError, RunData
from rehab_hil.report.therapy import cycle_table, session_table

__all__ = ["default_output", "force_calibration_text", "progress_rows", "report_page", "stop_text"]


def _get(d: Any, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def _identity(page: Page, run: RunData) -> None:
    m = run.meta
    fw = m.get("firmware") or {}
    dev = m.get("device") or {}
    page.facts([
        ("plant", m.get("plant")), ("rig", m.get("rig_id")), ("controller", m.get("controller")),
        ("device", f"{dev.get('kind')}" + (f" on {dev['port']}" if dev.get("port") else "")),
        ("firmware", f"{fw.get('name', '?')} {fw.get('version', '?')}, protocol {fw.get('protocol_version', '?')}"
         if fw else "none (no handshake)"),
        ("encoder", f"{_get(m, 'calibration', 'encoder_counts_per_rev')} counts/rev"),
        ("sensors", "; ".join(sensor_text(a) for a in _get(m, "calibration", "adc") or []) or "none"),
        ("force calibration", force_calibration_text(_get(m, "calibration", "force"))),
        ("config", f"{m.get('config_path')} (sha256 {str(m.get('config_sha256', ''))[:16]}…)"),
        ("simulated plant", _get(m, "sim_plant", "config_path") or "–"),
        ("start / end (UTC)", f"{m.get('start_time_utc')} / {m.get('end_time_utc', 'no end record')}"),
        ("duration", duration_text(run)),
        ("stopped", stop_text(m)),
        ("samples / rows / gaps", f"{m.get('samples', '?')} / {m.get('rows', '?')} / {m.get('sample_gaps', '?')}"),
        ("device PWM off at end", pwm_off_text(m)),
        ("rehab-hil", f"{m.get('rehab_hil_version')} on {m.get('host')}"),
        ("run directory", str(run.path.resolve())),
    ])
    if m.get("config_text"):
        page.details("config text (as run)", m["config_text"])


def sensor_text(adc: dict[str, Any]) -> str:
    """One ADC channel as a person reads it: "patient torque [N m] on adc0 (100 counts per N m, offset 512)"."""
    name = str(adc.get("signal", "?"))
    per, off, u = adc.get("counts_per_unit"), adc.get("offset_counts"), unit(name)
    cal = f" ({per:g} counts per {u}, offset {off:g} counts)" if isinstance(per, int | float) and isinstance(
        off, int | float) else ""
    return f"{label(name)} on {adc.get('source', '?')}{cal}"


def force_calibration_text(force: dict[str, Any] | None) -> str:
    """The force calibration (metadata ``calibration.force``) in a sentence, never a dict."""
    if not force:
        return "not recorded"
    limit = force.get("firmware_force_limit_counts")
    tail = f"; limit {force['max_force_n']:g} N" if isinstance(force.get("max_force_n"), int | float) else ""
    tail += (f" = {limit} counts in the firmware" if isinstance(limit, int) else
             f" (firmware limit not set: {force['firmware_force_limit_error']})"
             if force.get("firmware_force_limit_error") else "")
    if not force.get("force_sensor"):
        return f"no force sensor: {force.get('note') or 'the firmware force limit is off'}"
    cal, lin = force.get("calibration"), force.get("linear_map")
    if isinstance(cal, dict):
        fit = (f", fit RMS {cal['fit_rms_n']:.3g} N" if isinstance(cal.get("fit_rms_n"), int | float) else "")
        hyst = (f", hysteresis {cal['hysteresis_pct_fs']:.3g} % FS"
                if isinstance(cal.get("hysteresis_pct_fs"), int | float) else "")
        upto = (f", calibrated up to {cal['max_calibrated_force_n']:g} N"
                if isinstance(cal.get("max_calibrated_force_n"), int | float) else "")
        return (f"{cal.get('file', '?')}: sensor {cal.get('sensor_id', '?')}, {cal.get('model', '?')} model"
                f"{fit}{hyst}{upto}, calibrated {cal.get('calibrated_at', '?')}{tail}")
    if isinstance(lin, dict):
        return (f"linear map of the config: {_g(lin.get('counts_per_n'))} counts/N, offset "
                f"{_g(lin.get('offset_counts'))} counts (no calibration file){tail}")
    return f"{force.get('force_sensor')}: no calibration recorded{tail}"


def _g(v: Any) -> str:
    return f"{v:g}" if isinstance(v, int | float) else "?"


def _fmt_s(v: Any) -> str:
    return f"{v:.2f} s" if isinstance(v, int | float) else "?"


def ran_s(meta: dict[str, Any], t_end: float | None = None) -> float | None:
    """The time the session ran: metadata's ``duration_s`` (a run recorded before it was the time
    ran: its first safety event, else what was asked), or the record's last time without an end record."""
    events = meta.get("safety_events") or []
    if "requested_duration_s" in meta:
        return meta.get("duration_s")
    if events and isinstance(events[0].get("t_s"), int | float):
        return float(events[0]["t_s"])
    return meta.get("duration_s", t_end)


def duration_text(run: RunData) -> str:
    m = run.meta
    ran = ran_s(m, float(run.t[-1]) if run.t.size else None)
    asked = m.get("requested_duration_s", m.get("duration_s"))
    if isinstance(ran, int | float) and isinstance(asked, int | float) and abs(ran - asked) > 1e-6:
        return f"{_fmt_s(ran)} of the {asked:g} s asked"
    return _fmt_s(ran)


def stop_text(meta: dict[str, Any]) -> str:
    """How the session ended, with the time: "safety trip: watchdog at 11.02 s (...)",
    "stop request (SIGINT) at 7.80 s", "the duration was reached"."""
    if "end_time_utc" not in meta:
        return "no end record (the run was killed?)"
    events = meta.get("safety_events") or []
    if not events:
        return "the duration was reached" if meta.get("stop_reason") == "duration reached" else str(
            meta.get("stop_reason", "?"))
    e = events[0]
    at = f" at {e['t_s']:.2f} s" if isinstance(e.get("t_s"), int | float) else ""
    if e.get("reason") == "stop_request":
        return f"stop request ({e.get('detail') or 'a signal'}){at}"
    head = f"safety trip: {e.get('reason')}{at}" + (f" ({e['detail']})" if e.get("detail") else "")
    return f"{head}; {e['cause']}" if e.get("cause") else head


def pwm_off_text(meta: dict[str, Any]) -> str:
    """Whether a sample after the end showed the PWM off: yes, NO, or unconfirmed and why."""
    off = meta.get("pwm_off_at_end")
    if off is None:
        why = meta.get("pwm_unconfirmed")
        return f"unconfirmed: {why}" if why else "not recorded"
    return "yes" if off else "NO"


def _cycle_table(run: RunData) -> str:
    sensor = run.sensor_name
    header = ["cycle", "start [s]", "range of motion [deg]", *([f"peak {label(sensor)}"] if sensor else []),
              "RMSE [deg]", "max error [deg]", "time to open [s]", "time to closed [s]",
              "peak est. temperature [°C]", "energy [J]"]
    rows = [[int(c["index"]), c["start_s"], c["rom_deg"], *([c["peak_force"]] if sensor else []), c["rmse_deg"],
             c["max_error_deg"], c["time_to_open_s"], c["time_to_closed_s"], c["peak_temperature_c"], c["energy_j"]]
            for c in run.cycles]
    if any("learn_trial" in c for c in run.cycles):  # the learning on the rig: the table each cycle ran, its update
        header += ["learned table (trial)", "update kept [share]", "update's predicted peak [°C]"]
        for row, c in zip(rows, run.cycles, strict=True):
            row += [c.get("learn_trial"), c.get("learn_share"), c.get("learn_predicted_peak_c")]
    return table(header, rows)


def learning_text(meta: dict[str, Any]) -> str | None:
    """One line on the learning on the rig (metadata.json ``rig_learning``), or None when it was off."""
    rl = meta.get("rig_learning")
    if not rl:
        return None
    cycles = meta.get("session_cycles") or []
    rmse = " -> ".join(f"{c['rmse_deg']:.2f}" for c in cycles[:1] + cycles[-1:]) if cycles else "–"
    start = "the table learned in earlier sessions" if rl.get("resumed") else "the model's table"
    return (f"Learning on the rig: from {start}, {rl.get('updates')} updates this session ({rl.get('trials')} in "
            f"all); per-cycle RMSE {rmse} deg; the table is kept in {rl.get('store')}.")


def _run_section(page: Page, run: RunData) -> None:
    for note in run.notes:
        page.note(note)
    page.heading("Identity")
    _identity(page, run)
    page.heading("Session")
    tr = run.meta.get("tracking") or {}
    s = run.meta.get("session") or {}
    if run.events and "end_time_utc" in run.meta:
        page.note(f"This session ran {duration_text(run)}: {stop_text(run.meta)}.")
    page.text(f"Tracking over the session (every recorded row with a reference): RMSE {_fmt(tr.get('rmse'))} deg, "
              f"max error {_fmt(tr.get('max_abs_error'))} deg; {int(s.get('cycles', 0))} complete open-close cycles.")
    if run.meta.get("step_response"):
        page.text(step_text(run.meta["step_response"]))
    for name, value in run.flat_sensors.items():
        page.text(f"{label(name)}: {value:.4g} {unit(name)} throughout the session (not drawn: nothing acted on the "
                  "sensor).")
    if run.events:
        page.raw(table(["t [s]", "safety event", "detail"],
                       [[e.get("t_s"), e.get("reason"), e.get("detail")] for e in run.events], left=0))
    else:
        page.text("Safety events: none.")
    _twin_section(page, run)
    page.figure(figures.session_figure(run))
    if run.cycles:
        page.heading("Cycles")
        page.figure(figures.cycle_figure(run))
        page.figure(figures.cycle_trend_figure(run))
        page.raw(_cycle_table(run))
        therapist = cycle_table(run.cycles)
        if therapist:
            page.heading("What a therapist reads", level=3)
            page.raw(therapist)
        if learning_text(run.meta):
            page.text(learning_text(run.meta))
    else:
        page.text("No complete open-close cycle in this run.")


def _twin_section(page: Page, run: RunData) -> None:
    """The live twin's model events and the patient's interaction estimate (``run --twin``; docs/twin.md)."""
    m = run.meta
    if "twin" not in m:
        page.text("Live twin: not run in this session (rehab-hil run --twin).")
        return
    events = m.get("model_events") or []
    if events:
        page.raw(table(["start t [s]", "seen at [s]", "model mismatch on", "size [counts]", "likely cause"],
                       [[e.get("t_s"), e.get("detected_s"), e.get("channel"), e.get("size_counts"), e.get("cause")]
                        for e in events], left=2))
    else:
        page.text("Model events (live twin): none; the model held over the whole session.")
    est = _get(m, "patient", "session") or {}
    if est:
        page.raw(table(["interaction parameter", "unit", "session", "95 % interval", "at the end", "config"],
                       [[name, unit(name) or "–", v.get("value"), v.get("ci95"), v.get("final"), v.get("nominal")]
                        for name, v in est.items()], left=2))


def interaction_stiffness(meta: dict[str, Any]) -> float | None:
    """The session's estimate of the first stiffness the twin estimated, or None."""
    est = _get(meta, "patient", "session") or {}
    return next((v.get("value") for name, v in est.items() if "stiffness" in name), None)


def stiffness_unit(runs: Sequence[RunData]) -> str:
    """The unit of the stiffness the twin estimated (from its parameter's name), "" when none was."""
    names = [n for r in runs for n in (_get(r.meta, "patient", "session") or {}) if "stiffness" in n]
    return unit(names[0]) if names else ""


def step_text(step: dict[str, Any]) -> str:
    """A step run's response (metadata ``step_response``) in a sentence."""
    return (f"Step {_fmt(step.get('start'))} -> {_fmt(step.get('target'))} deg: overshoot "
            f"{_fmt(step.get('overshoot'))} deg ({_fmt(step.get('overshoot_pct'))} %), rise time (10-90 %) "
            f"{_fmt(step.get('rise_time_s'))} s, settling time (2 %) {_fmt(step.get('settling_time_s'))} s, "
            f"final error {_fmt(step.get('final_error'))} deg.")


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, int | float) and math.isfinite(v) else "–"


def progress_rows(runs: Sequence[RunData]) -> list[dict[str, Any]]:
    """One row per run: start time, how it stopped and the time it ran, mean range of motion and
    peak sensor value per cycle, tracking RMSE, energy per cycle (``session`` in metadata.json, the
    peak from the record)."""
    out = []
    for r in runs:
        s = r.meta.get("session") or {}
        peaks = np.array([c["peak_force"] for c in r.cycles], float)
        out.append({"label": r.label, "start": r.meta.get("start_time_utc"), "cycles": int(s.get("cycles", 0)),
                    "rom_deg": s.get("rom_deg"), "peak_force": float(np.nanmean(peaks))
                    if np.isfinite(peaks).any() else None, "rmse_deg": s.get("rmse_deg"),
                    "energy_per_cycle_j": s.get("energy_per_cycle_j"), "controller": r.meta.get("controller"),
                    "stiffness": interaction_stiffness(r.meta), "stopped": stop_text(r.meta),
                    "ran_s": ran_s(r.meta, float(r.t[-1]) if r.t.size else None), "rig": r.meta.get("rig_id")})
    return out


def report_page(runs: Sequence[RunData]) -> Page:
    """The page for one run, or for several (progress first, then the newest run in full)."""
    if not runs:
        raise ReportError("no run to report")
    plants = sorted({str(r.meta.get("plant")) for r in runs})
    if len(plants) > 1:
        raise ReportError("runs of different plants (" + ", ".join(plants) + "): report each plant's runs apart")
    last = runs[-1]
    if len(runs) == 1:
        page = Page(f"rehab-hil session report: {last.meta.get('plant')}, rig {last.meta.get('rig_id')}")
        page.text(f"{last.path.name}, {last.meta.get('start_time_utc')}", cls="sub")
        _run_section(page, last)
        return page
    page = Page(f"rehab-hil progress: {len(runs)} sessions, {plants[0]}")
    rows = progress_rows(runs)
    sensor = next((r.sensor_name for r in runs if r.sensor_name), None)
    peak = f"peak {label(sensor)}" if sensor else None
    page.text(f"From {runs[0].meta.get('start_time_utc')} to {last.meta.get('start_time_utc')}; per session the "
              "mean over its cycles" + (f" ({peak} per cycle, from the record)." if peak else "."), cls="sub")
    page.figure(figures.progress_figure(rows, sensor))
    if not any(r["stiffness"] is not None for r in rows):
        page.note("Interaction stiffness: no session ran the live twin with an interaction estimate (docs/twin.md).")
    k_unit = stiffness_unit(runs)
    page.raw(table(["run", "start (UTC)", "rig", "controller", "stopped", "ran [s]", "cycles", "range of motion [deg]",
                    *([peak] if peak else []), "RMSE [deg]", "energy per cycle [J]",
                    "interaction stiffness" + (f" [{k_unit}]" if k_unit else "")],
                   [[r["label"], r["start"], r["rig"], r["controller"], r["stopped"], r["ran_s"], r["cycles"],
                     r["rom_deg"], *([r["peak_force"]] if peak else []), r["rmse_deg"], r["energy_per_cycle_j"],
                     r["stiffness"]] for r in rows], left=5))
    therapist = session_table([r.label for r in runs], [r.meta.get("session") or {} for r in runs])
    if therapist:
        page.heading("What a therapist reads, session by session", level=2)
        page.raw(therapist)
    page.heading(f"Newest session: {last.label}", level=2)
    _run_section(page, last)
    return page


def default_output(run_dirs: Sequence[Path]) -> Path:
    """report.html in the run directory; for several runs progress.html in their common folder."""
    if len(run_dirs) == 1:
        return run_dirs[0] / "report.html"
    return Path(os.path.commonpath([str(d.resolve().parent) for d in run_dirs])) / "progress.html"
