"""Pose search and pose-route plans (discs mode): known answers on hand-built disc-centre maps.

The maps are safe areas for disc *centres* (a map already inflated by the disc radius):
strips 0.1 m wide are passages the footprint fits only aligned with. The body carries three
discs at -0.15, 0, +0.15 m along its axis (sweep 0.15 m), box margin 0.02 m, lattice 5 cm.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning_maps import areas_from_rects
from sanav_mj.planning.pose_reference import chain_walk, route_plan
from sanav_mj.planning.pose_search import (
    FORWARD,
    HEADINGS,
    REVERSE,
    SPIN,
    PointRaster,
    PoseSearchConfig,
    member_boxes,
    poses_free,
    search_poses,
    wrap,
)

OFFSETS = np.array([[-0.15, 0.0], [0.0, 0.0], [0.15, 0.0]])
SWEEP = 0.15
H = 0.05
MARGIN = 0.02


def _search(rects, shape, start, goal, **cfg):
    areas = areas_from_rects(rects)
    return areas, search_poses(areas, (0.0, 0.0), shape, H, OFFSETS, SWEEP, np.asarray(start, float),
                               np.asarray(goal, float), PoseSearchConfig(margin=MARGIN, **cfg))


def _in_spin_region(rect, p):
    r = SWEEP + MARGIN
    return rect[0] + r - 1e-9 <= p[0] <= rect[2] - r + 1e-9 and rect[1] + r - 1e-9 <= p[1] <= rect[3] - r + 1e-9


def test_headings_are_the_lattice_directions():
    assert HEADINGS.shape == (16,)
    assert HEADINGS[0] == 0.0 and HEADINGS[4] == pytest.approx(math.pi / 2) and HEADINGS[1] == pytest.approx(math.atan2(1, 2))
    assert np.all(np.diff(np.unwrap(HEADINGS)) > 0)


def test_member_boxes_known_answer():
    areas = areas_from_rects([[0, 0, 1, 1], [1, 0.25, 2, 0.75]])
    boxes = member_boxes(areas, 0.02)
    # the two areas shrunk, then the bridge across the vertical portal x = 1, y in [0.25, 0.75]
    np.testing.assert_allclose(boxes, [[0.02, 0.02, 0.98, 0.98], [1.02, 0.27, 1.98, 0.73], [0.02, 0.27, 1.98, 0.73]])


def test_point_raster_is_conservative_and_exact_on_aligned_boxes():
    r = PointRaster.build(np.array([[0.1, 0.1, 0.3, 0.2]]), (0.0, 0.0), (0.5, 0.5), 0.01)
    assert r.free.sum() == 20 * 10
    assert r.is_free(np.array([[0.1, 0.1], [0.2999, 0.1999]])).all()
    assert not r.is_free(np.array([[0.0999, 0.15], [0.3001, 0.15], [0.2, 0.2001], [-1.0, 0.15]])).any()


def test_passage_fitting_only_aligned():
    # room A, strip B (0.1 m wide: the discs fit only at heading 0 or pi), room C
    rects = [[0, 0, 1, 1], [1, 0.45, 3, 0.55], [3, 0, 4, 1]]
    areas, res = _search(rects, (20, 80), (0.5, 0.5, math.pi / 2), (3.5, 0.5))
    assert res.route is not None, res.detail
    p, kinds = res.route.poses, res.route.kinds
    assert np.hypot(*(p[0, :2] - (0.5, 0.5))) <= math.hypot(0.025, 0.025) + 1e-12 and np.hypot(*(p[-1, :2] - (3.5, 0.5))) <= 0.1
    in_strip = (p[:, 0] > 1.0 + 0.15) & (p[:, 0] < 3.0 - 0.15)
    assert in_strip.sum() > 30
    assert np.all(np.abs(np.sin(p[in_strip, 2])) < 1e-12)  # aligned with the strip
    assert np.all(np.abs(p[in_strip, 1] - 0.5) <= 0.03 + 1e-12)
    assert set(kinds[in_strip[:-1] & in_strip[1:]].tolist()) <= {FORWARD, REVERSE}
    # every pose's disc centres are in the shrunk areas / bridges
    raster = PointRaster.build(member_boxes(areas, MARGIN), (0, 0), (4, 1), 0.005)
    assert poses_free(raster, p, OFFSETS).all()
    # the opening turn (pi/2 -> 0) is made in room A, where the sweep fits
    spins = np.flatnonzero(kinds == SPIN)
    assert all(_in_spin_region(rects[0], p[i]) or _in_spin_region(rects[2], p[i]) for i in spins)


def test_l_corner_turns_only_in_the_wide_cell():
    # horizontal strip H, wide corner cell W, vertical strip V (both strips 0.1 m wide)
    H_, W, V = [0, 0.45, 2.0, 0.55], [2.0, 0.25, 2.5, 0.75], [2.2, 0.75, 2.3, 2.5]
    areas, res = _search([H_, W, V], (50, 50), (0.3, 0.5, 0.0), (2.25, 2.2))
    assert res.route is not None, res.detail
    p, kinds = res.route.poses, res.route.kinds
    yaw = wrap(p[:, 2])
    axis = (np.abs(np.sin(yaw)) < 1e-12) | (np.abs(np.cos(yaw)) < 1e-12)
    # every pose not aligned with an axis is inside the wide cell, as is every turn on the spot
    assert np.all((p[~axis, 0] >= W[0]) & (p[~axis, 0] <= W[2]) & (p[~axis, 1] >= W[1]) & (p[~axis, 1] <= W[3]))
    turned = np.flatnonzero(kinds == SPIN)
    assert turned.size > 0
    assert np.all((p[turned, 0] >= W[0]) & (p[turned, 0] <= W[2]) & (p[turned, 1] >= W[1]) & (p[turned, 1] <= W[3]))
    assert abs(np.cos(yaw[-1])) < 1e-12  # up the vertical strip aligned


def test_l_corner_without_room_to_turn_has_no_pose_path():
    # the same L of 0.1 m strips with no wide cell: the three collinear discs cannot be in
    # both legs at once, so no motion turns the body round the corner
    areas, res = _search([[0, 0.45, 2.3, 0.55], [2.2, 0.55, 2.3, 2.5]], (50, 50), (0.3, 0.5, 0.0), (2.25, 2.2))
    assert res.route is None
    assert "no pose path" in res.detail


def test_start_without_a_free_pose_is_reported():
    areas, res = _search([[0, 0.45, 2.0, 0.55]], (20, 50), (1.0, 0.9, 0.0), (1.5, 0.5))
    assert res.route is None and "start" in res.detail


def test_route_plan_reference_and_corridors():
    rects = [[0, 0, 1, 1], [1, 0.45, 3, 0.55], [3, 0, 4, 1]]
    areas, res = _search(rects, (20, 80), (0.5, 0.5, math.pi / 2), (3.5, 0.5))
    plan, why = route_plan(areas, res.route, np.array([3.5, 0.5]), OFFSETS, 0.1, 1.0, 0.3, 1.5, 1.0, 3.0, 1.0)
    assert plan is not None, why
    ref = plan.reference
    # starts and ends at the route's end poses, at rest
    np.testing.assert_allclose(ref.states[0], res.route.poses[0], atol=1e-12)
    np.testing.assert_allclose(ref.states[-1], res.route.poses[-1], atol=1e-12)
    assert np.all(ref.inputs[-1] == 0)
    # inputs are the finite differences of the states
    d = np.diff(ref.states, axis=0)
    np.testing.assert_allclose(ref.inputs[:-1, 1] * 0.1, d[:, 2], atol=1e-12)
    assert np.all(ref.inputs[:, 0] <= 1.0 + 1e-9) and np.all(ref.inputs[:, 0] >= -0.3 - 1e-9)
    # every reference sample's discs are free, and each disc walks its own corridor monotonically
    raster = PointRaster.build(member_boxes(areas, MARGIN), (0, 0), (4, 1), 0.005)
    assert poses_free(raster, ref.states, OFFSETS).all()
    assert plan.corridor.tolist() == [0, 1, 2]
    assert np.all(np.diff(np.searchsorted([0, 1, 2], ref.area)) >= 0)
    assert chain_walk(areas.rects, plan.corridor, ref.states[:, :2]) is not None
    # each disc's chain holds its centre the way SA-MPC's stage boxes do (the controller's code)
    from sanav_mj.control.disc_stages import member_chain_of
    from sanav_mj.control.stages import assign_stages, box_slack, stage_boxes

    assert len(plan.disc_corridors) == 3
    for d, members in enumerate(plan.disc_corridors):
        chain = member_chain_of(areas, members, MARGIN)
        c = ref.states[:, :2] + np.column_stack([np.cos(ref.states[:, 2]), np.sin(ref.states[:, 2])]) * OFFSETS[d, 0]
        s = assign_stages(chain, c, tol=1e-9)
        assert s[0] == 0 and s[-1] == len(chain) - 1
        assert np.all(box_slack(c, stage_boxes(chain, s)) >= -1e-9)


def test_reference_reverses_with_negative_speed():
    # a dead-end strip: start facing into it, goal behind: reversing out is the cheap way
    rects = [[0, 0.45, 1.5, 0.55]]
    areas, res = _search(rects, (20, 40), (1.0, 0.5, 0.0), (0.4, 0.5))
    assert res.route is not None, res.detail
    assert set(res.route.kinds.tolist()) == {REVERSE}
    plan, why = route_plan(areas, res.route, np.array([0.4, 0.5]), OFFSETS, 0.1, 1.0, 0.3, 1.5, 1.0, 3.0, 1.0)
    assert plan is not None, why
    v = plan.reference.inputs[:, 0]
    assert v.min() < -0.2 and v.max() <= 1e-12 and v.min() >= -0.3 - 1e-9


def test_spin_and_translation_timing_known_answers():
    from sanav_mj.planning.pose_reference import SPIN as _SPIN, _spin_times, time_poses

    # rest-to-rest turn of pi/2 at w_cap = 1 rad/s, alpha = 1 rad/s^2: 1 s up, 0.5708 s cruise, 1 s down
    th = np.linspace(0.0, math.pi / 2, 50)
    t = _spin_times(th, 1.0, 1.0)
    assert t[-1] == pytest.approx(2.0 + (math.pi / 2 - 1.0), abs=1e-12)
    assert np.all(np.diff(t) > 0)
    # a 2 m straight run, cap 1 m/s (a = 1 m/s^2): the speed scale 0.5 makes it a 0.5 m/s
    # trapezoid (0.5 s up, 3.5 s cruise, 0.5 s down); the nodes are 1 cm apart: the profile
    # is exact where the acceleration changes at a node (the unscaled run: at 0.5 m) and
    # otherwise off by less than one node interval at cruise speed (0.01 m / 0.5 m/s)
    x = np.linspace(0.0, 2.0, 201)
    dense = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    kinds = np.full(200, FORWARD)
    full = time_poses(dense, kinds, 1.0, 0.3, 1.0, 1.0, 1.0, 1.0)
    half = time_poses(dense, kinds, 1.0, 0.3, 1.0, 1.0, 1.0, 1.0, v_scale=np.full(201, 0.5))
    assert full[-1] == pytest.approx(3.0, abs=1e-9)  # 1 s up, 1 s cruise, 1 s down
    assert half[-1] == pytest.approx(4.5, abs=0.01 / 0.5)
    assert half[-1] > full[-1] + 1.4
    spin = time_poses(np.column_stack([np.zeros(50), np.zeros(50), th]), np.full(49, _SPIN), 1.0, 0.3, 1.0, 1.0, 1.0, 1.0)
    assert spin[-1] == pytest.approx(t[-1], abs=1e-12)


def test_stops_mark_where_the_motion_kind_changes():
    # the L with a wide corner cell: the route turns on the spot there
    areas, res = _search([[0, 0.45, 2.0, 0.55], [2.0, 0.25, 2.5, 0.75], [2.2, 0.75, 2.3, 2.5]], (50, 50),
                         (0.3, 0.5, 0.0), (2.25, 2.2))
    args = (areas, res.route, np.array([2.25, 2.2]), OFFSETS, 0.1, 1.0, 0.3, 1.5, 1.0, 3.0, 1.0)
    assert route_plan(*args)[0].reference.stops is None  # off by default
    plan, _ = route_plan(*args, hold_at_stops=True)
    ref = plan.reference
    changes = int(np.sum(res.route.kinds[1:] != res.route.kinds[:-1]))
    assert changes >= 1 and 1 <= ref.stops.size <= changes
    # the reference is at rest at each stop (its motion runs are timed rest to rest)
    v = np.abs(ref.inputs[:, 0]) + 0.17 * np.abs(ref.inputs[:, 1])
    for s in ref.stops:
        assert min(v[max(0, s - 1)], v[s]) < 0.15
