"""Column names as a person reads them, with the unit: every plant's recorded signals."""

from __future__ import annotations

import pytest

from rehab_hil.report.names import label, unit


@pytest.mark.parametrize(("name", "text"), [
    ("contact_force_n", "contact force [N]"),
    ("patient_torque_nm", "patient torque [N m]"),
    ("applied_duty0_ratio", "applied duty, channel 0 [0-1]"),
    ("theta_mcp_deg", "MCP joint angle [deg]"),
    ("iris_angle_deg", "iris angle [deg]"),
    ("estimated_temperature_c", "estimated actuator temperature [°C]"),
    ("tcp_force_n", "TCP force [N]"),
    ("power_w", "power [W]"),
])
def test_a_column_reads_as_words_and_its_unit(name, text):
    assert label(name) == text


def test_a_twin_estimates_unit_comes_from_its_name():
    assert unit("contact_spring_damper.stiffness_nm_per_rad") == "N m/rad"
    assert unit("contact.stiffness_n_per_m") == "N/m"
    assert label("something") == "something" and unit("something") == ""  # no unit is invented
