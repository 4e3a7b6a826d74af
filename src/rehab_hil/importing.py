"""Lab logger files into the workflow: ``.mat`` (v4-v7 through scipy.io, v7.3 through h5py) and CSV,
through a small mapping.

A mapping (``[import]`` in a plant config, or a TOML file of its own with that table) says which
variable is which model signal, in what unit, with what scale and offset, and where time comes
from (a variable, or a sample time). ``read_mapped`` returns an interchange ``Recording``;
``rehab-hil import`` writes it as an interchange CSV, and the discrepancy workflow reads a ``.mat``
file directly when the plant config carries the mapping.

    [import]
    time = "t"                      # variable with the time stamps [s]; or sample_time_s
    [import.signals.position_m]
    variable = "qm"
    unit = "m"                      # unit of the variable; converted to the signal's (its name's suffix)
    [import.signals.drive_torque_nm]
    variable = "data(:,3)"          # one column of a matrix, as MATLAB indexes it (from 1; also data(2,:), s.field)

A file that is not what it claims (not a MAT file, cut short, a CSV with text below its header) is
one ``CsvError`` naming it and what is wrong.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from rehab_hil.config import Field, Section, model_validator
from rehab_hil.interchange import SIGNAL_NAME, CsvError, Recording

__all__ = ["ImportMapping", "SignalMapping", "load_mapping", "read_mapped", "unit_factor"]

# factor from a source unit to the SI unit a signal name ends in (its suffix)
_TO_SI: dict[str, tuple[str, float]] = {
    "m": ("m", 1.0), "mm": ("m", 1e-3), "um": ("m", 1e-6), "cm": ("m", 1e-2),
    "rad": ("rad", 1.0), "deg": ("deg", 1.0), "mrad": ("rad", 1e-3),
    "n": ("n", 1.0), "kn": ("n", 1e3), "mn": ("n", 1e-3), "nm": ("nm", 1.0),
    "v": ("v", 1.0), "mv": ("v", 1e-3), "a": ("a", 1.0), "ma": ("a", 1e-3),
    "s": ("s", 1.0), "ms": ("s", 1e-3), "c": ("c", 1.0), "counts": ("counts", 1.0), "w": ("w", 1.0),
    "n m": ("nm", 1.0), "n*m": ("nm", 1.0), "n.m": ("nm", 1.0), "mnm": ("nm", 1e-3), "mn m": ("nm", 1e-3),
    "rad/s": ("rad_s", 1.0), "rpm": ("rad_s", 2.0 * np.pi / 60.0), "deg/s": ("deg_s", 1.0),
    "m/s": ("m_s", 1.0), "mm/s": ("m_s", 1e-3),
}
_RATE_SUFFIXES = ("rad_s", "deg_s", "m_s")  # a velocity's name ends in two parts: velocity_rad_s


def unit_factor(source: str, signal: str) -> float:
    """Factor from ``source`` unit to the unit ``signal``'s name ends in (deg <-> rad converted)."""
    target = next((r for r in _RATE_SUFFIXES if signal.endswith("_" + r)), signal.rsplit("_", 1)[-1])
    s = " ".join(source.lower().split())
    if s not in _TO_SI:
        raise ValueError(f"unknown unit {source!r}; known: {sorted(_TO_SI)}")
    base, f = _TO_SI[s]
    if base == target:
        return f
    if (base, target) == ("rad", "deg"):
        return f * 180.0 / np.pi
    if (base, target) == ("deg", "rad"):
        return f * np.pi / 180.0
    if (base, target) == ("rad_s", "deg_s"):
        return f * 180.0 / np.pi
    if (base, target) == ("deg_s", "rad_s"):
        return f * np.pi / 180.0
    raise ValueError(f"unit {source!r} does not convert to {target!r} (signal {signal})")


class SignalMapping(Section):
    """One model signal from one variable: value = (raw x scale + offset) in ``unit``, then to SI."""

    variable: str = Field(min_length=1, description="variable name in the .mat file (a struct field as s.x, a matrix "
                          "column as MATLAB indexes it: data(:,3)), or CSV column header")
    unit: str = Field(min_length=1, description="unit of the variable after scale and offset (m, mm, deg, V, N ...)")
    scale: float = Field(1.0, description="multiplies the raw variable (counts -> unit, a sign flip)")
    offset: float = Field(0.0, description="added after the scale [unit]")
    optional: bool = Field(False, description="a file may lack the variable (the signal is then left out)")


