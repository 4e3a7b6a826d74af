"""Plant registration: a config's [[effects]] reach both the offline build and the rig binding."""

from __future__ import annotations

from pathlib import Path

import pytest

from rehab_hil.plants import compose, get_plant, load_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
EFFECT = '\n[[effects]]\nname = "coulomb_friction"\nparams = { level_nm = 0.03 }\n'


@pytest.mark.parametrize("plant", ["finger_extensor"])
def test_config_effects_reach_the_build_and_the_simulated_rig(tmp_path, plant):
    path = tmp_path / f"{plant}.toml"
    path.write_text((CONFIGS / f"{plant}.toml").read_text() + EFFECT)
    cfg = load_config(path)
    spec = get_plant(plant)
    plain = {p.name for p in spec.device(load_config(CONFIGS / f"{plant}.toml")).parts}
    built = {p.name for p in compose(spec, cfg)}
    rig = {p.name for p in spec.device(cfg).parts}
    added = built - plain
    assert added, "the effect was not attached to the build"
    assert added <= rig, "the simulated rig's binding lost the config's effects"
