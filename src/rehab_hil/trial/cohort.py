"""A virtual cohort: ``profiles/sim/cohort.toml`` read, validated and sampled into patient profiles.

A cohort is a set of severity strata (e.g. Fugl-Meyer bands), each a share of the cohort. A stratum
is a patient profile (``patient/profile.py``) whose values may be distributions: a number is fixed,
an inline table draws it per patient (``{ dist = "normal", mean = .., sd = .. }``, ``"lognormal"``
with ``median`` and ``sigma_log``, ``"uniform"`` with ``low`` and ``high``, or ``"around"``: the
stratum's ``centre`` profile's value with a ``relative_sd``); ``min`` / ``max`` clip a draw, and so
does the parameter's own range in the profile schema. A trait table (``[fatigue]``, ``[spasticity]``
...) may carry ``prevalence``: the share of the stratum's patients who have it. ``[[correlations]]``
correlate two parameters (``between``, ``rho``) wherever both are drawn: a Gaussian copula, ``rho``
the correlation of the normal scores (of the logs, for a log-normal).

Every patient has its own random stream, ``SeedSequence(trial seed, spawn_key=(index,))``: patient 7
is the same patient in a trial of 10 or of 1000, whichever machine draws it. Errors name the file
and the key (``ConfigError``), one line.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from rehab_hil.config import ConfigError, load_toml, validate
from rehab_hil.patient.profile import PatientProfile, load_patient

__all__ = ["Cohort", "Param", "SampledPatient", "Stratum", "load_cohort", "profile_tables"]

TOP_KEYS = {"cohort_id", "note", "strata", "correlations"}
STRATUM_KEYS = {"share", "fugl_meyer_ue", "centre", "note"}
DIST_KEYS = {"normal": {"mean", "sd"}, "lognormal": {"median", "sigma_log"}, "uniform": {"low", "high"},
             "around": {"relative_sd"}}
CLIP_KEYS = {"min", "max"}


def profile_tables() -> dict[str, type[BaseModel]]:
    """The patient profile's tables by name, each with its schema (``[voluntary]`` -> VoluntarySection)."""
    out = {}
    for name, f in PatientProfile.model_fields.items():
        types = [t for t in (getattr(f.annotation, "__args__", None) or (f.annotation,)) if t is not type(None)]
        if isinstance(types[0], type) and issubclass(types[0], BaseModel):
            out[name] = types[0]
    return out


@dataclass(frozen=True)
class Param:
    """One drawn parameter of a stratum: ``table.key``, its distribution and the range a draw is clipped to."""

    name: str
    dist: str
    args: dict[str, float]
    low: float
    high: float

    def value(self, z: float) -> float:
        """The parameter at normal score ``z`` (the copula's), clipped to its range."""
        a = self.args
        if self.dist == "normal" or self.dist == "around":
            v = a["mean"] + a["sd"] * z
        elif self.dist == "lognormal":
            v = a["median"] * math.exp(a["sigma_log"] * z)
        else:  # uniform: the normal score's quantile
            v = a["low"] + (a["high"] - a["low"]) * 0.5 * math.erfc(-z / math.sqrt(2.0))
        return min(max(v, self.low), self.high)

    def centre(self) -> float:
        """The value at the distribution's centre (z = 0): what the load-time check validates."""
        return self.value(0.0)


@dataclass(frozen=True)
class Stratum:
    """A severity band: its share, its Fugl-Meyer band, the fixed values, the drawn ones and the traits'
    prevalence, and the Cholesky factor of its drawn parameters' correlations."""

    name: str
    share: float
    fugl_meyer_ue: tuple[int, int] | None
    fixed: dict[str, dict[str, Any]]  # table -> key -> value (the centre profile's, then the stratum's)
    params: tuple[Param, ...]
    prevalence: dict[str, float]  # trait table -> share of patients who have it
    chol: np.ndarray


