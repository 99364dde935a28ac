"""Reachable-position bounds (sanav_mj.control.reach) and the SA-MPC step that skips a solve
they prove infeasible."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sanav_mj.control.base import Observation
from sanav_mj.control.reach import position_intervals, unreachable_stage
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig
from sanav_mj.control.unicycle import rollout_np

from mpc_cases import ROBOT


def test_intervals_contain_every_rollout_within_the_bounds():
    rng = np.random.default_rng(3)
    n, dt = 20, 0.1
    for _ in range(50):
        x0 = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi)])
        a = rng.uniform([-0.5, -4.0], [2.0, 4.0], (n, 2))
        b = rng.uniform([-0.5, -4.0], [2.0, 4.0], (n, 2))
        lb, ub = np.minimum(a, b), np.maximum(a, b)
        for frame in (0.0, float(x0[2])):
            lo, hi = position_intervals(x0, lb.ravel(), ub.ravel(), dt, frame)
            c, s = np.cos(frame), np.sin(frame)
            for t in np.linspace(0.0, 1.0, 5):
                corner = rng.integers(0, 2, (n, 2))  # extreme and interior inputs
                u = np.where(corner, lb + t * (ub - lb), ub - t * (ub - lb))
                d = rollout_np(x0, u, dt)[1:, :2] - x0[:2]
                q = np.stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]), axis=1)
                tol = 1e-12 * (1 + np.abs(q))
                assert np.all(q >= lo - tol) and np.all(q <= hi + tol)


def test_straight_braking_exact_answer():
    # v_k in [1 - 0.1 (k+1), 1], w = 0: heading +x, travel after k steps >= sum of the lows
    n, dt = 10, 0.1
    v_lo = np.maximum(1.0 - 0.1 * np.arange(1, n + 1), 0.0)
    lb = np.stack((v_lo, np.zeros(n)), axis=1).ravel()
    ub = np.stack((np.ones(n), np.zeros(n)), axis=1).ravel()
    x0 = np.array([0.0, 0.0, 0.0])
    lo, hi = position_intervals(x0, lb, ub, dt, 0.0)
    assert lo[:, 0] == pytest.approx(np.cumsum(v_lo) * dt, abs=1e-12)
    assert hi[:, 0] == pytest.approx(np.arange(1, n + 1) * dt, abs=1e-12)
    assert np.all(np.abs(lo[:, 1]) < 1e-15) and np.all(np.abs(hi[:, 1]) < 1e-15)  # sin(0) via cos(-pi/2)
    stop = float(np.sum(v_lo) * dt)  # 0.45 m: the shortest stop
    box = lambda x_hi: (np.tile([-1.0, -1.0], n), np.tile([x_hi, 1.0], n))
    assert unreachable_stage(x0, lb, ub, *box(stop + 1e-3), dt, 1e-6) is None
    # the box ends short of the stop: the first stage whose shortest travel passes its end
    k = unreachable_stage(x0, lb, ub, *box(0.30), dt, 1e-6)
    assert k == int(np.argmax(np.cumsum(v_lo) * dt > 0.30 + 1e-6)) + 1
    # the same along a rotated heading (both pairs of axes are checked)
    th = 0.7
    rot = np.array([np.cos(th), np.sin(th)])
    x1 = np.array([0.0, 0.0, th])
    end = 0.30 * rot
    b_lo, b_hi = np.minimum(end, 0) - 0.05, np.maximum(end, 0) + 0.05
    assert unreachable_stage(x1, lb, ub, np.tile(b_lo, n), np.tile(b_hi, n), dt, 1e-6) is not None
    with pytest.raises(ValueError, match="2N"):
        unreachable_stage(x0, lb[:-2], ub, *box(1.0), dt, 1e-6)


def _fast_towards_the_wall(reach_check: bool, x_start: float):
    """SA-MPC in one box [0, 4] x [0, 1], robot at (x_start, 0.5) heading -x at 1.5 m/s."""
    from mpc_cases import make_areas, make_plan

    areas = make_areas([[0.0, 0.0, 4.0, 1.0]])
    plan = make_plan(areas, [0], [[0.5, 0.5], [3.5, 0.5]])
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(reach_check=reach_check))
    x = np.array([x_start, 0.5, np.pi])
    ctl.reset(x, u_prev=np.array([1.5, 0.0]), opening_turn=False)
    calls = []
    real = ctl.backend.solve
    ctl.backend.solve = lambda *a, **k: calls.append(1) or real(*a, **k)
    cmd = ctl.step(Observation(t=0.0, pose=x, velocity=np.array([1.5, 0.0])))
    return ctl, cmd, len(calls)


def test_step_that_cannot_stop_in_its_box_brakes_without_a_solve():
    # 0.45 m to the wall, ~0.8 m needed to stop from 1.5 m/s at 1.5 m/s^2: infeasible
    ctl, cmd, solves = _fast_towards_the_wall(True, 0.45)
    assert solves == 0 and ctl.unreachable == 1
    assert cmd.status == "fallback_stop" and not cmd.ok
    assert ctl.last_failure_reason.startswith("unreachable:stage=")
    # without the check the solver runs, is rejected, and the same braking command follows
    ref, cmd_ref, solves_ref = _fast_towards_the_wall(False, 0.45)
    assert solves_ref == 1 and ref.unreachable == 0
    assert cmd_ref.status == "fallback_stop" and ref.last_failure_reason.startswith("rejected")
    assert (cmd.v, cmd.w) == (cmd_ref.v, cmd_ref.w)
    assert np.array_equal(cmd.predicted, cmd_ref.predicted)


def test_step_with_room_to_stop_is_solved():
    ctl, cmd, solves = _fast_towards_the_wall(True, 3.5)
    assert solves == 1 and ctl.unreachable == 0


def test_reach_check_must_be_a_bool():
    with pytest.raises(ValueError, match="reach_check"):
        MPCConfig(reach_check=1)
    assert replace(MPCConfig(), reach_check=True).reach_check
