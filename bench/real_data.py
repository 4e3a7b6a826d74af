"""Real measured data (issue 24): the discrepancy workflow on the EMPS benchmark and the FlexiForce
figures of Dickmann et al. 2021, printed side by side with the published reference values.

EMPS (``../shared/data/emps``): ``rehab-hil discrepancy --config configs/emps_nominal.toml --data
DATA_EMPS.mat --validate DATA_EMPS_PULSES.mat`` run from the CLI with an empty engine cache (what a
fresh clone pays: every diagram compiled), wall and CPU time; then the same from the reference model
(``configs/emps.toml``). Table: nominal, fitted (search + joint identification), the benchmark's
reference, error; the control-effort error on the validation run before and after.
FlexiForce (``../shared/data/flexiforce_dickmann``): the static calibration refitted beside the
authors' linear fits; creep time constant, creep in 5 s, hysteresis and run-to-run gain spread per
sensor from the dead-weight staircases.
DC motor and generator (Lacerda Junior et al. 2017, ``tests/data/dc_motor_generator``, MIT): the
workflow from the linear least-squares model (``configs/dc_motor_generator.toml``) and from the driven
part of an independent switched fit, beside independent least-squares fits of the same rows (linear
first order; driven and coasting phases with Coulomb deceleration and a dead time).
KUKA KR300 axis 1 (Weigand et al. 2021, ``tests/data/kuka_kr300_axis1``, MIT; both directions): the
workflow over records A and B, validated on C, from the model without Coulomb friction
(``configs/kuka_kr300_axis1_nominal.toml``) and from the reference holding the published friction
(``configs/kuka_kr300_axis1.toml``), beside independent least-squares fits of the link torque
(inertia, viscous friction, a Coulomb level per direction; per record and over A and B) and the
friction the records' feedforward used.
Writes bench/results/real_data.json. Usage: python bench/real_data.py [--data-dir ../shared/data]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.io

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = {"load.mass_kg": 95.1089, "load.viscous_n_s_per_m": 203.5034, "coulomb_n": 20.3935, "offset_n": -3.1648}


def _cli(args: list[str], cache: str) -> tuple[int, str, float, float]:
    env = {**os.environ, "REHAB_HIL_CACHE_DIR": cache}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "rehab_hil.cli", *args], capture_output=True, text=True, env=env,
                       cwd=ROOT)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return p.returncode, p.stdout + p.stderr[-2000:], wall, cpu


def emps(data: Path, out: Path) -> dict:
    est, val = data / "emps" / "DATA_EMPS.mat", data / "emps" / "DATA_EMPS_PULSES.mat"
    res: dict = {}
    with tempfile.TemporaryDirectory() as cache:
        for name, cfg, cold in (("nominal", "configs/emps_nominal.toml", True),
                                ("nominal_warm", "configs/emps_nominal.toml", False),
                                ("reference", "configs/emps.toml", False)):
            rep_dir = out / f"emps_{name}"
            rc, text, wall, cpu = _cli(["discrepancy", "--config", cfg, "--data", str(est), "--validate", str(val),
                                        "--out", str(rep_dir)], cache)
            if rc != 0:
                raise SystemExit(f"{name}: exit {rc}\n{text}")
            rep = json.loads((rep_dir / "report.json").read_text())
            res[name] = {"wall_s": wall, "cpu_s": cpu, "cold_cache": cold, "conclusion": rep["conclusion"],
                         "named": [c["effect"] for c in rep["chosen"]],
                         "chosen": {c["effect"]: c["params"] for c in rep["chosen"]},
                         "joint": rep["joint_identification"], "validation": rep["validation"],
                         "metrics": rep["metrics"], "replay": rep["replay"]["loop"]}
    return res


def _fitted(run: dict) -> dict[str, float]:
    """The fitted values: Coulomb and offset from the chosen effects, M and Fv from the joint fit."""
    joint = run["joint"] or {"parameters": [], "corrected": {}}
    vals = {p["name"]: p["value"] for p in joint["parameters"]}
    out = {k: joint["corrected"].get(k, float("nan")) for k in ("load.mass_kg", "load.viscous_n_s_per_m")}
    out["coulomb_n"] = vals.get("coulomb_friction.level_nm", run["chosen"].get("coulomb_friction", {}).get("level_nm",
                                                                                                            0.0))
    # ConstantLoad pushes -level on the axis: its level is EMPS eq 1's offset (tau = ... + offset)
    out["offset_n"] = vals.get("constant_load.level_nm", run["chosen"].get("constant_load", {}).get("level_nm", 0.0))
    return out


DC_DATA = ROOT / "tests" / "data" / "dc_motor_generator" / "motor_generator_30s.csv"
DC_CONFIG = ROOT / "configs" / "dc_motor_generator.toml"
DC_ROW_S = 0.002  # the copy's rows (raw sample taken as 0.1 ms, README)
DC_FIT_ROWS = 10000  # the first 20 s, as the workflow's fit part


def _dc_rows() -> tuple[np.ndarray, np.ndarray]:
    raw = np.loadtxt(DC_DATA, delimiter=",", skiprows=1)
    return raw[:, 1], raw[:, 2] - raw[:200, 2].mean()


def _switched(p: np.ndarray, k: int, u: np.ndarray, n: int) -> np.ndarray:
    """w' = g u - b w - c while driven (u > 0), -c coasting, stopped at 0; u delayed by k rows."""
    from numba import njit

    @njit(cache=True)
    def run(g: float, b: float, c: float, k: int, u: np.ndarray, n: int, dt: float) -> np.ndarray:
        out = np.zeros(n)
        v = 0.0
        for i in range(n - 1):
            ui = u[i - k] if i >= k else 0.0
            v += dt * ((g * ui - b * v - c) if ui > 0 else -c)
            v = max(v, 0.0)
            out[i + 1] = v
        return out

    return run(float(p[0]), float(p[1]), float(p[2]), k, u, n, DC_ROW_S)


