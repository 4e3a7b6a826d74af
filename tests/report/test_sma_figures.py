"""``python -m rehab_hil.analysis.sma_experiments``: --help, a missing config in one line, and
--html drawing the figures it prints."""

from __future__ import annotations

import pytest

from rehab_hil.analysis.sma_experiments import main
from rehab_hil.testing import CONFIGS


def test_help_and_a_missing_config_are_answered_without_a_traceback(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0 and "--html" in capsys.readouterr().out
    assert main([str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"python -m rehab_hil.analysis.sma_experiments: error: {tmp_path / 'nope.toml'}: file not found"


def test_html_draws_the_bend_and_the_pwm_staircase(tmp_path, capsys):
    out = tmp_path / "sma.html"
    assert main([str(CONFIGS / "sma_exoskeleton.toml"), "--html", str(out)]) == 0
    page = out.read_text()
    assert page.count('class="plot"') == 2 and "paper max MCP 37.5 deg" in page
    assert "PWM staircase" in page and "max_mcp_deg" in page
    assert f"wrote {out}" in capsys.readouterr().out
