"""Assistance learned across open-close cycles, per direction: the assist-as-needed scale.

One sampled part reads the reference's phase from its own clock (device time, ``dt_s``), watches
whether the angle reaches each move's target in time, and once per move updates that direction's
assistance (Emken, Benitez & Reinkensmeyer 2007, with a success-rate target as FINGER's: Taheri et al.
2014, Rowe et al. 2017):

    failed move:            a <- a + gain x target_success
    success, in time:       a <- a - gain x (1 - target_success)           (zero drift at the target rate)
    success, with margin:   a <- (1 - forgetting) a - gain x (1 - target_success)

"With margin": reached by the end of the planned move plus half the success window; only then does
the assistance also forget, so a patient who needs the help keeps it at the target success rate,
while one who moves well alone sees it fade (forgetting faster than a slacking patient relearns to
rely on it: Emken et al. 2007).
The feedback command is scaled by the assistance of the current move's direction. An actuator that
pulls one way (``one_way``: an SMA wire, a TCP muscle) has one assistance, the opening move's (the
direction it pulls): it scales each of its pulls, in the closing move and the closed hold too (a
finger one encoder count past the closed target drew the full pull there, cycle after cycle).
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["ASSIST_PARAMS", "ASSIST_STATES", "AssistScale"]

ASSIST_PARAMS = ("closed", "opened", "move_s", "hold_open_s", "hold_closed_s", "first_open_s", "tolerance",
                 "window_s", "gain", "forgetting", "target_success", "min_assistance", "max_assistance",
                 "learn_open", "learn_close", "one_way")
ASSIST_STATES = ("t_s", "assist_open", "assist_close", "reached_open", "reached_close", "early_open", "early_close",
                 "done_open", "done_close")


@njit
def _phase(t, p):
    """(cycle index, time into the cycle, opening?) on the session's clock (before the first move: -1)."""
    tc = t - p[5]
    if tc < 0.0:
        return -1, 0.0, False
    period = 2.0 * p[2] + p[3] + p[4]
    k = math.floor(tc / period)
    u = tc - k * period
    return k, u, u < p[2] + p[3]


@njit
def _learn(a, reached, early, p):
    """The next assistance of one direction after one move."""
    if reached < 0.5:
        a = a + p[8] * p[10]
    else:
        if early > 0.5:
            a = (1.0 - p[9]) * a
        a = a - p[8] * (1.0 - p[10])
    return min(max(a, p[11]), p[12])


class AssistScale(Part):
    """``demand`` = the feedback ``command`` x the assistance of the current move's direction;
    ``reference``/``measurement`` in deg; the assistance per direction as outputs."""

    inputs = ("command", "measurement", "dt_s")
    discrete_states = ASSIST_STATES
    outputs = ("demand", "assist_open", "assist_close")
    params = ASSIST_PARAMS
    feedthrough = ("command",)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        _, _, opening = _phase(xd[0], p)
        y[0] = (xd[1] if opening or p[15] > 0.5 else xd[2]) * u[0]
        y[1] = xd[1]
        y[2] = xd[2]

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        for i in range(len(xd)):
            xd_next[i] = xd[i]
        k, ph, _ = _phase(xd[0], p)
        xd_next[0] = xd[0] + u[2]
        if k < 0:
            return
        move, hold_open, window = p[2], p[3], p[7]
        close_start = move + hold_open
        if ph <= move + window and abs(u[1] - p[1]) <= p[6]:
            xd_next[3] = 1.0
            if ph <= move + 0.5 * window:
                xd_next[5] = 1.0
        if close_start <= ph <= close_start + move + window and abs(u[1] - p[0]) <= p[6]:
            xd_next[4] = 1.0
            if ph <= close_start + move + 0.5 * window:
                xd_next[6] = 1.0
        if ph > move + window and xd[7] < k + 0.5:  # the opening move of cycle k is over
            if p[13] > 0.5:
                xd_next[1] = _learn(xd[1], xd_next[3], xd_next[5], p)
            xd_next[3], xd_next[5], xd_next[7] = 0.0, 0.0, k + 1.0
        if ph > close_start + move + window and xd[8] < k + 0.5:
            if p[14] > 0.5:
                xd_next[2] = _learn(xd[2], xd_next[4], xd_next[6], p)
            xd_next[4], xd_next[6], xd_next[8] = 0.0, 0.0, k + 1.0
