"""The shared episode-termination rules (runner and NavEnv): order, windows, progress measures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sanav_mj.sim.termination import (
    GoalDistanceProgress,
    RouteProgress,
    Termination,
    TerminationConfig,
    route_of,
)

# A route that first leads 6 m away from the goal, folds back and ends at the goal (0, 2).
FOLD = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 2.0], [0.0, 2.0]])


def test_route_progress_is_the_arc_length_of_the_projection():
    prog = RouteProgress(FOLD)
    assert prog.length == 14.0
    assert prog([0.0, 0.0]) == 0.0
    assert prog([2.5, -0.3]) == 2.5  # foot (2.5, 0) on the first leg
    assert prog([6.4, 1.0]) == 7.0  # foot (6, 1): 6 + 1
    assert prog([3.0, 2.2]) == 11.0  # last leg: 6 + 2 + 3
    assert prog([-1.0, 2.0]) == 14.0  # beyond the end: clamped to the last vertex
    assert prog([-1.0, -1.0]) == 0.0  # before the start


def test_route_progress_handles_one_vertex_and_repeated_vertices():
    assert RouteProgress(np.array([[1.0, 1.0]]))([5.0, 5.0]) == 0.0
    prog = RouteProgress(np.array([[0.0, 0.0], [0.0, 0.0], [3.0, 0.0]]))
    assert prog([2.0, 1.0]) == 2.0


def test_goal_distance_progress_is_minus_the_distance():
    assert GoalDistanceProgress(np.array([3.0, 4.0]))([0.0, 0.0]) == -5.0


def test_route_of_appends_a_projected_goal_only():
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert route_of(path, [1.0, 0.0]).shape == (2, 2)
    np.testing.assert_array_equal(route_of(path, [1.0, 0.5])[-1], [1.0, 0.5])


def drive(rules: Termination, points: np.ndarray) -> tuple[str | None, int]:
    """Feed positions step by step; the first reason and the step it came at."""
    for k, p in enumerate(points, start=1):
        reason = rules.arrival(p, 0) or rules.stalled(p, k)
        if reason is not None:
            return reason, k
    return None, len(points)


def along(route: np.ndarray, speed: float, dt: float) -> np.ndarray:
    """Positions every dt driving along the polyline at a constant speed."""
    seg = np.hypot(*np.diff(route, axis=0).T)
    s = np.arange(1, int(seg.sum() / (speed * dt)) + 1) * speed * dt
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    return np.column_stack([np.interp(s, cum, route[:, 0]), np.interp(s, cum, route[:, 1])])


def test_a_route_leading_away_from_the_goal_is_progress_not_stuck():
    """Issue 12: driving at 1 m/s along a route that first leads away from the goal ends
    ``stuck`` under the straight-line rule (after the 8 s window) but reaches the goal when
    progress is measured along the route."""
    cfg, dt, goal = TerminationConfig(), 0.1, FOLD[-1]
    points = along(FOLD, 1.0, dt)
    assert drive(Termination(cfg, dt, goal), points) == ("stuck", 81)
    reason, k = drive(Termination(cfg, dt, goal, RouteProgress(FOLD)), points)
    assert reason == "goal" and k >= 130


def test_standing_still_on_the_route_is_stuck_after_the_window():
    cfg = TerminationConfig(stuck_window_s=2.0, stuck_progress_m=0.05)
    rules = Termination(cfg, 0.1, FOLD[-1], RouteProgress(FOLD))
    assert drive(rules, np.tile([3.0, 0.0], (100, 1))) == ("stuck", 21)
    # progress just below the threshold over the window is stuck, at it is not
    rules.reset()
    slow = np.column_stack([np.arange(1, 100) * 0.0024, np.zeros(99)])  # 0.048 m per 2 s
    assert drive(rules, slow)[0] == "stuck"
    rules.reset()
    fast = np.column_stack([np.arange(1, 60) * 0.0026, np.zeros(59)])  # 0.052 m per 2 s
    assert drive(rules, fast) == (None, 59)


def test_rule_order_collision_before_goal_and_stuck_before_timeout():
    cfg = TerminationConfig(time_limit_s=1.0, stuck_window_s=0.5)
    rules = Termination(cfg, 0.1, [0.0, 0.0])
    assert rules.max_steps == 10
    assert rules.arrival([0.0, 0.0], 1) == "collision"
    assert rules.arrival([0.0, 0.1], 0) == "goal"
    assert rules.arrival([0.0, 0.2], 0) is None
    assert drive(rules, np.tile([5.0, 0.0], (20, 1))) == ("stuck", 6)
    rules.reset()
    away = np.column_stack([5.0 + np.arange(1, 20) * 0.1, np.zeros(19)])
    rules2 = Termination(cfg, 0.1, [0.0, 0.0], RouteProgress(np.array([[5.0, 0.0], [9.0, 0.0]])))
    assert drive(rules2, away) == ("timeout", 10)


def test_max_steps_matches_the_runner_count():
    assert TerminationConfig(time_limit_s=60.0).max_steps(0.1) == 600
    assert TerminationConfig(time_limit_s=40.0).max_steps(0.1) == 400
    assert TerminationConfig(time_limit_s=0.25).max_steps(0.1) == 3


@pytest.mark.parametrize("field, value", [("time_limit_s", 0.0), ("goal_tolerance_m", math.nan),
                                          ("stuck_window_s", -1.0), ("stuck_progress_m", -0.1),
                                          ("time_limit_s", True)])
def test_bad_config_is_rejected_naming_the_field(field, value):
    with pytest.raises(ValueError, match=f"TerminationConfig.{field}"):
        TerminationConfig(**{field: value})


def test_bad_route_is_rejected():
    with pytest.raises(ValueError, match="route"):
        RouteProgress(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="route"):
        RouteProgress(np.array([[0.0, np.nan]]))


def test_runner_and_training_env_share_one_config():
    """The runner's settings are a TerminationConfig, and NavEnv's default rules are the
    runner's (issue 13: the DQN trained under other rules than it was evaluated with)."""
    from dataclasses import fields

    from sanav_mj.sim.runner import RunConfig

    run = RunConfig()
    assert isinstance(run, TerminationConfig)
    shared = {f.name: getattr(run, f.name) for f in fields(TerminationConfig)}
    assert TerminationConfig(**shared) == TerminationConfig()
    nav_env = pytest.importorskip("sanav_mj.sim.nav_env")
    assert nav_env.NavEnvConfig().termination == TerminationConfig(**shared)
    with pytest.raises(ValueError, match="RunConfig.stuck_window_s"):
        RunConfig(stuck_window_s=0.0)


def test_replanned_route_progress_sums_advance_along_each_route_and_ignores_replans():
    """Exact arc lengths: 2 m along the first route, a replan onto a route leading back the
    other way adds nothing, then 1.5 m along it counts as progress (backing out of a dead
    end), whereas the distance to the goal grew."""
    from sanav_mj.sim.termination import ReplannedRouteProgress

    goal = np.array([10.0, 0.0])
    current = {"r": None}
    prog = ReplannedRouteProgress(lambda: current["r"], goal)
    assert prog(np.array([0.0, 0.0])) == 0.0  # no route yet: no progress
    current["r"] = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert prog(np.array([1.0, 0.0])) == 0.0
    assert prog(np.array([3.0, 0.0])) == pytest.approx(2.0, abs=1e-12)
    current["r"] = np.array([[3.0, 0.0], [0.0, 0.0], [0.0, 5.0], [10.0, 5.0]])  # a new array: replanned
    assert prog(np.array([3.0, 0.0])) == pytest.approx(2.0, abs=1e-12)
    assert prog(np.array([1.5, 0.2])) == pytest.approx(3.5, abs=1e-12)
