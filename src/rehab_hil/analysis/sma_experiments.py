"""Seed 000 experiments on the SMA exoskeleton model, side by side with the paper.

``python -m rehab_hil.analysis.sma_experiments [config]`` prints the tables that
docs/sma_exoskeleton.md reports: the 32 V bending experiment (Fig. 7-9), the PWM-ratio sweep
(Fig. 10), the eq 29 shrinkage-torque comparison with and without contact (Fig. 15-16), the
k, c regression (Table 4, eq 30) on the model's contact data, and the LE muscle force (eq 1-3).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.analysis.contact_regression import ContactFit, fit_contact
from rehab_hil.analysis.torque_decomposition import compare, decompose
from rehab_hil.loading import load_config
from rehab_hil.models.finger_chain import COUPLING, chain_param_vector
from rehab_hil.models.hill_muscle import paper_literal_force_n, passive_length_factor
from rehab_hil.models.system import CompiledSystem, Diagram, SimulationResult
from rehab_hil.plants import sma_exoskeleton as sx

__all__ = [
    "PAPER",
    "bending",
    "compile_plant",
    "muscle_figures",
    "pwm_sweep",
    "regression_on_run",
    "report",
    "shrinkage_comparison",
]

# Seed 000, sec VI and abstract.
PAPER = {"max_mcp_deg": 37.5, "max_pip_deg": 42.0, "max_dip_deg": 29.5, "bend_time_s": 5.0,
         "transformation_sim_s": 0.96, "transformation_actual_s": 1.12, "le_force_n": 0.1082,
         "error_without_nmm": (0.0, 19.57), "error_with_nmm": (-0.74, 10.89), "accuracy_gain_pct": 7.05,
         "k_n_per_mm": 0.9815122, "c_n_s_per_mm": -0.3732791, "vif": 1.05}

_SIGNALS = [*sx.OUTPUTS, "theta_mcp_rad", "theta_pip_rad", "theta_dip_rad", "martensite_fraction",
            "passive_tension_n", "muscle_force_n", "contact_displacement_m", "contact_velocity_m_s", "exo_offset_rad"]


def compile_plant(cfg: sx.SMAExoskeletonConfig) -> CompiledSystem:
    diagram = Diagram(sx.build(cfg), inputs=("pwm_duty", "supply_voltage_v"), sums=sx.ports(cfg).sums)
    return diagram.compile(cfg.simulation.step_s, cfg.simulation.substeps)


def _run(cfg: sx.SMAExoskeletonConfig, system: CompiledSystem, duty: np.ndarray,
         params: np.ndarray | None = None) -> SimulationResult:
    return system.simulate(len(duty), {"pwm_duty": duty, "supply_voltage_v": cfg.drive.supply_voltage_v},
                           outputs=_SIGNALS, params=params)


def bending(cfg: sx.SMAExoskeletonConfig, system: CompiledSystem,
            params: np.ndarray | None = None) -> tuple[SimulationResult, dict[str, float]]:
    """The pwm-step scenario (32 V, duty 1 for 5 s, then cooling) and its metrics."""
    sc = sx.pwm_step_scenario(cfg)
    res = _run(cfg, system, np.asarray(sc.inputs["pwm_duty"]), params)
    return res, sx.bend_metrics(res)


def pwm_sweep(cfg: sx.SMAExoskeletonConfig, system: CompiledSystem) -> dict[float, float]:
    """Fig. 10: MCP angle [deg] at thermal equilibrium for each duty, each run from cold."""
    sc = cfg.scenarios.pwm_sweep
    n = round(sc.hold_s / cfg.simulation.step_s)
    return {d: float(_run(cfg, system, np.full(n, d))["theta_mcp_deg"][-1]) for d in sc.duty_levels}


def shrinkage_comparison(cfg: sx.SMAExoskeletonConfig, res: SimulationResult,
                         t_end_s: float = 5.0) -> dict[str, Any]:
    """Eq 29 decomposition on the run, projected on the coupled coordinate (s^T tau), against
    the constitutive (Tanaka) torque s.r F_SMA1, over the heating phase."""
    k = res.t <= t_end_s
    q = np.column_stack([res["theta_mcp_rad"], res["theta_pip_rad"], res["theta_dip_rad"]])[k]
    m = cfg.muscle
    dec = decompose(res.t[k], q, res["contact_force_n"][k], res["passive_tension_n"][k], res["muscle_force_n"][k],
                    chain_param_vector(sx.chain_params(cfg)),
                    np.array([cfg.tendon.mcp_radius_m, cfg.tendon.pip_radius_m, cfg.tendon.dip_radius_m]),
                    np.array([m.mcp_moment_arm_m, m.pip_moment_arm_m, m.dip_moment_arm_m]))
    s = np.array(COUPLING)
    simulated = sx.tendon_lever_m(cfg) * res["sma_tension_n"][k]
    return {"without_contact": compare(dec.sma_without_contact @ s, simulated),
            "with_contact": compare(dec.sma_with_contact @ s, simulated),
            "peak_simulated_nmm": float(simulated.max() * 1e3)}


def regression_on_run(res: SimulationResult, n: int = 32, t_start_s: float = 0.2, t_end_s: float = 1.0,
                      noise: float = 0.03, seed: int = 0, signed: bool = False) -> ContactFit:
    """Table 4 / eq 30 on ``n`` samples of the model's contact data during the bend, with the
    Flexiforce's +-3 % (sec III.A) as multiplicative noise on the force.

    ``signed=False`` regresses on |q_ces| and |q'_ces| as eq 18 writes them; ``signed=True`` on
    the pad's signed deformation and its rate, the Kelvin-Voigt law the model integrates."""
    idx = np.linspace(np.searchsorted(res.t, t_start_s), np.searchsorted(res.t, t_end_s) - 1, n).astype(int)
    rng = np.random.default_rng(seed)
    f = res["contact_force_n"][idx] * (1.0 + noise * rng.uniform(-1.0, 1.0, n))
    d = res["contact_displacement_m"]
    if signed:
        d = d * np.sign(res["exo_offset_rad"])
        v = np.gradient(d, res.t)
    else:
        v = res["contact_velocity_m_s"]
    return fit_contact(f, d[idx] * 1e3, v[idx] * 1e3)


