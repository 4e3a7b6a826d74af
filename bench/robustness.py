"""Each plant's shipped session on rigs that differ from the host's model the way a lab meets them
(issue 39, item 4).

Every case is the plant's shipped rehabilitation session (``[rig.session]``: its controller and
open-close cycles, built from the HOST config exactly as ``rehab-hil run`` builds it) through
``open_session(..., twin=True)`` on the in-process rig (the firmware's logic with the SIM plant
config's plant in this process, lockstep, 1 count of ADC noise), the sim plant a copy of the shipped
config with ONE value changed (``case_config``: the line of that key rewritten, everything else as
shipped). The host's model is never changed. Per cycle: RMSE and largest tracking error, the peak of
the host's temperature estimate; per case: any safety event, and the live twin's thermal estimates
(``twin/thermal.py``) beside the sim plant's truth.

The set, and why (a lab's day, not a fault):

* SMA exoskeleton: the room 7 C warmer (summer, a radiator) and 5 C colder (a winter morning) -
  the wire's heat balance runs from the room's temperature (seed 000 eq 12); 30 % more convection
  (a fan or an open window) and 20 % less (still air under a sleeve); the supply 10 % low (a sagging
  bench supply, a long cable); the wire's pre-strain 15 % lower (re-tensioned); the patient: a 2x
  stiffer contact, a half as stiff one, and a 1.5x stronger extensor.
* Finger Extensor: 3x the Coulomb friction (a dry chain), 3x the return spring, 2x the viscous
  friction, the motor's magnet 10 % weaker (k_t, a warm or aged motor) and its supply 10 % low. The
  patient's torque is measured (an input of the model), so it is not a model difference here.
* TCP finger: the supply 10 % low (max_power_w, the power at full duty), the return springs 1.5x
  stiffer, the joints' damping 2x, the room 7 C warmer (the shipped Table 1 transfer functions are
  deviations from rest: the room should not move them, and the case shows it does not).

    .venv/bin/python bench/robustness.py [--quick] [--plants sma_exoskeleton,tcp_finger]
        [--controller model_based] [--setting key=value ...] [--cycles N] [--cases name,...]

``--controller``/``--setting`` run another controller or a setting of its ``[controllers.<name>]``
table (the learning variant: ``--setting <its key>=true``) on the same rigs. Prints a table per
plant (each case beside the nominal rig) and writes bench/results/robustness.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
RESULTS = ROOT / "bench" / "results" / "robustness.json"
ADC_NOISE_COUNTS = 1.0
SEED = 1
CYCLES = {"sma_exoskeleton": 10, "finger_extensor": 10, "tcp_finger": 10}
QUICK_CYCLES = {"sma_exoskeleton": 4, "finger_extensor": 4, "tcp_finger": 2}
# issue 39's targets: SMA RMSE <= 1 deg over cycles 3 on and <= 0.5 deg by cycle 10, wire <= 103 C;
# Finger Extensor <= 0.3 deg; TCP <= 5 % of its range
TARGET_RMSE_DEG = {"sma_exoskeleton": 1.0, "finger_extensor": 0.3}
TARGET_TCP_SHARE = 0.05
TARGET_SMA_LATE_DEG = 0.5
TARGET_SMA_TEMP_C = 103.0


@dataclass(frozen=True)
class Case:
    """One rig: the plant, the changed key and its value's change (scale or shift), and why."""

    plant: str
    name: str
    key: str = ""  # dotted config key; "" = the nominal rig
    scale: float = 1.0
    shift: float = 0.0
    why: str = ""

    def value(self, base: float) -> float:
        return base * self.scale + self.shift