@dataclass(frozen=True)
class SampledPatient:
    """One patient drawn from the cohort: the profile to write, and the values drawn (flat, ``table.key``)."""

    index: int
    patient_id: str
    stratum: str
    fugl_meyer_ue: tuple[int, int] | None
    seed: int
    traits: tuple[str, ...]  # the optional tables this patient has
    parameters: dict[str, float]  # every numeric value of the profile, ``table.key``
    profile: dict[str, Any]  # the PATIENT.toml's tables


@dataclass(frozen=True)
class Cohort:
    """A validated cohort file."""

    path: Path
    cohort_id: str
    note: str
    strata: tuple[Stratum, ...]

    def sample(self, seed: int, index: int) -> SampledPatient:
        """Patient ``index`` of a trial seeded ``seed`` (its own stream: independent of the others)."""
        ss = np.random.SeedSequence(seed, spawn_key=(index,))
        rng = np.random.default_rng(ss)
        shares = np.array([s.share for s in self.strata])
        stratum = self.strata[int(rng.choice(len(self.strata), p=shares / shares.sum()))]
        z = stratum.chol @ rng.standard_normal(len(stratum.params))
        has = {t: bool(rng.random() < p) for t, p in sorted(stratum.prevalence.items())}
        tables: dict[str, dict[str, Any]] = {t: dict(v) for t, v in stratum.fixed.items() if has.get(t, True)}
        for p, zi in zip(stratum.params, z, strict=True):
            table, key = p.name.split(".")
            if has.get(table, True):
                tables.setdefault(table, {})[key] = p.value(float(zi))
        pid = f"p{index:04d}"
        profile = {"patient_id": f"{self.cohort_id}-{pid}",
                   "note": f"drawn from {self.path.name}, stratum {stratum.name}, seed {seed}, patient {index}",
                   **tables}
        flat = {f"{t}.{k}": float(v) for t, kv in tables.items() for k, v in kv.items()
                if isinstance(v, int | float) and not isinstance(v, bool)}
        traits = tuple(t for t in tables if t not in ("voluntary", "cue"))
        return SampledPatient(index, pid, stratum.name, stratum.fugl_meyer_ue, seed, traits, flat, profile)


def load_cohort(path: str | Path) -> Cohort:
    """Read and validate a cohort file: every key known, every distribution complete, the shares
    summing to 1, the correlations positive definite, and each stratum's centre a valid patient
    (``ConfigError`` naming the file and the key)."""
    path = Path(path)
    data = load_toml(path)
    _known(path, "", data, TOP_KEYS)
    cohort_id = _text(path, "cohort_id", data.get("cohort_id"), required=True)
    strata_data = data.get("strata")
    if not isinstance(strata_data, dict) or not strata_data:
        raise ConfigError(path, "strata", "a cohort needs at least one [strata.NAME] table")
    corr = _correlations(path, data.get("correlations", []))
    strata = tuple(_stratum(path, cohort_id, name, s, corr) for name, s in strata_data.items())
    total = sum(s.share for s in strata)
    if abs(total - 1.0) > 1e-6:
        raise ConfigError(path, "strata", f"the strata's shares must sum to 1, got {total:g} "
                          f"({', '.join(f'{s.name} {s.share:g}' for s in strata)})")
    drawn = {p.name for s in strata for p in s.params}
    for k, (a, b, _) in enumerate(corr):
        for name in (a, b):
            if name not in drawn:
                raise ConfigError(path, f"correlations[{k}].between", f"{name} is drawn in no stratum "
                                  "(a fixed value cannot be correlated)")
    return Cohort(path, cohort_id, _text(path, "note", data.get("note", "")), strata)


def _text(path: Path, key: str, value: Any, required: bool = False) -> str:
    if value is None and not required:
        return ""
    if not isinstance(value, str) or (required and not value.strip()) or len(value) > 500:
        raise ConfigError(path, key, f"must be a non-empty string of at most 500 characters, got {value!r}")
    return value


