"""Corridor search, goal projection and portal waypoints (sanav_mj/planning/corridor.py)."""

from __future__ import annotations

import numpy as np
import pytest
from planning_maps import areas_from_rects, grid_to_rects
from scipy.optimize import minimize

from sanav_mj.planning.corridor import (
    build_graph,
    contains,
    find_area,
    funnel_path,
    oriented_portals,
    path_length,
    portal_waypoints,
    project_into_rect,
    reachable_from,
    rect_distance,
    shortest_corridor_astar,
    shortest_corridor_dijkstra,
    shrink_portals,
)

RECTS = np.array([[0.0, 0.0, 2.0, 1.0], [2.0, 0.0, 3.0, 3.0], [5.0, 5.0, 6.0, 6.0]])


def test_rect_distance_known_answers():
    d = rect_distance(RECTS, np.array([1.0, 0.5]))
    assert d[0] == 0.0
    assert d[1] == pytest.approx(1.0)
    assert d[2] == pytest.approx(np.hypot(4.0, 4.5))
    # corner distance
    assert rect_distance(RECTS[:1], np.array([3.0, 2.0]))[0] == pytest.approx(np.hypot(1.0, 1.0))


def test_contains_closed_boundary():
    m = contains(RECTS, np.array([[2.0, 0.5], [2.5, 3.0], [4.0, 4.0], [2.0 + 1e-12, 1.0]]))
    assert m.tolist() == [[True, True, False], [False, True, False], [False, False, False], [True, True, False]]


def test_find_area_inside_nearest_and_allowed():
    assert find_area(RECTS, np.array([2.5, 2.0])) == (1, 0.0)
    i, d = find_area(RECTS, np.array([4.0, 4.0]))  # nearest is rect 1 (corner 3,3)
    assert i == 1 and d == pytest.approx(np.hypot(1.0, 1.0))
    i, d = find_area(RECTS, np.array([4.0, 4.0]), allowed=np.array([True, False, True]))
    assert i == 2 and d == pytest.approx(np.hypot(1.0, 1.0))
    assert find_area(RECTS, np.array([4.0, 4.0]), allowed=np.zeros(3, bool))[0] == -1


def test_project_into_rect_edge_corner_and_narrow():
    r = np.array([0.0, 0.0, 4.0, 2.0])
    np.testing.assert_allclose(project_into_rect(r, np.array([5.0, 1.0]), 0.1), [3.9, 1.0])
    np.testing.assert_allclose(project_into_rect(r, np.array([-1.0, -1.0]), 0.1), [0.1, 0.1])
    np.testing.assert_allclose(project_into_rect(r, np.array([2.0, 1.0]), 0.1), [2.0, 1.0])  # inside: unchanged
    narrow = np.array([0.0, 0.0, 4.0, 0.1])
    np.testing.assert_allclose(project_into_rect(narrow, np.array([2.0, 3.0]), 0.1), [2.0, 0.05])


def test_graph_lookup_and_reachability():
    areas = areas_from_rects(RECTS)
    g = build_graph(areas)
    assert g.edge_between(np.array([0, 1, 0]), np.array([1, 0, 2])).tolist() == [0, 0, -1]
    assert reachable_from(g, 0).tolist() == [True, True, False]
    assert shortest_corridor_astar(g, 0, 2) is None
    assert shortest_corridor_dijkstra(g, 0, 2) is None
    assert shortest_corridor_astar(g, 1, 1).tolist() == [1]


def _random_areas(seed: int, ny: int = 9, nx: int = 12, p_free: float = 0.72):
    rng = np.random.default_rng(seed)
    free = rng.random((ny, nx)) < p_free
    return areas_from_rects(grid_to_rects(free, 1.0)), rng


def _cost(areas, path):
    g = build_graph(areas)
    e = g.edge_between(path[:-1], path[1:])
    assert np.all(e >= 0), "consecutive corridor areas must be adjacent"
    return float(np.sum(areas.weights[e]))


@pytest.mark.parametrize("seed", range(12))
def test_astar_and_dijkstra_find_equally_short_corridors(seed):
    areas, rng = _random_areas(seed)
    g = build_graph(areas)
    R = len(areas.rects)
    for _ in range(6):
        a, b = (int(v) for v in rng.integers(0, R, 2))
        pa = shortest_corridor_astar(g, a, b)
        pd = shortest_corridor_dijkstra(g, a, b)
        assert (pa is None) == (pd is None)
        assert (pa is None) == (not reachable_from(g, a)[b])
        if pa is not None:
            assert pa[0] == a and pa[-1] == b and pd[0] == a and pd[-1] == b
            assert _cost(areas, pa) == pytest.approx(_cost(areas, pd), rel=1e-12, abs=1e-12)