CASES = (
    Case("sma_exoskeleton", "nominal", why="the model's own rig"),
    Case("sma_exoskeleton", "room +7 C", "sma.ambient_c", shift=7.0, why="summer, a radiator"),
    Case("sma_exoskeleton", "room -5 C", "sma.ambient_c", shift=-5.0, why="a winter morning"),
    Case("sma_exoskeleton", "draft +30 %", "sma.h1_w_per_m2_c", 1.3, why="a fan, an open window"),
    Case("sma_exoskeleton", "still air -20 %", "sma.h1_w_per_m2_c", 0.8, why="under a sleeve"),
    Case("sma_exoskeleton", "supply -10 %", "drive.supply_voltage_v", 0.9, why="a sagging supply, a long cable"),
    Case("sma_exoskeleton", "pre-strain -15 %", "sma.prestrain", 0.85, why="the wire re-tensioned"),
    Case("sma_exoskeleton", "patient 2x stiffer", "contact.stiffness_n_per_m", 2.0, why="a firmer finger pad"),
    Case("sma_exoskeleton", "patient 0.5x stiffer", "contact.stiffness_n_per_m", 0.5, why="a softer pad"),
    Case("sma_exoskeleton", "patient 1.5x stronger", "muscle.max_isometric_force_n", 1.5, why="a stronger extensor"),
    Case("finger_extensor", "nominal", why="the model's own rig"),
    Case("finger_extensor", "friction 3x", "iris.coulomb_nm", 3.0, why="a dry chain"),
    Case("finger_extensor", "spring 3x", "iris.spring_nm_per_rad", 3.0, why="a stiffer return spring"),
    Case("finger_extensor", "viscous 2x", "iris.viscous_nm_s_per_rad", 2.0, why="cold grease"),
    Case("finger_extensor", "magnet k_t -10 %", "motor.kt_nm_per_a", 0.9, why="a warm or aged motor"),
    Case("finger_extensor", "supply -10 %", "motor.supply_v", 0.9, why="a sagging supply"),
    Case("tcp_finger", "nominal", why="the model's own rig"),
    Case("tcp_finger", "supply -10 %", "muscle.max_power_w", 0.9, why="a sagging supply"),
    Case("tcp_finger", "springs 1.5x", "finger.spring_nm_per_deg", 1.5, why="stiffer return springs"),
    Case("tcp_finger", "damping 2x", "finger.damping_nm_s_per_rad", 2.0, why="stiffer joints"),
    Case("tcp_finger", "room +7 C", "muscle.ambient_c", shift=7.0, why="summer (no effect on Table 1's TFs)"),
)


# -- the rigs ----------------------------------------------------------------------------------
def _format(v: float) -> str:
    """A TOML float that reads back as the same float."""
    r = repr(float(v))
    return r if ("." in r or "e" in r or "inf" in r or "nan" in r) else r + ".0"


def set_key(text: str, key: str, value: float) -> str:
    """``text`` (a config file) with the line of ``key`` (dotted: table path, then the key) set to
    ``value``, its comment kept. Raises KeyError when the file has no such line in that table."""
    table, _, name = key.rpartition(".")
    current = ""
    lines = text.split("\n")
    for i, line in enumerate(lines):
        head = re.match(r"^\s*\[([^\[\]]+)\]", line)
        if head:
            current = head.group(1).strip()
            continue
        m = re.match(rf"^(\s*{re.escape(name)}\s*=\s*)([^#\s][^#]*?)(\s*(#.*)?)$", line)
        if current == table and m:
            lines[i] = m.group(1) + _format(value) + m.group(3)
            return "\n".join(lines)
    raise KeyError(f"{key}: no such line in its table")


def case_config(base: Path, case: Case, out: Path) -> Path:
    """Write ``out``: the config ``base`` with the case's key changed (a copy for the nominal case);
    loaded once, so a bad value raises the ConfigError a user would see."""
    from rehab_hil.loading import load_config
    from rehab_hil.twin.thermal import config_value

    text = base.read_text()
    if case.key:
        text = set_key(text, case.key, case.value(config_value(load_config(base), case.key)))
    out.write_text(text)
    load_config(out)
    return out


def host_config(base: Path, controller: str | None, settings: dict[str, str], out: Path) -> Path:
    """The host's config: the shipped one, or a copy with ``settings`` in ``[controllers.<name>]``
    (a key the table has is rewritten, another is added to it)."""
    if not settings:
        return base
    from rehab_hil.loading import load_config

    name = controller or load_config(base).rig.session.controller
    text = base.read_text()
    for k, v in settings.items():
        try:
            text = _set_raw(text, f"controllers.{name}.{k}", v)
        except KeyError:
            text = re.sub(rf"(?m)^(\[controllers\.{re.escape(name)}\][^\n]*\n)", rf"\g<1>{k} = {v}\n", text, count=1)
    out.write_text(text)
    load_config(out)
    return out


def _set_raw(text: str, key: str, raw: str) -> str:
    """``set_key`` with the value's TOML text as given (true, 0.5, "name")."""
    marker = 1.2345678901234567e-300
    return set_key(text, key, marker).replace(_format(marker), raw)


# -- one session --------------------------------------------------------------------------------
@dataclass
class CaseResult:
    plant: str
    case: str
    key: str
    host_value: float | None
    rig_value: float | None
    cycles: list[dict[str, float]]
    safety_events: list[str]
    thermal: dict[str, dict[str, float]] = field(default_factory=dict)  # key -> estimate, ci95, truth
    thermal_events: list[str] = field(default_factory=list)
    model_events: int = 0
    wall_s: float = 0.0
    thermal_cpu_s_per_window: float = math.nan
    replans: list[str] = field(default_factory=list)  # the feedforward re-planned on the twin's estimates


