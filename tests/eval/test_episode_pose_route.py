"""The discs mode's pose route in the run path (:func:`sanav_mj.eval.prepare.footprint_route_plan`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sanav_mj.control.config import MPCConfig
from sanav_mj.control.spec import ControllerSpec
from sanav_mj.eval.prepare import footprint_route_plan
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.scene import load_scenario

DISCS = ControllerSpec("sa-mpc", replace(MPCConfig(), footprint="discs", footprint_route="pose"))


def _areas(rects):
    """SafeAreas of rectangles on the 5 cm grid from the origin (via the mapping stage's graph)."""
    from sanav_mj.mapping.safe_areas import connectivity

    xy = np.rint(np.asarray(rects, float) / 0.05).astype(np.int64)  # x0, y0, x1, y1 in cells
    return connectivity(xy[:, [1, 0, 3, 2]], np.zeros(2), 0.05)  # cell boxes are [row0, col0, row1, col1)


def _grid(nx, ny):
    return OccupancyGrid(np.zeros((ny, nx), bool), 0.05, np.zeros(2), 0.28, np.array([0.0, 0.0, nx * 0.05, ny * 0.05]))


def _corridor_plan(goal):
    """A stand-in for the corridor planner's successful plan (only ok and goal are used)."""
    ref = Reference(0.1, np.array([[0.3, 0.5, 0.0], [*goal, 0.0]]), np.zeros((2, 2)), np.array([0, 0]))
    return Plan(True, "ok", np.array([0]), np.asarray(goal, float), np.zeros((0, 2)), np.zeros((0, 2)),
                np.zeros((0, 2)), ref, {"timing_ms": {"total": 1.0}})


def test_no_pose_path_is_a_clean_no_path_and_a_wide_corner_gives_a_route():
    sc = load_scenario("u_shape")  # the packaged robot: 3 discs at 0, +-0.167 m
    start = np.array([0.3, 0.5, 0.0])
    goal = np.array([2.25, 2.2])
    # an L of 0.1 m strips for the disc centres: the body cannot turn round its corner
    narrow = _areas([[0, 0.45, 2.3, 0.55], [2.2, 0.55, 2.3, 2.5]])
    out = footprint_route_plan(_corridor_plan(goal), narrow, _grid(50, 52), sc, start, DISCS)
    assert not out.ok and out.reason == "no_path" and out.reference is None and out.corridor.size == 0
    assert "no pose path" in out.info["detail"] and out.info["pose_search_ms"] > 0
    # the same with a wide cell at the corner: a route, one chain per disc, the route's yaw
    wide = _areas([[0, 0.45, 2.0, 0.55], [2.0, 0.1, 2.5, 0.9], [2.2, 0.9, 2.3, 2.5]])
    out = footprint_route_plan(_corridor_plan(goal), wide, _grid(50, 52), sc, start, DISCS)
    assert out.ok and out.info["pose_route"] and len(out.disc_corridors) == 3
    assert np.hypot(*(out.reference.states[-1, :2] - goal)) <= 0.1
    assert abs(np.cos(out.reference.states[-1, 2])) < 1e-9  # up the vertical strip, aligned
    # other modes, and a failed corridor plan, pass through untouched
    plan = _corridor_plan(goal)
    assert footprint_route_plan(plan, wide, _grid(50, 52), sc, start) is plan
    corridor = ControllerSpec("sa-mpc", replace(MPCConfig(), footprint="discs"))  # the default route
    assert footprint_route_plan(plan, wide, _grid(50, 52), sc, start, corridor) is plan
