"""The state at the record's start, from the data, for any plant.

1. Measured outputs set their matching states: the output Jacobian at the start (finite
   differences of one-step simulations) says which state each measured channel is (an encoder
   angle is the joint angle times a gain, a measured current is the armature current); a channel
   whose output is one state (>= ``MATCH_SHARE`` of its row) is matched, and the matched states
   are solved (Gauss-Newton, a few steps) so the model's outputs equal the first measured samples.
2. The other states (velocity, a wire temperature nobody measures, a pad angle) and the material
   memory of the nominal parts (an SMA's martensite fraction) are nuisance parameters: fitted by
   least squares on the first ``WINDOW_S`` of the record, open loop, from the config's rest state.

The candidate effects' discrete states (a delay's FIFO, a backlash's held angle) start at their
input's value at the start.
3. An estimated start is a guess fitted with the model under test: where it differs from the
   config's rest in a way the model remembers for a while (a session cut mid-way: a hot wire that
   takes seconds to cool), the fits skip the samples until the runs from the guess and from rest
   agree (``_memory``), so a start guessed under a wrong model cannot bias a candidate's fit
   (measured on an SMA record with a hidden driver dead zone: the fitted width went from a third
   of the true one to the true one); a session from power-up keeps its first heating.
4. A record that starts at rest (``Replay.start``: "rest" said by the user, or "auto" and no measured
   channel moves in its first ``REST_WINDOW_S``: ``starts_at_rest``) keeps the config's rest for the
   unmeasured states instead of estimating them (all of them for "rest"; for "auto" the velocities,
   put back to rest after the nuisance fit when the fitted ones would move a channel beyond its
   noise at the start: ``_back_to_rest``; a wire's temperature may still differ from ambient): a
   servo record from standstill was given start velocities of -2 and +7 rad/s by the nuisance fit.
The result says which states were set from which channel and which
were estimated; the matched channel-state pairs also give the anchor gain that multiple shooting
re-anchors with.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import least_squares

from rehab_hil.control.cascade import LOOP_PREFIX
from rehab_hil.discrepancy.replay import CANDIDATE_PREFIX
from rehab_hil.discrepancy.selection import bounded
from rehab_hil.discrepancy.verdict import NOISE_FACTOR, SPREAD_SHARE, noise_floor

if TYPE_CHECKING:
    from rehab_hil.discrepancy.replay import Replay

__all__ = ["MATCH_SHARE", "MAX_MEMORY_SHARE", "RANGE_MARGIN", "REST_WINDOW_S", "WINDOW_S", "InitialState",
           "estimate_initial_state", "matched_states", "starts_at_rest", "state_scales"]

MATCH_SHARE = 0.95  # a channel "is" a state when that state carries this share of its sensitivity
REST_WINDOW_S = 0.05  # a record whose channels stay within their noise for this long starts at rest
WINDOW_S = 1.5  # nuisance states are fitted on this much of the record's start
FD_SHARE = 0.05  # finite-difference step: this share of a state's spread over the nominal replay
RANGE_MARGIN = 0.01  # a nuisance start state may lie this share of its visited range beyond it
MAX_MEMORY_SHARE = 0.5  # a longer memory than this share of the fit part counts as never forgetting (a wire
# cut mid-session keeps its temperature below the angle's threshold until the next heating, 4.6 s of 12 s on
# an SMA record: at 0.3 none was skipped and a hidden 0.10 dead zone was fitted at 0.106 with a residual)


@dataclass
class InitialState:
    """The start state and what it came from."""

    x0: np.ndarray
    xd0: np.ndarray
    set_from_data: dict[str, str] = field(default_factory=dict)  # state -> channel
    estimated: dict[str, float] = field(default_factory=dict)  # state -> value (nuisance fit)
    config_rest: dict[str, float] = field(default_factory=dict)  # state -> config value (moved ones)
    at_rest: str = ""  # "" (estimated), "option" (--start rest) or "data" (no channel moves at the start)

    def describe(self) -> list[str]:
        """One line per state that did not come from the config's rest state."""
        out = [f"{s} = {self.x0_of(s):.4g} set from the first sample of {c}" for s, c in self.set_from_data.items()]
        if self.at_rest:
            why = ("said so (--start rest)" if self.at_rest == "option" else
                   f"found from the data: no channel moves beyond its noise in the first {1000 * REST_WINDOW_S:g} ms")
            out.append(f"starts at rest, {why}: the unmeasured {'states' if self.at_rest == 'option' else 'velocities'}"
                       " keep the config's rest values")
        out += [f"{s} = {v:.4g} estimated (nuisance parameter, first {WINDOW_S:g} s)"
                for s, v in self.estimated.items()]
        return out

    def x0_of(self, state: str) -> float:
        return float(self._values.get(state, float("nan")))

    _values: dict[str, float] = field(default_factory=dict, repr=False)


