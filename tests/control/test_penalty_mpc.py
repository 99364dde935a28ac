"""Obstacle-penalty MPC baseline: polygons, the penalty term, reference, closed loop, fallbacks."""

from __future__ import annotations

import math

import casadi as cs
import numpy as np
import pytest
from mpc_cases import ROBOT

from sanav_mj.control.base import Observation
from sanav_mj.control.penalty_mpc import (
    ObstaclePenalty,
    PenaltyConfig,
    PenaltyMPC,
    normalised_rows,
    obstacle_polygon,
)
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


@pytest.mark.parametrize("form", ["depth", "product"])
def test_penalty_matches_numpy_zero_outside_positive_inside(form):
    pen = ObstaclePenalty(3, 8, form)
    poly_a = obstacle_polygon(_box(0.0, 0.0, 0.3, 0.5, 0.5), 0.1)
    poly_b = obstacle_polygon(_cyl(3.0, 0.0, 0.4), 0.1)
    theta = np.zeros((3, pen.slot_size))
    theta[0, :-1], theta[0, -1] = poly_a.ravel(), 100.0
    theta[1, :-1], theta[1, -1] = poly_b.ravel(), 50.0
    theta[2, :-1] = np.tile(pen.pad_row(), 8)  # an unused slot (weight 0)
    p = cs.SX.sym("p", 2)
    th = cs.SX.sym("th", pen.n_params)
    f = cs.Function("f", [p, th], [pen.expr(p, th)])
    pts = np.random.default_rng(1).uniform(-1.5, 4.5, (300, 2))
    values = pen.values_np(pts, theta.ravel())
    inside = _inside(poly_a, pts) | _inside(poly_b, pts)
    assert 10 < inside.sum() < 290
    assert np.all(values[~inside] == 0.0) and np.all(values[inside] > 0.0)
    for pt, want in zip(pts, values):
        assert float(f(pt, theta.ravel())) == pytest.approx(want, rel=1e-9, abs=1e-12)
        assert pen.value_np(pt, theta.ravel()) == want
    # inside, the descent direction leads out through the nearest edge (here: the bottom one)
    g = cs.Function("g", [p, th], [cs.gradient(pen.expr(p, th), p)])
    theta_axis = theta.copy()
    theta_axis[0, :-1] = obstacle_polygon(_box(0.0, 0.0, 0.0, 0.5, 0.5), 0.1).ravel()
    grad = np.array(g([0.0, -0.3], theta_axis.ravel())).ravel()
    assert grad[1] > 0 and abs(grad[0]) < 1e-12  # descent moves down, out through y = -0.6


def test_depth_penalty_known_answers():
    # box half 0.6 inflated by 0.4: edges 1.0 m from the centre, corner cuts 0.6 sqrt(2) + 0.4 m
    pen = ObstaclePenalty(1, 8, "depth")
    theta = np.concatenate((obstacle_polygon(_box(0.0, 0.0, 0.0, 0.6, 0.6), 0.4).ravel(), [2.0]))
    cut = 0.6 * np.sqrt(2) + 0.4
    pts = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, -0.7], [0.99, 0.0], [1.0, 0.0], [1.2, 0.3], [-3.0, 0.0],
                    [0.8, 0.8], [0.9, 0.9]])
    # penetration depth = distance to the nearest edge line; (0.9, 0.9) is 0.42 m from the box
    # corner (0.6, 0.6): outside the inflated box and outside the octagon
    want = [2 * 1.0**2, 2 * 0.5**2, 2 * 0.3**2, 2 * 0.01**2, 0.0, 0.0, 0.0,
            2 * min(0.2, cut - 0.8 * np.sqrt(2)) ** 2, 0.0]
    np.testing.assert_allclose(pen.values_np(pts, theta), want, rtol=1e-12, atol=1e-15)


