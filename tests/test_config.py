"""Config loading: every kind of error names the file and the dotted key."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from rehab_hil.config import ConfigError
from rehab_hil.loading import load_config

BASE = (Path(__file__).resolve().parents[1] / "configs" / "finger_extensor.toml").read_text()


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


def edit(old: str, new: str) -> str:
    assert re.search(old, BASE, flags=re.M), old
    return re.sub(old, new, BASE, count=1, flags=re.M)


def test_every_error_of_a_config_is_named_on_its_one_line(tmp_path):
    text = edit(r"^radius_m = 0.055.*$", "radius_m = -1.0")
    text = re.sub(r"^gear_ratio = 32.5.*$", 'gear_ratio = "x"', text, count=1, flags=re.M)
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, text))
    msg = str(e.value)
    assert "\n" not in msg and "more errors" not in msg
    assert "iris.radius_m: input should be greater than 0" in msg and "motor.gear_ratio: wrong type" in msg


def test_shipped_finger_extensor_config_loads():
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "finger_extensor.toml")
    assert cfg.iris.radius_m == pytest.approx(0.055)
    assert cfg.motor.kt_nm_per_a == pytest.approx(0.791)


@pytest.mark.parametrize(
    ("old", "new", "key", "fragment"),
    [
        (r"^radius_m = 0.055.*$", "radius_m = 0.055\nradius_in = 2.0", "iris.radius_in", "unknown key"),
        (r"^radius_m = 0.055.*$", "", "iris.radius_m", "missing key"),
        (r"^gear_ratio = 32.5.*$", 'gear_ratio = "32.5"', "motor.gear_ratio", "wrong type"),
        (r"^gear_ratio = 32.5.*$", "gear_ratio = nan", "motor.gear_ratio", "finite"),
        (r"^gear_ratio = 32.5.*$", "gear_ratio = inf", "motor.gear_ratio", "finite"),
        (r"^radius_m = 0.055.*$", "radius_m = -0.055", "iris.radius_m", "greater than 0"),
        (r"^substeps = 1 .*$", "substeps = 1.5", "simulation.substeps", "wrong type"),
        (r"^max_angle_deg = 130.0", "max_angle_deg = -10.0", "rig.limits", "min_angle_deg must be below"),
    ],
)
def test_each_config_error_names_file_and_key(tmp_path, old, new, key, fragment):
    path = write(tmp_path, edit(old, new))
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    msg = str(exc.value)
    assert str(path) in msg
    assert exc.value.key == key
    assert fragment in msg


def test_missing_and_unknown_plant_are_named(tmp_path):
    with pytest.raises(ConfigError, match="plant: missing key"):
        load_config(write(tmp_path, BASE.replace('plant = "finger_extensor"', "")))
    with pytest.raises(ConfigError, match="unknown plant 'robot_arm'"):
        load_config(write(tmp_path, BASE.replace('"finger_extensor"', '"robot_arm"')))


def test_malformed_toml_and_missing_file_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "plant = \n"))
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.toml")


def test_a_command_can_demand_a_plant(tmp_path):
    path = write(tmp_path, BASE)
    with pytest.raises(ConfigError, match="needs a 'tcp_finger' config"):
        load_config(path, expect="tcp_finger")


def test_an_unreachable_temperature_limit_is_refused_naming_the_key(tmp_path):
    # Finger Extensor: the estimate levels off at 23 + 120 x max_duty 1.0 = 143 C
    p = write(tmp_path, edit(r"^max_temperature_c = 90.0.*$", "max_temperature_c = 150.0"))
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert e.value.key == "rig.limits.max_temperature_c"
    assert "143.0 C" in str(e.value) and "unreachable" in str(e.value) and str(p) in str(e.value)
    load_config(write(tmp_path, edit(r"^max_temperature_c = 90.0.*$", "max_temperature_c = 142.0")))


@pytest.mark.parametrize(("old", "new", "key"), [
    (r"^normally_closed = true.*$", 'normally_closed = "yes"', "rig.estop.normally_closed"),
    (r"^enabled = true$", "", "rig.estop.enabled"),
    (r"^force_debounce_ms = 3 .*$", "force_debounce_ms = 0", "rig.limits.force_debounce_ms"),
    (r"^to_host_flush_bytes = 96 .*$", "to_host_flush_bytes = 0", "rig.link.to_host_flush_bytes"),
    (r"^jitter_ms = 0.0 .*$", "jitter_s = 0.0", "rig.link.jitter_s"),
])
def test_estop_debounce_and_link_keys_are_validated(tmp_path, old, new, key):
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, edit(old, new)))
    assert e.value.key == key


# --- changes during a session (issue 23 item 5): [[effects]] start_s / ramp_s, [[changes]] ---------------------


@pytest.mark.parametrize(
    ("tables", "key", "fragment"),
    [
        ('[[changes]]\nkey = "motor.supply_vv"\nscale = 0.9', "changes.0.key",
         "unknown key 'motor.supply_vv' (did you mean 'motor.supply_v'?)"),
        ('[[changes]]\nkey = "motor.supply_v"\nscale = 0.9\nvalue = 20.0', "changes.0",
         "exactly one of scale (a factor) or value"),
        ('[[changes]]\nkey = "motor.supply_v"', "changes.0", "exactly one of scale (a factor) or value"),
        ('[[changes]]\nkey = "motor.supply_v"\nscale = -1.0', "changes.0.scale",
         "motor.supply_v = -24 is refused: input should be greater than 0"),
        ('[[changes]]\nkey = "motor.supply_v"\nvalue = 90.0', "changes.0.value", "motor.supply_v = 90 is refused"),
        ('[[changes]]\nkey = "motor.supply_v"\nscale = 0.9\nstart_s = -1.0', "changes.0.start_s",
         "greater than or equal to 0"),
        ('[[changes]]\nkey = "motor.supply_v"\nscale = 0.9\nramp_s = -0.5', "changes.0.ramp_s",
         "greater than or equal to 0"),
        ('[[changes]]\nkey = "motor.supply_v"\nscale = "x"', "changes.0.scale", "wrong type"),
        ('[[changes]]\nkey = "encoder.counts_per_rev"\nscale = 2.0', "changes.0.key", "not a real number"),
        ('[[changes]]\nkey = "rig.limits.max_duty"\nscale = 0.5', "changes.0.key", "shared table (rig)"),
        ('[[changes]]\nkey = "scenarios.step.target_deg"\nscale = 2.0', "changes.0.key", "changes nothing"),
        ('[[changes]]\nkey = "torque_sensor.counts_per_nm"\nscale = 2.0', "changes.0.key",
         "changes the plant's structure"),
        ('[[changes]]\nkey = "motor.supply_v"\nscale = 0.9\n[[changes]]\nkey = "motor.supply_v"\nvalue = 20.0',
         "changes.1.key", "moves scale motor_voltage_v, which changes.0 moves too"),
        ('[[effects]]\nname = "coulomb_friction"\nstart_s = -2.0', "effects.0.start_s", "greater than or equal"),
        ('[[effects]]\nname = "coulomb_friction"\nparams = { level_nm = 0.0 }\nstart_s = 1.0', "effects.0",
         "changes nothing"),
    ],
)
def test_each_bad_scheduled_change_is_one_line_naming_file_and_key(tmp_path, tables, key, fragment):
    path = write(tmp_path, BASE + "\n" + tables + "\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert err.value.key == key, msg
    assert msg.startswith(f"{path}: {key}: ") and fragment in msg and "\n" not in msg


def test_scheduled_changes_load_and_the_host_model_keeps_the_config_as_written(tmp_path):
    from rehab_hil.plants import compose, get_plant

    path = write(tmp_path, BASE + '\n[[effects]]\nname = "coulomb_friction"\nparams = { level_nm = 0.05 }\n'
                 'start_s = 30\nramp_s = 2.5\n\n[[changes]]\nkey = "motor.supply_v"\nscale = 0.92\nstart_s = 30.0\n')
    cfg = load_config(path)
    assert (cfg.effects[0].start_s, cfg.effects[0].ramp_s) == (30.0, 2.5)
    assert (cfg.changes[0].key, cfg.changes[0].scale, cfg.changes[0].value) == ("motor.supply_v", 0.92, None)
    plant = get_plant(cfg.plant)
    friction = next(p for p in compose(plant, cfg) if p.name == "effect_coulomb_friction")
    assert friction.param_values[0] == 0.05  # outside a simulated rig: the effect from the start, at its value
    binding = plant.device(cfg)  # the simulated rig: the plant at the session's start, and the schedule
    assert binding.duty_inputs["motor_voltage_v"].scale == 24.0
    start = next(p for p in binding.parts if p.name == "effect_coulomb_friction")
    assert start.param_values[0] == 0.0 and [i.key for i in binding.schedule.items] == ["effects.0", "changes.0.key"]


def test_the_host_limits_are_the_rig_limits_less_the_host_margins_with_at_least_one_period_of_heating():
    rig = load_config(Path(__file__).resolve().parents[1] / "configs" / "finger_extensor.toml").rig
    lim, m, host = rig.limits, rig.host, rig.host_limits()
    assert (host.min_angle_deg, host.max_angle_deg) == (lim.min_angle_deg + m.angle_margin_deg,
                                                        lim.max_angle_deg - m.angle_margin_deg)
    assert host.max_force_n == lim.max_force_n - m.force_margin_n
    assert host.max_heating_s == lim.max_heating_s - m.heating_margin_s
    no_time_left = rig.model_copy(update={"host": m.model_copy(update={"heating_margin_s": lim.max_heating_s})})
    assert no_time_left.host_limits().max_heating_s == 1.0 / rig.sample_rate_hz
    no_margins = rig.model_copy(update={"host": None}).host_limits()
    assert (no_margins.min_angle_deg, no_margins.max_heating_s) == (lim.min_angle_deg, lim.max_heating_s)
