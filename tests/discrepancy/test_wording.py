"""A report speaks of the plant it is about (issue 38 item 5): a drive's axis and amplifier with
general references, a finger rig with its seed papers; effect parameters in the axis's units."""

from __future__ import annotations

from rehab_hil.discrepancy.verdict import channel_unit
from rehab_hil.discrepancy.wording import effect_words, param_label, param_unit


def test_effect_parameters_carry_the_units_of_their_axis():
    assert param_unit("level_nm", linear=True) == "N" and param_unit("level_nm") == "N m"
    assert param_unit("damping_nm_s_per_rad", linear=True) == "N s/m"
    assert param_unit("damping_nm_s_per_rad") == "N m s/rad"
    assert param_unit("stiffness_nm_per_rad", linear=True) == "N/m"
    assert param_unit("width_rad", linear=True) == "m" and param_unit("delay_s") == "s"
    assert param_label("damping_nm_s_per_rad") == "damping" and param_label("level_nm") == "level"
    assert channel_unit("velocity_rad_s") == "rad/s" and channel_unit("angle_deg") == "deg"
    assert channel_unit("position_m") == "m" and channel_unit("drive_input_v") == "V"


def test_a_drive_is_described_in_its_own_words_and_a_finger_rig_in_its_seed_papers():
    text, source = effect_words("actuator_dead_zone", "motor_axis")
    assert "drive amplifier" in text and "PWM" not in text and "seed" not in source
    text, source = effect_words("contact_spring_damper", "motor_axis")
    assert "finger" not in text and "patient" not in text
    text, source = effect_words("coulomb_friction", "motor_axis")
    assert text == "extra Coulomb friction with stiction on the axis" and "Karnopp" in source
    text, source = effect_words("coulomb_friction", "finger_extensor")
    assert "joint axis" in text and source.startswith("seed 002")
