"""Slow steps say what they do; quick ones say nothing (rehab_hil.progress)."""

from __future__ import annotations

import threading

import pytest

from rehab_hil import progress


@pytest.fixture
def lines():
    got: list[str] = []
    progress.set_sink(got.append)
    yield got
    progress.set_sink(None)


def test_a_quick_step_says_nothing(lines):
    with progress.announce("learning the plan", after_s=60.0):
        pass
    assert lines == []


def test_a_slow_step_names_itself_while_it_runs_and_its_time_at_the_end(lines):
    said = threading.Event()
    progress.set_sink(lambda line: (lines.append(line), said.set()))
    with progress.announce("learning the plan", after_s=0.0):
        assert said.wait(10.0)  # named while the step still runs
        assert lines == ["learning the plan ..."]
    assert len(lines) == 2 and lines[1].startswith("learning the plan: done in ") and lines[1].endswith(" s")


def test_without_a_sink_the_library_is_quiet(capsys):
    progress.set_sink(None)
    with progress.announce("compiling", after_s=0.0):
        pass
    assert capsys.readouterr() == ("", "")


def test_a_step_that_fails_still_ends_its_line(lines):
    said = threading.Event()
    progress.set_sink(lambda line: (lines.append(line), said.set()))
    with pytest.raises(KeyboardInterrupt), progress.announce("the pre-flight", after_s=0.0):
        said.wait(10.0)
        raise KeyboardInterrupt
    assert lines[-1].startswith("the pre-flight: done in ")