class ImportMapping(Section):
    """``[import]``: time base and signals of a lab logger's files."""

    time: str | None = Field(None, min_length=1, description="variable with the time stamps (data(:,1): a column)")
    time_unit: str = Field("s", description="unit of the time variable (s, ms)")
    sample_time_s: float | None = Field(None, gt=0.0, le=10.0, description="sample time when no time variable [s]")
    signals: dict[str, SignalMapping] = Field(description="model signal -> variable")

    @model_validator(mode="after")
    def _check(self) -> ImportMapping:
        if (self.time is None) == (self.sample_time_s is None):
            raise ValueError("give exactly one of time (a variable) and sample_time_s")
        bad = [n for n in self.signals if not SIGNAL_NAME.match(n) or n == "time_s"]
        if bad:
            raise ValueError(f"signal names must look like <quantity>_<unit>: {bad}")
        for name, m in self.signals.items():
            try:
                unit_factor(m.unit, name)
            except ValueError as e:
                raise ValueError(f"signals.{name}.unit: {e}") from None
        return self


class _MappingFile(Section):
    import_: ImportMapping = Field(alias="import")


def load_mapping(path: str | Path) -> ImportMapping:
    """An ``[import]`` table from a TOML file (a mapping file, or a plant config that has one)."""
    from rehab_hil.config import ConfigError, load_toml, validate

    data = load_toml(path)
    if not isinstance(data.get("import"), dict):
        raise ConfigError(path, "import", "missing table (the mapping: time or sample_time_s, signals)")
    return validate(path, {"import": data["import"]}, _MappingFile).import_


def _flatten(prefix: str, value: object, out: dict[str, np.ndarray]) -> None:
    """A loadmat value into ``out``: arrays by name, a struct's fields as ``name.field`` (nested)."""
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else k, v, out)
    else:
        out[prefix] = np.asarray(value)


def _hdf5_variables(path: Path) -> dict[str, np.ndarray]:
    """A MATLAB v7.3 file (HDF5): its numeric datasets, transposed back to MATLAB's row x column order
    (MATLAB writes column-major, so h5py sees a 20000 x 7 matrix as 7 x 20000); groups (structs) as
    ``name.field``."""
    try:
        import h5py
    except ImportError:
        raise CsvError(path, None, "a MATLAB v7.3 (HDF5) file; reading it needs h5py (pip install h5py), or save "
                                   "it with -v7 in MATLAB") from None
    out: dict[str, np.ndarray] = {}

    def visit(name: str, obj: object) -> None:
        if isinstance(obj, h5py.Dataset) and not name.startswith("#") and obj.dtype.kind in "fiub":
            out[name.replace("/", ".")] = np.asarray(obj[()]).T

    try:
        with h5py.File(path, "r") as f:
            f.visititems(visit)
    except (OSError, ValueError, KeyError) as e:
        raise CsvError(path, None, f"cannot read as a MATLAB v7.3 (HDF5) file: {_one_line(e)}") from None
    return out


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _mat_variables(path: Path) -> dict[str, np.ndarray]:
    """The variables of a ``.mat`` file, v4-v7 (scipy.io) or v7.3 (HDF5, h5py); a file that is not a MAT
    file, or is cut short, is one error naming it."""
    import scipy.io

    try:
        with path.open("rb") as fh:
            head = fh.read(128)
    except OSError as e:
        raise CsvError(path, None, f"cannot open: {e.strerror}") from None
    if head[:19] == b"MATLAB 7.3 MAT-file" or head[:8] == b"\x89HDF\r\n\x1a\n":
        return _hdf5_variables(path)
    try:
        raw = scipy.io.loadmat(path, simplify_cells=True)
    except NotImplementedError:  # scipy's word for v7.3 without the text header
        return _hdf5_variables(path)
    except Exception as e:  # scipy raises ValueError, TypeError, zlib and struct errors on a foreign or cut file
        what = "not a MAT file" if not head.startswith(b"MATLAB") and head[:4] != b"\x00\x00\x00\x00" else \
            "a MAT file that cannot be read (cut short?)"
        raise CsvError(path, None, f"{what}: {_one_line(e)}") from None
    out: dict[str, np.ndarray] = {}
    for k, v in raw.items():
        if not k.startswith("__"):
            _flatten(k, v, out)
    return out


