"""Per-sensor force calibration of the Flexiforce on A0: fit, store, load, and the firmware force limit.

The sensor's conductance is linear in force (Tekscan, FlexiForce user manual); in the inverting
op-amp circuit ``V_out = -V_ref * R_f / R_s`` (docs/wiring.md) the output, and so the ADC count, is
proportional to the conductance ``1/R_s``; in a plain divider (``V = Vcc R_m / (R_m + R_s)``) the
conductance is ``counts / (1023 - counts) / R_m``. ``fit_calibration`` fits force against
conductance (linear) and low-order polynomials in counts, and keeps the one the corrected AIC of
the residuals prefers; it reports the fit and the loading/unloading hysteresis.

Files: ``calibrations/<sensor-id>.toml`` (``CalibrationFile``), referenced from a plant config by
``[rig] force_calibration = "calibrations/<id>.toml"`` (``REFERENCE_KEY``; that optional schema key
belongs to ``rehab_hil.config``: until it is declared there, no config can carry it, and the
plant's linear ``counts_per_n``/``offset_counts`` map is used). ``force_limit_counts`` gives the
firmware's A0 limit and refuses one the 10-bit ADC cannot represent (1023 means "off").
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from rehab_hil.config import ConfigError, Section, load_toml, validate
from rehab_hil.interfaces import AdcChannel, DeviceBinding
from rehab_hil.plants.sections import PlantConfig

__all__ = ["ADC_MAX", "CIRCUITS", "G0", "REFERENCE_KEY", "Calibration", "CalibrationFile", "CalibrationPoint",
           "ForceLimitError", "calibration_for", "calibration_summary", "fit_calibration", "force_limit_counts",
           "load_calibration", "write_calibration"]

ADC_MAX = 1023  # 10-bit ADC; the firmware reads force_limit_counts = 1023 as "force limit off"
CIRCUITS = ("opamp", "divider")
REFERENCE_KEY = "rig.force_calibration"
G0 = 9.80665  # standard gravity [m/s^2]: known masses -> force
SENSOR_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


class ForceLimitError(ValueError):
    """The configured force limit cannot be given to the firmware in ADC counts."""


@dataclass(frozen=True)
class CalibrationPoint:
    """One reading: the applied force, the mean ADC count, and whether the load was rising."""

    force_n: float
    counts: float
    loading: bool = True


class CalibrationFile(Section):
    """``calibrations/<sensor-id>.toml``: force_n = sum_k coefficients[k] * x**k, where x is the
    conductance proxy (``model = "conductance"``) or counts above the tare (``"polynomial"``)."""

    sensor_id: str = Field(pattern=SENSOR_ID.pattern, description="the sensor's label, also the file name")
    circuit: Literal["opamp", "divider"] = Field(description="how the sensor reaches A0 (docs/wiring.md)")
    model: Literal["conductance", "polynomial"]
    coefficients: list[float] = Field(min_length=2, max_length=5, description="force_n per x**k, k = 0..")
    tare_counts: float = Field(ge=0.0, le=ADC_MAX, description="A0 counts with no load")
    max_calibrated_force_n: float = Field(gt=0.0, le=10_000.0, description="largest known load applied [N]")
    fit_rms_n: float = Field(ge=0.0, description="RMS residual of the fit over every point [N]")
    hysteresis_pct_fs: float = Field(ge=0.0, description="largest loading/unloading difference, % of full scale")
    calibrated_at: str = Field(min_length=1, description="ISO 8601 time of the calibration")
    points_force_n: list[float] = Field(default_factory=list, description="the applied loads, in order [N]")
    points_counts: list[float] = Field(default_factory=list, description="the mean A0 counts, in order")

    @model_validator(mode="after")
    def _points(self) -> CalibrationFile:
        if len(self.points_force_n) != len(self.points_counts):
            raise ValueError("points_force_n and points_counts must have the same length")
        return self


@dataclass(frozen=True)
class Calibration:
    """A fitted curve: counts <-> force for one sensor (``file``: where it was loaded from, if so)."""

    data: CalibrationFile
    file: str = ""

    def _x(self, counts: np.ndarray | float) -> np.ndarray:
        c = np.asarray(counts, dtype=float)
        if self.data.model == "polynomial":
            return c - self.data.tare_counts
        return _conductance(c, self.data.circuit) - _conductance(np.asarray(self.data.tare_counts), self.data.circuit)

    def force_n(self, counts: np.ndarray | float) -> np.ndarray:
        """Force [N] for A0 counts (tare subtracted)."""
        return np.polynomial.polynomial.polyval(self._x(counts), self.data.coefficients)

    def limit_counts(self, force_n: float) -> int:
        """The largest count whose force is at most ``force_n`` (the firmware trips above it); the
        curve must rise monotonically from the tare up to there. ForceLimitError otherwise."""
        counts = np.arange(math.ceil(self.data.tare_counts), ADC_MAX + 1)
        f = self.force_n(counts)
        above = np.nonzero(f > force_n)[0]
        if above.size == 0:
            raise ForceLimitError(f"{self.file or self.data.sensor_id}: {force_n} N is beyond the ADC range: the "
                                  f"calibration reaches only {f[-1]:.3g} N at {ADC_MAX} counts")
        if above[0] == 0:
            raise ForceLimitError(f"{self.file or self.data.sensor_id}: {force_n} N is at or below the tare "
                                  f"({self.data.tare_counts:.0f} counts)")
        if np.any(np.diff(f[:above[0] + 1]) <= 0):
            raise ForceLimitError(f"{self.file or self.data.sensor_id}: the curve is not rising between the tare "
                                  f"and {force_n} N; recalibrate")
        return int(counts[above[0] - 1])


def _conductance(counts: np.ndarray, circuit: str) -> np.ndarray:
    """Conductance proxy from counts: proportional to 1/R_s (op-amp) or R_m/R_s (divider)."""
    if circuit == "opamp":
        return counts
    return counts / np.maximum(ADC_MAX + 1 - counts, 1e-9)


def _aicc(rss: float, n: int, k: int) -> float:
    rss = max(rss, 1e-12 * n)
    extra = 2 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else math.inf
    return n * math.log(rss / n) + 2 * k + extra


def fit_calibration(points: Sequence[CalibrationPoint], tare_counts: float, sensor_id: str,
                    circuit: str = "opamp", max_degree: int = 3) -> tuple[Calibration, dict[str, float]]:
    """Fit force against the readings (tare subtracted): linear in conductance, or a polynomial in
    counts of degree 1..``max_degree``; the lowest corrected AIC wins (fewer terms unless the
    residuals really drop). Returns the calibration and the RMS residual [N] of every candidate."""
    if circuit not in CIRCUITS:
        raise ValueError(f"circuit must be one of {CIRCUITS}, got {circuit!r}")
    if not SENSOR_ID.match(sensor_id):
        raise ValueError(f"sensor id {sensor_id!r}: letters, digits, '.', '_', '-' only (it names the file)")
    loads = {round(p.force_n, 9) for p in points}
    if len(loads) < 3 or max(loads) <= 0:
        raise ValueError(f"need at least 3 different loads including a non-zero one, got {sorted(loads)}")
    f = np.array([p.force_n for p in points])
    c = np.array([p.counts for p in points])
    n = len(points)
    if np.ptp(c) < 3:
        raise ValueError(f"the readings barely move ({c.min():.1f}..{c.max():.1f} counts): is the sensor connected?")
    x_cond = _conductance(c, circuit) - _conductance(np.asarray(tare_counts, dtype=float), circuit)
    candidates: dict[str, tuple[str, np.ndarray, float, int]] = {}
    poly = np.polynomial.polynomial
    coef = poly.polyfit(x_cond, f, 1)
    candidates["conductance"] = ("conductance", coef, float(np.sum((poly.polyval(x_cond, coef) - f) ** 2)), 2)
    for deg in range(2, max_degree + 1):
        if n - (deg + 1) - 1 <= 0:
            break
        coef = np.polynomial.polynomial.polyfit(c - tare_counts, f, deg)
        rss = float(np.sum((np.polynomial.polynomial.polyval(c - tare_counts, coef) - f) ** 2))
        candidates[f"polynomial{deg}"] = ("polynomial", coef, rss, deg + 1)
    best = min(candidates, key=lambda k: _aicc(candidates[k][2], n, candidates[k][3]))
    model, coef, rss, _ = candidates[best]
    fs = float(f.max())
    cal = Calibration(CalibrationFile(
        sensor_id=sensor_id, circuit=circuit, model=model, coefficients=[float(v) for v in coef],
        tare_counts=float(tare_counts), max_calibrated_force_n=fs, fit_rms_n=math.sqrt(rss / n),
        hysteresis_pct_fs=0.0, calibrated_at=datetime.now(UTC).isoformat(timespec="seconds"),
        points_force_n=[float(v) for v in f], points_counts=[float(v) for v in c]))
    hyst = _hysteresis_pct(cal, points, fs)
    cal = Calibration(cal.data.model_copy(update={"hysteresis_pct_fs": hyst}))
    return cal, {k: math.sqrt(v[2] / n) for k, v in candidates.items()}


def _hysteresis_pct(cal: Calibration, points: Sequence[CalibrationPoint], full_scale_n: float) -> float:
    """Largest |force read while loading - force read while unloading| at the same load, % of full scale."""
    worst = 0.0
    for load in {p.force_n for p in points}:
        up = [p.counts for p in points if p.force_n == load and p.loading]
        down = [p.counts for p in points if p.force_n == load and not p.loading]
        if up and down:
            worst = max(worst, abs(float(cal.force_n(np.mean(up)) - cal.force_n(np.mean(down)))))
    return 100.0 * worst / full_scale_n


def write_calibration(cal: Calibration, directory: str | Path) -> Path:
    """Write ``<directory>/<sensor-id>.toml`` (replacing an older calibration of that sensor)."""
    d = cal.data
    path = Path(directory) / f"{d.sensor_id}.toml"
    path.parent.mkdir(parents=True, exist_ok=True)

    def floats(v: Sequence[float]) -> str:
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"

    x = "counts - tare_counts" if d.model == "polynomial" else "conductance(counts) - conductance(tare_counts)"
    path.write_text(
        f"# Flexiforce calibration written by `rehab-hil calibrate force` (rehab_hil.calibration)\n"
        f"# force_n = sum_k coefficients[k] * x**k; x = {x}\n"
        f'sensor_id = "{d.sensor_id}"\n'
        f'circuit = "{d.circuit}"  # opamp: counts ~ conductance; divider: conductance ~ c / (1024 - c)\n'
        f'model = "{d.model}"\n'
        f"coefficients = {floats(d.coefficients)}\n"
        f"tare_counts = {d.tare_counts!r}\n"
        f"max_calibrated_force_n = {d.max_calibrated_force_n!r}\n"
        f"fit_rms_n = {d.fit_rms_n!r}\n"
        f"hysteresis_pct_fs = {d.hysteresis_pct_fs!r}\n"
        f'calibrated_at = "{d.calibrated_at}"\n'
        f"points_force_n = {floats(d.points_force_n)}\n"
        f"points_counts = {floats(d.points_counts)}\n")
    return path


def load_calibration(path: str | Path) -> Calibration:
    """Load and validate a calibration file; errors name the file and the key (``ConfigError``)."""
    data = validate(path, load_toml(path), CalibrationFile)
    if Path(path).stem != data.sensor_id:
        raise ConfigError(path, "sensor_id", f"{data.sensor_id!r} does not match the file name {Path(path).name!r}")
    return Calibration(data, str(path))


def calibration_reference(cfg: PlantConfig) -> str | None:
    """The config's ``[rig] force_calibration`` path, or None (also while the schema has no such key)."""
    ref = cfg.rig.model_dump().get("force_calibration")
    return ref if isinstance(ref, str) and ref else None


