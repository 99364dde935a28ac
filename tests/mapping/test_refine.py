"""Tests for sanav_mj.mapping.refine: finer cells where passages are narrow, every area still free."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _mapping_reference import cell_obstacle_distance
from sanav_mj.mapping import MapConfig, build_map, locate, rasterise
from sanav_mj.mapping.refine import free_run_lengths, refine_narrow
from sanav_mj.scene import Obstacle

RHO = 0.2306 + 0.02  # [m] inflation: 3-disc radius of the robot + a 0.02 m margin
BOUNDS = (0.0, 0.0, 2.0, 2.0)


def box(x0, y0, x1, y1) -> Obstacle:
    c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    return Obstacle("b", "box", c, 0.0, np.array([(x1 - x0) / 2, (y1 - y0) / 2]), 1.0, -1)


def cylinder(cx, cy, r) -> Obstacle:
    return Obstacle("c", "cylinder", np.array([cx, cy], float), 0.0, np.array([r, r], float), 1.0, -1)


def gap_walls(a: float, b: float) -> list[Obstacle]:
    """Two walls across y in [0.9, 1.1] leaving a gap whose free interval for the centre is (a, b) in x."""
    return [box(-0.5, 0.9, a - RHO, 1.1), box(b + RHO, 0.9, 2.5, 1.1)]


def connected(m, p, q) -> bool:
    """Whether the safe areas containing points p and q are joined in the graph (BFS)."""
    a, b = locate(m.areas, p), locate(m.areas, q)
    seen, todo = {a}, [a]
    while todo:
        i = todo.pop()
        for u, v in m.areas.edges:
            for x, y in ((u, v), (v, u)):
                if x == i and y not in seen:
                    seen.add(int(y))
                    todo.append(int(y))
    return b in seen


def test_free_run_lengths_known_answer():
    free = np.array([[1, 1, 0, 1],
                     [0, 1, 1, 1],
                     [1, 1, 0, 0]], dtype=bool)
    along_x, along_y = free_run_lengths(free)
    np.testing.assert_array_equal(along_x, [[2, 2, 0, 1], [0, 3, 3, 3], [2, 2, 0, 0]])
    np.testing.assert_array_equal(along_y, [[1, 3, 0, 2], [0, 3, 1, 2], [1, 3, 0, 0]])


def test_free_run_lengths_rejects_non_bool():
    with pytest.raises(ValueError, match="bool"):
        free_run_lengths(np.zeros((2, 2)))


def test_passage_opens_with_refinement_and_is_closed_without():
    # The gap is 2 RHO + 0.027 m wide: the centre's free interval is (0.999, 1.026) m. No 0.05 m
    # cell fits inside it ([1.0, 1.05] reaches past 1.026); the 0.025 m cell [1.0, 1.025] does.
    obstacles = gap_walls(0.999, 1.026)
    row = int(1.0 / 0.025)  # a fine row through the walls (y in [1.0, 1.025])
    coarse = build_map(obstacles, BOUNDS, RHO, MapConfig(resolution=0.05))
    assert not (~coarse.grid.occupied[row // 2]).any()
    fine_everywhere = build_map(obstacles, BOUNDS, RHO, MapConfig(resolution=0.025))
    refined = build_map(obstacles, BOUNDS, RHO, MapConfig(resolution=0.05, refine=2, refine_width=0.25))
    assert refined.grid.resolution == 0.025 and refined.grid.shape == (80, 80)
    for m in (fine_everywhere, refined):
        free_cols = np.flatnonzero(~m.grid.occupied[row])
        np.testing.assert_array_equal(free_cols, [40])  # exactly the cell [1.0, 1.025] in x
    # the safe areas join the two sides through that column only
    k = locate(refined.areas, (1.0125, 1.0))
    np.testing.assert_allclose(refined.rects[k, [0, 2]], [1.0, 1.025])
    assert connected(refined, (1.0125, 0.2), (1.0125, 1.8))
    assert not connected(coarse, (1.0125, 0.2), (1.0125, 1.8))
    # a refinement width below the passage's run closes it again: the coarse grid at the fine cell
    none = build_map(obstacles, BOUNDS, RHO, MapConfig(resolution=0.05, refine=2, refine_width=0.0))
    up = np.repeat(np.repeat(coarse.grid.occupied, 2, axis=0), 2, axis=1)
    np.testing.assert_array_equal(none.grid.occupied, up)


def test_one_millimetre_narrower_stays_closed_at_the_fine_cell():
    # free interval (1.0005, 1.026): 0.0255 m, but no 0.025 m cell of the lattice fits in it
    refined = build_map(gap_walls(1.0005, 1.026), BOUNDS, RHO, MapConfig(resolution=0.05, refine=2))
    assert refined.grid.occupied[40].all()


def test_wide_space_keeps_the_coarse_cells():
    # one cylinder in open space: no run of free cells near it is short, nothing is refined
    obstacles = [cylinder(1.0, 1.0, 0.075)]
    coarse = rasterise(obstacles, BOUNDS, 0.05, inflation=RHO)
    fine = rasterise(obstacles, BOUNDS, 0.025, inflation=RHO)
    out = refine_narrow(coarse, fine, 0.25)
    np.testing.assert_array_equal(out.occupied, np.repeat(np.repeat(coarse.occupied, 2, axis=0), 2, axis=1))
    assert (fine.occupied != out.occupied).any()  # the fine grid alone would differ there


def test_refine_narrow_checks_its_inputs():
    coarse = rasterise([], BOUNDS, 0.05, inflation=RHO)
    with pytest.raises(ValueError, match="integer >= 2"):
        refine_narrow(coarse, rasterise([], BOUNDS, 0.03, inflation=RHO), 0.25)
    with pytest.raises(ValueError, match="inflation"):
        refine_narrow(coarse, rasterise([], BOUNDS, 0.025, inflation=0.1), 0.25)
    with pytest.raises(ValueError, match="width"):
        refine_narrow(coarse, rasterise([], BOUNDS, 0.025, inflation=RHO), -0.1)


@pytest.mark.parametrize("kwargs, match", [({"refine": 0}, "refine"), ({"refine": True}, "refine"),
                                           ({"refine": 2.0}, "refine"), ({"refine_width": -1.0}, "refine_width"),
                                           ({"refine_width": float("nan")}, "refine_width")])
def test_map_config_validates_refinement(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MapConfig(**kwargs)


coord = st.floats(0.1, 1.9, allow_nan=False)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(coord, coord, st.floats(0.02, 0.2)), min_size=1, max_size=8),
       st.lists(st.tuples(coord, coord, st.floats(0.0, 0.3), st.floats(0.0, 0.3)), max_size=3),
       st.sampled_from([2, 4]), st.floats(0.0, 0.6), st.sampled_from([0.0, 0.1, RHO]))
def test_every_refined_safe_area_is_free(cyls, boxes, factor, width, inflation):
    obstacles = [cylinder(x, y, r) for x, y, r in cyls] + [box(x - hx, y - hy, x + hx, y + hy) for x, y, hx, hy in boxes]
    m = build_map(obstacles, BOUNDS, inflation, MapConfig(resolution=0.1, refine=factor, refine_width=width))
    coarse = rasterise(obstacles, BOUNDS, 0.1, inflation=inflation)
    fine = rasterise(obstacles, BOUNDS, 0.1 / factor, inflation=inflation)
    free = ~m.grid.occupied
    # between the coarse grid and the fine one
    assert not (free & fine.occupied).any()
    assert not (np.repeat(np.repeat(~coarse.occupied, factor, 0), factor, 1) & ~free).any()
    # independent check: every safe rectangle (closed) is farther than the inflation from every obstacle
    for x0, y0, x1, y1 in m.rects:
        assert BOUNDS[0] <= x0 and x1 <= BOUNDS[2] + 1e-12 and BOUNDS[1] <= y0 and y1 <= BOUNDS[3] + 1e-12
        for ob in obstacles:
            assert cell_obstacle_distance(ob, x0, y0, x1, y1) > inflation - 1e-9
