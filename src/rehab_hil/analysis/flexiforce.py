"""FlexiForce A201 on real data (Dickmann et al. 2021, ../shared/data/flexiforce_dickmann/): the
published static calibration refitted, and creep and loading/unloading hysteresis identified from
the dead-weight staircases.

Static calibration (``fit_static``): force against raw 12-bit counts, per sensor. Candidates: a
straight line (the authors' form, F = a ADC + b) and a quadratic (the op-amp FlexiForce circuit's
output bends as the sensor's conductance saturates), fitted by least squares
(``numpy.polynomial``) and chosen by AICc (Hurvich and Tsai 1989); the residual is reported beside
the authors' published linear fit (``PUBLISHED_LINEAR``: F_A = 0.0036 ADC - 2.0806, F_B = 0.0033 ADC
- 2.2402 [N], the data's README).

Staircase (``staircase``): dead weights 0, 4.013, 6.916, 9.820 N up and back down, 10 s each, 100 ms
samples, three runs per sensor. Each plateau after a step is fitted (``scipy.optimize.least_squares``)
with a first-order creep, y(t) = y_inf - d exp(-(t - t_step) / tau), tau shared by every plateau of a
sensor; creep is reported as the relative change from 0.5 s after the step to 5 s after it (the
Tekscan manual's "drift": % per logarithmic time), hysteresis as the unloading minus the loading
plateau reading at the same load, in counts and in newtons through the staircase's own slope (the
sensor in the staircase rig reads other counts than on the static rig: 4 N gives ~850 counts there,
~1780 in the static calibration).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.polynomial import Polynomial
from scipy.optimize import least_squares
from scipy.signal import find_peaks, medfilt

__all__ = [
    "PUBLISHED_LINEAR",
    "STAIRCASE_LOADS_N",
    "StaircaseFit",
    "StaticFit",
    "fit_static",
    "read_points",
    "staircase",
]

# the authors' linear fits, F = slope * counts + intercept [N] (Dickmann et al. 2021, data README)
PUBLISHED_LINEAR: dict[str, tuple[float, float]] = {"A": (0.0036, -2.0806), "B": (0.0033, -2.2402)}
STAIRCASE_LOADS_N = (0.0, 4.013, 6.916, 9.820, 6.916, 4.013, 0.0)  # the dead weights, in order


def read_points(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``sensor,load_n,raw_counts`` rows -> sensor -> (load [N], counts). Errors name file and line."""
    from rehab_hil.interchange import CsvError

    path = Path(path)
    try:
        rows = list(csv.reader(path.read_text().splitlines()))
    except (OSError, UnicodeDecodeError) as e:
        raise CsvError(path, None, f"cannot read: {e}") from None
    if not rows or [h.strip() for h in rows[0]] != ["sensor", "load_n", "raw_counts"]:
        raise CsvError(path, 1, "the header must be sensor,load_n,raw_counts")
    out: dict[str, tuple[list[float], list[float]]] = {}
    for i, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != 3:
            raise CsvError(path, i, f"{len(row)} cells, expected 3 (sensor,load_n,raw_counts)")
        try:
            load, counts = float(row[1]), float(row[2])
        except ValueError:
            raise CsvError(path, i, f"load_n and raw_counts must be numbers, got {row[1]!r}, {row[2]!r}") from None
        if not (np.isfinite(load) and np.isfinite(counts)):
            raise CsvError(path, i, "non-finite value")
        f, c = out.setdefault(row[0].strip(), ([], []))
        f.append(load)
        c.append(counts)
    for s, (f, _) in out.items():
        if len(f) < 4:
            raise CsvError(path, None, f"sensor {s!r}: {len(f)} points, at least 4 needed for a fit")
    return {s: (np.array(f), np.array(c)) for s, (f, c) in out.items()}


def _aicc(rss: float, n: int, k: int) -> float:
    return n * np.log(max(rss, 1e-300) / n) + 2 * k + (2 * k * (k + 1)) / max(n - k - 1, 1)


@dataclass
class StaticFit:
    """One sensor's static calibration: the chosen model, its coefficients (F = sum c_i counts^i,
    lowest first), RMS residuals of every candidate and of the published linear fit [N]."""

    sensor: str
    model: str
    coefficients: list[float]
    rms_n: dict[str, float]
    max_abs_n: dict[str, float]
    published_rms_n: float | None
    n_points: int

    def force_n(self, counts: np.ndarray | float) -> np.ndarray:
        return np.asarray(Polynomial(self.coefficients)(np.asarray(counts, float)))


def fit_static(sensor: str, load_n: np.ndarray, counts: np.ndarray) -> StaticFit:
    """Linear and quadratic force-from-counts fits; the lower AICc is chosen."""
    fits = {"linear": Polynomial.fit(counts, load_n, 1).convert(),
            "quadratic": Polynomial.fit(counts, load_n, 2).convert()}
    res = {k: p(counts) - load_n for k, p in fits.items()}
    rss = {k: float(r @ r) for k, r in res.items()}
    aicc = {k: _aicc(rss[k], counts.size, deg + 1) for deg, k in enumerate(fits, start=1)}
    best = min(aicc, key=aicc.__getitem__)
    pub = PUBLISHED_LINEAR.get(sensor)
    pub_rms = None
    if pub is not None:
        pub_rms = float(np.sqrt(np.mean((pub[0] * counts + pub[1] - load_n) ** 2)))
    return StaticFit(sensor, best, [float(c) for c in fits[best].coef],
                     {k: float(np.sqrt(rss[k] / counts.size)) for k in fits},
                     {k: float(np.max(np.abs(r))) for k, r in res.items()}, pub_rms, int(counts.size))


