"""Output written whole or not at all (rehab_hil.outputs): Ctrl-C or an error part-way leaves the
file or the report folder as it was."""

from __future__ import annotations

import pytest

from rehab_hil.outputs import replacing, staged_folder


def test_a_file_is_replaced_only_when_the_writing_finished(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text("old\n")
    with pytest.raises(KeyboardInterrupt), replacing(path) as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert path.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]
    with replacing(path) as tmp:
        tmp.write_text("new\n")
    assert path.read_text() == "new\n" and sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]


def test_an_interrupted_report_leaves_no_folder_with_one_plot(tmp_path):
    out = tmp_path / "report"
    with pytest.raises(KeyboardInterrupt), staged_folder(out) as tmp:
        (tmp / "fit.png").write_bytes(b"png")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []  # neither the report folder nor the staging folder


def test_a_finished_report_moves_in_beside_what_the_folder_held(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "report.md").write_text("old")
    with staged_folder(out) as tmp:
        (tmp / "report.md").write_text("new")
        (tmp / "fit.png").write_bytes(b"png")
    assert sorted(p.name for p in out.iterdir()) == ["fit.png", "notes.txt", "report.md"]
    assert (out / "report.md").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]