def test_product_penalty_known_answers_on_a_normalised_square():
    # square |x|, |y| <= 1 after normalisation by the inradius (box half 0.6 + inflation 0.4), weight 2
    pen = ObstaclePenalty(1, 4, "product")
    poly = obstacle_polygon(_box(0.0, 0.0, 0.0, 0.6, 0.6), 0.4, corner_cuts=False)
    theta = np.concatenate((normalised_rows(poly, np.zeros(2)).ravel(), [2.0]))
    pts = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, -0.5], [0.99, 0.0], [1.0, 0.0], [1.2, 0.3], [-3.0, 0.0],
                    [0.9, 0.9]])
    want = [2.0, 2 * 1.5**2 * 0.5**2, 2 * (1.5 * 0.5) ** 4, 2 * 1.99**2 * 0.01**2, 0.0, 0.0, 0.0,
            2 * (1.9 * 0.1) ** 4]
    np.testing.assert_allclose(pen.values_np(pts, theta), want, rtol=1e-12, atol=1e-15)
    # with the corner cuts (octagon), (0.9, 0.9) is outside and (0.8, 0.8) gets the cuts' factors
    octagon = obstacle_polygon(_box(0.0, 0.0, 0.0, 0.6, 0.6), 0.4)
    assert octagon.shape == (8, 3)
    pen8 = ObstaclePenalty(1, 8, "product")
    theta8 = np.concatenate((normalised_rows(octagon, np.zeros(2)).ravel(), [2.0]))
    cut = 0.6 * np.sqrt(2) + 0.4  # distance of the corner cuts from the centre [m]
    assert pen8.value_np(np.array([0.9, 0.9]), theta8) == 0.0
    assert pen8.value_np(np.array([0.8, 0.8]), theta8) == pytest.approx(
        2 * (0.2 * 1.8) ** 4 * ((cut - 0.8 * np.sqrt(2)) * (cut + 0.8 * np.sqrt(2))) ** 2 * cut**4, rel=1e-12
    )


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


def test_drives_around_a_box_centred_on_the_straight_line():
    # the single_rect situation: the straight line runs through the middle of the polygon
    obs = [_box(2.5, 0.0, 0.0, 0.4, 0.4)]
    goal = np.array([5.0, 0.0])
    ctl = PenaltyMPC(ROBOT, obs, 0.35, goal, MPCConfig())
    ok, path = _run(ctl, [0.0, 0.0, 0.0], goal)
    assert ok and ctl.failures == 0
    assert ctl.stats.counts.get("escape_taken", 0) >= 1  # the swerve came from an escape start
    # soft cost: it cuts into the inflated polygon (0.35 m) at the corner: 0.05 m measured with
    # the depth penalty, 0.11-0.13 m with the product form (docs/results.md)
    assert obs[0].signed_distance(path).min() > 0.35 - 0.08
    assert np.abs(path[:, 1]).max() > 0.6  # it left the line by about the polygon's half width


def test_without_lookahead_and_escapes_it_stops_in_front_of_the_box():
    # the first version of the baseline (reference from the robot, warm start only): braking
    # in front of the polygon is the better plan, so it never gets past (docs/results.md)
    obs = [_box(2.5, 0.0, 0.0, 0.4, 0.4)]
    goal = np.array([5.0, 0.0])
    first = PenaltyConfig(lookahead=0.0, escape_yaw_rates=())
    ctl = PenaltyMPC(ROBOT, obs, 0.35, goal, MPCConfig(), first)
    ok, path = _run(ctl, [0.0, 0.0, 0.0], goal, steps=80)
    assert not ok and 1.0 < path[-1, 0] < 1.8 and np.abs(path[:, 1]).max() < 0.05


def test_reference_known_answers():
    goal = np.array([3.0, 4.0])  # 5 m from the origin, bearing atan2(4, 3)
    cfg = PenaltyConfig(lookahead=1.0, reference_speed=2.5)
    ctl = PenaltyMPC(ROBOT, [], 0.3, goal, MPCConfig(), cfg)  # N = 20, dt = 0.1 s
    bearing = math.atan2(4.0, 3.0)
    xr, ur = ctl.reference(np.array([0.0, 0.0, bearing]))
    s = np.minimum(1.0 + 0.25 * np.arange(21), 5.0)  # 1 m ahead, 0.25 m per step, capped at the goal
    np.testing.assert_allclose(xr[:, :2], np.column_stack((0.6 * s, 0.8 * s)), atol=1e-12)
    np.testing.assert_allclose(xr[:, 2], bearing)
    np.testing.assert_allclose(ur[:, 0], np.where(s[1:] < 5.0, 2.5, 0.0))
    np.testing.assert_allclose(ur[:, 1], 0.0)
    # facing away, on another yaw branch: same positions, yaw on the measured branch
    xr2, _ = ctl.reference(np.array([0.0, 0.0, bearing + math.pi + 4 * math.pi - 0.1]))
    np.testing.assert_allclose(xr2[:, :2], xr[:, :2], atol=1e-12)
    np.testing.assert_allclose(xr2[:, 2], bearing + 4 * math.pi, atol=1e-9)