def state_scales(replay: Replay, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per state: a scale (its spread over the replay from rest under the record's drive) and the
    range it visits there, widened by ``RANGE_MARGIN`` of the spread. A start outside that range is
    not one this drive makes (a wire colder than ambient, 7 C fitted on an SMA record whose first
    heating the nominal model found too strong), so the nuisance fit stays inside it."""
    s = replay.system
    X, _ = s.run_arrays(s.x0.copy(), s.xd0.copy(), replay.U, P[:replay.n_diagram_params],
                        s.out_slots(replay.channels[:1]), s.workspace())
    X = np.vstack([s.x0, np.nan_to_num(X)])
    scales = np.maximum(np.maximum(np.std(X, axis=0), 0.1 * np.abs(s.x0)), 1e-3)
    pad = RANGE_MARGIN * (X.max(axis=0) - X.min(axis=0))
    return scales, X.min(axis=0) - pad, X.max(axis=0) + pad


def _outputs(replay: Replay, P: np.ndarray, x: np.ndarray, xd: np.ndarray) -> np.ndarray:
    return replay.run(P, 0, 1, x.copy(), xd.copy())[0] / replay.scale


def _jacobian(replay: Replay, P: np.ndarray, x: np.ndarray, xd: np.ndarray, h: np.ndarray) -> np.ndarray:
    C = np.zeros((len(replay.channels), x.size))
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[i] += h[i]
        xm[i] -= h[i]
        C[:, i] = (_outputs(replay, P, xp, xd) - _outputs(replay, P, xm, xd)) / (2 * h[i])
    return C


def matched_states(C: np.ndarray, channels: Sequence[int], tol: float = 1e-9) -> dict[int, int]:
    """channel -> the state it "is": the one that carries ``MATCH_SHARE`` of its row of the output
    Jacobian ``C`` (an encoder angle is the joint angle times a gain); channels that are no one state
    are left out. The live twin re-anchors on the same pairs (``twin/model.py``)."""
    matched: dict[int, int] = {}
    for c in channels:
        row = np.abs(C[c])
        norm = float(np.linalg.norm(row))
        if norm > tol and row.max() >= MATCH_SHARE * norm:
            matched[c] = int(np.argmax(row))
    return matched


def estimate_initial_state(replay: Replay, P: np.ndarray, n_train: int) -> InitialState:
    """Set ``replay.x0``, ``xd0`` and ``anchor_gain`` from the data; returns what was done."""
    s = replay.system
    names = s.diagram.state_names
    x, xd = s.x0.copy(), s.xd0.copy()
    scales, lo, hi = state_scales(replay, P)
    matched = _set_matched_states(replay, P, x, xd, FD_SHARE * scales)
    states = sorted(set(matched.values()))
    # nuisance: unmatched states and the nominal parts' discrete memory
    free_x = [i for i in range(x.size) if i not in states and hi[i] > lo[i]]  # a state the drive never moves stays
    dnames = s.diagram.discrete_state_names
    # the candidates' memory starts from its input; a replayed controller's from the record (closed_loop)
    free_xd = [i for i, n in enumerate(dnames) if not n.startswith((CANDIDATE_PREFIX + "_", LOOP_PREFIX + "_"))]
    at_rest = "option" if getattr(replay, "start", "estimate") == "rest" else \
        "data" if getattr(replay, "start", "estimate") == "auto" and starts_at_rest(replay) else ""
    if at_rest == "option":
        free_x, free_xd = [], []
    estimated: dict[str, float] = {}
    if free_x or free_xd:
        n_win = max(2, min(int(np.searchsorted(replay.t, WINDOW_S)), n_train))
        _fit_nuisance(replay, P, x, xd, free_x, free_xd, (scales, lo, hi), n_win)
        estimated = {names[i]: float(x[i]) for i in free_x}
        estimated.update({dnames[i]: float(xd[i]) for i in free_xd})
    if at_rest == "data":
        at_rest = _back_to_rest(replay, P, x, xd, [i for i in free_x if "velocity" in names[i]])
        estimated = {k: v for k, v in estimated.items() if not (at_rest and "velocity" in k)}
    _settle_candidates(replay, P, x, xd)
    replay.x0, replay.xd0 = x, xd
    replay.fit_start = _memory(replay, P, n_train, x, xd, free_x, free_xd) if estimated else 0
    from_data: dict[str, str] = {}
    for c, st in sorted(matched.items()):
        from_data[names[st]] = ", ".join(filter(None, [from_data.get(names[st], ""), replay.channels[c]]))
    out = InitialState(x, xd, from_data, estimated,
                       {names[i]: float(s.x0[i]) for i in range(x.size)}, at_rest)
    out._values = {**{n: float(v) for n, v in zip(names, x, strict=True)}, **estimated}
    return out


def _back_to_rest(replay: Replay, P: np.ndarray, x: np.ndarray, xd: np.ndarray, velocities: list[int]) -> str:
    """On a record that starts at rest, put the fitted start velocities back to the config's rest when
    they move some channel beyond its noise within ``REST_WINDOW_S`` (a fit that found -2 and +7 rad/s
    on a servo standing still); a velocity too small to show is left as fitted. Returns "data" when
    reset, "" when not."""
    if not velocities:
        return ""
    n = max(5, int(np.searchsorted(replay.t, REST_WINDOW_S)))
    rest = x.copy()
    rest[velocities] = replay.system.x0[velocities]
    fitted, reset = replay.simulate_from(P, n, x, xd), replay.simulate_from(P, n, rest, xd)
    shows = any(float(np.max(np.abs(fitted[c] - reset[c]))) > NOISE_FACTOR * max(noise_floor(replay.measured[c]),
                                                                                    1e-12)
                for c in replay.channels if c in replay.spec.outputs)
    if shows:
        x[velocities] = rest[velocities]
    return "data" if shows else ""


def starts_at_rest(replay: Replay) -> bool:
    """Does the record start at rest? Every measured plant output stays within its noise over the first
    ``REST_WINDOW_S`` (its span under 2 x ``NOISE_FACTOR`` noise floors), and a measured velocity is
    zero there within the same noise."""
    n = max(5, int(np.searchsorted(replay.t, REST_WINDOW_S)))
    chans = [c for c in replay.channels if c in replay.spec.outputs]
    if not chans or n >= replay.t.size:
        return False
    for c in chans:
        y = replay.measured[c]
        tol = 2.0 * NOISE_FACTOR * max(noise_floor(y), 1e-12)
        head = y[:n]
        if float(np.ptp(head)) > tol or ("velocity" in c and abs(float(np.mean(head))) > tol / 2.0):
            return False
    return True


def _set_matched_states(replay: Replay, P: np.ndarray, x: np.ndarray, xd: np.ndarray, h: np.ndarray) -> dict[int, int]:
    """Solve the states the measured channels are (``matched_states``) so the model's outputs equal
    the first samples (Gauss-Newton, in ``x``), and set ``replay.anchor_gain`` from them; returns
    channel -> state."""
    C = _jacobian(replay, P, x, xd, h)
    target = replay.measured_grid[:, 0] / replay.scale
    # a replayed loop's effort is no state of the plant
    matched = matched_states(C, [c for c in range(C.shape[0]) if replay.channels[c] in replay.spec.outputs
                                 and np.isfinite(target[c])])
    states = sorted(set(matched.values()))
    chans = sorted(matched)
    K = np.zeros((x.size, C.shape[0]))
    if states:
        for _ in range(3):  # Gauss-Newton on the matched channels
            C = _jacobian(replay, P, x, xd, h)
            err = target[chans] - _outputs(replay, P, x, xd)[chans]
            dx, *_ = np.linalg.lstsq(C[np.ix_(chans, states)], err, rcond=None)
            x[states] += dx
        K[np.ix_(states, chans)] = np.linalg.pinv(C[np.ix_(chans, states)])
    replay.anchor_gain = K if states else None
    return matched


def _fit_nuisance(replay: Replay, P: np.ndarray, x: np.ndarray, xd: np.ndarray, free_x: list[int],
                  free_xd: list[int], ranges: tuple[np.ndarray, np.ndarray, np.ndarray], n_win: int) -> None:
    """Fit the free states (within the range the drive visits, ``ranges`` = scale, low, high) and the
    free discrete memory by least squares on the first ``n_win`` samples; ``x``/``xd`` are moved only
    if the fit improves on them."""
    scales, lo, hi = ranges
    sc = np.concatenate([scales[free_x], np.ones(len(free_xd))])
    base_x, base_xd = x.copy(), xd.copy()

    def fun(z: np.ndarray) -> np.ndarray:
        xx, dd = base_x.copy(), base_xd.copy()
        xx[free_x] += z[:len(free_x)] * sc[:len(free_x)]
        dd[free_xd] += z[len(free_x):] * sc[len(free_x):]
        r = replay.residual(replay.simulate_from(P, n_win, xx, dd), slice(0, n_win), weighted=True).ravel()
        return bounded(r)

    z0 = np.zeros(sc.size)
    r0 = fun(z0)
    zlo = np.concatenate([(lo[free_x] - base_x[free_x]) / sc[:len(free_x)], np.full(len(free_xd), -np.inf)])
    zhi = np.concatenate([(hi[free_x] - base_x[free_x]) / sc[:len(free_x)], np.full(len(free_xd), np.inf)])
    z0 = np.clip(z0, np.minimum(zlo, -1e-9), np.maximum(zhi, 1e-9))
    sol = least_squares(fun, z0, bounds=(np.minimum(zlo, -1e-9), np.maximum(zhi, 1e-9)), diff_step=FD_SHARE,
                        max_nfev=12 * sc.size, xtol=1e-3, ftol=1e-4)
    if float(np.mean(sol.fun**2)) < float(np.mean(r0**2)):
        x[free_x] += sol.x[:len(free_x)] * sc[:len(free_x)]
        xd[free_xd] += sol.x[len(free_x):] * sc[len(free_x):]


def _memory(replay: Replay, P: np.ndarray, n_train: int, x: np.ndarray, xd: np.ndarray, free_x: list[int],
            free_xd: list[int]) -> int:
    """Samples the estimated start matters for: the run from it and the run from the config's rest
    (the estimated states put back) are compared, and the fits start where they agree for good to
    within what the verdict would call a fit (``verdict.SPREAD_SHARE`` of each channel's spread: a
    guess 1 C off ambient at a power-up keeps the first heating, which the fit needs). A record
    that starts at rest (a session from power-up) skips nothing; one cut mid-session (a hot wire)
    skips the seconds the wire takes to cool. A plant that never forgets (an integrator, a martensite
    fraction no full transformation resets) skips nothing either: its start is carried through the
    record (or re-anchored by shooting)."""
    s = replay.system
    xr, xdr = x.copy(), xd.copy()
    xr[free_x] = s.x0[free_x]
    xdr[free_xd] = s.xd0[free_xd]
    a = replay.simulate_from(P, n_train, x.copy(), xd.copy())
    b = replay.simulate_from(P, n_train, xr, xdr)
    d = np.max(np.abs(np.vstack([(b[c] - a[c]) / sc for c, sc in zip(replay.channels, replay.scale, strict=True)])),
               axis=0)
    if not np.isfinite(d).all():
        return 0
    above = np.nonzero(d > SPREAD_SHARE)[0]
    last = int(above[-1]) + 1 if above.size else 0
    return last if last <= MAX_MEMORY_SHARE * n_train else 0


def _settle_candidates(replay: Replay, P: np.ndarray, x: np.ndarray, xd: np.ndarray) -> None:
    """Candidate effects' discrete states are past copies of their input (a delay's FIFO, a play's
    held angle, a sampled temperature): start them at the input's value at the record's start, so
    an effect switched on during fitting starts centred instead of carrying a start-up offset."""
    s = replay.system
    d = s.diagram
    names = d.discrete_state_names
    parts = [p for p in d.parts if p.name.startswith(CANDIDATE_PREFIX + "_") and p.discrete_states]
    if not parts:
        return
    u0 = replay.U[0] * P[replay.n_diagram_params:]
    known = {k: float(u0[j]) for j, k in enumerate(s.input_names)}
    signals = sorted({sig for p in parts for sig, _ in p.connections[p.inputs[0]]} - set(known))
    if signals:
        res = s.simulate(1, {k: replay.U[:1, j] for j, k in enumerate(s.input_names)}, outputs=signals,
                         params=P[:replay.n_diagram_params], x0=x, xd0=xd)
        known.update({sig: float(res.signals[sig][0]) for sig in signals})
    for p in parts:
        value = sum(w * known[sig] for sig, w in p.connections[p.inputs[0]])
        for st in p.discrete_states:
            xd[names.index(f"{p.name}.{st}")] = value
