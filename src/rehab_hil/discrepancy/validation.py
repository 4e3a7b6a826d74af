"""Estimation and validation as a user would: fit on one record, score on another.

The augmented model found on the estimation record (its parameter vector: chosen effects and
corrected parameters) and the nominal model are both replayed on the validation record, each from
its own start state estimated from that record (``initial_state``), with the same replay (the
recorded controller's closed loop when the config declares it and the record carries its reference:
EMPS, whose validation run adds known force pulses to the drive input, ``closed_loop.py``). The
figures are whole-record per-channel RMSE and the cut, nominal -> augmented, worded as what it is
("cut by 81.5 %", "worse by 92.5 %": ``wording.change_words``). The workflow also judges its
findings on these records (``judge``): a term that makes them worse than the model as given is not
reported, so the augmented model scored here holds only what they did not reject.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.discrepancy.initial_state import estimate_initial_state
from rehab_hil.discrepancy.replay import Replay, channel_metrics
from rehab_hil.discrepancy.result import Result
from rehab_hil.discrepancy.wording import change_words
from rehab_hil.interchange import Recording
from rehab_hil.plants import get_plant

__all__ = ["Validation", "validate", "validation_replay"]


@dataclass
class Validation:
    data: str
    replay: str  # which replay (closed loop and its controller, or open loop)
    channels: list[str]
    nominal: dict[str, dict[str, float]]  # channel -> rmse, mae, max_abs_error
    augmented: dict[str, dict[str, float]]
    cut_pct: dict[str, float]  # 100 (1 - augmented RMSE / nominal RMSE)
    t: np.ndarray
    measured: dict[str, np.ndarray]
    nominal_sim: dict[str, np.ndarray]
    augmented_sim: dict[str, np.ndarray]

    def as_dict(self) -> dict[str, Any]:
        return {"data": self.data, "replay": self.replay, "channels": self.channels,
                "metrics": {"nominal": self.nominal, "augmented": self.augmented},
                "error_cut_pct": self.cut_pct, "error_change": {c: change_words(v) for c, v in self.cut_pct.items()}}

    def lines(self) -> list[str]:
        out = [f"validation on {self.data} ({self.replay}; RMSE of the whole-record open-loop replay):"]
        for c in self.channels:
            out.append(f"  {c:24s} RMSE {self.nominal[c]['rmse']:.4g} -> {self.augmented[c]['rmse']:.4g} "
                       f"({change_words(self.cut_pct[c])})")
        return out


def validation_replay(fitted: Any, cfg: Any, rec: Recording, data_path: str | Path) -> Replay:
    """A validation record bound as the fit's records are (``fitted``: their ``Replay`` or
    ``RecordSet``): the same loop and start rule; a record whose replay has another parameter layout
    than the fit's (other columns) is refused."""
    replay = Replay.build(get_plant(cfg.plant), cfg, rec, data_path, closed_loop=bool(fitted.loop))
    first = fitted.replays[0] if hasattr(fitted, "replays") else fitted  # several records: a RecordSet
    replay.start = first.start  # the same start rule as the fit (--start)
    n_fit, n_val = first.nominal_params().size, replay.nominal_params().size
    if n_fit != n_val:  # same plant, same config, same effects: only another replay structure differs
        raise ValueError(f"{data_path}: the validation record's replay has {n_val} parameters, the fit's {n_fit} "
                         "(a record with other columns than the estimation record)")
    return replay


def validate(res: Result, cfg: Any, rec: Recording, data_path: str | Path) -> Validation:
    """Score the nominal and the augmented model of ``res`` on another record of the same plant."""
    replay = validation_replay(res.extras["replay"], cfg, rec, data_path)
    P0 = replay.nominal_params()
    P = np.asarray(res.extras["P"], float)
    n = replay.t.size
    sims = {}
    for name, params in (("nominal", P0), ("augmented", P)):
        estimate_initial_state(replay, params, n)
        sims[name] = replay.simulate(params)
    nom = {c: channel_metrics(replay.measured[c], sims["nominal"][c]) for c in replay.channels}
    aug = {c: channel_metrics(replay.measured[c], sims["augmented"][c]) for c in replay.channels}
    cut = {c: 100.0 * (1.0 - aug[c]["rmse"] / nom[c]["rmse"]) if nom[c]["rmse"] > 0 else 0.0 for c in replay.channels}
    return Validation(str(data_path), replay.loop or "open loop: the recorded plant inputs drive the model",
                      list(replay.channels), nom, aug, cut, replay.t, replay.measured, sims["nominal"],
                      sims["augmented"])
