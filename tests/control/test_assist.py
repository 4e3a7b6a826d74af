"""The assist-as-needed scale alone: its update rule (the fixed point is the target success rate, the
assistance rises after failures and never leaves its bounds, it forgets only in a run of successes
longer than the target allows), the assistance per direction over whole cycles, and the headroom's
integral action."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.control.assist import AssistScale, assist_step, streak_moves
from rehab_hil.control.trajectories import open_close_reference
from rehab_hil.models.system import Diagram

DT = 0.01
CLOSED, OPEN, MOVE, HOLD = 10.0, 110.0, 3.0, 3.0
PERIOD = 2 * MOVE + 2 * HOLD
INPUTS = ("command", "measurement", "dt_s", "reference", "saturation")
GAIN, FORGET = 0.2, 0.3


def _rule(a, b, streak, reached, early=False, target=0.8, gain=GAIN, forgetting=FORGET, lo=0.0, hi=1.0):
    """(assistance, level, streak) after one move."""
    return assist_step(a, b, streak, 1.0 if reached else 0.0, 1.0 if early else 0.0, gain, forgetting, target,
                       streak_moves(target), lo, hi)


def _long_run(patient, target, moves=4000, a=1.0):
    """The success rate of a patient (``patient(a, k)``: (reached, early)) under the update, its first
    200 moves left out; and the assistance each move."""
    b, streak, hits, seen = -1.0, 0.0, [], []
    for k in range(moves):
        reached, early = patient(a, k)
        hits.append(reached)
        seen.append(a)
        a, b, streak = _rule(a, b, streak, reached, early, target=target)
    return float(np.mean(hits[200:])), np.array(seen)


# --- the update rule -----------------------------------------------------------------------------------


@pytest.mark.parametrize("target", [0.6, 0.8, 0.9])
@pytest.mark.parametrize("needed", [0.15, 0.42, 0.77])
def test_the_fixed_point_is_the_target_success_rate_for_a_patient_who_needs_a_given_assistance(target, needed):
    # succeeds whenever the assistance is at least what they need, with margin well above it
    rate, _ = _long_run(lambda a, k: (a >= needed, a >= needed + 0.05), target)
    assert rate == pytest.approx(target, abs=0.01)


@pytest.mark.parametrize("target", [0.7, 0.8, 0.9])
def test_the_fixed_point_is_the_target_success_rate_for_a_patient_who_varies(target):
    # a patient whose success is a chance that grows with the assistance (the variability of real moves)
    rng = np.random.default_rng(4)

    def patient(a, k):
        p = 1.0 / (1.0 + np.exp(-(a - 0.5) / 0.08))
        ok = bool(rng.random() < p)
        return ok, ok and rng.random() < 0.5

    rate, _ = _long_run(patient, target, moves=20000)
    assert rate == pytest.approx(target, abs=0.02)


def test_the_first_update_forgot_on_every_success_with_margin_and_held_below_its_target():
    # the rule this one replaced: a success with margin also forgot a tenth; its equilibrium sat below the target
    def old(a, reached, early, gain=0.4, forgetting=0.1, target=0.8):
        if not reached:
            return min(a + gain * target, 1.0)
        return max((1.0 - forgetting) * a if early else a, 0.0) - gain * (1.0 - target)

    a, hits = 1.0, []
    for _ in range(2000):
        ok = a >= 0.5
        hits.append(ok)
        a = max(old(a, ok, ok), 0.0)
    assert np.mean(hits[100:]) < 0.78  # (0.75 here)
    rate, _ = _long_run(lambda a, k: (a >= 0.5, a >= 0.5), 0.8)
    assert rate == pytest.approx(0.8, abs=0.01)


def test_the_assistance_rises_after_failures_and_stops_at_its_ceiling():
    a, b, streak = _rule(0.3, 0.3, 3.0, reached=False)
    assert a == b == pytest.approx(0.3 + GAIN * 0.8) and streak == 0.0
    seen = [a]
    for _ in range(10):
        a, b, streak = _rule(a, b, streak, reached=False)
        seen.append(a)
    assert np.all(np.diff(seen) >= 0.0) and seen[-1] == 1.0


def test_a_failure_gives_back_what_the_run_of_successes_forgot():
    a, b, streak = 1.0, 1.0, 0.0
    for _ in range(8):
        a, b, streak = _rule(a, b, streak, reached=True, early=True)
    assert b == pytest.approx(1.0 - 8 * GAIN * 0.2) and a < b - 0.1  # forgot beyond the level's steps
    a, b, streak = _rule(a, b, streak, reached=False)
    assert a == b == pytest.approx(1.0 - 8 * GAIN * 0.2 + GAIN * 0.8)


def test_the_assistance_never_leaves_its_bounds():
    rng = np.random.default_rng(7)
    for lo, hi in ((0.0, 1.0), (0.2, 0.9)):
        a, b, streak = hi, -1.0, 0.0
        for _ in range(5000):
            ok = bool(rng.random() < 0.7)
            a, b, streak = _rule(a, b, streak, ok, ok and rng.random() < 0.5, target=float(rng.uniform(0.5, 0.95)),
                                 gain=float(rng.uniform(0.01, 1.0)), forgetting=float(rng.uniform(0.0, 0.9)),
                                 lo=lo, hi=hi)
            assert lo <= a <= b <= hi


def test_it_forgets_only_in_a_run_of_successes_longer_than_the_target_allows():
    # at 0.8 a patient succeeds four times per failure: the fifth success in a row with margin forgets
    a, b, streak, seen = 1.0, 1.0, 0.0, []
    for _ in range(6):
        a, b, streak = _rule(a, b, streak, reached=True, early=True)
        seen.append(a)
    step = GAIN * 0.2
    assert seen[:4] == pytest.approx([1 - step, 1 - 2 * step, 1 - 3 * step, 1 - 4 * step])
    assert seen[4] == pytest.approx((1 - FORGET) * seen[3] - step)
    # without margin (reached late, in the window) it never forgets
    a, b, streak = 1.0, 1.0, 0.0
    for _ in range(6):
        a, b, streak = _rule(a, b, streak, reached=True, early=False)
    assert a == b == pytest.approx(1 - 6 * step)


def test_a_capable_patient_drives_the_assistance_to_nothing_and_a_tiring_one_raises_it():
    rate, seen = _long_run(lambda a, k: (True, True), 0.8, moves=300)
    assert rate == 1.0 and seen[12] < 0.1 and seen[-1] == 0.0
    # a patient who tires: the assistance they need grows from 0.2 to 0.8 over 200 moves
    need = lambda k: 0.2 + 0.6 * min(k, 200) / 200  # noqa: E731
    _, seen = _long_run(lambda a, k: (a >= need(k), a >= need(k) + 0.05), 0.8, moves=300)
    assert np.mean(seen[40:60]) < 0.5 < 0.8 <= np.mean(seen[220:260])


# --- the scale over whole cycles -----------------------------------------------------------------------


def _scale(**over):
    p = dict(closed=CLOSED, opened=OPEN, move_s=MOVE, hold_open_s=HOLD, hold_closed_s=HOLD, first_open_s=HOLD,
             tolerance=5.0, window_s=1.0, gain=0.4, forgetting=0.1, target_success=0.8, min_assistance=0.0,
             max_assistance=1.0, learn_open=1.0, learn_close=1.0, one_way=0.0, streak_moves=streak_moves(0.8),
             headroom=0.0, ki=0.0)
    p.update(over)
    a0 = p.pop("a0", 1.0)
    return AssistScale("assist", xd0=[0.0, a0, a0, 0, 0, 0, 0, 0, 0, 0, 0, 0, -2.0, -1.0, -1.0], **p)


def _ref(t):
    return np.array([open_close_reference(x + PERIOD - HOLD, CLOSED, OPEN, MOVE, HOLD, HOLD) for x in t])


def _run(part, measurement, n, reference=0.0, saturation=0.0):
    system = Diagram([part], inputs=INPUTS).compile(DT, 1)
    return system.simulate(n, {"command": 1.0, "measurement": measurement, "dt_s": DT, "reference": reference,
                               "saturation": saturation}, outputs=["demand", "assist_open", "assist_close"])


def test_moves_that_succeed_with_margin_fade_the_assistance_in_both_directions():
    n = int((HOLD + 12 * PERIOD) / DT)
    t = np.arange(n) * DT
    res = _run(_scale(), _ref(t), n)  # the angle follows the reference exactly
    assert res["assist_open"][-1] == 0.0 and res["assist_close"][-1] == 0.0
    # after the first cycle: 1 - 0.4 x 0.2 = 0.92 (no forgetting before a run longer than 4 successes)
    assert res["assist_open"][int((HOLD + PERIOD) / DT)] == pytest.approx(0.92)
    assert res["assist_open"][int((HOLD + 5 * PERIOD) / DT)] == pytest.approx(0.9 * 0.68 - 0.08)
    # the demand is the command scaled by the current direction's assistance
    assert np.all(res["demand"] <= 1.0)


def test_moves_that_fail_raise_the_assistance_to_its_ceiling():
    n = int((HOLD + 6 * PERIOD) / DT)
    res = _run(_scale(gain=0.2, a0=0.3), np.full(n, 50.0), n)  # never reaches either target
    assert res["assist_open"][-1] == 1.0 and res["assist_close"][-1] == 1.0
    assert res["assist_open"][int((HOLD + PERIOD) / DT)] == pytest.approx(0.3 + 0.2 * 0.8)


def test_an_unlearned_direction_keeps_its_assistance():
    n = int((HOLD + 8 * PERIOD) / DT)
    t = np.arange(n) * DT
    res = _run(_scale(learn_close=0.0), _ref(t), n)
    assert res["assist_close"][-1] == 1.0 and res["assist_open"][-1] < 0.5


def test_a_patient_who_needs_help_is_held_at_the_target_success_rate():
    # the patient reaches the opening target only when the assistance is at least 0.6 (a weak patient),
    # and then only late (no margin): the assistance settles where 80 % of moves succeed
    part = _scale(learn_close=0.0)
    system = Diagram([part], inputs=INPUTS).compile(DT, 1)
    step = system.stepper(["assist_open"])
    idx = {n: i for i, n in enumerate(system.input_names)}
    u = np.zeros(len(idx))
    u[idx["command"]], u[idx["dt_s"]] = 1.0, DT
    successes = []
    for _cycle in range(60):
        a = float(step.step(u)[0])
        reach = a >= 0.6
        successes.append(reach)
        for k in range(1, int(PERIOD / DT)):
            tc = (k * DT) - HOLD  # time into the cycle
            late = MOVE + 0.8  # reached after the planned move and half the window, inside the window
            at_open = reach and late <= tc % PERIOD <= MOVE + HOLD
            u[idx["measurement"]] = OPEN if at_open else CLOSED + 50.0
            step.step(u)
    rate = float(np.mean(successes[20:]))
    assert rate == pytest.approx(0.8, abs=0.02)


def test_an_actuator_that_pulls_one_way_scales_every_pull_by_its_one_assistance():
    n = int((HOLD + 4 * PERIOD) / DT)
    t = np.arange(n) * DT
    closing = (t > HOLD + 2 * PERIOD + MOVE + HOLD) & (t < HOLD + 3 * PERIOD)  # the third closing move and hold
    two = _run(_scale(learn_close=0.0), _ref(t), n)
    one = _run(_scale(learn_close=0.0, one_way=1.0), _ref(t), n)
    assert np.all(two["demand"][closing] == 1.0)  # a direction of its own, never learned
    assert np.allclose(one["demand"][closing], one["assist_open"][closing]) and one["demand"][closing].max() < 0.9


# --- the headroom: integral action once the feedback is at its full gains ------------------------------


def test_below_the_headroom_the_feedback_is_scaled_and_above_it_the_integral_adds_in_the_hold_only():
    n = int((HOLD + PERIOD) / DT)
    t = np.arange(n) * DT
    ref = _ref(t)
    short = ref - np.where(t >= HOLD, 2.0, 0.0)  # the angle 2 deg behind the reference from the first move on
    full = _run(_scale(headroom=0.25, ki=0.5, learn_open=0.0, learn_close=0.0), short, n, reference=ref)
    knee = _run(_scale(headroom=0.25, ki=0.5, learn_open=0.0, learn_close=0.0, a0=0.75), short, n, reference=ref)
    half = _run(_scale(headroom=0.25, ki=0.5, learn_open=0.0, learn_close=0.0, a0=0.375), short, n, reference=ref)
    assert np.allclose(knee["demand"], 1.0) and np.allclose(half["demand"], 0.5)  # the feedback alone, scaled
    moving = (t >= HOLD + 0.1) & (t < HOLD + MOVE)
    assert np.allclose(full["demand"][moving], 1.0)  # no integral during the move
    # in the opening hold the integral of the 2 deg error, x 0.5 per (deg s)
    i_end_hold = int((HOLD + MOVE + HOLD) / DT) - 2
    held = (i_end_hold - int((HOLD + MOVE) / DT)) * DT
    assert full["demand"][i_end_hold] == pytest.approx(1.0 + 0.5 * 2.0 * held, rel=0.02)
    # it restarts at the closing move
    closing = int((HOLD + MOVE + HOLD + 0.5) / DT)
    assert full["demand"][closing] == pytest.approx(1.0)


def test_the_headroom_integral_freezes_where_the_effort_limit_cuts_and_a_one_way_actuator_has_none_closing():
    n = int((HOLD + PERIOD) / DT)
    t = np.arange(n) * DT
    ref = _ref(t)
    short = ref - 2.0
    cut = _run(_scale(headroom=0.25, ki=0.5, learn_open=0.0, learn_close=0.0), short, n, reference=ref,
               saturation=1.0)
    assert np.allclose(cut["demand"], 1.0)  # the error pushes the way the limit already cuts: no windup
    one = _run(_scale(headroom=0.25, ki=0.5, learn_open=0.0, learn_close=0.0, one_way=1.0), short, n, reference=ref)
    closed_hold = (t > HOLD + 2 * MOVE + HOLD + 0.1)
    assert np.allclose(one["demand"][closed_hold], 1.0)  # the wire's release is the spring's: no integral
    assert one["demand"][int((HOLD + MOVE + HOLD) / DT) - 2] > 1.5
