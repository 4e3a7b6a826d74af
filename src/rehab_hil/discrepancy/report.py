"""Write the workflow's result: report.json (schema in docs/discrepancy.md), report.md, PNG
figures (matplotlib, Agg) and augmented.toml (the input config plus the chosen effects)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.discrepancy import localise
from rehab_hil.discrepancy.judge import cut_pct
from rehab_hil.discrepancy.parameters import corrected_config_text
from rehab_hil.discrepancy.result import Result, parameter_sentence
from rehab_hil.discrepancy.shooting import SEGMENT_S
from rehab_hil.discrepancy.verdict import channel_unit
from rehab_hil.discrepancy.wording import change_words, effect_words, is_linear, param_label, param_unit
from rehab_hil.effects import EFFECTS
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

__all__ = ["SCHEMA", "augmented_toml", "effect_params_text", "report_dict", "write_report"]

SCHEMA = "rehab-hil/discrepancy-report/1"


def _clean(x: Any) -> Any:
    """JSON-safe: numpy scalars to Python, NaN and infinity to null."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _residual(res: Result, model: dict[str, np.ndarray]) -> np.ndarray:
    return np.vstack([(model[c] - res.measured[c]) / res.scale[c] for c in res.channels])


def report_dict(res: Result, config_path: Path, data_path: Path | str, figures: list[str]) -> dict[str, Any]:
    """The report as a JSON-ready dict (docs/discrepancy.md describes every key)."""
    before, after = res.metrics("nominal"), res.metrics("augmented")
    r0, r1 = _residual(res, res.nominal), _residual(res, res.augmented)
    combined0 = np.sqrt(np.mean(r0**2, axis=0))
    gap = {c: cut_pct(before[c]["rmse"], after[c]["rmse"]) for c in res.channels}
    init = res.initial_state
    return _clean({
        "schema": SCHEMA,
        "plant": res.plant,
        "config": str(config_path),
        "data": str(data_path),
        "samples": int(res.t.size),
        "duration_s": float(res.t[-1] - res.t[0]),
        "holdout_start_s": res.split_s,
        "channels": res.channels,
        "channel_scale": res.scale,
        "conclusion": res.conclusion,
        "chosen": [_chosen(res, f) for f in res.chosen],
        "channel_units": {c: channel_unit(c) for c in res.channels},
        "residual": res.residuals(),
        "initial_state": {
            "set_from_data": init.set_from_data if init else {}, "estimated": init.estimated if init else {},
            "summary": init.describe() if init else [],
        },
        "validation": res.validation.as_dict() if res.validation is not None else None,
        "joint_identification": _joint(res),
        "replay": {"mode": res.mode, "segment_s": SEGMENT_S if res.mode == "shooting" else None, **res.drift,
                   "measure": res.measure,
                   "loop": res.extras["replay"].loop or "open loop: the recorded plant inputs drive the model"},
        "aliases": [{"round": a.round, "chosen": a.chosen, "other": a.other, "delta_bic": a.delta_bic,
                     "experiment": a.experiment, "sentence": a.sentence()} for a in res.aliases],
        "unexplained": {"channels": res.unexplained, "where": res.unexplained_where},
        "metrics": {
            "nominal": before, "augmented": after,
            "nominal_holdout": res.metrics("nominal", "holdout"),
            "augmented_holdout": res.metrics("augmented", "holdout"),
        },
        "gap_reduction_pct": gap,
        "gap_change": {c: change_words(v) for c, v in gap.items()},
        "held_out_judgement": res.judgement.as_dict() if res.judgement is not None else None,
        "rounds": _rounds(res),
        "gaps": res.gaps, "at_bound": res.bounds, "records_lack": res.lacking, "dropped_from_best_set": res.dropped,
        "localisation": {
            "time_windows": localise.time_windows(res.t, combined0),
            "regions": localise.regions(res.t, res.measured, r0, res.channels, res.kinds),
            "regions_after": localise.regions(res.t, res.measured, r1, res.channels, res.kinds),
            "signatures": localise.signatures(res.t, res.measured, res.nominal, res.channels, res.kinds),
        },
        "wall_s": res.wall_s,
        "figures": figures,
    })


