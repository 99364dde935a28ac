"""Replans that keep the rectangles the robot is using (sanav_mj/control/replan.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.control.replan import kept_prefix, prefixed_areas, rect_cells, rects_safe
from sanav_mj.control.stages import CorridorChain, assign_stages, stage_boxes
from sanav_mj.mapping.sensed_map import SensedMap
from sanav_mj.planning import PlannerConfig, plan
from sanav_mj.scene import RobotParams

H = 0.05
ORIGIN = np.zeros(2)


def _brute_safe(blocked: np.ndarray, rect: np.ndarray) -> bool:
    """Every cell whose centre lies in ``rect`` has a zero count (reference for rects_safe)."""
    ny, nx = blocked.shape
    xs = (np.arange(nx) + 0.5) * H
    ys = (np.arange(ny) + 0.5) * H
    inside = ((xs[None, :] > rect[0]) & (xs[None, :] < rect[2]) & (ys[:, None] > rect[1]) & (ys[:, None] < rect[3]))
    return bool(inside.any()) and not blocked[inside].any()


def _corridor():
    # three rectangles along x, touching: [0, 2] x [0, 1], [2, 3] x [0.2, 0.8], [3, 5] x [0, 1]
    return np.array([[0.0, 0.0, 2.0, 1.0], [2.0, 0.2, 3.0, 0.8], [3.0, 0.0, 5.0, 1.0]])


def _pts(x0, x1, y=0.5, n=12):
    return np.column_stack([np.linspace(x0, x1, n), np.full(n, y)])


def test_rect_cells_and_rects_safe_against_brute_force():
    rng = np.random.default_rng(3)
    blocked = (rng.random((40, 60)) < 0.02).astype(np.int32)
    rects = np.array([[0.0, 0.0, 1.0, 0.5], [0.5, 0.5, 2.95, 2.0], [1.0, 1.0, 1.05, 1.05], [2.0, 0.0, 3.0, 0.1]])
    cells = rect_cells(rects, ORIGIN, H)
    assert cells[0].tolist() == [0, 0, 10, 20] and cells[2].tolist() == [20, 20, 21, 21]
    assert rects_safe(blocked, cells).tolist() == [_brute_safe(blocked, r) for r in rects]
    assert rects_safe(blocked, np.array([[0, 0, 0, 5], [0, 55, 5, 61]])).tolist() == [False, False]


def test_all_safe_keeps_the_rectangles_holding_the_predicted_positions():
    blocked = np.zeros((20, 100), dtype=np.int32)
    c = _corridor()
    kept = kept_prefix(c, _pts(1.0, 2.5), blocked, ORIGIN, H)
    assert np.array_equal(kept, c[:2])  # the third holds no predicted position
    kept = kept_prefix(c, _pts(2.2, 4.0), blocked, ORIGIN, H)
    assert np.array_equal(kept, c[1:])  # from the robot's own rectangle on
    # the robot outside the corridor: nothing kept
    assert kept_prefix(c, _pts(5.5, 6.0), blocked, ORIGIN, H).shape == (0, 4)


def test_an_unsafe_cell_away_from_the_plan_cuts_the_rectangle_to_a_safe_part():
    blocked = np.zeros((20, 100), dtype=np.int32)
    blocked[1, 24] = 1  # cell [1.2, 1.25] x [0.05, 0.1]: in the first rectangle, below the plan
    c = _corridor()
    kept = kept_prefix(c, _pts(0.5, 2.5), blocked, ORIGIN, H)
    assert len(kept) == 2 and np.array_equal(kept[1], c[1])
    assert rects_safe(blocked, rect_cells(kept, ORIGIN, H)).all()
    k0 = kept[0]
    assert k0[0] >= 0 and k0[2] <= 2.0 and k0[1] >= 0 and k0[3] <= 1.0  # inside the old rectangle
    pts = _pts(0.5, 2.0)
    assert ((pts >= k0[:2]) & (pts <= k0[2:])).all()  # holds the predicted positions in it
    assert k0[2] == 2.0  # still meets the next rectangle


def _covers(r, p):
    return bool(((p >= r[:2] - 1e-9) & (p <= r[2:] + 1e-9)).all())


def test_an_unsafe_cell_on_the_plan_ends_the_prefix_before_it():
    c = _corridor()
    pts = _pts(1.0, 4.0)  # x = 1.0, 1.27, ..., 3.45, 3.73, 4.0 on y = 0.5
    blocked = np.zeros((20, 100), dtype=np.int32)
    blocked[10, 70] = 1  # (3.5, 0.5): on the predicted path in the third rectangle
    kept = kept_prefix(c, pts, blocked, ORIGIN, H)
    assert np.array_equal(kept[:2], c[:2]) and len(kept) == 3
    assert rects_safe(blocked, rect_cells(kept, ORIGIN, H)).all()
    assert _covers(c[2], kept[2][:2]) and _covers(c[2], kept[2][2:])  # a part of the third
    # the positions before the unsafe cell are held, the one past it is not
    assert any(_covers(r, pts[9]) for r in kept) and not any(_covers(r, pts[10]) for r in kept)
    blocked[10, 30] = 1  # (1.5, 0.5): in the robot's own rectangle, on its third position
    kept = kept_prefix(c, pts, blocked, ORIGIN, H)
    assert len(kept) == 1 and rects_safe(blocked, rect_cells(kept, ORIGIN, H)).all()
    assert _covers(kept[0], pts[1]) and not _covers(kept[0], pts[2])
    blocked[10, 20] = 1  # the robot's own cell: nothing can be kept
    assert kept_prefix(c, pts, blocked, ORIGIN, H).shape == (0, 4)


def test_a_rectangle_cut_across_the_plan_is_covered_by_overlapping_parts():
    """The case of double_rect, seed 0, step 78: a thin rectangle whose bottom row became unsafe
    behind the robot, the plan dropping into that row further on: one part cannot hold every
    position, two overlapping parts do."""
    blocked = np.zeros((20, 140), dtype=np.int32)
    c = np.array([[3.0, 0.8, 5.8, 0.95], [5.0, 0.6, 6.2, 1.0]])
    blocked[16, 74:88] = 1  # row y in [0.8, 0.85), x in [3.7, 4.4)
    pts = np.column_stack([np.linspace(4.05, 5.87, 20), np.linspace(0.91, 0.68, 20)])
    kept = kept_prefix(c, pts, blocked, ORIGIN, H)
    assert np.allclose(kept, [[3.0, 0.85, 5.8, 0.95], [4.4, 0.8, 5.8, 0.95], [5.0, 0.6, 6.2, 1.0]])
    assert rects_safe(blocked, rect_cells(kept, ORIGIN, H)).all()
    assert all(any(_covers(r, p) for r in kept) for p in pts)


def test_repeated_and_contained_rectangles_are_kept_once():
    blocked = np.zeros((20, 100), dtype=np.int32)
    c = np.array([[0.0, 0.0, 2.0, 1.0], [0.0, 0.0, 2.0, 1.0], [0.5, 0.2, 1.5, 0.8], [2.0, 0.0, 3.0, 1.0]])
    kept = kept_prefix(c, _pts(0.2, 2.5), blocked, ORIGIN, H)
    assert np.array_equal(kept, c[[0, 3]])


def test_kept_rectangles_follow_a_scan_that_makes_a_cell_occupied():
    """With a real sensed map: rectangles observed safe are kept; after a scan puts a return
    inside one, it is cut (return away from the plan) or dropped (return on the plan), and
    every kept rectangle is safe in the map of that step."""
    m = SensedMap((0.0, 0.0, 8.0, 6.0), 0.3)
    angles = np.linspace(-np.pi, np.pi, 1441)
    pose = np.array([4.0, 3.0, 0.0])
    for _ in range(3):  # no returns: everything within 2.5 m observed free
        m.integrate(pose, np.full(angles.size, 2.5), np.zeros(angles.size, bool), angles)
    c = np.array([[3.0, 2.5, 4.5, 3.5], [4.5, 2.6, 5.5, 3.4]])
    g = m.grid
    assert m.rects_still_safe(c).all()
    pts = _pts(3.2, 5.2, y=3.0)
    assert np.array_equal(kept_prefix(c, pts, g.blocked, g.origin, g.resolution), c)
    # one return near the lower edge of the first rectangle, off the predicted path
    beam = np.array([np.arctan2(2.58 - 3.0, 3.62 - 4.0)])
    m.integrate(pose, np.hypot(3.62 - 4.0, 2.58 - 3.0) * np.ones(1), np.ones(1, bool), beam)
    assert not m.rects_still_safe(c)[0]
    kept = kept_prefix(c, pts, g.blocked, g.origin, g.resolution)
    assert len(kept) == 2 and np.array_equal(kept[1], c[1])
    assert m.rects_still_safe(kept).all() and kept[0][1] > c[0][1]
    assert ((pts[pts[:, 0] <= 4.5] >= kept[0][:2]) & (pts[pts[:, 0] <= 4.5] <= kept[0][2:])).all()
    # a return on the path in the second rectangle: the prefix ends before it
    beam = np.array([0.0])
    m.integrate(pose, np.array([1.0]), np.ones(1, bool), beam)
    assert not m.rects_still_safe(c[1:])[0]
    kept = kept_prefix(c, pts, g.blocked, g.origin, g.resolution)
    assert len(kept) == 1 and m.rects_still_safe(kept).all()


def _areas_of(rects):
    from sanav_mj.mapping.safe_areas import connectivity

    boxes = rect_cells(rects, ORIGIN, H)
    return connectivity(boxes, ORIGIN, H), boxes


def test_prefixed_areas_put_the_kept_rectangles_first_and_the_plan_runs_through_them():
    # current areas: the same free space cut differently (two rows instead of columns)
    cur = np.array([[0.0, 0.0, 5.0, 0.5], [0.0, 0.5, 5.0, 1.0], [5.0, 0.0, 6.0, 1.0]])
    areas, boxes = _areas_of(cur)
    kept = np.array([[0.0, 0.0, 2.0, 1.0], [2.0, 0.2, 3.0, 0.8]])
    aug, aug_boxes = prefixed_areas(areas, boxes, kept, ORIGIN, H)
    assert np.array_equal(aug.rects[:2], kept) and np.array_equal(aug.rects[2:], cur)
    assert np.array_equal(aug_boxes, np.vstack([rect_cells(kept, ORIGIN, H), boxes]))
    e = {tuple(x) for x in aug.edges.tolist()}
    assert e == {(0, 1), (1, 2), (1, 3), (2, 3), (2, 4), (3, 4)}
    for (i, j), por in zip(aug.edges, aug.portals):  # every portal lies in both rectangles
        for r in (aug.rects[i], aug.rects[j]):
            assert (por >= r[:2] - 1e-9).all() and (por <= r[2:] + 1e-9).all()
    robot = RobotParams(0.1, 0.38, 0.33, 20.0, 2.0, 3.0, 1.5, 4.0)
    p = plan(aug, np.array([0.5, 0.5, 0.0]), np.array([5.5, 0.5]), robot, PlannerConfig())
    assert p.ok and p.corridor[:2].tolist() == [0, 1]
    # the shifted plan (points through the kept rectangles) fits the chain's stage boxes
    chain = CorridorChain.build(aug, p.corridor, 0.02)
    guess = _pts(0.5, 2.8, n=21)
    s = assign_stages(chain, guess, None)
    b = stage_boxes(chain, s)[1:]
    g = guess[1:]
    assert ((g >= b[:, :2] - 1e-9) & (g <= b[:, 2:] + 1e-9)).all()


def test_without_kept_rectangles_the_same_guess_leaves_the_boxes():
    """The failure the kept prefix removes: the current areas cut across the guess's path
    (a horizontal split at y = 0.5 with the guess on y = 0.48 .. 0.52 crossing it), so the
    plain corridor's boxes do not hold it."""
    cur = np.array([[0.0, 0.0, 2.5, 0.5], [0.0, 0.5, 2.5, 1.0], [2.5, 0.0, 6.0, 1.0]])
    areas, _ = _areas_of(cur)
    robot = RobotParams(0.1, 0.38, 0.33, 20.0, 2.0, 3.0, 1.5, 4.0)
    p = plan(areas, np.array([0.5, 0.45, 0.0]), np.array([5.5, 0.9]), robot, PlannerConfig())
    chain = CorridorChain.build(areas, p.corridor, 0.02)
    guess = np.column_stack([np.linspace(0.5, 2.8, 21), 0.48 + 0.04 * (np.arange(21) % 2)])
    s = assign_stages(chain, guess, None)
    b = stage_boxes(chain, s)[1:]
    g = guess[1:]
    assert not ((g >= b[:, :2] - 1e-9) & (g <= b[:, 2:] + 1e-9)).all()


@pytest.mark.parametrize("seed", range(20))
def test_random_maps_every_kept_rectangle_is_safe_and_a_chain(seed):
    rng = np.random.default_rng(seed)
    blocked = (rng.random((30, 80)) < 0.01).astype(np.int32)
    xs = np.sort(rng.choice(np.arange(1, 80), 3, replace=False)) * H
    edges = np.concatenate([[0.0], xs, [4.0]])
    c = np.array([[edges[k], 0.0, edges[k + 1], 1.5] for k in range(4)])
    pts = np.column_stack([np.linspace(0.1, 3.9, 25), 0.75 + 0.3 * np.sin(np.linspace(0, 3, 25))])
    kept = kept_prefix(c, pts, blocked, ORIGIN, H)
    if len(kept):
        assert rects_safe(blocked, rect_cells(kept, ORIGIN, H)).all()
        assert all(_brute_safe(blocked, r) for r in kept)
        assert ((pts[0] >= kept[0][:2]) & (pts[0] <= kept[0][2:])).all()
        for a, b in zip(kept[:-1], kept[1:]):
            w = np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2])
            assert (w >= -1e-9).all() and w.max() > 1e-9