def test_blocked_known_answers():
    obs = [_box(2.0, 0.0, 0.0, 0.3, 0.3)]  # polygon x in [1.4, 2.6] with inflation 0.3
    ctl = PenaltyMPC(ROBOT, obs, 0.3, np.array([5.0, 0.0]), MPCConfig(), PenaltyConfig(reference_speed=1.0))
    theta = ctl.obstacle_params(np.zeros(2))
    # the reference travels N * 1 m/s * dt = 2 m; a plan is blocked below 60 % of it (1.2 m)
    creep = np.tile([1.1 / (ctl.N * ctl.dt), 0.0], (ctl.N, 1))  # 1.1 m
    assert ctl.blocked(np.array([0.4, 0.0, 0.0]), creep, theta)  # ends at x = 1.5, inside
    assert not ctl.blocked(np.array([-0.5, 0.0, 0.0]), creep, theta)  # ends at x = 0.6, outside
    assert not ctl.blocked(np.array([0.4, 3.0, 0.0]), creep, theta)  # passes beside the polygon
    fast = np.tile([1.3 / (ctl.N * ctl.dt), 0.0], (ctl.N, 1))  # 1.3 m, ends at x = 1.5, inside
    assert not ctl.blocked(np.array([0.2, 0.0, 0.0]), fast, theta)


@pytest.mark.parametrize("err", [2.5, -0.5, 3.1, 0.05])
def test_turn_plan_turns_by_the_error_within_the_bounds(err):
    ctl = PenaltyMPC(ROBOT, [], 0.3, np.array([3.0, 0.0]))
    u = ctl.turn_plan(err)
    assert u.shape == (ctl.N, 2) and np.all(u[:, 0] == 0.0)
    steps = np.abs(np.diff(np.vstack(([0.0, 0.0], u)), axis=0))
    assert np.all(steps[:, 1] <= ctl.rate_step[1] + 1e-12) and np.all(np.abs(u[:, 1]) <= ctl.limits.w_max)
    assert np.all(np.sign(u[:, 1]) * np.sign(err) >= 0) and u[-1, 1] == 0.0  # one direction, ends at rest
    assert abs(u[:, 1].sum() * ctl.dt - err) <= ctl.rate_step[1] * ctl.dt  # within one step's turn


def _statuses(ctl, x, steps):
    """Reset ``ctl`` at pose ``x`` and run it ``steps`` control steps (0.1 s) on the exact
    unicycle; returns (each step's command status, the final pose)."""
    ctl.reset(x)
    statuses = []
    for k in range(steps):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=np.zeros(2)))
        statuses.append(cmd.status)
        x = step_np(x, [cmd.v, cmd.w], 0.1)
    return statuses, x


def test_opening_turn_when_facing_away_then_the_mpc():
    ctl = PenaltyMPC(ROBOT, [], 0.3, np.array([3.0, 0.0]))
    # 2 rad off the goal's bearing (> turn_in_place = 1 rad)
    statuses, x = _statuses(ctl, np.array([0.0, 0.0, 2.0]), 30)
    n_turn = statuses.index("ok")
    assert n_turn > 3 and statuses[:n_turn] == ["turn"] * n_turn and "turn" not in statuses[n_turn:]
    assert ctl.stats.counts["turn"] == n_turn and ctl.failures == 0
    assert x[0] > 0.5  # then it drives to the goal
    # a small heading error at the first step: no opening turn
    ctl.reset(np.array([0.0, 0.0, 0.5]))
    assert ctl.step(Observation(t=0.0, pose=np.array([0.0, 0.0, 0.5]), velocity=np.zeros(2))).status != "turn"


def test_forward_only_sets_the_lower_speed_bound():
    shared = PenaltyMPC(ROBOT, [], 0.3, np.array([3.0, 0.0]))
    assert shared.limits.v_min == MPCConfig().limits(ROBOT).v_min < 0  # default: SA-MPC's bounds
    fwd = PenaltyMPC(ROBOT, [], 0.3, np.array([3.0, 0.0]), MPCConfig(), PenaltyConfig(forward_only=True))
    assert fwd.limits.v_min == 0.0 and fwd.input_bounds()[0][0] == 0.0


def test_injected_failures_fall_back_then_recover():
    goal = np.array([3.0, 0.0])
    ctl = PenaltyMPC(ROBOT, [], 0.3, goal, MPCConfig(), failure_injector=lambda k: 5 <= k < 8)
    statuses, _ = _statuses(ctl, np.zeros(3), 12)
    assert statuses[5:8] == ["fallback_shift"] * 3 and statuses[8] == "ok"
    assert ctl.failures == 3