def calibration_for(cfg: PlantConfig, config_path: str | Path = "<config>", base_dir: str | Path | None = None,
                    ) -> Calibration | None:
    """The calibration a config references (relative paths against ``base_dir``, default the current
    directory), or None. A missing or invalid file is a ``ConfigError`` naming the file and key."""
    ref = calibration_reference(cfg)
    if ref is None:
        return None
    path = Path(ref) if Path(ref).is_absolute() or base_dir is None else Path(base_dir) / ref
    if not path.exists():
        raise ConfigError(config_path, REFERENCE_KEY, f"{ref}: no such calibration file (rehab-hil calibrate force)")
    return load_calibration(path)


def _force_channel(binding: DeviceBinding) -> AdcChannel | None:
    """A0's channel when it is a force (the only channel the firmware limits), else None."""
    return binding.adc[0] if binding.adc and binding.adc[0].kind == "force" else None


def force_limit_counts(cfg: PlantConfig, binding: DeviceBinding, calibration: Calibration | None = None) -> int:
    """The firmware's A0 force limit in counts for ``[rig.limits] max_force_n``: from the sensor's
    calibration when there is one (``calibration`` or the config's reference), else the plant's
    linear map. 1023 (off) when A0 is not a force sensor. Raises ``ForceLimitError`` when the limit
    cannot be represented (at or beyond 1023 counts, or at/below the zero-force reading) instead of
    silently turning the firmware's force trip off."""
    ch = _force_channel(binding)
    if ch is None:
        return ADC_MAX
    max_force_n = cfg.rig.limits.max_force_n
    cal = calibration if calibration is not None else calibration_for(cfg)
    if cal is not None:
        return cal.limit_counts(max_force_n)
    counts = ch.offset_counts + ch.counts_per_unit * max_force_n
    if counts >= ADC_MAX:
        raise ForceLimitError(
            f"rig.limits.max_force_n = {max_force_n} N is {counts:.0f} ADC counts on A0 ({ch.offset_counts:g} + "
            f"{ch.counts_per_unit:g} counts/N): the firmware limit must be below {ADC_MAX} ({ADC_MAX} turns it off); "
            "lower max_force_n or the sensor gain (R_f, docs/wiring.md)")
    return math.floor(counts)


