"""``rehab-hil simulate``: run a plant scenario offline, write the interchange CSV, print metrics."""

from __future__ import annotations

import argparse
import inspect
import time
from pathlib import Path

from rehab_hil.cli import UserError, config_file
from rehab_hil.interchange import write_csv
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant, run_scenario
from rehab_hil.plants.changes import scheduled
from rehab_hil.plants.sections import EffectSpec, PlantConfig


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("simulate", help="simulate a plant scenario and write the interchange CSV")
    p.add_argument("--config", required=True, type=config_file, help="plant config (configs/*.toml)")
    p.add_argument("--scenario", default=None, help="scenario name (plant-specific, e.g. step, cycle)")
    p.add_argument("--controller", default=None, metavar="NAME",
                   help="instead of a scenario: a session of this controller (rehab_hil.controllers; 'session' = "
                        "[rig.session] controller) composed with the plant model; --effect then changes the plant "
                        "only, as a rig with an effect the controller's model lacks")
    p.add_argument("--reference", choices=("session", "step"), default="session",
                   help="with --controller: the session's open-close cycles or a step to [rig.session] step_deg")
    p.add_argument("--duration", type=float, default=None, help="duration [s] (default: from the config)")
    p.add_argument("--out", type=Path, default=None, help="CSV to write")
    p.add_argument("--effect", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                   help="add a library effect (docs/discrepancy.md), e.g. coulomb_friction:level_nm=0.02; repeatable")
    p.add_argument("--power-w", type=float, default=None,
                   help="actuation power [W] for scenarios that take one (e.g. tcp_finger pulse, regular)")
    return p


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    spec = get_plant(cfg.plant)
    if scheduled(cfg):  # docs/models.md, changes during a session
        print(f"warning: {args.config} schedules changes mid-session (start_s / ramp_s, [[changes]]): simulate runs "
              "every effect from the start at its value and applies no [[changes]]; the schedule acts on a "
              "simulated rig (rehab-hil run --sim-plant)")
    if args.out is not None and args.out.is_dir():
        raise UserError(f"--out {args.out} is a directory; give the CSV file to write")
    if (args.scenario is None) == (args.controller is None):
        raise UserError("give --scenario NAME (an offline experiment) or --controller NAME (a session), not both")
    if args.controller is not None:
        return _controlled(args, cfg)
    if args.effect:
        cfg = _with_effects(cfg, args.effect)
    if args.scenario not in spec.scenarios:
        raise UserError(f"plant {spec.name!r} has no scenario {args.scenario!r}; choose from {sorted(spec.scenarios)}")
    if args.duration is not None and not (0 < args.duration <= 24 * 3600):
        raise UserError(f"--duration must be in (0, 86400] s, got {args.duration}")
    factory = spec.scenarios[args.scenario]
    extra = {}
    if args.power_w is not None:  # forwarded only when given, to scenarios that accept it
        if "power_w" not in inspect.signature(factory).parameters:
            raise UserError(f"scenario {args.scenario!r} of plant {spec.name!r} takes no --power-w")
        if not (0 <= args.power_w <= 1000):
            raise UserError(f"--power-w must be in [0, 1000] W, got {args.power_w}")
        extra["power_w"] = args.power_w
    scenario = factory(cfg, duration_s=args.duration, **extra)
    t0 = time.perf_counter()
    res = run_scenario(spec, cfg, scenario)
    wall = time.perf_counter() - t0
    sim_s = scenario.n_steps * spec.step(cfg)[0]
    print(f"{spec.name} / {scenario.name}: {scenario.n_steps} steps, {sim_s:.3f} s simulated in {wall:.3f} s wall")
    if scenario.metrics:
        for k, v in scenario.metrics(res).items():
            print(f"  {k:24s} {v:12.4f}")
    if args.out:
        write_csv(args.out, res.t, res.signals)
        print(f"wrote {args.out} ({len(res.t)} rows, columns: time_s, {', '.join(res.signals)})")
    return 0


def _controlled(args: argparse.Namespace, cfg: PlantConfig) -> int:
    """A session on the model: the controller built from the config, the plant with ``--effect``."""
    from rehab_hil.controllers import Reference, build_controller, closed_loop, offline_session

    plant_cfg = _with_effects(cfg, args.effect) if args.effect else None
    name = None if args.controller == "session" else args.controller
    ref = Reference.session(cfg) if args.reference == "session" else Reference.step(cfg)
    ctl = build_controller(cfg, name, ref, source=str(args.config))
    for note in ctl.notes:
        print(f"warning: {note}")
    t0 = time.perf_counter()
    if ref.kind == "session":
        cycles = 3 if args.duration is None else max(1, round((args.duration - ref.first_open_s) / ref.period_s))
        res, figures = offline_session(ctl, cycles, plant_cfg)
        print(f"{cfg.plant} / {ctl.name} session: {cycles} cycles after a {ref.first_open_s:g} s rest, "
              f"{res.t[-1]:.1f} s simulated in {time.perf_counter() - t0:.3f} s wall; per cycle (first left out):")
    else:
        from rehab_hil import metrics

        res = closed_loop(ctl, args.duration or ref.period_s, plant_cfg=plant_cfg)
        figures = metrics.step_metrics(res.t, res[ctl.ctx.angle], ref.start_deg, ref.open_deg)
        print(f"{cfg.plant} / {ctl.name} step to {ref.open_deg:g} deg:")
    for k, v in {**figures, **(ctl.plan.figures if ctl.plan else {})}.items():
        print(f"  {k:28s} {v:12.4f}")
    if args.out:
        write_csv(args.out, res.t, res.signals)
        print(f"wrote {args.out} ({len(res.t)} rows, columns: time_s, {', '.join(res.signals)})")
    return 0


def _with_effects(cfg: PlantConfig, options: list[str]) -> PlantConfig:
    """The config with the ``--effect`` options appended to its ``effects`` list."""
    from rehab_hil.effects import applicable, not_applicable_message, parse_effect_option

    added = []
    ports = get_plant(cfg.plant).ports(cfg)
    ok = {e.name for e in applicable(ports)}
    for text in options:
        try:
            name, params = parse_effect_option(text)
        except ValueError as e:
            raise UserError(str(e)) from None
        if name not in ok:
            raise UserError(f"--effect {text!r}: {not_applicable_message(name, cfg.plant, ports)}")
        added.append(EffectSpec(name=name, params=params))
    return cfg.model_copy(update={"effects": [*cfg.effects, *added]})