def independent_dc_fit() -> dict:
    """Least-squares fits of the copy's first 20 s, outside the workflow: a linear first-order model
    (w' = g u - Fv w; closed form by lfilter), and the switched model (``_switched``) over a grid of
    dead times; RMS of each over the fit part and the 10 s after it, beside the noise floor."""
    from scipy.optimize import least_squares
    from scipy.signal import lfilter

    from rehab_hil.discrepancy.verdict import noise_floor

    u, w = _dc_rows()
    n, dt = DC_FIT_ROWS, DC_ROW_S

    def linear(p: np.ndarray, m: int) -> np.ndarray:
        return lfilter([0.0, p[0] * dt], [1.0, -(1.0 - p[1] * dt)], u[:m])

    lin = least_squares(lambda p: linear(p, n) - w[:n], [6000.0, 3.0])
    best = None
    for k in range(0, 40, 2):
        fit = least_squares(lambda p, k=k: _switched(p, k, u, n) - w[:n], [6000.0, 5.0, 100.0],
                            x_scale=[1e3, 1.0, 100.0], bounds=([0, 0, 0], [1e6, 100, 1e5]))
        rms = float(np.sqrt(np.mean(fit.fun**2)))
        if best is None or rms < best[0]:
            best = (rms, k, fit.x)
    assert best is not None
    _, k, p = best
    m = u.size
    return {"linear": {"g_per_s_v": float(lin.x[0]), "fv_per_s": float(lin.x[1]),
                       "rms_fit": float(np.sqrt(np.mean(lin.fun**2))),
                       "rms_all": float(np.sqrt(np.mean((linear(lin.x, m) - w) ** 2)))},
            "switched": {"g_per_s_v": float(p[0]), "fv_driven_per_s": float(p[1]), "coulomb_per_s": float(p[2]),
                         "delay_s": k * dt, "rms_fit": best[0],
                         "rms_all": float(np.sqrt(np.mean((_switched(p, k, u, m) - w) ** 2)))},
            "noise_floor": noise_floor(w), "spread": float(np.std(w))}