def _known(path: Path, where: str, data: Any, known: set[str]) -> None:
    """Every key of table ``where`` is one of ``known`` (a typo names the closest)."""
    if not isinstance(data, dict):
        raise ConfigError(path, where.rstrip("."), f"must be a table, got {type(data).__name__}")
    for key in data:
        if key not in known:
            close = difflib.get_close_matches(key, sorted(known), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else f"; known: {', '.join(sorted(known))}"
            raise ConfigError(path, f"{where}{key}", f"unknown key{hint}")


def _number(path: Path, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(path, key, f"must be a finite number, got {value!r}")
    return float(value)


def _correlations(path: Path, data: Any) -> list[tuple[str, str, float]]:
    """``[[correlations]]``: ``between = ["table.key", "table.key"]``, ``rho`` in (-1, 1)."""
    if not isinstance(data, list):
        raise ConfigError(path, "correlations", "must be an array of tables ([[correlations]])")
    tables = profile_tables()
    out = []
    for k, c in enumerate(data):
        where = f"correlations[{k}]."
        _known(path, where, c, {"between", "rho"})
        pair = c.get("between")
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(p, str) for p in pair)
                and pair[0] != pair[1]):
            raise ConfigError(path, where + "between", f"must be two different \"table.key\" names, got {pair!r}")
        for name in pair:
            table, _, key = name.partition(".")
            if table not in tables or key not in tables[table].model_fields:
                raise ConfigError(path, where + "between", f"{name!r} is not a patient parameter (table.key)")
        rho = _number(path, where + "rho", c.get("rho"))
        if not -1.0 < rho < 1.0:
            raise ConfigError(path, where + "rho", f"must be in (-1, 1), got {rho:g}")
        out.append((pair[0], pair[1], rho))
    return out


def _stratum(path: Path, cohort_id: str, name: str, s: Any, corr: list[tuple[str, str, float]]) -> Stratum:
    """One ``[strata.NAME]``: its own keys, its centre profile, its fixed and drawn values, checked
    by validating the patient at every distribution's centre."""
    where = f"strata.{name}."
    tables = profile_tables()
    _known(path, where, s, STRATUM_KEYS | set(tables))
    share = _number(path, where + "share", s.get("share"))
    if not 0.0 < share <= 1.0:
        raise ConfigError(path, where + "share", f"must be in (0, 1], got {share:g}")
    centre = _centre(path, where, s.get("centre"))
    fixed: dict[str, dict[str, Any]] = {t: dict(v) for t, v in centre.items()}
    params: list[Param] = []
    prevalence: dict[str, float] = {}
    for table, schema in tables.items():
        if table not in s:
            continue
        optional = table not in ("voluntary", "cue")
        _known(path, f"{where}{table}.", s[table], set(schema.model_fields) | ({"prevalence"} if optional else set()))
        fixed.setdefault(table, {})
        for key, value in s[table].items():
            k = f"{where}{table}.{key}"
            if key == "prevalence":
                prevalence[table] = _number(path, k, value)
                if not 0.0 <= prevalence[table] <= 1.0:
                    raise ConfigError(path, k, f"must be in [0, 1], got {value!r}")
            elif isinstance(value, dict):
                params.append(_param(path, k, f"{table}.{key}", value, schema.model_fields[key],
                                     centre.get(table, {}).get(key)))
                fixed[table].pop(key, None)
            else:
                fixed[table][key] = value  # checked with the rest by the profile's schema below
    at_centre = {t: dict(v) for t, v in fixed.items()}
    for p in params:
        table, key = p.name.split(".")
        at_centre[table][key] = p.centre()
    validate(path, {"patient_id": f"{cohort_id}-{name}", **at_centre}, PatientProfile, prefix=where)
    return Stratum(name, share, _band(path, where, s.get("fugl_meyer_ue")), fixed, tuple(params), prevalence,
                   _cholesky(path, name, params, corr))


def _centre(path: Path, where: str, centre: Any) -> dict[str, dict[str, Any]]:
    """The tables of the stratum's centre profile (a path relative to the cohort file), or none."""
    if centre is None:
        return {}
    if not isinstance(centre, str):
        raise ConfigError(path, where + "centre", f"must be a patient file's path, got {centre!r}")
    file = path.parent / centre
    try:
        profile = load_patient(file)
    except ConfigError as e:
        raise ConfigError(path, where + "centre", str(e)) from None
    data = profile.model_dump(exclude_none=True)
    return {t: v for t, v in data.items() if isinstance(v, dict)}