def test_fallbacks_are_finite_when_every_solve_fails_or_the_pose_is_nan():
    goal = np.array([3.0, 0.0])
    ctl = PenaltyMPC(ROBOT, [], 0.3, goal, MPCConfig(), failure_injector=lambda k: k >= 3)
    x = np.zeros(3)
    ctl.reset(x)
    for k in range(3 + ctl.N + 5):
        pose = x if k != 10 else np.array([np.nan, 0.0, 0.0])
        cmd = ctl.step(Observation(t=0.1 * k, pose=pose, velocity=np.zeros(2)))
        assert np.isfinite(cmd.v) and np.isfinite(cmd.w)
        assert ctl.limits.v_min <= cmd.v <= ctl.limits.v_max and abs(cmd.w) <= ctl.limits.w_max
        x = step_np(x, [cmd.v, cmd.w], 0.1)
    assert cmd.status == "fallback_stop" and cmd.v == 0.0 and cmd.w == 0.0  # braked to rest
    assert ctl.failures == ctl.N + 5


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(q_obs=0.0), "q_obs"),
        (dict(form="sum"), "form"),
        (dict(n_slots=0), "n_slots"),
        (dict(n_edges=3), "n_edges"),
        (dict(reference_speed=-1.0), "reference_speed"),
        (dict(lookahead=-0.1), "lookahead"),
        (dict(escape_yaw_rates=(1.0, float("nan"))), "escape_yaw_rates"),
        (dict(escape_steps=0), "escape_steps"),
        (dict(escape_speed=-1.0), "escape_speed"),
        (dict(blocked_travel=0.0), "blocked_travel"),
        (dict(min_outer_iter=0), "min_outer_iter"),
        (dict(escape_budget_ms=0.0), "escape_budget_ms"),
    ],
)
def test_config_errors_name_the_field(kwargs, fragment):
    with pytest.raises(ValueError, match=f"PenaltyConfig.{fragment}"):
        PenaltyConfig(**kwargs)


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


class _RecordingBackend:
    """Wraps a back-end (not shared: the controller's attribute is replaced) and keeps every result."""

    def __init__(self, inner):
        self.inner = inner
        self.results = []

    def solve(self, *args, **kwargs):
        res = self.inner.solve(*args, **kwargs)
        self.results.append(res)
        return res


@pytest.mark.parametrize("budget_ms, escape_ms, want", [
    (None, None, None), (50.0, None, 50.0), (None, 5.0, 5.0), (1.0, 5.0, 1.0), (8.0, 5.0, 5.0),
])
def test_escape_solves_get_the_tighter_of_the_two_budgets(budget_ms, escape_ms, want):
    ctl = PenaltyMPC(ROBOT, [], 0.3, np.array([3.0, 0.0]), MPCConfig(solve_budget_ms=budget_ms),
                     PenaltyConfig(escape_budget_ms=escape_ms))
    assert ctl.backend.settings.budget_ms == budget_ms
    assert ctl.escape_backend.settings.budget_ms == want


@pytest.mark.parametrize("budget_ms", [None, 1e-3])
def test_every_solve_respects_a_tiny_solve_budget(budget_ms):
    # the single_rect situation, close to the box: the plan is blocked, so the escape starts
    # are solved too. Unbudgeted they converge; with a 1 us budget (the ``solve_budget_ms``
    # mismatch) every solve, escape solves included, stops at the time limit
    obs = [_box(2.5, 0.0, 0.0, 0.4, 0.4)]
    ctl = PenaltyMPC(ROBOT, obs, 0.35, np.array([5.0, 0.0]), MPCConfig(solve_budget_ms=budget_ms))
    ctl.backend = _RecordingBackend(ctl.backend)
    ctl.escape_backend = _RecordingBackend(ctl.escape_backend)
    x = np.array([1.0, 0.0, 0.0])
    ctl.reset(x)
    cmd = ctl.step(Observation(t=0.0, pose=x, velocity=np.zeros(2)))
    assert ctl.stats.counts["escape_tried"] == 1
    main, escapes = ctl.backend.results, ctl.escape_backend.results
    assert len(main) == 1 and len(escapes) == len(PenaltyConfig().escape_yaw_rates)
    if budget_ms is None:
        assert all(r.converged for r in main + escapes) and cmd.status == "ok"
    else:
        assert [r.status for r in main + escapes] == ["MaxTime"] * 3
        assert cmd.status == "fallback_stop" and (cmd.v, cmd.w) == (0.0, 0.0)
