"""The therapist's measures in the report: a per-cycle table, and across sessions a change flagged
only beyond the smallest real difference."""

from __future__ import annotations

from rehab_hil.report.therapy import SRD_SHARE, changes, cycle_table, session_table


def test_a_change_is_flagged_only_beyond_the_smallest_real_difference():
    before = {"success": 0.6, "assistance_ratio": 1.0, "sparc": -1.6}
    small = {"success": 0.6 * (1 + SRD_SHARE * 0.9), "assistance_ratio": 0.8, "sparc": -1.7}
    assert changes(before, small) == []
    big = {"success": 0.9, "assistance_ratio": 0.5, "sparc": -1.7}
    assert changes(before, big) == ["success rate up", "assistance ratio down"]


def test_the_tables_show_the_measures_a_session_has_and_nothing_for_an_older_run():
    cycles = [{"index": 0, "success": 1.0, "assistance_ratio": 0.8, "sparc": -1.5,
               "patient_torque_open_nm": float("nan")}]
    html = cycle_table(cycles)
    assert html is not None and "assistance ratio" in html and "SPARC" in html
    assert "patient torque" not in html  # no torque sensor on this rig: the column is left out
    assert cycle_table([{"index": 0, "rmse_deg": 1.0}]) is None
    across = session_table(["a", "b"], [{"success": 0.5, "assistance_ratio": 1.0},
                                        {"success": 0.9, "assistance_ratio": 1.0}])
    assert across is not None and "success rate up" in across


def test_the_patient_torque_shows_the_sensor_and_the_model_side_by_side_with_their_intervals():
    cycles = [{"index": 0, "success": 1.0, "patient_torque_open_nm": -0.2136, "patient_torque_open_ci_nm": 0.005,
               "patient_torque_open_model_nm": -0.2231, "patient_torque_open_model_ci_nm": 0.0069,
               "patient_torque_model_source": "model + encoder"}]
    html = cycle_table(cycles)
    assert html is not None
    assert "patient torque, opening, torque sensor [N m]" in html and "-0.214 ± 0.005" in html
    assert "patient torque, opening, model + encoder [N m]" in html and "-0.223 ± 0.0069" in html
    sma = [{"index": 0, "success": 1.0, "patient_torque_open_nm": float("nan"),
            "patient_torque_close_model_nm": 0.05, "patient_torque_close_model_ci_nm": 0.01,
            "patient_torque_model_source": "model + encoder + contact_force_n"}]
    html = cycle_table(sma)
    assert html is not None and "torque sensor" not in html
    assert "patient torque, closing, model + encoder + contact_force_n [N m]" in html