def muscle_figures(cfg: sx.SMAExoskeletonConfig) -> dict[str, float]:
    """LE passive force at the paper's maximum bend (37.5, 42, 29.5 deg), young and old, and eq 3 literal."""
    m = cfg.muscle
    q = np.radians([PAPER["max_mcp_deg"], PAPER["max_pip_deg"], PAPER["max_dip_deg"]])
    stretch = m.mcp_moment_arm_m * q[0] + m.pip_moment_arm_m * q[1] + m.dip_moment_arm_m * q[2]
    ln = m.rest_length_ratio + stretch / m.optimal_fibre_length_m
    out = {f"le_force_{g}_n": m.max_isometric_force_n * passive_length_factor(ln, s.k_pe, s.e_o)
           for g, s in (("young", m.young), ("old", m.old))}
    out["le_force_literal_eq3_n"] = paper_literal_force_n(m.max_isometric_force_n, m.tendon_slack_length_m,
                                                          m.optimal_fibre_length_m, m.young.k_pe, m.young.e_o)
    out["normalised_length"] = ln
    return out


def report(cfg: sx.SMAExoskeletonConfig) -> dict[str, Any]:
    system = compile_plant(cfg)
    res, bend = bending(cfg, system)
    g_idx = system.diagram.param_index("finger.gravity_y_m_s2")
    p_grav = system.params.copy()
    p_grav[g_idx] = -9.81  # flexion against gravity (finger horizontal, palm up)
    res_g, bend_g = bending(cfg, system, p_grav)
    fit = regression_on_run(res)
    return {
        "bending": bend, "bending_against_gravity": bend_g, "pwm_sweep_mcp_deg": pwm_sweep(cfg, system),
        "shrinkage": shrinkage_comparison(cfg, res), "shrinkage_against_gravity": shrinkage_comparison(cfg, res_g),
        "regression": fit.__dict__, "regression_table": fit.table(),
        "regression_signed": regression_on_run(res, signed=True).__dict__,
        "regression_against_gravity": regression_on_run(res_g).__dict__, "muscle": muscle_figures(cfg),
        "paper": PAPER,
    }


def main(argv: list[str] | None = None) -> int:
    """``python -m rehab_hil.analysis.sma_experiments [CONFIG] [OUT.json]``: every model-vs-paper figure."""
    import argparse

    from rehab_hil.config import ConfigError

    ap = argparse.ArgumentParser(prog="python -m rehab_hil.analysis.sma_experiments",
                                 description="the SMA exoskeleton model against every figure of seed 000: prints the "
                                             "regression table and the figures as JSON")
    ap.add_argument("config", nargs="?", default="configs/sma_exoskeleton.toml", help="the SMA exoskeleton config")
    ap.add_argument("out", nargs="?", type=Path, default=None, help="also write the JSON to this file")
    ap.add_argument("--html", type=Path, default=None, metavar="FILE",
                    help="also draw the figures: the 32 V bend and the PWM staircase, one HTML file")
    args = ap.parse_args(argv)
    try:
        cfg = load_config(args.config)
    except ConfigError as e:
        print(f"{ap.prog}: error: {e}", file=sys.stderr)
        return 2
    if args.out is not None and args.out.is_dir():
        print(f"{ap.prog}: error: {args.out} is a directory; give the JSON file to write", file=sys.stderr)
        return 2
    out = report(cfg)
    print(out.pop("regression_table"))
    print(json.dumps(out, indent=1, default=str))
    if args.out is not None:
        try:
            args.out.write_text(json.dumps(out, indent=1, default=str))
        except OSError as e:
            print(f"{ap.prog}: error: {args.out}: cannot write: {e.strerror}", file=sys.stderr)
            return 2
    if args.html is not None:
        from rehab_hil.report.sma_figures import sma_figures_page

        system = compile_plant(cfg)
        res, _ = bending(cfg, system)
        try:
            sma_figures_page(res, out["pwm_sweep_mcp_deg"], out, PAPER).write(args.html)
        except OSError as e:
            print(f"{ap.prog}: error: --html {args.html}: cannot write: {e.strerror}", file=sys.stderr)
            return 2
        print(f"wrote {args.html}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
