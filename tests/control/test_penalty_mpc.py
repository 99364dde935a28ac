"""Obstacle-penalty MPC baseline: polygons, the penalty term, closed loop, fallbacks."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest
from mpc_cases import ROBOT

from sanav_mj.control.base import Observation
from sanav_mj.control.penalty_mpc import ObstaclePenalty, PenaltyMPC, normalised_rows, obstacle_polygon
from sanav_mj.control.sa_mpc import MPCConfig
from sanav_mj.control.unicycle import step_np
from sanav_mj.scene import Obstacle


def _box(cx, cy, yaw, hx, hy, name="box"):
    return Obstacle(name, "box", np.array([cx, cy]), yaw, np.array([hx, hy]), 0.5, 0)


def _cyl(cx, cy, r):
    return Obstacle("cyl", "cylinder", np.array([cx, cy]), 0.0, np.array([r, r]), 0.5, 1)


def _inside(poly, pts):
    return np.all(poly[:, 2][None] - pts @ poly[:, :2].T >= -1e-12, axis=1)


@pytest.mark.parametrize("obs", [_box(1.0, 2.0, 0.7, 0.5, 0.2), _cyl(-1.0, 0.5, 0.3)])
def test_polygon_covers_the_inflated_obstacle(obs):
    rho = 0.25
    poly = obstacle_polygon(obs, rho)
    np.testing.assert_allclose(np.hypot(poly[:, 0], poly[:, 1]), 1.0)
    # points of the inflated footprint (obstacle grown by a disc of radius rho) are inside
    rng = np.random.default_rng(0)
    if obs.kind == "box":
        local = rng.uniform(-1, 1, (2000, 2)) * obs.half_size
        c, s = np.cos(obs.yaw), np.sin(obs.yaw)
        base = local @ np.array([[c, -s], [s, c]]).T + obs.center
    else:
        ang = rng.uniform(0, 2 * np.pi, 2000)
        base = obs.center + obs.half_size[0] * np.column_stack((np.cos(ang), np.sin(ang)))
    ang = rng.uniform(0, 2 * np.pi, 2000)
    pts = base + rho * np.column_stack((np.cos(ang), np.sin(ang)))
    assert _inside(poly, pts).all()
    assert not _inside(poly, obs.center[None] + np.array([[3.0, 0.0]])).any()


def test_penalty_matches_numpy_and_is_zero_outside():
    pen = ObstaclePenalty(2, 8)
    poly_a = obstacle_polygon(_box(0.0, 0.0, 0.3, 0.5, 0.5), 0.1)
    theta = np.zeros((2, pen.slot_size))
    rows = np.tile([0.0, 0.0, 1.0], (8, 1))
    rows[:4] = poly_a
    theta[0, :-1], theta[0, -1] = rows.ravel(), 100.0
    theta[1, :-1] = obstacle_polygon(_cyl(3.0, 0.0, 0.4), 0.1).ravel()
    theta[1, -1] = 50.0
    p = cs.SX.sym("p", 2)
    th = cs.SX.sym("th", pen.n_params)
    f = cs.Function("f", [p, th], [pen.expr(p, th)])
    for pt in np.random.default_rng(1).uniform(-1.5, 4.5, (300, 2)):
        want = pen.value_np(pt, theta.ravel())
        assert float(f(pt, theta.ravel())) == pytest.approx(want, rel=1e-9, abs=1e-12)
        inside = _inside(poly_a, pt[None])[0] or _inside(theta[1, :-1].reshape(8, 3), pt[None])[0]
        if not inside:
            assert want == 0.0
    # at the centre of the box every edge is 0.5 + 0.1 m away: 100 * (0.6^2)^4
    assert pen.value_np(np.zeros(2), theta.ravel()) == pytest.approx(100 * 0.6**8, rel=1e-12)
    # inside, the gradient points towards the nearest way out (here: the bottom edge)
    g = cs.Function("g", [p, th], [cs.gradient(pen.expr(p, th), p)])
    theta_axis = theta.copy()
    theta_axis[0, :12] = obstacle_polygon(_box(0.0, 0.0, 0.0, 0.5, 0.5), 0.1).ravel()
    grad = np.array(g([0.0, -0.3], theta_axis.ravel())).ravel()
    assert grad[1] > 0 and abs(grad[0]) < 1e-12  # descent moves down, out through y = -0.6


def _run(ctl, start, goal, steps=300):
    x = np.asarray(start, float)
    ctl.reset(x)
    path = [x[:2].copy()]
    for k in range(steps):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=np.zeros(2)))
        assert np.isfinite(cmd.v) and np.isfinite(cmd.w)
        x = step_np(x, [0.95 * cmd.v, 1.05 * cmd.w], 0.1)
        path.append(x[:2].copy())
        if np.hypot(*(x[:2] - goal)) < 0.05 and abs(cmd.v) < 0.05:
            return True, np.array(path)
    return False, np.array(path)


def test_drives_around_an_obstacle_off_the_straight_line():
    obs = [_box(2.5, 0.5, 0.0, 0.4, 0.4)]  # inflated, it overlaps the straight line by 0.25 m
    goal = np.array([5.0, 0.0])
    ctl = PenaltyMPC(ROBOT, obs, 0.35, goal, MPCConfig())
    ok, path = _run(ctl, [0.0, 0.0, 0.0], goal)
    assert ok and ctl.failures == 0
    poly = obstacle_polygon(obs[0], 0.35)
    depth = np.min(poly[:, 2][None] - path @ poly[:, :2].T, axis=1)
    assert depth.max() < 0.1  # a shallow penetration of the inflated polygon (soft cost), far from contact
    assert path[:, 1].min() < -0.2  # it went around below the box


def test_stalls_in_front_of_an_obstacle_far_across_the_line():
    # the documented weakness of the baseline: a local minimum in front of the obstacle
    obs = [_box(2.5, 0.25, 0.0, 0.4, 0.4)]
    goal = np.array([5.0, 0.0])
    ctl = PenaltyMPC(ROBOT, obs, 0.35, goal, MPCConfig())
    ok, path = _run(ctl, [0.0, 0.0, 0.0], goal, steps=80)
    assert not ok and path[-1, 0] < 1.8


def test_injected_failures_fall_back_then_recover():
    goal = np.array([3.0, 0.0])
    ctl = PenaltyMPC(ROBOT, [], 0.3, goal, MPCConfig(), failure_injector=lambda k: 5 <= k < 8)
    x = np.zeros(3)
    ctl.reset(x)
    statuses = []
    for k in range(12):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=np.zeros(2)))
        statuses.append(cmd.status)
        x = step_np(x, [cmd.v, cmd.w], 0.1)
    assert statuses[5:8] == ["fallback_shift"] * 3 and statuses[8] == "ok"
    assert ctl.failures == 3


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="inflation"):
        PenaltyMPC(ROBOT, [], -1.0, np.zeros(2))
    with pytest.raises(ValueError, match="goal"):
        PenaltyMPC(ROBOT, [], 0.3, np.array([np.nan, 0.0]))


def test_normalised_rows_scale_by_the_inradius():
    poly = obstacle_polygon(_box(1.0, 1.0, 0.0, 0.5, 0.2), 0.1)  # inradius 0.3 about the centre
    np.testing.assert_allclose(normalised_rows(poly, np.array([1.0, 1.0])), poly / 0.3)
    circle = obstacle_polygon(_cyl(2.0, -1.0, 0.4), 0.1)
    np.testing.assert_allclose(normalised_rows(circle, np.array([2.0, -1.0])), circle / 0.5)
