"""Per-patient profiles: applied over the SMA exoskeleton config, tighten-only, errors name file and key,
and the tightened force limit reaches the firmware's CONFIGURE."""

from __future__ import annotations

from pathlib import Path

import pytest

from rehab_hil.config import ConfigError
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.profiles import apply_profile, load_profile, profile_summary
from rehab_hil.service.assembly import firmware_configure

ROOT = Path(__file__).resolve().parents[1]
SMA = ROOT / "configs" / "sma_exoskeleton.toml"
EXAMPLE = ROOT / "profiles" / "example.toml"


def write(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "p.toml"
    p.write_text('patient_id = "P-1"\n' + body)
    return p


def test_the_example_profile_overrides_session_and_tightens_limits() -> None:
    cfg = load_config(SMA)
    out = apply_profile(cfg, load_profile(EXAMPLE), SMA, EXAMPLE)
    assert out.rig.session.cycles_per_minute == 3.0 and out.rig.session.open_deg == 25.0
    assert (out.rig.limits.min_angle_deg, out.rig.limits.max_angle_deg, out.rig.limits.max_force_n) == (-5, 40, 10)
    assert out.rig.limits.max_heating_s == cfg.rig.limits.max_heating_s  # untouched keys stay
    binding = get_plant(cfg.plant).device(cfg)
    assert firmware_configure(out, binding).force_limit_counts < firmware_configure(cfg, binding).force_limit_counts
    assert profile_summary(load_profile(EXAMPLE), EXAMPLE)["limits.max_force_n"] == 10.0


@pytest.mark.parametrize(("body", "key", "words"), [
    ("[limits]\nmax_force_n = 25.0\n", "limits.max_force_n", "25 N widens the rig's rig.limits.max_force_n = 20 N"),
    ("[limits]\nmax_angle_deg = 95.0\n", "limits.max_angle_deg", "widens"),
    ("[limits]\nmin_angle_deg = -20.0\n", "limits.min_angle_deg", "widens"),
    ("[limits]\nmin_angle_deg = 30.0\nmax_angle_deg = 20.0\n", "limits", "must be below"),
    ("[session]\namplitude_deg = 50.0\n[limits]\nmax_angle_deg = 40.0\n", "session.amplitude_deg",
     "outside the range of motion"),
    ("[session]\ncycles_per_minute = -1.0\n", "session.cycles_per_minute", "greater than 0"),
    ("[session]\npace = 3.0\n", "session.pace", "unknown key"),
])
def test_bad_profiles_name_the_file_and_key(tmp_path: Path, body: str, key: str, words: str) -> None:
    path = write(tmp_path, body)
    with pytest.raises(ConfigError) as e:
        apply_profile(load_config(SMA), load_profile(path), SMA, path)
    assert str(e.value).startswith(f"{path}: {key}: ") and words in str(e.value)


def test_run_with_a_widening_profile_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rehab_hil.cli import main

    path = write(tmp_path, "[limits]\nmax_force_n = 99.0\n")
    assert main(["run", "--config", str(SMA), "--device", "inprocess", "--profile", str(path), "--duration", "1",
                 "--no-display"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "limits.max_force_n: 99 N widens" in err[0]
