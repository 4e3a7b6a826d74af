"""Lab logger files into the workflow: ``.mat`` (scipy.io) and CSV, through a small mapping.

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
"""

from __future__ import annotations

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
}


def unit_factor(source: str, signal: str) -> float:
    """Factor from ``source`` unit to the unit ``signal``'s name ends in (deg <-> rad converted)."""
    target = signal.rsplit("_", 1)[-1]
    s = source.lower()
    if s not in _TO_SI:
        raise ValueError(f"unknown unit {source!r}; known: {sorted(_TO_SI)}")
    base, f = _TO_SI[s]
    if base == target:
        return f
    if (base, target) == ("rad", "deg"):
        return f * 180.0 / np.pi
    if (base, target) == ("deg", "rad"):
        return f * np.pi / 180.0
    raise ValueError(f"unit {source!r} does not convert to {target!r} (signal {signal})")


class SignalMapping(Section):
    """One model signal from one variable: value = (raw x scale + offset) in ``unit``, then to SI."""

    variable: str = Field(min_length=1, description="variable name in the .mat file, or CSV column header")
    unit: str = Field(min_length=1, description="unit of the variable after scale and offset (m, mm, deg, V, N ...)")
    scale: float = Field(1.0, description="multiplies the raw variable (counts -> unit, a sign flip)")
    offset: float = Field(0.0, description="added after the scale [unit]")
    optional: bool = Field(False, description="a file may lack the variable (the signal is then left out)")


class ImportMapping(Section):
    """``[import]``: time base and signals of a lab logger's files."""

    time: str | None = Field(None, min_length=1, description="variable with the time stamps")
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


def _variables(path: Path) -> dict[str, np.ndarray]:
    if path.suffix.lower() == ".mat":
        import scipy.io

        try:
            raw = scipy.io.loadmat(path)
        except (OSError, ValueError) as e:
            raise CsvError(path, None, f"cannot read as a MATLAB file: {e}") from None
        return {k: np.asarray(v) for k, v in raw.items() if not k.startswith("__")}
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise CsvError(path, None, f"cannot read: {e}") from None
    lines = text.splitlines()
    if not lines:
        raise CsvError(path, None, "empty file")
    names = [h.strip() for h in lines[0].split(",")]
    try:
        data = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    except ValueError as e:
        raise CsvError(path, None, f"not a numeric CSV below its header: {e}") from None
    if data.shape[1] != len(names):
        raise CsvError(path, 2, f"{data.shape[1]} columns, the header names {len(names)}")
    return {n: data[:, i] for i, n in enumerate(names)}


def read_mapped(path: str | Path, mapping: ImportMapping, source: str | Path = "<mapping>") -> Recording:
    """Read ``path`` (.mat or CSV) through ``mapping``; errors name the file and the variable."""
    path = Path(path)
    if not path.is_file():
        raise CsvError(path, None, "no such file")
    var = _variables(path)

    def get(name: str, key: str) -> np.ndarray:
        if name not in var:
            raise CsvError(path, None, f"no variable {name!r} (mapping {source}: {key}); the file has {sorted(var)}")
        v = np.asarray(var[name])
        if v.ndim > 2 or (v.ndim == 2 and min(v.shape) != 1):
            raise CsvError(path, None, f"variable {name!r} ({key}) has shape {v.shape}, not a vector")
        return np.ravel(v).astype(float)

    signals = {}
    for sig, m in mapping.signals.items():
        if m.optional and m.variable not in var:
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