def calibration_summary(cfg: PlantConfig, binding: DeviceBinding, base_dir: str | Path | None = None) -> dict[str, Any]:
    """What a session's metadata records about its force sensor: the calibration in use (file,
    sensor, model, coefficients, fit, hysteresis, date) or the plant's linear map, and the
    firmware force limit in counts (or why it cannot be set). ``binding``: the config's rig binding,
    which the caller holds."""
    ch = _force_channel(binding)
    out: dict[str, Any] = {"max_force_n": cfg.rig.limits.max_force_n}
    if ch is None:
        return {**out, "force_sensor": None, "firmware_force_limit_counts": ADC_MAX,
                "note": "A0 is not a force sensor: the firmware force limit is off"}
    cal = calibration_for(cfg, base_dir=base_dir)
    if cal is None:
        out.update(force_sensor=ch.signal, calibration=None,
                   linear_map={"counts_per_n": ch.counts_per_unit, "offset_counts": ch.offset_counts})
    else:
        d = cal.data
        out.update(force_sensor=ch.signal, calibration={
            "file": cal.file, "sensor_id": d.sensor_id, "circuit": d.circuit, "model": d.model,
            "coefficients": list(d.coefficients), "tare_counts": d.tare_counts, "fit_rms_n": d.fit_rms_n,
            "hysteresis_pct_fs": d.hysteresis_pct_fs, "max_calibrated_force_n": d.max_calibrated_force_n,
            "calibrated_at": d.calibrated_at})
    try:
        out["firmware_force_limit_counts"] = force_limit_counts(cfg, binding, cal)
    except ForceLimitError as e:
        out["firmware_force_limit_counts"] = None
        out["firmware_force_limit_error"] = str(e)
    return out