def _chosen(res: Result, f: Any) -> dict[str, Any]:
    """A chosen term for report.json: its fit, and for an effect its words and source in the plant's
    vocabulary and each parameter's unit on its axis (``wording``)."""
    out = {"effect": f.effect, "kind": f.kind, "params": f.params, "stderr": f.stderr}
    if f.kind != "effect":
        return {**out, "sentence": parameter_sentence(f)}
    description, seed = effect_words(f.effect, res.plant)
    linear = is_linear(res.extras.get("replay"))
    return {**out, "seed": seed, "description": description,
            "units": {k: param_unit(k, linear) for k in f.params}}


def _joint(res: Result) -> dict[str, Any] | None:
    """The joint identification with each parameter's unit: an effect's in its axis's unit, a declared
    parameter's value is a relative error."""
    if res.joint is None:
        return None
    d = res.joint.as_dict()
    linear = is_linear(res.extras.get("replay"))
    for p in d.get("parameters", []):
        effect, _, param = str(p["name"]).partition(".")
        p["unit"] = param_unit(param, linear) if param and effect in EFFECTS else "relative error"
    return d


def _rounds(res: Result) -> list[dict[str, Any]]:
    """Each round of the search: its baseline, the term chosen and every candidate's fit and score
    (an effect's parameters with their units on the axis)."""
    linear = is_linear(res.extras.get("replay"))
    return [{
        "baseline": {"holdout_rms": rd.baseline.rms, "bic": rd.baseline.bic, "n_params": rd.baseline.n_params},
        "chosen": rd.chosen,
        "candidates": [{
            "effect": c.fit.effect, "params": c.fit.params, "stderr": c.fit.stderr, "start": c.fit.start,
            "units": {k: param_unit(k, linear) for k in c.fit.params} if c.fit.effect in EFFECTS else {},
            "holdout_rms": c.score.rms, "holdout_channel_rms": dict(zip(res.channels, c.score.channel_rms,
                                                                        strict=True)),
            "bic": c.score.bic, "delta_bic": c.delta_bic, "improvement": c.improvement,
            "significant": c.significant, "n_params": c.score.n_params, "n_simulations": c.fit.n_simulations,
        } for c in rd.candidates],
    } for rd in res.rounds]


def augmented_toml(res: Result, config_path: Path) -> str:
    """The input config's text with each parameter found off corrected in place and one
    ``[[effects]]`` table per chosen effect appended; a term the held-out data rejected (``judge``) is
    neither, only a comment that says so (the given value stays)."""
    text = config_path.read_text(encoding="utf-8").rstrip("\n") + "\n"
    if res.parameters:
        declared = {fp.name: fp for fp in get_plant(res.plant).fit_parameters}
        fixes = {declared[f.effect]: 1.0 + f.params["error_fraction"] for f in res.parameters}
        text = corrected_config_text(text, load_config(config_path), fixes)
    for r in res.rejected:  # kept at the given value: said where the next user of the file looks
        text += f"\n# rehab-hil discrepancy: {r.sentence()}\n"
    for f in res.chosen:
        if f.kind != "effect":
            continue
        params = ", ".join(f"{k} = {float(v)!r}" for k, v in f.params.items())
        text += (f"\n# added by rehab-hil discrepancy ({effect_words(f.effect, res.plant)[1]})\n"
                 f"[[effects]]\nname = \"{f.effect}\"\nparams = {{ {params} }}\n")
    return text


