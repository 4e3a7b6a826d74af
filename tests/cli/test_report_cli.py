"""``rehab-hil run --record`` then ``rehab-hil report`` on its recording: a lockstep in-process
session (PID, 15 cycles a minute instead of the shipped 5, so a cycle fits in 8 s), then its report."""

from __future__ import annotations

import json
import re

from rehab_hil.cli import main
from rehab_hil.testing import CONFIGS


def test_report_of_a_recorded_session_is_written_in_its_run_dir(tmp_path, capsys):
    cfg = tmp_path / "sma.toml"
    text = (CONFIGS / "sma_exoskeleton.toml").read_text()
    cfg.write_text(re.sub(r"(\[rig\.session\][^\[]*?cycles_per_minute = )5\.0", r"\g<1>15.0", text, count=1))
    assert main(["run", "--config", str(cfg), "--device", "inprocess", "--controller", "pid", "--duration", "8",
                 "--record", str(tmp_path / "runs"), "--no-display"]) == 0
    (run_dir,) = (tmp_path / "runs").iterdir()
    summary = capsys.readouterr().out
    assert summary.count(str(run_dir.name)) == 1  # the run directory once, in full
    assert f"recorded: {run_dir.resolve()}/ (run.csv, run.mcap, metadata.json)" in summary
    assert main(["report", str(run_dir)]) == 0
    assert f"wrote {run_dir / 'report.html'}" in capsys.readouterr().out
    meta = json.loads((run_dir / "metadata.json").read_text())
    page = (run_dir / "report.html").read_text()
    assert meta["session_cycles"], "the session has a complete cycle"
    assert f"{meta['session_cycles'][0]['rom_deg']:.4g}" in page  # the per-cycle table
    assert meta["config_sha256"][:16] in page and meta["firmware"]["version"] in page
    assert page.count('class="plot"') == 3
