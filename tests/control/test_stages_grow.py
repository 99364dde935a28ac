"""The corridor chain grown to maximal free rectangles (``SafeAreas.free``): free, larger, same order."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sanav_mj.control.stages import CorridorChain, box_intersection, safe_area_params
from sanav_mj.mapping.grow import FreeCells
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.safe_areas import build_safe_areas, locate

H = 0.05


def staircase_grid() -> OccupancyGrid:
    """A 45-degree channel three cells wide (measured along x) through a 16 x 16 grid."""
    n = 16
    i, j = np.mgrid[0:n, 0:n]
    occ = np.abs(i - j) > 1
    return OccupancyGrid(occ, H, np.zeros(2), 0.0, np.array([0.0, 0.0, n * H, n * H]))


def corridor_between(areas, p, q) -> np.ndarray:
    """Shortest chain of adjacent areas (BFS over the graph) from the area of p to the area of q."""
    a, b = locate(areas, p), locate(areas, q)
    prev = {a: -1}
    todo = [a]
    while todo:
        nxt = []
        for k in todo:
            for u, v in areas.edges:
                for x, y in ((int(u), int(v)), (int(v), int(u))):
                    if x == k and y not in prev:
                        prev[y] = k
                        nxt.append(y)
        todo = nxt
    path = [b]
    while prev[path[-1]] != -1:
        path.append(prev[path[-1]])
    return np.array(path[::-1])


def test_grown_chain_is_free_contains_the_plain_one_and_overlaps_more():
    g = staircase_grid()
    m = build_safe_areas(g)
    corridor = corridor_between(m.areas, (0.025, 0.025), (0.775, 0.775))
    assert len(corridor) > 4  # a staircase of thin areas
    plain = CorridorChain.build(m.areas, corridor, 0.0)
    grown = CorridorChain.build(replace(m.areas, free=FreeCells.of(g)), corridor, 0.0)
    assert plain.area_rects is None
    np.testing.assert_array_equal(grown.rect_pair, plain.rect_pair)
    cells = FreeCells.of(g)
    for box, old in zip(grown.boxes, plain.boxes):
        i0, j0, i1, j1 = cells.cells_of(box)
        assert not g.occupied[i0:i1, j0:j1].any()  # only free cells
        assert np.all(box[:2] <= old[:2]) and np.all(box[2:] >= old[2:])  # contains the plain member
    inter = lambda c: np.prod(np.maximum(c[1:, 2:] - c[1:, :2], 0.0), axis=1)  # noqa: E731
    a_plain = inter(box_intersection(plain.boxes[:-1], plain.boxes[1:])[None][0])
    a_grown = inter(box_intersection(grown.boxes[:-1], grown.boxes[1:])[None][0])
    assert np.all(a_grown >= a_plain - 1e-12) and a_grown.sum() > a_plain.sum()
    # J_SA's slots take the grown areas of a grown chain, the areas themselves otherwise
    q = np.array([5.0, 5.0])
    changed = [p for p, a in enumerate(corridor) if not np.allclose(grown.area_rects[a], m.areas.rects[a])]
    assert changed
    p = changed[0]
    th_plain = safe_area_params(plain, m.areas.rects, (2 * p, 2 * p), 2, q, 0.0).reshape(2, 6)
    th_grown = safe_area_params(grown, m.areas.rects, (2 * p, 2 * p), 2, q, 0.0).reshape(2, 6)
    np.testing.assert_allclose(th_plain[0, :4], m.areas.rects[corridor[p]])
    np.testing.assert_allclose(th_grown[0, :4], grown.area_rects[corridor[p]])
    np.testing.assert_allclose(th_grown[0, :4], grown.boxes[2 * p])


def test_growth_limit_zero_gives_the_plain_members():
    g = staircase_grid()
    m = build_safe_areas(g)
    corridor = corridor_between(m.areas, (0.025, 0.025), (0.775, 0.775))
    plain = CorridorChain.build(m.areas, corridor, 0.02)
    zero = CorridorChain.build(replace(m.areas, free=FreeCells.of(g, 0.0)), corridor, 0.02)
    np.testing.assert_array_equal(zero.boxes, plain.boxes)
    np.testing.assert_array_equal(zero.stay, plain.stay)
    np.testing.assert_array_equal(zero.advance, plain.advance)


def test_tightened_growth_keeps_the_plain_room_and_tightens_only_the_added_room():
    g = staircase_grid()
    m = build_safe_areas(g)
    corridor = corridor_between(m.areas, (0.025, 0.025), (0.775, 0.775))
    plain = CorridorChain.build(m.areas, corridor, 0.01)
    loose = CorridorChain.build(replace(m.areas, free=FreeCells.of(g)), corridor, 0.01)
    tight = CorridorChain.build(replace(m.areas, free=FreeCells.of(g, tighten=0.05)), corridor, 0.01)
    huge = CorridorChain.build(replace(m.areas, free=FreeCells.of(g, tighten=10.0)), corridor, 0.01)
    for c in (loose, tight, huge):
        for box, mem in ((c.stay, c.boxes), (c.advance[1:], c.boxes[1:])):
            assert np.all(box[:, :2] >= mem[:, :2] - 1e-12) and np.all(box[:, 2:] <= mem[:, 2:] + 1e-12)
    for a, b in ((plain, tight), (tight, loose)):  # plain <= tight <= loose, side by side
        for x, y in ((a.stay, b.stay), (a.advance, b.advance)):
            assert np.all(y[:, :2] <= x[:, :2] + 1e-12) and np.all(y[:, 2:] >= x[:, 2:] - 1e-12)
    # a tightening larger than any growth leaves exactly the plain stage boxes
    np.testing.assert_allclose(huge.stay, plain.stay)
    np.testing.assert_allclose(huge.advance, plain.advance)
    # a side grown by d moves out by max(0, d - 0.05) beyond where the plain box's side is (here: shrink
    # by 0.01 on a member at least 0.1 m wide)
    k = int(np.argmax((loose.boxes[:, 2] - loose.boxes[:, 0]) - (plain.boxes[:, 2] - plain.boxes[:, 0])))
    d = plain.boxes[k, 0] - loose.boxes[k, 0]
    assert tight.stay[k, 0] == pytest.approx(min(plain.stay[k, 0], loose.boxes[k, 0] + 0.01 + 0.05))
    assert d > 0


def l_turn_grid() -> OccupancyGrid:
    """A passage 5 cells (0.25 m) tall along x turning up into one 2 cells (0.1 m) wide, with
    free cells below the junction: the portal bridge, grown, is the narrow passage."""
    n = 20
    free = np.zeros((n, n), bool)
    free[4:9, 0:15] = True  # the wide passage, y 0.2..0.45, x 0..0.75
    free[4:, 13:15] = True  # the narrow one going up, x 0.65..0.75
    free[1:4, 8:14] = True  # room below the junction
    return OccupancyGrid(~free, H, np.zeros(2), 0.0, np.array([0.0, 0.0, n * H, n * H]))


def test_bridge_at_a_turn_into_a_narrow_passage_is_the_roomier_free_rectangle():
    g = l_turn_grid()
    m = build_safe_areas(g)
    corridor = corridor_between(m.areas, (0.025, 0.325), (0.725, 0.975))
    cells = FreeCells.of(g)
    chain = CorridorChain.build(replace(m.areas, free=cells), corridor, 0.0)
    assert len(chain) == 3
    # the portal strip grown is the narrow passage (0.1 m); the overlap of the grown areas,
    # grown, is the wide passage (0.25 m): room for the footprint to swing round
    np.testing.assert_allclose(chain.boxes[1], [0.0, 0.2, 0.75, 0.45], atol=1e-12)
    inter = box_intersection(chain.boxes[:-1], chain.boxes[1:])
    assert np.all(inter[:, 2:] - inter[:, :2] > 0)  # consecutive members overlap
    for box in np.concatenate((chain.boxes, chain.stay, chain.advance[1:])):
        i0, j0, i1, j1 = cells.cells_of(box)
        assert not g.occupied[i0:i1, j0:j1].any()  # only free cells
    # with a margin the stage boxes are the members shrunk (the plain bridge is not kept)
    m2 = CorridorChain.build(replace(m.areas, free=cells), corridor, 0.02)
    np.testing.assert_allclose(m2.stay[1], [0.02, 0.22, 0.73, 0.43], atol=1e-12)
    np.testing.assert_allclose(m2.advance[2], [0.67, 0.22, 0.73, 0.43], atol=1e-12)
