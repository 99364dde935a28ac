"""The corridor search's narrow-place penalty (footprint discs mode)."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.corridor import build_graph, penalise_narrow, shortest_corridor_dijkstra


def _areas() -> SafeAreas:
    """Start area 0 and goal area 3 joined by a short way through a 5 cm sliver (1) and a
    longer way through a 0.4 m wide area (2)."""
    rects = np.array([
        [0.0, 0.0, 1.0, 1.0],    # 0 start
        [1.0, 0.45, 1.5, 0.5],   # 1 sliver, short side 0.05
        [0.0, 1.0, 2.5, 1.4],    # 2 wide detour, short side 0.4
        [1.5, 0.0, 2.5, 1.0],    # 3 goal
    ])
    edges = np.array([[0, 1], [1, 3], [0, 2], [2, 3]])
    portals = np.array([
        [[1.0, 0.45], [1.0, 0.5]], [[1.5, 0.45], [1.5, 0.5]],
        [[0.0, 1.0], [1.0, 1.0]], [[1.5, 1.0], [2.5, 1.0]],
    ])
    c = (rects[:, :2] + rects[:, 2:]) / 2
    w = np.hypot(*(c[edges[:, 0]] - c[edges[:, 1]]).T)
    return SafeAreas(rects, edges, w, portals)


def test_narrow_edges_get_the_penalty_known_answer():
    a = _areas()
    out = penalise_narrow(a, 0.1, 1.0)
    np.testing.assert_allclose(out.weights - a.weights, [1.0, 1.0, 0.0, 0.0], rtol=0, atol=0)
    np.testing.assert_array_equal(out.rects, a.rects)
    assert penalise_narrow(a, 0.0, 1.0) is a and penalise_narrow(a, 0.1, 0.0) is a
    with pytest.raises(ValueError, match="width"):
        penalise_narrow(a, -0.1, 1.0)


def test_the_search_takes_the_wider_way_when_penalised():
    a = _areas()
    assert shortest_corridor_dijkstra(build_graph(a), 0, 3).tolist() == [0, 1, 3]
    assert shortest_corridor_dijkstra(build_graph(penalise_narrow(a, 0.1, 1.0)), 0, 3).tolist() == [0, 2, 3]
