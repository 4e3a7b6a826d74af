"""Assistance learned across open-close cycles, per direction: the assist-as-needed scale.

One sampled part reads the reference's phase from its own clock (device time, ``dt_s``), watches
whether the angle reaches each move's target in time, and once per move updates that direction's
assistance ``a`` (0..1): an error-based update with a forgetting factor (Emken, Benitez & Reinkensmeyer
2007: F <- f_R F + g_R e) whose error is the move's outcome against a target success rate T, as FINGER
holds one (Taheri et al. 2014; Rowe et al. 2017). Two numbers per direction: the level ``b``, which
follows the success-rate rule alone, and the assistance applied, ``a`` <= ``b``, which also forgets:

    failed move:   b <- b + gain x T;            a <- b  (what was forgotten is given back; streak 0)
    success:       b <- b - gain x (1 - T);      a <- a - gain x (1 - T)
                   with margin, in a run of more than T / (1 - T) successes: a <- (1 - forgetting) a first

The level's expected step is gain x (T - p) at a success rate p, and over any run of moves
sum(T - s) = (b_end - b_start) / gain: while the level stays inside its bounds the long-run success
rate IS the target, for a patient whose success is certain at a given assistance or a chance that
grows with it, whatever the forgetting. The forgetting lets a patient who does better than the target
(T / (1 - T) successes per failure at T: 4 at 0.8) show they can do with less, faster than the
level's steps (faster than a slacking patient relearns to rely on it: Emken et al. 2007); a failure
says they could not, and the assistance returns to the level. The first version forgot after every
success with margin and had nothing to return: a patient at the assistance they need succeeds with
margin too, and the update's equilibrium sat at 75-78 % of moves against its own 80 % (the SMA
exoskeleton's bends, issue 48). "With margin": reached by the end of the planned move plus half the
success window.

The feedback command is scaled by the assistance of the current move's direction. ``headroom``: the
top share of the range is integral action (Wolbrecht et al. 2008's adaptive assistance learns the
patient's weakness as a force from the integrated tracking error; here one such force per move):

    a <= 1 - headroom:  demand = a / (1 - headroom) x command
    a >  1 - headroom:  demand = command + (a - (1 - headroom)) / headroom x ki x integral(reference - angle)

the integral restarting at each move (the opening move's resisting torque is not the closing move's) and
integrating in the hold after the planned move only, where the reference stands still and the error left
is the patient's steady resisting torque over the feedback's stiffness (during the move it is the lag of
a ramp, the feedback's business: integrated there it wound up and carried the Finger Extensor's iris past
its range at the end of the move), frozen where the effort limit cuts the demand (anti-windup). Without
it full assistance was the PD alone, whose steady error against a stiff flexed finger (the severe
patients on the Finger Extensor: 11-28 deg) stayed outside the success tolerance with nothing left to
learn. An actuator that pulls one way (``one_way``: an SMA wire, a TCP muscle) has one assistance, the
opening move's (the direction it pulls): it scales each of its pulls, in the closing move and the closed
hold too (a finger one encoder count past the closed target drew the full pull there, cycle after
cycle); its integral acts in the opening move's hold only (the release is the spring's and the patient's).
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["ASSIST_PARAMS", "ASSIST_STATES", "AssistScale", "assist_step", "streak_moves"]

ASSIST_PARAMS = ("closed", "opened", "move_s", "hold_open_s", "hold_closed_s", "first_open_s", "tolerance",
                 "window_s", "gain", "forgetting", "target_success", "min_assistance", "max_assistance",
                 "learn_open", "learn_close", "one_way", "streak_moves", "headroom", "ki")
ASSIST_STATES = ("t_s", "assist_open", "assist_close", "reached_open", "reached_close", "early_open", "early_close",
                 "done_open", "done_close", "streak_open", "streak_close", "integral", "integral_move", "level_open",
                 "level_close")


def streak_moves(target_success: float) -> float:
    """The successes per failure at the target rate, T / (1 - T): a longer run of successes is a patient
    doing better than the target (the forgetting's gate)."""
    return target_success / (1.0 - target_success)


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
def assist_step(a, b, streak, reached, early, gain, forgetting, target, streak_gate, lo, hi):
    """One direction's (next assistance, next level, next streak) after one move: see the module docstring.
    A level below 0 is not set yet: the session's first move starts it at the assistance (the config's
    initial one, or the one a kept store started the session from)."""
    if b < 0.0:
        b = a
    if reached < 0.5:
        b = b + gain * target
        a = b
        streak = 0.0
    else:
        streak = streak + 1.0
        if early > 0.5 and streak > streak_gate + 1e-9:
            a = (1.0 - forgetting) * a
        a = a - gain * (1.0 - target)
        b = b - gain * (1.0 - target)
    b = min(max(b, lo), hi)
    return min(max(a, lo), b), b, streak


@njit
def _scales(a, p, opening):
    """(the feedback's scale, the integral's scale) at assistance ``a``."""
    h = p[17]
    if h <= 0.0:
        return a, 0.0
    knee = 1.0 - h
    if a <= knee:
        return a / knee, 0.0
    return 1.0, (min(a, 1.0) - knee) / h if (opening or p[15] < 0.5) else 0.0


@njit
def _move_index(k, opening):
    """The move the sample belongs to (its opening move and hold, or its closing move and hold)."""
    return 2.0 * k + (0.0 if opening else 1.0)


class AssistScale(Part):
    """``demand`` = the feedback ``command`` x the assistance of the current move's direction, plus
    the headroom's integral; ``reference``/``measurement`` in deg; the assistance per direction as outputs."""

    inputs = ("command", "measurement", "dt_s", "reference", "saturation")
    discrete_states = ASSIST_STATES
    outputs = ("demand", "assist_open", "assist_close")
    params = ASSIST_PARAMS
    feedthrough = ("command",)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        k, _, opening = _phase(xd[0], p)
        a = xd[1] if opening or p[15] > 0.5 else xd[2]
        fb, ib = _scales(a, p, opening)
        integral = xd[11] if xd[12] == _move_index(k, opening) else 0.0  # a new move's integral starts at 0
        y[0] = fb * u[0] + ib * p[18] * integral
        y[1] = xd[1]
        y[2] = xd[2]

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        for i in range(len(xd)):
            xd_next[i] = xd[i]
        k, ph, opening = _phase(xd[0], p)
        xd_next[0] = xd[0] + u[2]
        move = _move_index(k, opening)
        if xd[12] != move:
            xd_next[11], xd_next[12] = 0.0, move
        move_s, hold_open, window = p[2], p[3], p[7]
        close_start = move_s + hold_open
        _, ib = _scales(xd[1] if opening or p[15] > 0.5 else xd[2], p, opening)
        e = u[3] - u[1]
        holding = k < 0 or (move_s <= ph < close_start) or ph >= close_start + move_s
        if ib > 0.0 and holding and not ((u[4] > 0.0 and e > 0.0) or (u[4] < 0.0 and e < 0.0)):
            xd_next[11] = xd_next[11] + e * u[2]
        if k < 0:
            return
        if ph <= move_s + window and abs(u[1] - p[1]) <= p[6]:
            xd_next[3] = 1.0
            if ph <= move_s + 0.5 * window:
                xd_next[5] = 1.0
        if close_start <= ph <= close_start + move_s + window and abs(u[1] - p[0]) <= p[6]:
            xd_next[4] = 1.0
            if ph <= close_start + move_s + 0.5 * window:
                xd_next[6] = 1.0
        if ph > move_s + window and xd[7] < k + 0.5:  # the opening move of cycle k is over
            if p[13] > 0.5:
                xd_next[1], xd_next[13], xd_next[9] = assist_step(xd[1], xd[13], xd[9], xd_next[3], xd_next[5], p[8],
                                                                  p[9], p[10], p[16], p[11], p[12])
            xd_next[3], xd_next[5], xd_next[7] = 0.0, 0.0, k + 1.0
        if ph > close_start + move_s + window and xd[8] < k + 0.5:
            if p[14] > 0.5:
                xd_next[2], xd_next[14], xd_next[10] = assist_step(xd[2], xd[14], xd[10], xd_next[4], xd_next[6], p[8],
                                                                   p[9], p[10], p[16], p[11], p[12])
            xd_next[4], xd_next[6], xd_next[8] = 0.0, 0.0, k + 1.0
