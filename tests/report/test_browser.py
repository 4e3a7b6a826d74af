"""The report in a real headless Chromium (Debian's, scripts/install_browser.sh): it loads with no
console error and every plot is drawn; a broken page is caught (the check can fail)."""

from __future__ import annotations

import pytest

from rehab_hil.report.browser import check_pages, find_chromium
from rehab_hil.report.build import report_page
from rehab_hil.report.runs import load_run

pytestmark = pytest.mark.skipif(find_chromium() is None,
                                reason="no chromium: scripts/install_browser.sh installs it (make test does, as root)")


def test_a_progress_report_draws_every_plot_with_no_console_error(tmp_path, make_run):
    runs = [load_run(make_run(tmp_path, f"2026110{d}T0900Z-a", events=[{"t_s": 5.0, "reason": "force_limit",
                                                                          "detail": "x"}])) for d in (1, 2)]
    page = report_page(runs)  # progress, then the newest session in full: every kind of figure
    both = page.write(tmp_path / "both.html")
    broken = tmp_path / "broken.html"  # plotly.js cut short: the page must say it drew nothing
    text = both.read_text()
    i = text.index('id="plotly-gz">') + len('id="plotly-gz">')
    broken.write_text(text[:i] + text[i:i + 1000] + text[text.index("</script>", i):])
    # a tripped torque-sensor run: empty reference cells after the stop, a flat sensor, a band per cycle
    tripped = report_page([load_run(make_run(tmp_path, "20261103T0900Z-fe", plant="finger_extensor",
                                             sensor=("patient_torque_nm", "torque", "nm"), flat_sensor=True,
                                             events=[{"t_s": 11.02, "reason": "watchdog", "detail": "x"}],
                                             requested_s=30.0))])
    gaps = tripped.write(tmp_path / "tripped.html")
    c_both, c_broken, c_gaps = check_pages([both, broken, gaps])
    assert c_gaps.state == "drawn" and c_gaps.errors == [] and c_gaps.drawn == tripped.n_figures == 3
    assert c_both.state == "drawn" and c_both.errors == [] and c_both.page_error == ""
    assert c_both.plots == page.n_figures == 4 and c_both.drawn == 4
    assert c_both.traces >= 4 + 4 + 3 + 4  # progress 4, session 4 rows, cycles 3 + reference, per-cycle 4
    assert c_broken.state == "failed" and c_broken.errors and "could not be drawn" in c_broken.page_error
    assert c_broken.drawn == 0