def run_case(case: Case, host: Path, n_cycles: int, controller: str | None, tmp: Path,
             replan: bool = True) -> CaseResult:
    """The case's session: ``n_cycles`` open-close cycles on its rig, lockstep, the twin beside it."""
    from rehab_hil.hardware.open import inprocess_hardware
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant
    from rehab_hil.service.session import open_session
    from rehab_hil.twin.thermal import config_value

    sim_path = case_config(CONFIGS / f"{case.plant}.toml", case, tmp / f"{case.plant}_{abs(hash(case.name))}.toml")
    cfg, sim = load_config(host), load_config(sim_path)
    # the first cycle starts after the rest (a share of a period): half a period more holds n whole cycles
    duration = (n_cycles + 0.5) * 60.0 / cfg.rig.session.cycles_per_minute
    hw = inprocess_hardware(get_plant(sim.plant).device(sim), adc_noise_counts=ADC_NOISE_COUNTS, seed=SEED)
    hw.connect()
    t0 = time.perf_counter()
    try:
        with open_session(host, hw=hw, twin=True, lockstep=True, realtime=False, sample_timeout_s=5.0,
                          controller=controller, thermal_replan=replan,
                          learning_store=tmp / "learning" / re.sub(r"\W+", "_", case.name)) as session:
            session.twin.live._cap = max(session.twin.live._cap, round(2 * duration / session.period_s))
            res = session.run(duration)
    finally:
        hw.close()
    twin = res.twin.get("twin", {}) if res.twin else {}
    thermal = twin.get("thermal") or {}
    return CaseResult(
        plant=case.plant, case=case.name, key=case.key,
        host_value=config_value(cfg, case.key) if case.key else None,
        rig_value=config_value(sim, case.key) if case.key else None,
        cycles=[{k: c[k] for k in ("index", "rmse_deg", "max_error_deg", "peak_temperature_c")}
                for c in res.session_cycles],
        safety_events=[f"{e.reason} at {e.t_s:.1f} s" for e in res.events if e.reason != "stop_request"],
        thermal={k: {"value": e["value"], "ci95": e["ci95"], "config": e["config"], "truth": config_value(sim, k)}
                 for k, e in thermal.get("estimates", {}).items()},
        thermal_events=[f"{e['label']} {e['value']:.4g} at {e['t_s']:.0f} s"
                        + ("" if e.get("explained", True) else " (not explained: not handed to the controller)")
                        for e in thermal.get("events", [])],
        model_events=len(res.twin.get("model_events", [])) if res.twin else 0, wall_s=time.perf_counter() - t0,
        thermal_cpu_s_per_window=thermal.get("cpu_s_per_window", math.nan),
        replans=[replan_text(e) for e in (res.learning or {}).get("replans", [])])


def replan_text(e: dict[str, Any]) -> str:
    """One re-plan, short: on what, when it was taken, how long it took."""
    if "replan_error" in e:
        return f"re-plan failed: {e['replan_error']}"
    on = ", ".join(f"{k.split('.')[-1]} {v:.4g}" for k, v in e["replan_updates"].items())
    return f"re-planned on {on} ({e['replan_s']:.1f} s), taken at {e['t_s']:.0f} s"


# -- the figures ----------------------------------------------------------------------------------
def figures(r: CaseResult) -> dict[str, float]:
    """The case's figures: RMSE over cycles 3 on (index 2 on), the last cycle's, the largest error
    and the hottest estimate over the session."""
    cyc = r.cycles
    late = [c["rmse_deg"] for c in cyc[2:]] or [c["rmse_deg"] for c in cyc]
    nan = math.nan
    return {"cycles": len(cyc), "rmse_3on_deg": float(sum(late) / len(late)) if late else nan,
            "rmse_last_deg": cyc[-1]["rmse_deg"] if cyc else nan,
            "max_error_deg": max((c["max_error_deg"] for c in cyc), default=nan),
            "peak_temperature_c": max((c["peak_temperature_c"] for c in cyc), default=nan)}


