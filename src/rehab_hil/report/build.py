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
from rehab_hil.report.page import Page, table
from rehab_hil.report.runs import ReportError, RunData
from rehab_hil.report.therapy import cycle_table, session_table

__all__ = ["default_output", "progress_rows", "report_page"]


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
    force_cal = _get(m, "calibration", "force") or {}
    cal_file = force_cal.get("calibration")
    cal_text = (f"{cal_file.get('path', cal_file)}" if isinstance(cal_file, dict) else
                f"linear map {force_cal.get('linear_map')}" if force_cal.get("linear_map") else "none")
    page.facts([
        ("plant", m.get("plant")), ("rig", m.get("rig_id")), ("controller", m.get("controller")),
        ("device", f"{dev.get('kind')}" + (f" on {dev['port']}" if dev.get("port") else "")),
        ("firmware", f"{fw.get('name', '?')} {fw.get('version', '?')}, protocol {fw.get('protocol_version', '?')}"
         if fw else "none (no handshake)"),
        ("encoder", f"{_get(m, 'calibration', 'encoder_counts_per_rev')} counts/rev"),
        ("force calibration", cal_text),
        ("config", f"{m.get('config_path')} (sha256 {str(m.get('config_sha256', ''))[:16]}…)"),
        ("simulated plant", _get(m, "sim_plant", "config_path") or "–"),
        ("start / end (UTC)", f"{m.get('start_time_utc')} / {m.get('end_time_utc', 'no end record')}"),
        ("duration", f"{_fmt_s(m.get('duration_s'))}, stopped: {m.get('stop_reason', '?')}"),
        ("samples / rows / gaps", f"{m.get('samples', '?')} / {m.get('rows', '?')} / {m.get('sample_gaps', '?')}"),
        ("device PWM off at end", {True: "yes", False: "NO"}.get(m.get("pwm_off_at_end"), "?")),
        ("rehab-hil", f"{m.get('rehab_hil_version')} on {m.get('host')}"),
        ("run directory", str(run.path.resolve())),
    ])
    if m.get("config_text"):
        page.details("config text (as run)", m["config_text"])


def _fmt_s(v: Any) -> str:
    return f"{v:.1f} s" if isinstance(v, int | float) else "?"


def _cycle_table(run: RunData) -> str:
    force = run.force_name or "force"
    header = ["cycle", "start [s]", "range of motion [deg]", f"peak {force}", "RMSE [deg]", "max error [deg]",
              "time to open [s]", "time to closed [s]", "peak est. temperature [C]", "energy [J]"]
    rows = [[int(c["index"]), c["start_s"], c["rom_deg"], c["peak_force"], c["rmse_deg"], c["max_error_deg"],
             c["time_to_open_s"], c["time_to_closed_s"], c["peak_temperature_c"], c["energy_j"]]
            for c in run.cycles]
    if any("learn_trial" in c for c in run.cycles):  # the learning on the rig: the table each cycle ran, its update
        header += ["learned table (trial)", "update kept [share]", "update's predicted peak [C]"]
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
    page.text(f"Tracking over the session: RMSE {_fmt(tr.get('rmse'))} deg, max error "
              f"{_fmt(tr.get('max_abs_error'))} deg; {int(s.get('cycles', 0))} complete open-close cycles.")
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
        page.raw(table(["interaction parameter", "session", "95 % interval", "at the end", "config"],
                       [[name, v.get("value"), v.get("ci95"), v.get("final"), v.get("nominal")]
                        for name, v in est.items()], left=1))


def interaction_stiffness(meta: dict[str, Any]) -> float | None:
    """The session's estimate of the first stiffness the twin estimated, or None."""
    est = _get(meta, "patient", "session") or {}
    return next((v.get("value") for name, v in est.items() if "stiffness" in name), None)


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, int | float) and math.isfinite(v) else "–"


def progress_rows(runs: Sequence[RunData]) -> list[dict[str, Any]]:
    """One row per run: start time, mean range of motion and peak force per cycle, tracking RMSE,
    energy per cycle (``session`` in metadata.json, the peak force from the record)."""
    out = []
    for r in runs:
        s = r.meta.get("session") or {}
        peaks = np.array([c["peak_force"] for c in r.cycles], float)
        out.append({"label": r.label, "start": r.meta.get("start_time_utc"), "cycles": int(s.get("cycles", 0)),
                    "rom_deg": s.get("rom_deg"), "peak_force": float(np.nanmean(peaks))
                    if np.isfinite(peaks).any() else None, "rmse_deg": s.get("rmse_deg"),
                    "energy_per_cycle_j": s.get("energy_per_cycle_j"), "controller": r.meta.get("controller"),
                    "stiffness": interaction_stiffness(r.meta),
                    "rig": r.meta.get("rig_id")})
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
    force = next((r.force_name for r in runs if r.force_name), "force")
    page.text(f"From {runs[0].meta.get('start_time_utc')} to {last.meta.get('start_time_utc')}; per session the "
              f"mean over its cycles (peak {force} per cycle, from the record).", cls="sub")
    page.figure(figures.progress_figure(rows))
    if not any(r["stiffness"] is not None for r in rows):
        page.note("Interaction stiffness: no session ran the live twin with an interaction estimate (docs/twin.md).")
    page.raw(table(["run", "start (UTC)", "rig", "controller", "cycles", "range of motion [deg]",
                    f"peak {force}", "RMSE [deg]", "energy per cycle [J]", "interaction stiffness"],
                   [[r["label"], r["start"], r["rig"], r["controller"], r["cycles"], r["rom_deg"], r["peak_force"],
                     r["rmse_deg"], r["energy_per_cycle_j"], r["stiffness"]] for r in rows], left=4))
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
