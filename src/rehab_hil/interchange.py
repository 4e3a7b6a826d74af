"""The interchange CSV: ``time_s`` then one ``<quantity>_<unit>`` column per signal.

Written by ``simulate`` and by rig recordings, read by the discrepancy workflow. Readers accept
extra columns; malformed files raise ``CsvError`` with the line number. A reference column
(``<name>_reference_<unit>``, ``reference_<unit>``) may be empty where nothing was tracked (a
recording's rows before the first command and after the stop): read as NaN. Every other cell is
a finite number.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rehab_hil.outputs import replacing

__all__ = ["SIGNAL_NAME", "CsvError", "Recording", "may_be_empty", "read_csv", "write_csv"]

SIGNAL_NAME = re.compile(r"^[a-z][a-z0-9]*(_[a-z0-9]+)+$")
REFERENCE_NAME = re.compile(r"(^|_)reference_[a-z0-9]+$")


def may_be_empty(name: str) -> bool:
    """A reference column: empty (NaN) in the rows where no reference was tracked."""
    return REFERENCE_NAME.search(name) is not None


class CsvError(ValueError):
    """A malformed interchange CSV; the message names the file and the line."""

    def __init__(self, path: str | Path, line: int | None, message: str) -> None:
        self.path, self.line = str(path), line
        super().__init__(f"{path}:{line}: {message}" if line else f"{path}: {message}")


@dataclass
class Recording:
    """Time base and named columns of one interchange CSV."""

    t: np.ndarray
    signals: dict[str, np.ndarray]
    truncated: bool = False  # the file's last line was cut short and dropped
    rig: bool = False  # recorded on a rig: its ADC channels are clipped to the converter's range

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]

    def require(self, names: Sequence[str], path: str | Path = "<recording>") -> None:
        missing = [n for n in names if n not in self.signals]
        if missing:
            raise CsvError(path, 1, f"missing columns {missing}; the file has {sorted(self.signals)}")


def write_csv(path: str | Path, t: np.ndarray, signals: Mapping[str, np.ndarray]) -> Path:
    """Write ``time_s`` and the signals, with full float precision (``%.10g``); a reference's NaN
    as an empty cell."""
    path = Path(path)
    t = np.asarray(t, float)
    names = list(signals)
    bad = [n for n in names if not SIGNAL_NAME.match(n) or n == "time_s"]
    if bad:
        raise ValueError(f"column names must look like <quantity>_<unit>: {bad}")
    cols = [np.asarray(signals[n], float) for n in names]
    for n, c in zip(names, cols, strict=True):
        if c.shape != t.shape:
            raise ValueError(f"column {n!r} has {c.shape[0]} rows, time has {t.shape[0]}")
    path.parent.mkdir(parents=True, exist_ok=True)
    data = np.column_stack([t, *cols]) if cols else t[:, None]
    header = ",".join(["time_s", *names])
    gaps = [i + 1 for i, (n, c) in enumerate(zip(names, cols, strict=True)) if may_be_empty(n) and np.isnan(c).any()]
    with replacing(path) as tmp:  # a reader never sees half a file, nor does Ctrl-C leave one
        if not gaps:
            np.savetxt(tmp, data, delimiter=",", header=header, comments="", fmt="%.10g")
            return path
        fmt = ",".join(["%.10g"] * data.shape[1])
        with Path(tmp).open("w", encoding="utf-8") as fh:
            fh.write(header + "\n")
            for row in data:
                line = fmt % tuple(row)
                if np.isnan(row[gaps]).any():
                    line = ",".join("" if i in gaps and v != v else c
                                    for i, (c, v) in enumerate(zip(line.split(","), row, strict=True)))
                fh.write(line + "\n")
    return path


def read_csv(path: str | Path, drop_partial_tail: bool = False) -> Recording:
    """Read and check an interchange CSV (header, numeric cells, finite, strictly increasing time).

    ``drop_partial_tail``: a last line cut short (no newline at the end of the file, as a killed
    writer or a full disk leaves it) is dropped and ``Recording.truncated`` set, instead of an error."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise CsvError(path, None, f"cannot open: {e.strerror}") from None
    truncated = False
    if drop_partial_tail and raw and not raw.endswith(b"\n") and b"\n" in raw:
        cut = raw[:raw.rindex(b"\n") + 1]
        try:
            rec = _parse(path, raw)
        except CsvError:
            rec, truncated = _parse(path, cut), True
        rec.truncated = truncated
        return rec
    return _parse(path, raw)


def _parse(path: Path, raw: bytes) -> Recording:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise CsvError(path, 1, f"unreadable: not UTF-8 at byte {e.start}") from None
    with io.StringIO(text, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise CsvError(path, 1, "empty file: expected a header row starting with time_s") from None
        except (csv.Error, UnicodeDecodeError) as e:
            raise CsvError(path, 1, f"unreadable header: {e}") from None
        header = [h.strip() for h in header]
        if not header or header[0] != "time_s":
            raise CsvError(path, 1, f"first column must be time_s, got {header[:1]}")
        if len(set(header)) != len(header):
            raise CsvError(path, 1, "duplicate column names")
        for h in header[1:]:
            if not SIGNAL_NAME.match(h):
                raise CsvError(path, 1, f"column name {h!r} is not <quantity>_<unit>")
        rows: list[list[float]] = []
        try:
            for row in reader:
                line = reader.line_num
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise CsvError(path, line, f"expected {len(header)} cells, got {len(row)}")
                vals = []
                for name, cell in zip(header, row, strict=True):
                    if not cell.strip() and may_be_empty(name):
                        vals.append(math.nan)
                        continue
                    try:
                        v = float(cell)
                    except ValueError:
                        raise CsvError(path, line, f"column {name}: not a number: {cell!r}") from None
                    if not math.isfinite(v):
                        raise CsvError(path, line, f"column {name}: not finite: {cell!r}")
                    vals.append(v)
                if rows and vals[0] <= rows[-1][0]:
                    raise CsvError(path, line, f"time_s must increase strictly ({vals[0]} after {rows[-1][0]})")
                rows.append(vals)
        except (csv.Error, UnicodeDecodeError) as e:
            raise CsvError(path, reader.line_num, f"malformed CSV: {e}") from None
    if not rows:
        raise CsvError(path, 2, "no data rows")
    data = np.array(rows, dtype=float)
    return Recording(data[:, 0], {h: data[:, i] for i, h in enumerate(header) if i > 0})
