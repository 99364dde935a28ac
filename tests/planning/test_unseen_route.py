"""Route weights that prefer seen space (`planning.unseen`, `SensingConfig.unseen_route`)."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.control.sensing_config import SensingConfig
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.corridor import shortest_corridor_dijkstra, build_graph
from sanav_mj.planning.unseen import penalise_unseen, unseen_fraction


def test_unseen_fraction_counts_cell_centres_known_answer():
    seen = np.ones((4, 6), dtype=bool)  # 0.1 m cells, origin (0, 0): x 0..0.6, y 0..0.4
    seen[0:2, 3:6] = False  # the lower right block, x 0.3..0.6, y 0..0.2
    rects = np.array([
        [0.0, 0.0, 0.3, 0.4],   # all seen: 0
        [0.3, 0.0, 0.6, 0.4],   # 6 of 12 unseen
        [0.3, 0.0, 0.6, 0.2],   # all unseen
        [0.32, 0.0, 0.38, 0.2],  # centre column x = 0.35 -> 2 of 2 unseen
        [0.31, 0.31, 0.34, 0.34],  # holds no cell centre: 0
    ])
    np.testing.assert_array_equal(unseen_fraction(rects, seen, (0.0, 0.0), 0.1), [0.0, 0.5, 1.0, 1.0, 0.0])
    with pytest.raises(ValueError, match="resolution"):
        unseen_fraction(rects, seen, (0.0, 0.0), 0.0)


def _two_ways() -> SafeAreas:
    """Start 0 and goal 3, joined by a short way through area 1 (unseen) and a longer way
    through area 2 (seen). 0.1 m cells over x 0..3, y 0..2."""
    rects = np.array([
        [0.0, 0.0, 1.0, 1.0],   # 0 start
        [1.0, 0.0, 2.0, 1.0],   # 1 straight on: unseen
        [0.0, 1.0, 3.0, 2.0],   # 2 round about: seen
        [2.0, 0.0, 3.0, 1.0],   # 3 goal
    ])
    edges = np.array([[0, 1], [1, 3], [0, 2], [2, 3]])
    portals = np.array([[[1.0, 0.0], [1.0, 1.0]], [[2.0, 0.0], [2.0, 1.0]],
                        [[0.0, 1.0], [1.0, 1.0]], [[2.0, 1.0], [3.0, 1.0]]])
    c = (rects[:, :2] + rects[:, 2:]) / 2
    return SafeAreas(rects, edges, np.hypot(*(c[edges[:, 0]] - c[edges[:, 1]]).T), portals)


def test_the_route_prefers_seen_space_only_with_the_factor():
    a = _two_ways()
    seen = np.ones((20, 30), dtype=bool)
    seen[0:10, 10:20] = False  # area 1
    straight = shortest_corridor_dijkstra(build_graph(a), 0, 3)
    assert list(straight) == [0, 1, 3]
    b = penalise_unseen(a, seen, (0.0, 0.0), 0.1, 1.0)
    # edges touching area 1 (u = 1) get 1 + 0.5, the others stay
    np.testing.assert_allclose(b.weights, a.weights * np.array([1.5, 1.5, 1.0, 1.0]), rtol=0, atol=0)
    assert list(shortest_corridor_dijkstra(build_graph(b), 0, 3)) == [0, 2, 3]
    assert penalise_unseen(a, seen, (0.0, 0.0), 0.1, 0.0) is a
    with pytest.raises(ValueError, match="factor"):
        penalise_unseen(a, seen, (0.0, 0.0), 0.1, -1.0)


def test_the_setting_is_checked_and_off_by_default():
    assert SensingConfig().unseen_route == 0.0
    with pytest.raises(ValueError, match="unseen_route"):
        SensingConfig(unseen_route=-0.5)