@dataclass
class StaircaseFit:
    """Creep and hysteresis of one sensor from its staircase runs."""

    sensor: str
    runs: int
    creep_time_constant_s: float
    creep_pct_in_5s: list[float]  # per loaded plateau and run: (y(5 s) - y(0.5 s)) / (y(0.5 s) - zero reading)
    hysteresis_counts: dict[float, float]  # load -> mean (unloading - loading) plateau reading
    hysteresis_n: dict[float, float]  # the same in newtons through the loading staircase's slope
    hysteresis_pct_fs: float  # the largest, % of the staircase's full load
    gain_spread_pct: float  # run-to-run spread of the top plateau reading above zero, (max - min) / mean
    plateaus: list[dict[str, float]] = field(default_factory=list)

    @property
    def creep_pct_median(self) -> float:
        return float(np.median(self.creep_pct_in_5s))


def _steps(y: np.ndarray, n_steps: int) -> np.ndarray:
    """Indices where the load changes: the ``n_steps`` largest jumps of the median-filtered reading,
    at least 3 s apart."""
    m = medfilt(y, 9)
    jump = np.abs(np.diff(m))
    peaks, _ = find_peaks(jump, distance=30)
    top = peaks[np.argsort(jump[peaks])[::-1][:n_steps]]
    return np.sort(top) + 1


def staircase(sensor: str, runs: list[np.ndarray], dt_s: float = 0.1,
              loads_n: tuple[float, ...] = STAIRCASE_LOADS_N) -> StaircaseFit:
    """Identify creep (shared time constant) and hysteresis from staircase runs of one sensor."""
    segs = []  # (run, plateau index, t from the step, readings)
    for r, y in enumerate(runs):
        y = np.asarray(y, float)
        edges = [0, *_steps(y, len(loads_n) - 1).tolist(), y.size]
        for k in range(len(loads_n)):
            a, b = edges[k] + 2, edges[k + 1] - 1  # skip the step itself
            segs.append((r, k, (np.arange(a, b) - edges[k]) * dt_s, y[a:b]))
    moving = [s for s in segs if 0 < s[1] < len(loads_n) - 1]  # loaded plateaus

    def resid(z: np.ndarray) -> np.ndarray:
        tau = np.exp(z[0])
        out = []
        for i, (_, _, t, yy) in enumerate(moving):
            yinf, d = z[1 + 2 * i], z[2 + 2 * i]
            out.append(yinf - d * np.exp(-t / tau) - yy)
        return np.concatenate(out)

    z0 = [np.log(2.0)]
    for _, _, _, yy in moving:
        z0 += [float(yy[-5:].mean()), float(yy[-5:].mean() - yy[:3].mean())]
    sol = least_squares(resid, np.array(z0), x_scale="jac")
    tau = float(np.exp(sol.x[0]))
    zero = {r: float(np.mean([s[3].mean() for s in segs if s[0] == r and s[1] in (0, len(loads_n) - 1)]))
            for r in range(len(runs))}
    creep, plateaus = [], []
    for i, (r, k, _t, yy) in enumerate(moving):
        yinf, d = sol.x[1 + 2 * i], sol.x[2 + 2 * i]
        y05, y5 = yinf - d * np.exp(-0.5 / tau), yinf - d * np.exp(-5.0 / tau)
        pct = 100.0 * (y5 - y05) / (y05 - zero[r])
        creep.append(float(pct))
        plateaus.append({"run": r, "load_n": loads_n[k], "loading": k <= len(loads_n) // 2,
                         "mean_counts": float(yy.mean()), "creep_pct_in_5s": float(pct)})
    level = {(p["run"], p["load_n"], p["loading"]): p["mean_counts"] for p in plateaus}
    half = len(loads_n) // 2
    up_loads = [loads_n[k] for k in range(1, half + 1)]
    slope = np.mean([np.polyfit(up_loads, [level[(r, f, True)] for f in up_loads], 1)[0] for r in range(len(runs))])
    hyst_c = {f: float(np.mean([level[(r, f, False)] - level[(r, f, True)] for r in range(len(runs))]))
              for f in loads_n[half + 1:-1]}
    hyst_n = {f: v / slope for f, v in hyst_c.items()}
    top = [level[(r, loads_n[half], True)] - zero[r] for r in range(len(runs))]
    return StaircaseFit(sensor, len(runs), tau, creep, hyst_c, hyst_n,
                        100.0 * max(abs(v) for v in hyst_n.values()) / max(loads_n),
                        100.0 * (max(top) - min(top)) / float(np.mean(top)), plateaus)
