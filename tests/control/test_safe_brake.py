"""The braking fallback held inside the safe areas (:mod:`sanav_mj.control.safe_brake`) and the
lidar ``"discs"`` mode's use of it (:class:`~sanav_mj.control.sensed_footprint.StraightBrakeSAMPC`)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from mpc_cases import ROBOT

from sanav_mj.control.config import MPCConfig
from sanav_mj.control.footprint import disc_centres
from sanav_mj.control.safe_brake import choose_brake, rect_slack
from sanav_mj.control.sensed_footprint import StraightBrakeSAMPC
from sanav_mj.control.tracking import ActivePlan, brake_inputs
from sanav_mj.control.unicycle import rollout_np
from sanav_mj.footprint import Footprint
from sanav_mj.mapping.safe_areas import SafeAreas

EPS = np.finfo(float).eps
BODY = Footprint(-0.25, 0.25, -0.2, 0.2)  # three discs along x: centres at x = -1/6, 0, +1/6 m
OFFSETS = np.array([[-1 / 6, 0.0], [0.0, 0.0], [1 / 6, 0.0]])
RATE = np.array([1.5, 4.0]) * 0.1  # [m/s, rad/s] per step: a_max 1.5 m/s^2, alpha_max 4 rad/s^2, dt 0.1 s
# the safe area of the tests: the straight stop from 0.9 m/s covers 0.1 (0.75 + 0.6 + 0.45 + 0.3
# + 0.15) = 0.225 m, so the front centre ends at 0.225 + 1/6 = 0.39167 m, past xmax = 0.37
BOX = np.array([[-0.2, -0.15, 0.37, 0.2]])


def _areas(rects) -> SafeAreas:
    rects = np.asarray(rects, dtype=float)
    return SafeAreas(rects, np.zeros((0, 2), dtype=np.int64), np.zeros(0), np.zeros((0, 2, 2)))


def test_rect_slack_is_the_deepest_box_edge_distance():
    rects = np.array([[0.0, 0.0, 1.0, 1.0], [1.0, 0.0, 3.0, 0.5]])
    pts = np.array([[0.5, 0.5], [2.0, 0.25], [1.0, 0.9], [3.5, 0.25], [-0.3, 2.0]])
    # centre of the square 0.5; middle of the strip 0.25; on the square's edge 0; 0.5 beyond the
    # strip's end; outside both: the square is 0.3 off in x, 1 off in y -> -1 (the larger axis)
    np.testing.assert_allclose(rect_slack(pts, rects), [0.5, 0.25, 0.0, -0.5, -1.0], rtol=0, atol=4 * EPS)
    assert np.all(rect_slack(pts, np.zeros((0, 4))) == -np.inf)


def test_choose_brake_takes_the_first_candidate_inside_else_the_least_outside():
    x0 = np.zeros(3)
    straight = brake_inputs(np.array([0.9, 0.0]), RATE, 20, 0.0)
    turn = brake_inputs(np.array([0.9, 0.0]), RATE, 20, 2.0)
    out = choose_brake(x0, [("straight", straight), ("turn", turn)], OFFSETS, BOX, 0.1, 1e-9)
    assert out.name == "turn" and out.inside and out.u is turn
    # the straight stop: the front centre 0.37 - (0.225 + 1/6) m outside, exactly (w = 0: the
    # rollout adds the steps along x; numbers below 1 m, 20 additions)
    assert abs(out.scores[0] - (0.37 - (0.225 + 1 / 6))) <= 32 * EPS
    # the turning one, checked against its own rollout (the reference): inside, 9.0 mm clear
    xs = rollout_np(x0, turn, 0.1)
    ref = rect_slack(disc_centres(xs[1:], OFFSETS).reshape(-1, 2), BOX).min()
    assert out.slack == ref and 0.0 < ref < 0.01
    # straight first when it fits (a longer box)
    long = choose_brake(x0, [("straight", straight), ("turn", turn)], OFFSETS, BOX + [0, 0, 0.1, 0], 0.1, 1e-9)
    assert long.name == "straight" and long.inside
    # nothing fits (a box 0.3 m long): the first candidate (otherwise=0), flagged; or, asked
    # for, the least outside
    short = BOX - [0, 0, 0.07, 0]
    none = choose_brake(x0, [("straight", straight), ("turn", turn)], OFFSETS, short, 0.1, 1e-9)
    assert not none.inside and none.name == "straight" and none.slack == none.scores[0] < max(none.scores) < 0
    least = choose_brake(x0, [("straight", straight), ("turn", turn)], OFFSETS, short, 0.1, 1e-9, otherwise=None)
    assert not least.inside and least.name == "turn" and least.slack == max(least.scores)
    with pytest.raises(ValueError, match="otherwise"):
        choose_brake(x0, [("straight", straight)], OFFSETS, short, 0.1, 1e-9, otherwise=1)
    # within the tolerance counts as inside
    tol = choose_brake(x0, [("straight", straight)], OFFSETS, BOX, 0.1, 0.022)
    assert tol.inside and tol.name == "straight"
    with pytest.raises(ValueError, match="at least one"):
        choose_brake(x0, [], OFFSETS, BOX, 0.1, 0.0)


@pytest.fixture(scope="module")
def brake_mpc():
    """A lidar-mode discs SA-MPC on a straight corridor (its plan is not used by the brake)."""
    from mpc_cases import make_areas, make_plan

    areas = make_areas([[-1.0, -1.0, 4.0, 1.0]])
    plan = make_plan(areas, [0], [[0.0, 0.0], [3.0, 0.0]])
    return StraightBrakeSAMPC(ROBOT, areas, plan, MPCConfig(footprint="discs", alpha_max=4.0), footprint=BODY)


def _prob(ctl, lb=-np.inf, ub=np.inf):
    n = ctl.N
    return SimpleNamespace(fb_lb=np.full(2 * n, lb), fb_ub=np.full(2 * n, ub))


def _at(ctl, u_prev, active=None, free=BOX):
    ctl.reset(np.zeros(3), u_prev=np.asarray(u_prev, dtype=float))
    np.testing.assert_array_equal(ctl.rate_step, RATE)
    ctl._active = active
    ctl.last_brake = None
    ctl.free_areas = None if free is None else (lambda: _areas(free))
    return ctl


def test_lidar_brake_follows_the_last_plan_when_the_straight_stop_leaves(brake_mpc):
    """At 0.9 m/s in a box whose end the straight stop passes (front centre 2.2 cm out), the
    last accepted plan (turning left while braking) is followed instead: every centre inside."""
    turn = brake_inputs(np.array([0.9, 0.0]), RATE, 20, 2.0)
    plan = np.vstack(([0.9, 0.0], turn[:-1]))  # its first input (0.9, 0) was applied at the last step
    ctl = _at(brake_mpc, [0.9, 0.0], ActivePlan(plan, 1))
    u = ctl.brake_plan(np.zeros(3), _prob(ctl))
    np.testing.assert_array_equal(u, turn)  # the rest of the plan, padded with the rest at (0, 0)
    assert ctl.last_brake.name == "kept" and ctl.last_brake.inside
    assert ctl.stats.counts == {"brake_kept": 1}
    assert abs(ctl.last_brake.scores[0] - (0.37 - (0.225 + 1 / 6))) <= 32 * EPS  # the straight one
    # what the unchecked straight brake did (main before h16brake): the front centre leaves
    np.testing.assert_array_equal(ctl.straight_inputs(), brake_inputs(np.array([0.9, 0.0]), RATE, 20, 0.0))


def test_lidar_brake_steers_without_a_plan_and_brakes_straight_when_it_fits(brake_mpc):
    # no plan to keep: the first steering candidate inside (yaw rate towards +w_max / 2)
    ctl = _at(brake_mpc, [0.9, 0.0])
    u = ctl.brake_plan(np.zeros(3), _prob(ctl))
    wm = ctl.limits.w_max
    np.testing.assert_array_equal(u, brake_inputs(np.array([0.9, 0.0]), RATE, 20, 0.5 * wm))
    assert ctl.last_brake.name == "steer" and ctl.last_brake.inside
    # a plan outside this step's input bounds is not kept (a speed cap of 0.5 m/s)
    turn = brake_inputs(np.array([0.9, 0.0]), RATE, 20, 2.0)
    ctl = _at(brake_mpc, [0.9, 0.0], ActivePlan(np.vstack(([0.9, 0.0], turn[:-1])), 1))
    assert ctl.kept_inputs(_prob(ctl, ub=0.5)) is None and ctl.kept_inputs(None) is None
    # nor one whose increments exceed this step's rate bounds (the traction limit lowered a_max)
    assert ctl.kept_inputs(_prob(ctl)) is not None
    ctl._set_accel(1.0)
    assert ctl.kept_inputs(_prob(ctl)) is None
    ctl._set_accel(ctl.limits.a_max)
    assert ctl.brake_plan(np.zeros(3), _prob(ctl, ub=0.5)) is ctl.last_brake.u
    assert ctl.last_brake.name == "steer"
    # room for the straight stop: straight, as before
    ctl = _at(brake_mpc, [0.9, 0.0], ActivePlan(np.vstack(([0.9, 0.0], turn[:-1])), 1), BOX + [0, 0, 0.1, 0])
    np.testing.assert_array_equal(ctl.brake_plan(np.zeros(3), _prob(ctl)), ctl.straight_inputs())
    assert ctl.stats.counts == {"brake_straight": 1}


def test_lidar_brake_brakes_straight_when_nothing_stays_inside_or_without_areas(brake_mpc):
    ctl = _at(brake_mpc, [0.9, 0.0], free=BOX - [0, 0, 0.07, 0])  # 0.3 m: no stop from 0.9 m/s fits
    u = ctl.brake_plan(np.zeros(3), _prob(ctl))
    assert not ctl.last_brake.inside and ctl.stats.counts == {"brake_straight": 1, "brake_outside": 1}
    np.testing.assert_array_equal(u, ctl.straight_inputs())  # straight, as before the check
    # without the current safe areas (no sensing loop): the straight brake, unchecked
    ctl = _at(brake_mpc, [0.9, 0.0], free=None)
    np.testing.assert_array_equal(ctl.brake_plan(np.zeros(3), _prob(ctl)), ctl.straight_inputs())
    assert ctl.last_brake is None and ctl.stats.counts == {}


def test_fallback_hands_the_problem_to_the_brake(brake_mpc):
    """A rejected step of :meth:`TrackingMPC._fallback` without a fitting shift brakes with the
    step's problem: the kept plan is applied (status ``fallback_stop``), and becomes the plan."""
    import time

    turn = brake_inputs(np.array([0.9, 0.0]), RATE, 20, 2.0)
    ctl = _at(brake_mpc, [0.9, 0.0], ActivePlan(np.vstack(([0.9, 0.0], turn[:-1])), 1, brake=True))
    cmd = ctl._fallback(np.zeros(3), time.perf_counter(), None, "test", _prob(ctl))
    assert cmd.status == "fallback_stop" and ctl.last_brake.name == "kept"
    assert (cmd.v, cmd.w) == (turn[0, 0], turn[0, 1])
    np.testing.assert_array_equal(ctl._active.u, turn)