def dc_motor_generator(out: Path, indep: dict) -> dict:
    """The workflow from the linear fit (the shipped config) and from the switched fit's driven part
    without its Coulomb deceleration and dead time (a config written beside the report)."""
    sw = indep["switched"]
    text = DC_CONFIG.read_text()
    driven = "\n".join(
        f"viscous_nm_s_per_rad = {sw['fv_driven_per_s'] * 1e-3:.6g}  # the switched fit's driven damping"
        if ln.startswith("viscous_nm_s_per_rad") else
        f"torque_constant_nm_per_v = {sw['g_per_s_v'] * 1e-3:.6g}  # the switched fit's gain"
        if ln.startswith("torque_constant_nm_per_v") else ln for ln in text.splitlines())
    out.mkdir(parents=True, exist_ok=True)
    (out / "dc_driven.toml").write_text(driven + "\n")
    res = {}
    with tempfile.TemporaryDirectory() as cache:
        for name, cfg in (("linear", str(DC_CONFIG)), ("driven", str(out / "dc_driven.toml"))):
            rep_dir = out / f"dc_{name}"
            rc, printed, wall, cpu = _cli(["discrepancy", "--config", cfg, "--data", str(DC_DATA), "--out",
                                           str(rep_dir)], cache)
            if rc != 0:
                raise SystemExit(f"dc {name}: exit {rc}\n{printed}")
            rep = json.loads((rep_dir / "report.json").read_text())
            res[name] = {"wall_s": wall, "cpu_s": cpu, "conclusion": rep["conclusion"],
                         "named": [c["effect"] for c in rep["chosen"]], "residual": rep["residual"],
                         "rmse": {k: rep["metrics"][k]["velocity_rad_s"]["rmse"] for k in ("nominal", "augmented")}}
    return res


def _print_dc(indep: dict, runs: dict) -> None:
    lin, sw = indep["linear"], indep["switched"]
    print("DC motor and generator (Lacerda Junior et al. 2017), 30 s, speed in the logger's unit (u.):")
    print(f"  independent least squares, first 20 s (noise floor {indep['noise_floor']:.3g} u., spread "
          f"{indep['spread']:.4g} u.):")
    print(f"    linear first order   g {lin['g_per_s_v']:.4g} u./s/V, Fv {lin['fv_per_s']:.4g} /s: RMS "
          f"{lin['rms_fit']:.4g} (fit part), {lin['rms_all']:.4g} u. (whole 30 s)")
    print(f"    driven / coasting    g {sw['g_per_s_v']:.4g} u./s/V, Fv while driven {sw['fv_driven_per_s']:.4g} /s, "
          f"Coulomb deceleration {sw['coulomb_per_s']:.4g} u./s, dead time {1e3 * sw['delay_s']:.0f} ms: RMS "
          f"{sw['rms_fit']:.4g}, {sw['rms_all']:.4g} u.")
    for name, r in runs.items():
        res = r["residual"]["velocity_rad_s"]
        print(f"  workflow from the {name:7s} model: named {r['named'] or 'nothing'}; held-out residual "
              f"{res['rms']:.4g} u. = {100 * res['share_of_spread']:.0f} % of the spread (noise floor "
              f"{res['noise_floor']:.3g}); replay RMSE {r['rmse']['nominal']:.4g} -> {r['rmse']['augmented']:.4g} u.; "
              f"wall {r['wall_s']:.1f} s")
        print(f"    {r['conclusion']}")


KUKA_DATA = ROOT / "tests" / "data" / "kuka_kr300_axis1"
KUKA_GEAR = 256.8571  # u(1), the records' para struct: motor torque x u = link torque
KUKA_PUBLISHED = {"coulomb_nm": 285.36 + 70.135, "offset_nm": 54.024, "viscous_nm_s_per_rad": 2050.35}  # para struct
KUKA_MOVING_RAD_S = 0.01  # the fits use samples turning faster than this (the tanh of the published law is saturated)