def _figures(res: Result, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    n = len(res.channels)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.8 * n), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], res.channels, strict=True):
        ax.plot(res.t, res.measured[c], "k.", ms=1.5, label="measured")
        ax.plot(res.t, res.nominal[c], "C0-", lw=1, label="nominal")
        ax.plot(res.t, res.augmented[c], "C3--", lw=1, label="augmented" + (f" (+{', '.join(res.named)})"
                                                                           if res.named else ""))
        ax.axvspan(res.split_s, res.t[-1], color="0.9", zorder=-1)
        ax.set_ylabel(c)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time_s (grey: held out from the fit)")
    names.append(_save(plt, fig, out, "overlay.png"))

    fig, axes = plt.subplots(n, 1, figsize=(10, 2.5 * n), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], res.channels, strict=True):
        ax.plot(res.t, res.nominal[c] - res.measured[c], "C0-", lw=0.8, label="residual before (nominal)")
        ax.plot(res.t, res.augmented[c] - res.measured[c], "C3-", lw=0.8, label="residual after (augmented)")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{c} residual")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time_s")
    names.append(_save(plt, fig, out, "residual.png"))

    r0, r1 = _residual(res, res.nominal), _residual(res, res.augmented)
    reg0 = localise.regions(res.t, res.measured, r0, res.channels, res.kinds)
    reg1 = localise.regions(res.t, res.measured, r1, res.channels, res.kinds)
    fig, ax = plt.subplots(figsize=(9, 3.5))
    x = np.arange(len(reg0))
    ax.bar(x - 0.2, [g["rms"] for g in reg0], 0.4, label="before")
    ax.bar(x + 0.2, [g["rms"] for g in reg1], 0.4, label="after")
    ax.set_xticks(x, [str(g["region"]) for g in reg0], rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("RMS scaled residual")
    ax.set_title("where the residual concentrates")
    ax.legend()
    names.append(_save(plt, fig, out, "regions.png"))
    return names


def _save(plt: Any, fig: Any, out: Path, name: str) -> str:
    """Lay out, write ``out/name`` (PNG, 110 dpi) and close ``fig``; returns ``name``."""
    fig.tight_layout()
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def _markdown(rep: dict[str, Any]) -> str:
    L = [f"# Discrepancy report: {rep['plant']}", "",
         f"Data `{rep['data']}` ({rep['samples']} samples, {rep['duration_s']:.2f} s; held out from "
         f"{rep['holdout_start_s']:.2f} s), config `{rep['config']}`.", "",
         f"**{rep['conclusion']}**", ""]
    for c in rep["chosen"]:
        if c["kind"] == "parameter":
            L.append(f"- {c['sentence']} (corrected in augmented.toml)")
            continue
        L.append(f"- `{c['effect']}`: {effect_params_text(c)} ({c['description']}; {c['seed']})")
    judged = rep.get("held_out_judgement") or {}
    for r in judged.get("rejected", []):
        L.append(f"- not a finding: {r['sentence']} (augmented.toml keeps the given value)")
    for a in rep["aliases"]:
        L.append(f"- round {a['round']}: {a['sentence']}")
    L += ["", f"Replay: {rep['replay']['loop']}.",
          f"Mode: {rep['replay']['mode']} (open-loop RMS {rep['replay'].get('open_rms') or float('nan'):.3g}, "
          f"shooting RMS {rep['replay'].get('shooting_rms') or float('nan'):.3g}, scaled). Start state: "
              + ("; ".join(rep["initial_state"]["summary"]) or "the config's rest state") + "."]
    several = len(rep.get("gaps", {}).get("records", [])) > 1
    L += ["", f"The search's own figures, both models measured the same way ({rep['replay']['measure']}"
          + ("; every record's fit part then every held-out part" if several else "")
          + "; the gap per record below is the measure a validation record gets, and the validation is always "
          "a whole-record open-loop replay):", "",
          "| channel | unit | RMSE before | RMSE after | MAE before | MAE after | max before | max after | error | "
          "held-out residual | noise floor |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for ch in rep["channels"]:
        b, a = rep["metrics"]["nominal"][ch], rep["metrics"]["augmented"][ch]
        r = rep["residual"][ch]
        L.append(f"| {ch} | {rep['channel_units'][ch]} | {b['rmse']:.4g} | {a['rmse']:.4g} | {b['mae']:.4g} | "
                 f"{a['mae']:.4g} | {b['max_abs_error']:.4g} | {a['max_abs_error']:.4g} | "
                 f"{change_words(rep['gap_reduction_pct'][ch])} | {r['rms']:.3g} | {r['noise_floor']:.3g} |")
    if judged:
        L += ["", f"Findings {judged['summary']} (a term that makes these data worse than its given value is "
              "rejected, not a finding)."]
    L += _gaps_md(rep.get("gaps")) + _validation_md(rep.get("validation")) + _joint_md(rep.get("joint_identification"))
    if rep.get("records_lack"):
        L += ["", "The records lack: " + "; ".join(rep["records_lack"]) + "."]
    for i, rd in enumerate(rep["rounds"], 1):
        L += ["", f"## Round {i}: candidates (held-out BIC, best first)", "",
              "| effect | parameters | ΔBIC | best channel cut | significant |", "|---|---|---|---|---|"]
        for c in rd["candidates"]:
            ps = effect_params_text({"params": c["params"], "units": c.get("units")})
            L.append(f"| {c['effect']} | {ps} | {c['delta_bic']:.1f} | {100 * c['improvement']:.1f} % | "
                     f"{'yes' if c['significant'] else 'no'} |")
    L += ["", "## Where the nominal residual concentrates", "", "| region | share of time | RMS | ratio |",
          "|---|---|---|---|"]
    for g in rep["localisation"]["regions"]:
        ratio = "n/a" if g["ratio"] is None else f"{g['ratio']:.2f}"
        rms = "n/a" if g["rms"] is None else f"{g['rms']:.3g}"
        L.append(f"| {g['region']} | {100 * g['share_of_time']:.1f} % | {rms} | {ratio} |")
    L += ["", "| channel | lag [s] | offset | gain error | dead-zone ratio |", "|---|---|---|---|---|"]
    for ch, s in rep["localisation"]["signatures"].items():
        f = ["n/a" if s[k] is None else f"{s[k]:.3g}" for k in ("lag_s", "offset", "gain_error", "dead_zone_ratio")]
        L.append(f"| {ch} | {' | '.join(f)} |")
    L += [""] + [f"![{n}]({n})" for n in rep["figures"]] + [""]
    return "\n".join(L)


def effect_params_text(c: dict[str, Any]) -> str:
    """``level = 20.27 N ± 0.1``: an effect's fitted parameters with their units (report.json's chosen item)."""
    units = c.get("units") or {}
    out = []
    for k, v in c["params"].items():
        if k == "error_fraction":  # a declared parameter: its relative error
            out.append(f"off by {100 * v:+.1f} %")
            continue
        se = (c.get("stderr") or {}).get(k)
        u = f" {units[k]}" if units.get(k) else ""
        out.append(f"{param_label(k)} = {v:.4g}{u}" + (f" ± {se:.2g}{u}" if se is not None else ""))
    return ", ".join(out)


def _gaps_md(gaps: dict[str, Any] | None) -> list[str]:
    if not gaps:
        return []
    L = ["", f"## The gap per record ({gaps['measure']})", "", "| record | channel | RMSE nominal | RMSE augmented |",
         "|---|---|---|---|"]
    for g in gaps["records"]:
        for ch, m in g["nominal"].items():
            L.append(f"| {g['data']} | {ch} | {m['rmse']:.4g} | {g['augmented'][ch]['rmse']:.4g} |")
    starts = [(g["data"], g["start"]["summary"]) for g in gaps["records"] if "start" in g]
    if starts:
        L += ["", "Start state per record:", ""] + [f"- {d}: {'; '.join(s) or 'the config rest state'}"
                                                    for d, s in starts]
    return L


def _validation_md(val: dict[str, Any] | None) -> list[str]:
    if not val:
        return []
    L = ["", f"## Validation on `{val['data']}`", "", f"Replay: {val['replay']}.", "",
         "| channel | RMSE nominal | RMSE augmented | error |", "|---|---|---|---|"]
    for ch in val["channels"]:
        n, a = val["metrics"]["nominal"][ch], val["metrics"]["augmented"][ch]
        L.append(f"| {ch} | {n['rmse']:.4g} | {a['rmse']:.4g} | {change_words(val['error_cut_pct'][ch])} |")
    return L


def _joint_md(joint: dict[str, Any] | None) -> list[str]:
    if not joint or not joint["parameters"]:
        return []
    L = ["", "## Joint identification (every parameter fitted together)", "",
         "| parameter | value | 95 % CI | note |", "|---|---|---|---|"]
    for p in joint["parameters"]:
        ci = "—" if p["ci95"] is None else f"{p['ci95'][0]:.4g} .. {p['ci95'][1]:.4g}"
        note = "held at its config value (inseparable)" if p["held_at_config"] else ""
        L.append(f"| {p['name']} | {p['value']:.4g} {p.get('unit', '')} | {ci} | {note} |")
    L += ["", "Parameters are relative errors of the config's value; effects in SI. Config values after the fit: "
          + ", ".join(f"`{k}` = {v:.6g}" for k, v in joint["corrected"].items()) + "."]
    L += [f"- {s}" for s in joint["sentences"]]
    return L


def write_report(res: Result, config_path: Path, data_path: Path | str, out: Path) -> dict[str, Any]:
    """Write every report file into ``out``; checks augmented.toml loads."""
    out.mkdir(parents=True, exist_ok=True)
    figures = _figures(res, out)
    rep = report_dict(res, config_path, data_path, figures)
    (out / "report.json").write_text(json.dumps(rep, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    (out / "report.md").write_text(_markdown(rep), encoding="utf-8")
    aug = out / "augmented.toml"
    aug.write_text(augmented_toml(res, config_path), encoding="utf-8")
    load_config(aug)
    return rep