def test_oriented_portals_left_and_right():
    # travelling +x from [0,0,1,1] into [1,0,2,1]: left end is the upper one
    areas = areas_from_rects([[0, 0, 1, 1], [1, 0, 2, 1]])
    g = build_graph(areas)
    np.testing.assert_allclose(oriented_portals(areas, g, np.array([0, 1]))[0], [[1, 1], [1, 0]])
    np.testing.assert_allclose(oriented_portals(areas, g, np.array([1, 0]))[0], [[1, 0], [1, 1]])
    with pytest.raises(ValueError, match="not adjacent"):
        oriented_portals(areas_from_rects(RECTS), build_graph(areas_from_rects(RECTS)), np.array([0, 2]))


def test_shrink_portals():
    p = np.array([[[0.0, 0.0], [0.0, 2.0]], [[1.0, 0.0], [1.3, 0.0]]])
    s = shrink_portals(p, 0.25)
    np.testing.assert_allclose(s[0], [[0, 0.25], [0, 1.75]])
    np.testing.assert_allclose(s[1], [[1.15, 0], [1.15, 0]])  # shorter than 2 * clearance: midpoint


def test_l_turn_waypoints_known_answer():
    areas = areas_from_rects([[0, 0, 4, 1], [3, 1, 4, 4]])
    g = build_graph(areas)
    por = oriented_portals(areas, g, np.array([0, 1]))
    wp = portal_waypoints(np.array([0.5, 0.5]), np.array([3.5, 3.5]), por, 0.25)
    np.testing.assert_allclose(wp, [[0.5, 0.5], [3.25, 1.0], [3.5, 3.5]])


def test_straight_through_portals_has_no_bend():
    areas = areas_from_rects([[0, 0, 1, 2], [1, 0, 2, 2], [2, 0, 3, 2]])
    g = build_graph(areas)
    por = oriented_portals(areas, g, np.array([0, 1, 2]))
    wp = portal_waypoints(np.array([0.5, 0.5]), np.array([2.5, 1.5]), por, 0.1)
    np.testing.assert_allclose(wp[1:3], [[1.0, 0.75], [2.0, 1.25]])
    assert path_length(wp) == pytest.approx(np.hypot(2.0, 1.0))


def _optimal_length(start, goal, shrunk):
    """Reference: minimise the polyline length over the crossing parameters by L-BFGS-B."""
    p0, p1 = shrunk[:, 0], shrunk[:, 1]
    e = p1 - p0

    def f(t):
        pts = np.vstack([start, p0 + t[:, None] * e, goal])
        d = np.diff(pts, axis=0)
        n = np.maximum(np.linalg.norm(d, axis=1), 1e-15)
        u = d / n[:, None]  # unit direction of each segment
        grad = np.einsum("ij,ij->i", u[:-1] - u[1:], e)
        return float(n.sum()), grad

    best = np.inf
    P = len(shrunk)
    for t0 in (np.full(P, 0.5), np.zeros(P), np.ones(P)):
        r = minimize(f, t0, jac=True, bounds=[(0, 1)] * P, method="L-BFGS-B", options={"ftol": 1e-15, "gtol": 1e-12})
        best = min(best, r.fun)
    return best


@pytest.mark.parametrize("seed", range(20))
def test_funnel_matches_numerical_optimum_and_stays_on_portals(seed):
    areas, rng = _random_areas(100 + seed)
    g = build_graph(areas)
    R = len(areas.rects)
    rects = np.asarray(areas.rects)
    for _ in range(10):
        a, b = (int(v) for v in rng.integers(0, R, 2))
        cor = shortest_corridor_astar(g, a, b)
        if cor is not None and len(cor) >= 3:
            break
    else:
        pytest.skip("no corridor of 3+ areas in this map")
    start = rects[a, :2] + rng.random(2) * (rects[a, 2:] - rects[a, :2])
    goal = rects[b, :2] + rng.random(2) * (rects[b, 2:] - rects[b, :2])
    por = oriented_portals(areas, g, cor)
    clearance = 0.2
    wp = portal_waypoints(start, goal, por, clearance)
    shrunk = shrink_portals(por, clearance)
    # every crossing lies on its shrunk portal
    for k in range(len(por)):
        a0, a1 = shrunk[k]
        q = wp[k + 1]
        seg = a1 - a0
        t = 0.5 if not seg.any() else float(np.dot(q - a0, seg) / np.dot(seg, seg))
        assert -1e-9 <= t <= 1 + 1e-9
        np.testing.assert_allclose(q, a0 + t * seg, atol=1e-9)
    # every segment lies in its corridor rectangle (both ends in the same closed rectangle)
    for k in range(len(cor)):
        assert contains(rects[cor[k] : cor[k] + 1], wp[k : k + 2]).all()
    # shortest: equal to the numerical optimum
    assert path_length(wp) == pytest.approx(_optimal_length(start, goal, shrunk), rel=1e-6, abs=1e-6)
    # a funnel vertex is a shrunk-portal end point (or the start / goal)
    verts, _ = funnel_path(start, goal, shrunk)
    ends = np.vstack([start, goal, shrunk.reshape(-1, 2)])
    for v in verts:
        assert np.min(np.linalg.norm(ends - v, axis=1)) < 1e-9