def meets(plant: str, f: dict[str, float], safety: list[str], range_deg: float) -> bool:
    """Issue 39's target for this plant's rig."""
    if safety or not f["cycles"]:
        return False
    if plant == "sma_exoskeleton":
        late_ok = f["rmse_last_deg"] <= TARGET_SMA_LATE_DEG if f["cycles"] >= 10 else True
        return f["rmse_3on_deg"] <= TARGET_RMSE_DEG[plant] and late_ok and f["peak_temperature_c"] <= TARGET_SMA_TEMP_C
    if plant == "tcp_finger":
        return f["rmse_3on_deg"] <= TARGET_TCP_SHARE * range_deg
    return f["rmse_3on_deg"] <= TARGET_RMSE_DEG[plant]


def thermal_text(r: CaseResult) -> str:
    """The twin's thermal estimates beside the rig's truth, short."""
    parts = []
    for k, e in r.thermal.items():
        parts.append(f"{k.split('.')[-1]} {e['value']:.4g}+-{e['ci95']:.2g} (rig {e['truth']:.4g})")
    return "; ".join(parts)


def table(plant: str, results: list[CaseResult], range_deg: float) -> str:
    """A plant's table: each case beside the nominal rig (the first row)."""
    head = (f"{'rig differs by':<22} {'cyc':>3} {'RMSE 3+':>8} {'last':>6} {'max':>6} {'peak T':>7} "
            f"{'target':>6}  safety / per-cycle RMSE [deg]")
    lines = [f"== {plant} (target RMSE: " + ("<= 1 deg from cycle 3, <= 0.5 by 10, T <= 103 C)"
                                            if plant == "sma_exoskeleton" else
                                            f"<= {TARGET_TCP_SHARE * range_deg:.2g} deg)" if plant == "tcp_finger"
                                            else "<= 0.3 deg)"), head, "-" * len(head)]
    for r in results:
        f = figures(r)
        per = " ".join(f"{c['rmse_deg']:.2f}" for c in r.cycles)
        safety = ", ".join(r.safety_events) or "-"
        lines.append(f"{r.case:<22} {f['cycles']:>3} {f['rmse_3on_deg']:>8.2f} {f['rmse_last_deg']:>6.2f} "
                     f"{f['max_error_deg']:>6.2f} {f['peak_temperature_c']:>7.1f} "
                     f"{'yes' if meets(plant, f, r.safety_events, range_deg) else 'no':>6}  {safety} | {per}")
        if r.thermal:
            lines.append(f"{'':<22}   twin: {thermal_text(r)}"
                         + (f"; events: {', '.join(r.thermal_events)}" if r.thermal_events else ""))
        if r.replans:
            lines.append(f"{'':<22}   {'; '.join(r.replans)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plants", default=",".join(CYCLES))
    ap.add_argument("--cases", default="", help="only these case names (comma-separated)")
    ap.add_argument("--controller", default=None, help="a controller's name (default: [rig.session] controller)")
    ap.add_argument("--setting", action="append", default=[], help="key=value in [controllers.<controller>]")
    ap.add_argument("--cycles", type=int, default=None)
    ap.add_argument("--quick", action="store_true", help="fewer cycles (SMA, FE 4; TCP 2)")
    ap.add_argument("--no-replan", action="store_true", help="the feedforward is not re-planned on the twin's "
                    "thermal estimates (the session option thermal_replan=False)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args(argv)
    from rehab_hil.loading import load_config

    settings = dict(s.split("=", 1) for s in a.setting)
    only = {c.strip() for c in a.cases.split(",") if c.strip()}
    out: dict[str, Any] = {"controller": a.controller, "settings": settings, "quick": a.quick,
                           "replan": not a.no_replan, "plants": {}}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for plant in [p.strip() for p in a.plants.split(",") if p.strip()]:
            try:
                host = host_config(CONFIGS / f"{plant}.toml", a.controller, settings, tmp / f"host_{plant}.toml")
            except ValueError as e:  # a ConfigError: the setting's key or value, named
                print(f"{plant}: {e}", file=sys.stderr)
                return 2
            s = load_config(host).rig.session
            range_deg = abs(s.open_deg - s.closed_deg)
            n = a.cycles or (QUICK_CYCLES if a.quick else CYCLES)[plant]
            results = []
            for case in (c for c in CASES if c.plant == plant and (not only or c.name in only)):
                results.append(run_case(case, host, n, a.controller, tmp, replan=not a.no_replan))
                print(f"  {plant} {case.name}: {results[-1].wall_s:.0f} s", file=sys.stderr, flush=True)
            print(table(plant, results, range_deg), flush=True)
            out["plants"][plant] = {"range_deg": range_deg, "cases": [
                {**asdict(r), "figures": figures(r), "meets_target": meets(plant, figures(r), r.safety_events,
                                                                            range_deg)} for r in results]}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1, default=float))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
