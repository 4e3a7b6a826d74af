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