def _band(path: Path, where: str, band: Any) -> tuple[int, int] | None:
    """``fugl_meyer_ue = [low, high]``: the band of the upper-extremity Fugl-Meyer score (0..66)."""
    if band is None:
        return None
    if not (isinstance(band, list) and len(band) == 2 and all(type(b) is int for b in band)
            and 0 <= band[0] <= band[1] <= 66):
        raise ConfigError(path, where + "fugl_meyer_ue", f"must be [low, high], integers 0..66, got {band!r}")
    return band[0], band[1]


def _param(path: Path, key: str, name: str, d: dict[str, Any], field: Any, centre: Any) -> Param:
    """A drawn value: its distribution's keys complete and sane, its range the schema's and its own."""
    dist = d.get("dist")
    if dist not in DIST_KEYS:
        raise ConfigError(path, key + ".dist", f"must be one of {', '.join(DIST_KEYS)}, got {dist!r}")
    _known(path, key + ".", d, {"dist"} | DIST_KEYS[dist] | CLIP_KEYS)
    if field.annotation is not float:
        raise ConfigError(path, key, f"{name} is a {field.annotation.__name__}: give it a fixed value")
    missing = sorted(DIST_KEYS[dist] - set(d))
    if missing:
        raise ConfigError(path, key, f"a {dist} distribution needs {', '.join(missing)}")
    args = {k: _number(path, f"{key}.{k}", v) for k, v in d.items() if k != "dist"}
    low, high = _schema_range(field)
    low, high = max(low, args.pop("min", -math.inf)), min(high, args.pop("max", math.inf))
    if not low <= high:
        raise ConfigError(path, key, f"min {low:g} is above max {high:g}")
    checks = {"sd": args.get("sd", 1.0) >= 0, "sigma_log": args.get("sigma_log", 1.0) >= 0,
              "median": args.get("median", 1.0) > 0, "relative_sd": args.get("relative_sd", 1.0) >= 0,
              "high": args.get("high", math.inf) > args.get("low", -math.inf)}
    bad = next((k for k, ok in checks.items() if not ok), None)
    if bad is not None:
        raise ConfigError(path, f"{key}.{bad}", {"high": "must be above low", "median": "must be above 0"}.get(
            bad, "must be at least 0") + f", got {args[bad]:g}")
    if dist == "around":
        if not isinstance(centre, int | float):
            raise ConfigError(path, key, f"'around' needs the stratum's centre profile to give {name}")
        args = {"mean": float(centre), "sd": args["relative_sd"] * abs(float(centre))}
    return Param(name, dist, args, low, high)


def _schema_range(field: Any) -> tuple[float, float]:
    """The range of a profile field from its ``ge``/``gt``/``le``/``lt``, as closed bounds."""
    low, high = -math.inf, math.inf
    for m in field.metadata:
        if getattr(m, "ge", None) is not None:
            low = max(low, float(m.ge))
        if getattr(m, "gt", None) is not None:  # an open bound: the next number inside it
            low = max(low, math.nextafter(float(m.gt), math.inf))
        if getattr(m, "le", None) is not None:
            high = min(high, float(m.le))
        if getattr(m, "lt", None) is not None:
            high = min(high, math.nextafter(float(m.lt), -math.inf))
    return low, high


def _cholesky(path: Path, name: str, params: list[Param], corr: list[tuple[str, str, float]]) -> np.ndarray:
    """The lower Cholesky factor of the stratum's correlation matrix (identity where none is given)."""
    index = {p.name: i for i, p in enumerate(params)}
    r = np.eye(len(params))
    for a, b, rho in corr:
        if a in index and b in index:
            r[index[a], index[b]] = r[index[b], index[a]] = rho
    try:
        return np.linalg.cholesky(r)
    except np.linalg.LinAlgError:
        raise ConfigError(path, "correlations", f"the correlations among stratum {name}'s drawn parameters "
                          "are not positive definite (no such cohort exists)") from None
