"""SensedMap: scans at a measured pose -> safe areas equal to a rebuild; corridor invalidation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sanav_mj.mapping.safe_areas import build_safe_areas
from sanav_mj.mapping.sensed_map import SensedMap, SensedMapConfig


def _scan(pose, offset, angles, boxes, room, max_range=6.0):
    """Ranges from the sensor (at ``offset`` in the robot frame) to a room's walls and boxes."""
    x, y, th = pose
    sx = x + math.cos(th) * offset[0] - math.sin(th) * offset[1]
    sy = y + math.sin(th) * offset[0] + math.cos(th) * offset[1]
    a = th + angles
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    best = np.full(len(a), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for bx in boxes:  # slab method, outside the boxes
            t0 = np.maximum(np.minimum((bx[0] - sx) / d[:, 0], (bx[2] - sx) / d[:, 0]),
                            np.minimum((bx[1] - sy) / d[:, 1], (bx[3] - sy) / d[:, 1]))
            t1 = np.minimum(np.maximum((bx[0] - sx) / d[:, 0], (bx[2] - sx) / d[:, 0]),
                            np.maximum((bx[1] - sy) / d[:, 1], (bx[3] - sy) / d[:, 1]))
            ok = (t1 >= t0) & (t0 >= 0)
            best = np.where(ok, np.minimum(best, t0), best)
        tx = np.where(d[:, 0] > 0, (room[2] - sx) / d[:, 0], (room[0] - sx) / d[:, 0])
        ty = np.where(d[:, 1] > 0, (room[3] - sy) / d[:, 1], (room[1] - sy) / d[:, 1])
    best = np.minimum(best, np.minimum(tx, ty))
    hit = best <= max_range
    return np.where(hit, best, max_range), hit


def _coverage(boxes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """How many of ``boxes`` (K, 4) [i0, j0, i1, j1) cover each cell of a ``shape`` grid."""
    cover = np.zeros(shape, dtype=int)
    for i0, j0, i1, j1 in boxes.tolist():
        cover[i0:i1, j0:j1] += 1
    return cover


def test_scans_give_the_rebuilds_coverage_and_replan_test():
    room = (0.0, 0.0, 8.0, 4.0)
    offset = (0.12, 0.0)
    sm = SensedMap(room, 0.3, offset)
    angles = np.linspace(-2.356, 2.356, 361)
    boxes = [(4.0, 1.5, 4.4, 2.5)]
    for k in range(10):
        pose = (0.8 + 0.2 * k, 2.0, 0.1 * math.sin(k))
        r, hit = _scan(pose, offset, angles, boxes, room)
        up = sm.integrate(pose, r, hit, angles)
        ref = build_safe_areas(sm.grid.safe_grid())
        paint = _coverage(up.boxes, sm.grid.shape)
        assert np.array_equal(paint, _coverage(ref.boxes, sm.grid.shape)) and paint.max() <= 1
        assert set(up.timing_ms) == {"map", "areas", "snapshot", "route", "total"}
        # route areas: the rebuild's coverage of the route grid (unknown passable)
        route_ref = build_safe_areas(sm.grid.route_grid())
        rp = _coverage(up.route_boxes, sm.grid.shape)
        assert np.array_equal(rp, _coverage(route_ref.boxes, sm.grid.shape)) and rp.max() <= 1
        assert np.all(rp[paint == 1] == 1)  # safe space is route space
    # unexplored space (behind the box, in the blind sector behind the robot) is routable, not safe
    assert rp.sum() > paint.sum()
    assert up.areas.rects.shape[0] > 0
    # the sensor offset is applied: the box's near face (x = 4.0) is occupied at its cell
    st = sm.grid.states()
    assert st[40, 80] == 2 and st[40, 78] == 1
    # every rectangle handed out is still safe; a new obstacle inside one invalidates it
    rects = up.areas.rects
    assert sm.rects_still_safe(rects).all()
    k = int(np.argmax((rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])))
    cx, cy = 0.5 * (rects[k, 0] + rects[k, 2]), 0.5 * (rects[k, 1] + rects[k, 3])
    pose = (cx - 1.0 - offset[0], cy, 0.0)
    new_box = (cx - 0.05, cy - 0.05, cx + 0.05, cy + 0.05)
    r, hit = _scan(pose, offset, angles, boxes + [new_box], room)
    # the new obstacle's face was seen free before: its cells turn non-free after at most
    # k returns, k = the least with l_min + k l_occ > free_thresh (LiveGridConfig.floor_at)
    c = sm.grid.config
    k_max = math.floor((c.free_thresh - c.l_min) / c.l_occ + 1e-9) + 1
    for n in range(1, k_max + 1):
        up2 = sm.integrate(pose, r, hit, angles)
        if not sm.rects_still_safe(rects)[k]:
            break
    assert up2.changed and not sm.rects_still_safe(rects)[k] and n <= k_max
    row = sm.grid.states()[int(cy / 0.05), int((cx - 0.1) / 0.05):int((cx + 0.1) / 0.05)]
    assert np.any(row != 1)  # the new obstacle's face: its cells non-free
    # an unchanged scan changes nothing
    up3 = sm.integrate(pose, r, hit, angles)
    assert up3.boxes is up2.boxes or np.array_equal(up3.boxes, up2.boxes)
    # without route areas
    plain = SensedMap(room, 0.3, offset, SensedMapConfig(route=False))
    upp = plain.integrate(pose, r, hit, angles)
    assert upp.route_boxes is None and upp.route_areas is None and not upp.route_changed
    assert plain.route_areas() == (None, None)


def test_route_areas_on_demand_equal_the_per_scan_snapshot():
    """route_snapshot=False: no route areas in the result, and SensedMap.route_areas() later
    gives exactly what a map taking the snapshot at every scan returned (same boxes,
    rectangles, edges, weights, portals); the snapshot is reused while nothing changed."""
    room = (0.0, 0.0, 8.0, 4.0)
    offset = (0.12, 0.0)
    eager, lazy = SensedMap(room, 0.3, offset), SensedMap(room, 0.3, offset)
    angles = np.linspace(-2.356, 2.356, 361)
    boxes = [(4.0, 1.5, 4.4, 2.5), (2.5, 0.4, 2.7, 0.9)]
    for k in range(12):
        pose = (0.8 + 0.25 * k, 2.0 + 0.3 * math.cos(k), 0.3 * math.sin(k))
        r, hit = _scan(pose, offset, angles, boxes, room)
        ue = eager.integrate(pose, r, hit, angles)
        ul = lazy.integrate(pose, r, hit, angles, route_snapshot=False)
        assert ul.route_boxes is None and ul.route_areas is None and ul.route_changed == ue.route_changed
        if k % 3 == 2:  # ask only now and then (as a controller does at replans)
            b, a = lazy.route_areas()
            assert np.array_equal(b, ue.route_boxes)
            for name in ("rects", "edges", "weights", "portals"):
                assert np.array_equal(getattr(a, name), getattr(ue.route_areas, name))
            assert lazy.route_areas()[1] is a  # nothing changed since: the same snapshot
    assert len(b) > 5


BODY = (-0.25, 0.25, -0.215, 0.215)  # the packaged robot's footprint rectangle (deck) [m]


def test_safe_areas_on_demand_equal_the_per_scan_snapshot():
    """snapshot=False (scans and body clearing): no safe areas in the result, and
    areas_now() / boxes_now() read later give exactly what a map taking the snapshot at
    every update returned (boxes, rectangles, edges, weights, portals); the snapshot is
    reused while nothing changed."""
    room = (0.0, 0.0, 8.0, 4.0)
    offset = (0.12, 0.0)
    eager, lazy = SensedMap(room, 0.3, offset), SensedMap(room, 0.3, offset)
    angles = np.linspace(-2.356, 2.356, 361)
    boxes = [(4.0, 1.5, 4.4, 2.5), (2.5, 0.4, 2.7, 0.9)]
    asked = 0
    for k in range(12):
        pose = (0.8 + 0.25 * k, 2.0 + 0.3 * math.cos(k), 0.3 * math.sin(k))
        r, hit = _scan(pose, offset, angles, boxes, room)
        if k % 4 == 1:
            ce = eager.clear_box(pose, BODY, 0.05)
            cl = lazy.clear_box(pose, BODY, 0.05, snapshot=False)
            assert cl.boxes is None and cl.areas is None and cl.changed == ce.changed
        ue = eager.integrate(pose, r, hit, angles)
        ul = lazy.integrate(pose, r, hit, angles, snapshot=False)
        assert ul.boxes is None and ul.areas is None and ul.changed == ue.changed
        assert ul.n_safe_changed == ue.n_safe_changed
        if k % 3 == 2:  # ask only now and then (as a controller does at replans)
            asked += 1
            a, b = lazy.areas_now(), lazy.boxes_now()
            assert np.array_equal(b, ue.boxes) and np.array_equal(b, eager.boxes_now())
            for name in ("rects", "edges", "weights", "portals"):
                assert np.array_equal(getattr(a, name), getattr(ue.areas, name))
            assert lazy.areas_now() is a  # nothing changed since: the same snapshot
    assert asked == 4 and len(b) > 5


def _inside_body(pts, pose, box, tol=1e-9):
    """Whether (P, 2) world points lie in the body rectangle ``box`` at ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = pts[:, 0] - pose[0], pts[:, 1] - pose[1]
    bx, by = c * dx + s * dy, -s * dx + c * dy
    return (bx >= box[0] - tol) & (bx <= box[1] + tol) & (by >= box[2] - tol) & (by <= box[3] + tol)


def _corners(m, cells):
    g = m.grid
    i, j = np.divmod(cells, g.shape[1])
    return [np.stack([g.origin[0] + (j + dj) * g.resolution, g.origin[1] + (i + di) * g.resolution], axis=1)
            for di in (0, 1) for dj in (0, 1)]


def test_body_cells_lie_inside_the_true_body_for_any_pose_error_within_the_bound():
    """Own-footprint clearing never frees a cell an obstacle could occupy: for random true
    poses and estimated poses off by at most e_p (position) and e_y (yaw), every cell
    box_cells returns for the estimate, shrunk by e_p + rho e_y, lies entirely (all four
    corners) inside the body rectangle at the TRUE pose, where no obstacle is. With no
    shrink, some cells stick out (the test can fail)."""
    m = SensedMap((-3.0, -3.0, 3.0, 3.0), 0.38, (0.12, 0.0))
    rng = np.random.default_rng(5)
    rho = max(math.hypot(x, y) for x in BODY[:2] for y in BODY[2:])
    e_p, e_y = 0.03, 0.02
    outside_unshrunk = 0
    for _ in range(300):
        true = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-math.pi, math.pi)])
        ang = rng.uniform(0, 2 * math.pi)
        est = true + np.array([e_p * math.cos(ang), e_p * math.sin(ang), rng.choice([-1, 1]) * e_y])
        cells = m.box_cells(est, BODY, e_p + rho * e_y)
        assert len(cells) > 20
        for corner in _corners(m, cells):
            assert _inside_body(corner, true, BODY).all()
        loose = m.box_cells(est, BODY, 0.0)
        outside_unshrunk += sum(int((~_inside_body(c, true, BODY)).any()) for c in _corners(m, loose))
    assert outside_unshrunk > 0


def test_clear_box_frees_the_body_cells_once_but_never_a_cell_that_held_a_return():
    m = SensedMap((-3.0, -3.0, 3.0, 3.0), 0.38, (0.12, 0.0))
    pose = np.array([0.0, 0.0, 0.4])
    cells = m.box_cells(pose, BODY, 0.04)
    g = m.grid
    # a return inside the body rectangle (impossible for a real robot; a stale scan)
    inside = cells[len(cells) // 2]
    i, j = divmod(int(inside), g.shape[1])
    x = g.origin[0] + (j + 0.5) * g.resolution
    y = g.origin[1] + (i + 0.5) * g.resolution
    sx, sy = x - 1.0, y  # a sensor 1 m to the left, one beam
    g.integrate((sx, sy), 0.0, np.array([1.0]), np.array([True]), np.array([0.0]))
    assert g.states().reshape(-1)[inside] == 2  # occupied
    before = g.log_odds.reshape(-1).copy()
    m.clear_box(pose, BODY, 0.04)
    st = g.states().reshape(-1)
    assert st[inside] != 1  # never freed
    others = cells[cells != inside]
    assert (st[others] == 1).all()  # the others are free after one observation
    expected = np.maximum(before[others] + np.float32(g.config.l_free), np.float32(g.config.l_min))
    assert np.array_equal(g.log_odds.reshape(-1)[others], expected)  # one l_free each


def test_compiled_rect_test_equals_the_python_loop():
    """rects_still_safe with the compiled test (sanav_mj.mapping.rect_kernel) answers as the
    Python loop: the safe areas' own rectangles (all safe), random rectangles (partly
    unsafe), rectangles off the grid, empty and inverted ones, and all of them moved to cell
    edges or 1e-12 m beside them, at several map states."""
    from sanav_mj.mapping import rect_kernel

    if not rect_kernel.kernel_available():
        pytest.skip("no C compiler: only the Python loop exists")
    room = (0.0, 0.0, 8.0, 4.0)
    offset = (0.12, 0.0)
    m = SensedMap(room, 0.3, offset)
    angles = np.linspace(-2.356, 2.356, 361)
    boxes = [(4.0, 1.5, 4.4, 2.5), (2.5, 0.4, 2.7, 0.9)]
    rng = np.random.default_rng(3)
    seen = [0, 0]
    for k in range(8):
        pose = (0.8 + 0.4 * k, 2.0 + 0.3 * math.cos(k), 0.3 * math.sin(k))
        r, hit = _scan(pose, offset, angles, boxes, room)
        m.integrate(pose, r, hit, angles)
        lo = rng.uniform(-1.0, 8.5, (300, 2))
        rects = np.concatenate([m.areas_now().rects, np.column_stack([lo, lo + rng.uniform(-0.2, 2.0, (300, 2))]),
                                [[-3.0, -3.0, -1.0, -1.0], [1.0, 1.0, 1.0, 2.0], [9.0, 1.0, 12.0, 2.0]]])
        rects = np.concatenate([rects, np.tile(m.grid.origin, 2) + np.round(  # on cell edges, or just beside
            (rects - np.tile(m.grid.origin, 2)) / 0.05) * 0.05 + rng.choice([0.0, 1e-12, -1e-12], rects.shape)])
        ref = m.rects_still_safe(rects, use_kernel=False)
        assert np.array_equal(m.rects_still_safe(rects), ref)
        seen[0] += ref.sum()
        seen[1] += (~ref).sum()
    assert min(seen) > 100
