"""The patient's interaction estimate: a simulated rig whose contact is stiffer than the host's model
is estimated at its truth, and a doubling of that stiffness mid-session is followed within 5 s."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv
from rehab_hil.plants.base import get_plant, load_config
from rehab_hil.testing import CONFIGS, config_with_changes
from rehab_hil.twin.interaction import resolve_parameters
from rehab_hil.twin.model import TwinModel, TwinSetupError

K, C, ANGLE = "stiffness_nm_per_rad", "damping_nm_s_per_rad", "contact_angle_rad"
DOUBLE_S = 8.0


def _contact(k: float, c: float, **timing: float) -> dict:
    return {"name": "contact_spring_damper", "params": {K: k, C: c, ANGLE: 0.3}, **timing}


@pytest.mark.slow
def test_contact_stiffness_and_damping_are_estimated_and_a_doubling_is_followed(tmp_path, capsys):
    host = config_with_changes(CONFIGS / "finger_extensor.toml", tmp_path / "host.toml", effects=[_contact(0.8, 0.02)])
    # the patient: k = 1.0, c = 0.025; a second identical contact from DOUBLE_S doubles both
    device = config_with_changes(CONFIGS / "finger_extensor.toml", tmp_path / "device.toml",
                                 effects=[_contact(1.0, 0.025), _contact(1.0, 0.025, start_s=DOUBLE_S)])
    root = tmp_path / "runs"
    code = main(["run", "--config", str(host), "--sim-plant", str(device), "--device", "inprocess", "--duration",
                 "14", "--record", str(root), "--no-display", "--twin"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    (run,) = root.iterdir()
    tw = read_csv(run / "twin.csv")
    k = tw[f"patient_contact_spring_damper_{K}"]
    c = tw[f"patient_contact_spring_damper_{C}"]
    before = (tw.t > DOUBLE_S - 1.0) & (tw.t < DOUBLE_S)
    assert np.all(np.abs(k[before] / 1.0 - 1) < 0.10)
    assert np.all(np.abs(c[before] / 0.025 - 1) < 0.20)  # damping: less excited than k (bench/live_twin.py)
    followed = tw.t[np.flatnonzero((tw.t > DOUBLE_S) & (np.abs(k / 2.0 - 1) < 0.10))[0]]
    assert followed - DOUBLE_S <= 5.0
    assert np.all(np.abs(k[tw.t > DOUBLE_S + 5.0] / 2.0 - 1) < 0.10)
    meta = json.loads((run / "metadata.json").read_text())
    final = meta["patient"]["session"][f"contact_spring_damper.{K}"]
    assert abs(final["final"] / 2.0 - 1) < 0.10 and final["nominal"] == 0.8 and final["final_ci95"] > 0


def test_an_unknown_parameter_to_estimate_is_refused_naming_it() -> None:
    cfg = load_config(CONFIGS / "finger_extensor.toml")
    model = TwinModel(cfg, get_plant(cfg.plant).device(cfg), 0.001)
    with pytest.raises(TwinSetupError, match=r"estimate 'contact\.stifness': no such model parameter"):
        resolve_parameters(model, ["contact.stifness"])


def test_parameters_shared_by_two_parts_are_estimated_together() -> None:
    """The SMA's pad and its contact force carry the same k: one estimate moves both."""
    cfg = load_config(CONFIGS / "sma_exoskeleton.toml")
    model = TwinModel(cfg, get_plant(cfg.plant).device(cfg), 0.001)
    (ix,) = resolve_parameters(model, ["contact.stiffness_n_per_m"])
    names = {model.system.diagram.param_names[i] for i in ix}
    assert names == {"contact.stiffness_n_per_m", "pad.stiffness_n_per_m"}
