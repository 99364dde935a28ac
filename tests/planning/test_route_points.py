"""route_points: stage 1 of plan() alone (the lidar mode's route)."""

from __future__ import annotations

import numpy as np

from sanav_mj.mapping.safe_areas import connectivity
from sanav_mj.planning import PlannerConfig, plan
from sanav_mj.planning.corridor import contains
from sanav_mj.planning.pipeline import route_points
from sanav_mj.planning.smoothing import cumulative_length, interpolate_uniform
from sanav_mj.scene import RobotParams

ROBOT = RobotParams(0.1, 0.38, 0.33, 20.0, 2.0, 3.0, 1.5, 4.0)


def _areas():
    # an L of cell boxes [i0, j0, i1, j1) at 0.05 m: along x, then up
    boxes = np.array([[0, 0, 20, 60], [0, 60, 20, 80], [20, 60, 80, 80]])
    return connectivity(boxes, np.zeros(2), 0.05)


def test_route_points_is_the_polyline_plan_smooths():
    areas = _areas()
    cfg = PlannerConfig()
    start, goal = np.array([0.3, 0.5, 0.0]), np.array([3.5, 3.5])
    p = plan(areas, start, goal, ROBOT, cfg)
    pts = route_points(areas, start, goal, cfg)
    assert p.ok and pts is not None
    assert np.allclose(pts[0], p.waypoints[0]) and np.allclose(pts[-1], p.waypoints[-1])
    # the samples of plan()'s own waypoint polyline (same corridor, start and goal used)
    assert np.array_equal(pts, interpolate_uniform(p.waypoints, cfg.spacing)[1])
    assert len(pts) == int(np.ceil(cumulative_length(p.waypoints)[-1] / cfg.spacing - 1e-9)) + 1
    rects = np.asarray(areas.rects)[p.corridor]
    assert contains(rects, pts).any(axis=1).all()  # inside the corridor


def test_route_points_no_path_and_projected_goal():
    areas = _areas()
    assert route_points(areas, np.array([0.3, 0.5]), np.array([9.0, 9.0]), PlannerConfig()) is None
    # a goal outside the areas but within max_projection: ends at the projected goal, as plan()
    start, goal = np.array([0.3, 0.5, 0.0]), np.array([4.3, 3.5])
    p = plan(areas, start, goal, ROBOT, PlannerConfig())
    pts = route_points(areas, start, goal, PlannerConfig())
    assert p.ok and np.allclose(pts[-1], p.goal)