def kuka_rows(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Link torque [N m], velocity and acceleration (Savitzky-Golay derivatives of the position) of a record."""
    from scipy.signal import savgol_filter

    d = np.genfromtxt(KUKA_DATA / f"record_{name}.csv", delimiter=",", names=True)
    q, dt = np.radians(d["act_pos_mot_deg_1"]), float(np.median(np.diff(d["time_cont"])))
    return (d["act_torque_abs_nm_1"] * KUKA_GEAR, savgol_filter(q, 11, 3, deriv=1, delta=dt),
            savgol_filter(q, 11, 3, deriv=2, delta=dt))


def independent_kuka_fit(names: tuple[str, ...]) -> dict:
    """Least squares of tau = J q'' + Fv q' + Fc+ [q' > 0] - Fc- [q' < 0] over the records ``names``
    (one parameter set), outside the workflow; also the symmetric form with a constant (Fc sgn q' + c)."""
    rows = [kuka_rows(n) for n in names]
    tau = np.concatenate([r[0] for r in rows])
    v, a = np.concatenate([r[1] for r in rows]), np.concatenate([r[2] for r in rows])
    m = np.abs(v) > KUKA_MOVING_RAD_S
    X = np.column_stack([a, v, (v > 0), -1.0 * (v < 0)]).astype(float)[m]
    th, *_ = np.linalg.lstsq(X, tau[m], rcond=None)
    Xs = np.column_stack([a, v, np.sign(v), np.ones_like(v)])[m]
    ts, *_ = np.linalg.lstsq(Xs, tau[m], rcond=None)
    return {"inertia_kg_m2": float(th[0]), "viscous_nm_s_per_rad": float(th[1]), "level_pos_nm": float(th[2]),
            "level_neg_nm": float(th[3]), "rms_nm": float(np.sqrt(np.mean((tau[m] - X @ th) ** 2))),
            "symmetric": {"coulomb_nm": float(ts[2]), "offset_nm": float(ts[3]),
                          "rms_nm": float(np.sqrt(np.mean((tau[m] - Xs @ ts) ** 2)))},
            "torque_spread_nm": float(np.std(tau[m])), "share_turning_pos": float(np.mean(v > KUKA_MOVING_RAD_S)),
            "share_turning_neg": float(np.mean(v < -KUKA_MOVING_RAD_S))}


def kuka(out: Path) -> dict:
    """The workflow from the CLI over records A and B, validated on C, from both configs."""
    res = {}
    data = [str(KUKA_DATA / f"record_{n}.csv") for n in ("a", "b")]
    with tempfile.TemporaryDirectory() as cache:
        for name in ("nominal", "reference"):
            cfg = f"configs/kuka_kr300_axis1{'_nominal' if name == 'nominal' else ''}.toml"
            rep_dir = out / f"kuka_{name}"
            rc, printed, wall, cpu = _cli(["discrepancy", "--config", cfg, "--data", data[0], "--data", data[1],
                                           "--validate", str(KUKA_DATA / "record_c.csv"), "--out", str(rep_dir)],
                                          cache)
            if rc != 0:
                raise SystemExit(f"kuka {name}: exit {rc}\n{printed}")
            rep = json.loads((rep_dir / "report.json").read_text())
            joint = rep.get("joint_identification") or {}
            res[name] = {"wall_s": wall, "cpu_s": cpu, "conclusion": rep["conclusion"],
                         "named": [c["effect"] for c in rep["chosen"]],
                         "params": {c["effect"]: c["params"] for c in rep["chosen"]},
                         "joint": {p["name"]: p["value"] for p in joint.get("parameters", [])},
                         "corrected": joint.get("corrected", {}), "gaps": rep["gaps"],
                         "candidates": [(c["effect"], c["params"], c["delta_bic"]) for rd in rep["rounds"]
                                        for c in rd["candidates"]]}
    return res


def _print_kuka(indep: dict, runs: dict) -> None:
    ab, per = indep["a+b"], {k: v for k, v in indep.items() if len(k) == 1}
    print("KUKA KR300 axis 1 (Weigand et al. 2021), records A and B (estimation), C (validation), 10 s at 250 Hz:")
    print(f"  independent least squares over A+B: J {ab['inertia_kg_m2']:.0f} kg m^2, "
          f"Fv {ab['viscous_nm_s_per_rad']:.0f} N m s/rad, Coulomb {ab['level_pos_nm']:.0f} N m turning +, "
          f"{ab['level_neg_nm']:.0f} turning - "
          f"(symmetric {ab['symmetric']['coulomb_nm']:.0f} + constant {ab['symmetric']['offset_nm']:.0f}); RMS "
          f"{ab['rms_nm']:.0f} of {ab['torque_spread_nm']:.0f} N m")
    print(f"    over A+B+C: J {indep['a+b+c']['inertia_kg_m2']:.1f} kg m^2 (the configs' inertia)")
    for k, f in per.items():
        print(f"    record {k.upper()}: J {f['inertia_kg_m2']:.0f}, Fv {f['viscous_nm_s_per_rad']:.0f}, Coulomb + "
              f"{f['level_pos_nm']:.0f} / - {f['level_neg_nm']:.0f} N m")
    pub = KUKA_PUBLISHED
    print(f"  published (the records' feedforward): Coulomb {pub['coulomb_nm']:.1f} N m + constant "
          f"{pub['offset_nm']:.1f} ({pub['coulomb_nm'] + pub['offset_nm']:.1f} turning +, "
          f"{pub['coulomb_nm'] - pub['offset_nm']:.1f} -), "
          f"Fv {pub['viscous_nm_s_per_rad']:.0f}")
    sym = ab["symmetric"]["coulomb_nm"]
    for name, r in runs.items():
        print(f"  from the {name} model: named {r['named'] or 'nothing'}; wall {r['wall_s']:.1f} s")
        for eff, params in r["params"].items():
            for k, v in params.items():
                print(f"    {eff}.{k} = {v:.4g} ({100 * (v / sym - 1):+.0f} % against the independent symmetric "
                      f"{sym:.0f} N m)")
        for k, v in r["joint"].items():
            print(f"    joint identification: {k} = {v:.4g}")
        print(f"    {r['conclusion']}")


def flexiforce(data: Path) -> dict:
    from rehab_hil.analysis.flexiforce import fit_static, read_points, staircase

    d = data / "flexiforce_dickmann"
    static = {s: fit_static(s, *fc) for s, fc in read_points(d / "static_calibration.csv").items()}
    raw = scipy.io.loadmat(d / "Sensor_Data_3_Runs_consec.mat")
    stairs = {name: staircase(name, [raw[f"Sensor_{k}{i}"].ravel().astype(float) for i in (1, 2, 3)])
              for name, k in (("B (upper)", "o"), ("A (lower)", "u"))}
    return {"static": {s: {"model": f.model, "coefficients": f.coefficients, "rms_n": f.rms_n,
                           "max_abs_n": f.max_abs_n, "published_linear_rms_n": f.published_rms_n}
                       for s, f in static.items()},
            "staircase": {s: {"creep_time_constant_s": f.creep_time_constant_s,
                              "creep_pct_in_5s_median": f.creep_pct_median,
                              "creep_pct_in_5s": f.creep_pct_in_5s, "hysteresis_counts": f.hysteresis_counts,
                              "hysteresis_n": f.hysteresis_n, "hysteresis_pct_fs": f.hysteresis_pct_fs,
                              "gain_spread_pct": f.gain_spread_pct} for s, f in stairs.items()}}


def _print_emps(runs: dict, fit: dict, nominal: dict) -> None:
    print("EMPS, rehab-hil discrepancy --config configs/emps_nominal.toml --data DATA_EMPS.mat --validate "
          "DATA_EMPS_PULSES.mat")
    print(f"  conclusion: {runs['nominal']['conclusion']}")
    print(f"  replay: {runs['nominal']['replay']}")
    print(f"  {'parameter':26s} {'nominal':>10s} {'fitted':>10s} {'reference':>10s} {'error':>8s}")
    for k, ref in REFERENCE.items():
        print(f"  {k:26s} {nominal[k]:10.4g} {fit[k]:10.4g} {ref:10.4g} {100 * (fit[k] - ref) / abs(ref):+7.2f} %")
    for name in ("nominal", "reference"):
        v = runs[name]["validation"]
        m = v["metrics"]
        print(f"  validation ({name} config): drive_input_v RMSE {m['nominal']['drive_input_v']['rmse']:.4g} -> "
              f"{m['augmented']['drive_input_v']['rmse']:.4g} V ({v['error_change']['drive_input_v']}), "
              f"position_m {m['nominal']['position_m']['rmse']:.3g} -> {m['augmented']['position_m']['rmse']:.3g} m")
    for name in ("nominal", "nominal_warm", "reference"):
        r = runs[name]
        cache = "empty" if r["cold_cache"] else "warm"
        print(f"  {name:13s} wall {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s ({cache} engine cache); "
              f"named: {r['named'] or 'nothing'}")
    print(f"  reference config: {runs['reference']['conclusion']}")
    print(f"  load average during the runs: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs (other work shares them)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "real_data.json")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        runs = emps(args.data_dir, Path(tmp))
        dc_indep = independent_dc_fit()
        dc_runs = dc_motor_generator(Path(tmp), dc_indep)
        kuka_indep = {"a+b": independent_kuka_fit(("a", "b")), "a+b+c": independent_kuka_fit(("a", "b", "c")),
                      **{n: independent_kuka_fit((n,)) for n in ("a", "b", "c")}}
        kuka_runs = kuka(Path(tmp))
    ff = flexiforce(args.data_dir)
    fit = _fitted(runs["nominal"])
    nominal = {"load.mass_kg": 95.1089, "load.viscous_n_s_per_m": 203.5034, "coulomb_n": 0.0, "offset_n": 0.0}
    _print_emps(runs, fit, nominal)
    _print_dc(dc_indep, dc_runs)
    _print_kuka(kuka_indep, kuka_runs)
    print("FlexiForce A201 (Dickmann et al. 2021), static calibration [N]:")
    print(f"  {'sensor':8s} {'chosen':10s} {'RMS linear':>11s} {'RMS quad':>9s} {'published':>10s}")
    for s, f in ff["static"].items():
        print(f"  {s:8s} {f['model']:10s} {f['rms_n']['linear']:11.3f} {f['rms_n']['quadratic']:9.3f} "
              f"{f['published_linear_rms_n']:10.3f}")
    print("  staircases (3 runs each): creep tau, creep in 5 s (median), hysteresis at 6.916 N, gain spread")
    for s, f in ff["staircase"].items():
        print(f"  {s:10s} tau {f['creep_time_constant_s']:.2f} s, creep {f['creep_pct_in_5s_median']:.2f} %, "
              f"hysteresis {f['hysteresis_counts'][6.916]:.0f} counts = {f['hysteresis_n'][6.916]:.3f} N "
              f"({f['hysteresis_pct_fs']:.2f} % of 9.82 N), gain spread {f['gain_spread_pct']:.1f} %")
    result = {"emps": {"runs": runs, "fitted": fit, "reference": REFERENCE, "nominal": nominal},
              "flexiforce": ff, "dc_motor_generator": {"independent": dc_indep, "workflow": dc_runs},
              "kuka_kr300_axis1": {"independent": kuka_indep, "workflow": kuka_runs, "published": KUKA_PUBLISHED},
              "python": sys.version.split()[0], "cpus": os.cpu_count(),
              "load_average": os.getloadavg()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, default=lambda o: o if not isinstance(o, np.generic)
                                   else o.item()) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
