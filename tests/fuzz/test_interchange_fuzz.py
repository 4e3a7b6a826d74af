"""Fuzzing the interchange CSV reader (``rehab_hil.interchange.read_csv``) with hypothesis.

Recordings are read back by the discrepancy workflow and by people: whatever a file holds (random
bytes, a valid recording with a damaged byte, a truncated tail from a killed writer), ``read_csv``
either returns a Recording or raises ``CsvError`` naming the file and a line, never anything else.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rehab_hil.interchange import CsvError, Recording, may_be_empty, read_csv, write_csv

FUZZ = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="csvfuzz-") as d:
        yield Path(d) / "recording.csv"


def read_or_csv_error(path: Path, data: bytes) -> Recording | CsvError:
    """Write ``data`` and read it; any exception other than CsvError fails the test."""
    path.write_bytes(data)
    n_lines = data.count(b"\n") + data.count(b"\r") + 1
    try:
        rec = read_csv(path)
    except CsvError as e:
        assert e.path == str(path)
        assert e.line is not None and 1 <= e.line <= n_lines + 1, e
        assert str(path) in str(e)
        return e
    assert rec.t.ndim == 1 and rec.t.size >= 1
    assert np.all(np.isfinite(rec.t)) and np.all(np.diff(rec.t) > 0)
    assert all(v.shape == rec.t.shape and (np.all(np.isfinite(v)) or may_be_empty(k)) for k, v in rec.signals.items())
    return rec


def valid_csv(n_rows: int, names: list[str], seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(1e-4, 1e-2, n_rows))
    signals = {n: rng.normal(0, 100, n_rows) for n in names}
    with tempfile.TemporaryDirectory() as d:
        return write_csv(Path(d) / "v.csv", t, signals).read_bytes()


names_st = st.lists(st.sampled_from(["angle_deg", "force_n", "pwm_duty", "current_a", "adc0_counts"]),
                    unique=True, max_size=4)


@FUZZ
@given(data=st.binary(max_size=600))
def test_arbitrary_bytes_give_a_recording_or_a_csv_error_with_a_line(scratch, data):
    read_or_csv_error(scratch, data)


@FUZZ
@given(text=st.text(alphabet=st.sampled_from(list("time_s,angle_deg\n\r\"0123456789.e-+ nainf\t")), max_size=300))
def test_csv_like_text_gives_a_recording_or_a_csv_error_with_a_line(scratch, text):
    read_or_csv_error(scratch, ("time_s,angle_deg\n" + text).encode())


@FUZZ
@given(n_rows=st.integers(1, 30), names=names_st, seed=st.integers(0, 2**32 - 1))
def test_written_recordings_read_back_exactly(scratch, n_rows, names, seed):
    data = valid_csv(n_rows, names, seed)
    rec = read_or_csv_error(scratch, data)
    assert isinstance(rec, Recording)
    assert rec.t.size == n_rows and sorted(rec.signals) == sorted(names)


@st.composite
def mutated_csvs(draw: st.DrawFn) -> bytes:
    data = bytearray(valid_csv(draw(st.integers(1, 20)), draw(names_st), draw(st.integers(0, 2**32 - 1))))
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "drop", "insert", "truncate", "dup_line", "swap_lines"]))
        if not data:
            break
        i = draw(st.integers(0, len(data) - 1))
        if kind == "flip":
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif kind == "drop":
            del data[i]
        elif kind == "insert":
            data.insert(i, draw(st.sampled_from(b",\n\r\"\x00\xff-e.9 ")))
        elif kind == "truncate":
            del data[i:]
        else:
            lines = bytes(data).split(b"\n")
            j = draw(st.integers(0, len(lines) - 1))
            k = draw(st.integers(0, len(lines) - 1))
            if kind == "dup_line":
                lines.insert(j, lines[k])
            else:
                lines[j], lines[k] = lines[k], lines[j]
            data = bytearray(b"\n".join(lines))
    return bytes(data)


@FUZZ
@given(data=mutated_csvs())
def test_damaged_recordings_give_a_recording_or_a_csv_error_with_a_line(scratch, data):
    read_or_csv_error(scratch, data)


@FUZZ
@given(n_rows=st.integers(2, 30), seed=st.integers(0, 2**32 - 1), cut=st.floats(0.0, 1.0))
def test_a_recording_cut_anywhere_keeps_every_complete_row_before_the_cut(scratch, n_rows, seed, cut):
    # what a killed writer leaves behind: a prefix of the file, possibly ending mid-row
    full = valid_csv(n_rows, ["angle_deg", "pwm_duty"], seed)
    prefix = full[: int(cut * len(full))]
    out = read_or_csv_error(scratch, prefix)
    complete_rows = max(0, prefix.count(b"\n") - 1)
    if isinstance(out, Recording):
        assert complete_rows <= out.t.size <= complete_rows + 1  # a cut row may still parse as numbers
        ref = read_csv_bytes(full)
        np.testing.assert_array_equal(out.t[:complete_rows], ref.t[:complete_rows])
    else:
        # only an empty prefix, a cut header, no data row or a cell cut to a non-number can fail
        assert complete_rows == 0 or out.line == complete_rows + 2, out


def read_csv_bytes(data: bytes) -> Recording:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "r.csv"
        p.write_bytes(data)
        return read_csv(p)


def test_a_missing_file_is_a_csv_error_naming_it(tmp_path):
    with pytest.raises(CsvError, match="cannot open"):
        read_csv(tmp_path / "absent.csv")


def test_non_finite_cells_are_refused_with_their_line(tmp_path):
    p = tmp_path / "nan.csv"
    p.write_text("time_s,angle_deg\n0,1\n0.1,nan\n")
    with pytest.raises(CsvError) as e:
        read_csv(p)
    assert e.value.line == 3