def _csv_variables(path: Path) -> dict[str, np.ndarray]:
    """A logger's CSV: a header row of column names, numbers below; comma, semicolon or tab separated."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise CsvError(path, None, f"cannot read: {_one_line(e)}") from None
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines:
        raise CsvError(path, None, "empty file")
    sep = max((",", ";", "\t"), key=lines[0].count)
    names = [h.strip().strip('"').strip("'") for h in lines[0].split(sep)]
    try:
        data = np.loadtxt(lines[1:], delimiter=sep, ndmin=2)
    except ValueError as e:
        raise CsvError(path, None, f"not a numeric CSV below its header: {_one_line(e)}") from None
    if data.shape[1] != len(names):
        raise CsvError(path, 2, f"{data.shape[1]} columns, the header names {len(names)}")
    return {n: data[:, i] for i, n in enumerate(names)}


def _variables(path: Path) -> dict[str, np.ndarray]:
    return _mat_variables(path) if path.suffix.lower() == ".mat" else _csv_variables(path)


# a variable as MATLAB names it: a name (struct fields after dots), optionally one column or row of a
# matrix by MATLAB's 1-based indexing: data(:,3), data(2,:), data(:,end)
_INDEXED = re.compile(r"^\s*(?P<name>[A-Za-z]\w*(?:\.[A-Za-z]\w*)*)\s*"
                      r"(?:\(\s*(?P<row>:|end|\d+)\s*,\s*(?P<col>:|end|\d+)\s*\))?\s*$")


def _select(var: dict[str, np.ndarray], expr: str, key: str, path: Path, source: str | Path) -> np.ndarray:
    """The vector ``expr`` names in ``var`` (``name``, ``name.field``, ``name(:,k)``, ``name(k,:)``)."""
    m = _INDEXED.match(expr)
    name = _base_name(expr)
    if name not in var:
        raise CsvError(path, None, f"no variable {name!r} (mapping {source}: {key}); the file has "
                                   f"{_describe(var)}")
    v = np.asarray(var[name])
    if v.dtype.kind not in "fiub":
        raise CsvError(path, None, f"variable {name!r} ({key}) is not numeric ({v.dtype})")
    if m and m["row"] is not None:
        if v.ndim != 2 or (m["row"] == ":") == (m["col"] == ":"):
            raise CsvError(path, None, f"{expr!r} ({key}): give one whole column, name(:,k), or one row, "
                                       f"name(k,:), of a matrix; {name!r} has shape {v.shape}")
        axis_len = v.shape[1] if m["row"] == ":" else v.shape[0]
        k_text = m["col"] if m["row"] == ":" else m["row"]
        k = axis_len if k_text == "end" else int(k_text)
        if not 1 <= k <= axis_len:
            raise CsvError(path, None, f"{expr!r} ({key}): index {k} is outside 1..{axis_len} "
                                       f"({name!r} has shape {v.shape}; MATLAB counts from 1)")
        v = v[:, k - 1] if m["row"] == ":" else v[k - 1, :]
    elif v.ndim > 2 or (v.ndim == 2 and min(v.shape) != 1):
        raise CsvError(path, None, f"variable {name!r} ({key}) has shape {v.shape}, not a vector: name one column "
                                   f"as MATLAB does, e.g. {name}(:,1)")
    return np.ravel(v).astype(float)


def _base_name(expr: str) -> str:
    """The variable an expression reads: ``data`` of ``data(:,3)``."""
    m = _INDEXED.match(expr)
    return m["name"] if m else expr


def _describe(var: dict[str, np.ndarray]) -> str:
    return ", ".join(f"{k} {'x'.join(map(str, np.shape(v))) or 'scalar'}" for k, v in sorted(var.items()))


def read_mapped(path: str | Path, mapping: ImportMapping, source: str | Path = "<mapping>") -> Recording:
    """Read ``path`` (.mat or CSV) through ``mapping``; errors name the file and the variable."""
    path = Path(path)
    if not path.is_file():
        raise CsvError(path, None, "no such file")
    var = _variables(path)

    def get(expr: str, key: str) -> np.ndarray:
        return _select(var, expr, key, path, source)

    signals = {}
    for sig, m in mapping.signals.items():
        if m.optional and _base_name(m.variable) not in var:
            continue
        signals[sig] = (get(m.variable, f"signals.{sig}.variable") * m.scale + m.offset) * unit_factor(m.unit, sig)
    n = {s: v.size for s, v in signals.items()}
    if mapping.time is not None:
        t = get(mapping.time, "time") * unit_factor(mapping.time_unit, "time_s")
    else:
        t = np.arange(max(n.values(), default=0)) * float(mapping.sample_time_s)  # type: ignore[arg-type]
    bad = {s: k for s, k in n.items() if k != t.size}
    if bad:
        raise CsvError(path, None, f"signals {bad} have a different length from the time base ({t.size})")
    for s, v in signals.items():
        if not np.all(np.isfinite(v)):
            raise CsvError(path, None, f"signal {s} ({mapping.signals[s].variable}) has non-finite values")
    if t.size < 2 or not np.all(np.diff(t) > 0):
        raise CsvError(path, None, "time is not strictly increasing")
    return Recording(t - t[0], signals)
