"""Tests for sanav_mj.mapping.safe_areas: merging, connectivity graph, locate, the whole stage."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from _mapping_reference import edges_reference, grids, merge_reference
from sanav_mj.mapping import MapConfig, build_map
from sanav_mj.mapping.occupancy import rasterise
from sanav_mj.mapping.quadtree import build_quadtree
from sanav_mj.mapping.safe_areas import (
    SafeAreas,
    build_safe_areas,
    connectivity,
    locate,
    merge_rects,
)
from sanav_mj.scene import Obstacle


def box(cx, cy, hx, hy, yaw=0.0) -> Obstacle:
    return Obstacle("b", "box", np.array([cx, cy], float), float(yaw), np.array([hx, hy], float), 1.0, -1)


def coverage(boxes, shape) -> np.ndarray:
    cover = np.zeros(shape, dtype=int)
    for i0, j0, i1, j1 in boxes:
        cover[i0:i1, j0:j1] += 1
    return cover


def shares_complete_edge(a, b) -> bool:
    i0, j0, i1, j1 = a
    k0, l0, k1, l1 = b
    return ((i0, i1) == (k0, k1) and (j1 == l0 or l1 == j0)) or ((j0, j1) == (l0, l1) and (i1 == k0 or k1 == i0))


@settings(max_examples=150, deadline=None)
@given(grids(), st.integers(1, 3))
def test_merged_rects_partition_the_free_cells(occ, min_cell):
    leaves = build_quadtree(occ, min_cell)
    free_leaves = leaves.boxes[leaves.free]
    rects = merge_rects(free_leaves)
    free_cells = coverage(free_leaves, occ.shape) == 1
    cover = coverage(rects, occ.shape)
    # Disjoint, free, and their union is exactly the free (leaf) cells.
    assert np.array_equal(cover, free_cells.astype(int))
    assert not np.any(occ[cover > 0])
    # Merging only joins leaves: every free leaf lies inside exactly one rectangle.
    for i0, j0, i1, j1 in free_leaves:
        inside = (rects[:, 0] <= i0) & (rects[:, 1] <= j0) & (rects[:, 2] >= i1) & (rects[:, 3] >= j1)
        assert inside.sum() == 1
    # Finished: no two rectangles share a complete edge.
    for a in range(len(rects)):
        for b in range(a + 1, len(rects)):
            assert not shares_complete_edge(rects[a], rects[b])
    order = np.lexsort((rects[:, 1], rects[:, 0]))
    assert np.array_equal(order, np.arange(len(rects)))


@settings(max_examples=80, deadline=None)
@given(grids(max_side=24))
def test_merge_follows_the_documented_order(occ):
    """Equal to a plain pairwise-merge loop following the documented pass order."""
    leaves = build_quadtree(occ)
    rects = merge_rects(leaves.boxes[leaves.free])
    assert [tuple(r) for r in rects.tolist()] == merge_reference(leaves.boxes[leaves.free])


@settings(max_examples=150, deadline=None)
@given(grids(), st.floats(0.01, 0.5), st.floats(-5, 5), st.floats(-5, 5))
def test_graph_is_exactly_the_touching_pairs(occ, res, ox, oy):
    leaves = build_quadtree(occ)
    rects = merge_rects(leaves.boxes[leaves.free])
    areas = connectivity(rects, [ox, oy], res)
    ref = edges_reference(rects)
    assert sorted(ref) == [tuple(e) for e in areas.edges.tolist()]
    assert areas.edges.shape == (len(ref), 2) and areas.portals.shape == (len(ref), 2, 2)
    expected_rects = np.stack([ox + res * rects[:, 1], oy + res * rects[:, 0],
                               ox + res * rects[:, 3], oy + res * rects[:, 2]], axis=1)
    # exact: connectivity computes origin + resolution * cell index with the same float64 operations
    np.testing.assert_array_equal(areas.rects, expected_rects)
    centre = 0.5 * (expected_rects[:, :2] + expected_rects[:, 2:])
    eps = np.finfo(float).eps
    for (a, b), w, portal in zip(areas.edges.tolist(), areas.weights, areas.portals):
        assert a < b
        # a 2-vector norm, reduced along an axis here and by a dot product (BLAS, maybe FMA) in
        # the test: sum of two squares and a sqrt, each correctly rounded -> within 4 eps relative
        assert w == pytest.approx(np.linalg.norm(centre[a] - centre[b]), rel=4 * eps, abs=0)
        (cx0, cy0), (cx1, cy1) = ref[(a, b)]
        # exact, as the rectangles
        np.testing.assert_array_equal(portal, [[ox + res * cx0, oy + res * cy0], [ox + res * cx1, oy + res * cy1]])
        assert np.linalg.norm(portal[1] - portal[0]) > 0


def test_corner_touching_is_not_an_edge():
    """Free cells (0, 0) and (1, 1) of a 2 x 2 grid touch only at a corner."""
    occ = np.array([[False, True], [True, False]])
    result = build_safe_areas(rasterise_free_grid(occ))
    assert len(result.areas.rects) == 2
    assert result.areas.edges.shape == (0, 2)
    assert result.areas.weights.shape == (0,) and result.areas.portals.shape == (0, 2, 2)


def rasterise_free_grid(occ: np.ndarray):
    """An OccupancyGrid with the given occupancy, 0.1 m cells from the origin."""
    ny, nx = occ.shape
    grid = rasterise([], [0.0, 0.0, 0.1 * nx, 0.1 * ny], 0.1, inflation=0.0)
    grid.occupied[...] = occ
    return grid


@pytest.mark.parametrize("bounds", [[0.0, 0.0, 6.4, 6.4], [-1.0, 2.0, 4.0, 5.0], [0, 0, 0.05, 0.05]])
def test_empty_map_is_one_rectangle(bounds):
    result = build_map([], bounds, inflation=0.3)
    assert len(result.areas.rects) == 1 and len(result.leaves) == 1
    # origin + resolution * n_cells vs the bound: one product and one sum, each rounded (<= 1 ulp
    # of the larger magnitude each), so within 2 eps of max |bound| (and the 1e-6-cell snapping of
    # grid_shape, which rounds the cell count, not these coordinates)
    eps = np.finfo(float).eps
    np.testing.assert_allclose(result.areas.rects[0], bounds, rtol=0, atol=2 * eps * max(1.0, np.abs(bounds).max()))
    assert len(result.areas.edges) == 0


def test_single_centred_box_known_answer():
    """An 8 x 8 grid of 0.1 m cells with the centre 2 x 2 cells (rows/columns 3, 4) occupied.

    A box [0.35, 0.45]^2 grown by 0.02 spans [0.33, 0.47]^2: it meets cells 3 and 4 only.

    Quadtree: the root splits into four 4 x 4 quadrants, each holding one occupied cell at
    its inner corner; each splits into three free 2 x 2 blocks and one mixed one, which
    splits into three free cells and one occupied. Per quadrant 6 free + 1 occupied:
    24 free, 4 occupied leaves.

    Merge (x-pass first): rows 0-1 -> one 2 x 8 strip; rows 6-7 likewise; row 2 -> cells
    2..5 in one 1 x 4 run; row 5 likewise; the 2 x 2 blocks of rows 2-3 and 4-5 at the
    sides and the single cells (3, 2), (3, 5), (4, 2), (4, 5) stay (12 rectangles). y-pass:
    the side blocks stack into two 4 x 2 columns and the single cells into two 2 x 1
    columns (8 rectangles). The next x-pass merges nothing: 8 rectangles.

    Graph: bottom strip - {left column, right column, row-2 run}, top strip likewise with
    the row-5 run; each side column - {its strip neighbours, row-2 run, row-5 run, its
    2 x 1 column}; each row run - both 2 x 1 columns. 3 + 3 + 2*3 + 4 = 16 edges.
    """
    result = build_map([box(0.4, 0.4, 0.05, 0.05)], [0.0, 0.0, 0.8, 0.8], inflation=0.02,
                       config=MapConfig(resolution=0.1))
    expected = np.zeros((8, 8), dtype=bool)
    expected[3:5, 3:5] = True
    assert np.array_equal(result.grid.occupied, expected)
    assert (result.leaves.n_free, result.leaves.n_occupied) == (24, 4)
    assert sorted(map(tuple, result.boxes.tolist())) == sorted([
        (0, 0, 2, 8), (6, 0, 8, 8), (2, 0, 6, 2), (2, 6, 6, 8),
        (2, 2, 3, 6), (5, 2, 6, 6), (3, 2, 5, 3), (3, 5, 5, 6),
    ])
    assert len(result.areas.edges) == 16
    assert result.areas.weights.min() > 0


def test_locate_matches_brute_force():
    rng = np.random.default_rng(3)
    occ = rng.random((30, 41)) < 0.2
    grid = rasterise_free_grid(occ)
    areas = build_safe_areas(grid).areas
    pts = np.concatenate([rng.uniform(-0.5, 4.6, (400, 2)), areas.rects[:, :2], areas.rects[:, 2:]])
    got = locate(areas, pts)
    r = areas.rects
    for p, k in zip(pts, got):
        inside = np.flatnonzero((p[0] >= r[:, 0]) & (p[0] <= r[:, 2]) & (p[1] >= r[:, 1]) & (p[1] <= r[:, 3]))
        assert k == (inside[0] if inside.size else -1)
    # A point inside an occupied cell's centre, and non-finite points, are in no area.
    i, j = np.argwhere(occ)[0]
    assert locate(areas, [[0.1 * j + 0.05, 0.1 * i + 0.05], [np.nan, 0.0]]).tolist() == [-1, -1]
    # tol grows every rectangle.
    corner = r[0, :2] - 0.01
    if locate(areas, corner) == -1:
        assert locate(areas, corner, tol=0.02) == 0


def test_locate_single_point_and_empty():
    areas = build_map([], [0, 0, 1, 1], inflation=0.1).areas
    assert locate(areas, [0.5, 0.5]) == 0
    assert locate(areas, [1.5, 0.5]) == -1
    assert locate(areas, np.zeros((0, 2))).shape == (0,)
    empty = SafeAreas(np.zeros((0, 4)), np.zeros((0, 2), int), np.zeros(0), np.zeros((0, 2, 2)))
    assert locate(empty, [[0.5, 0.5]]).tolist() == [-1]
    with pytest.raises(ValueError, match="tol"):
        locate(areas, [0.5, 0.5], tol=-1.0)


def test_fully_occupied_map_has_no_areas():
    grid = rasterise_free_grid(np.ones((5, 7), dtype=bool))
    result = build_safe_areas(grid)
    assert result.areas.rects.shape == (0, 4) and result.areas.edges.shape == (0, 2)
    assert result.to_json()["leaves"] == {"free": 0, "occupied": 1}


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 6))
def test_whole_stage_on_random_obstacle_maps(seed, count):
    rng = np.random.default_rng(seed)
    obstacles = [box(*rng.uniform(0, 3, 2), *rng.uniform(0.05, 0.5, 2), rng.uniform(-3, 3)) for _ in range(count)]
    result = build_map(obstacles, [0.0, 0.0, 3.0, 2.5], inflation=0.2, config=MapConfig(resolution=0.1))
    cover = coverage(result.boxes, result.grid.shape)
    assert np.array_equal(cover, (~result.grid.occupied).astype(int))
    # Every free cell centre is located in the area built from it.
    ii, jj = np.nonzero(~result.grid.occupied)
    centres = np.stack([0.1 * jj + 0.05, 0.1 * ii + 0.05], axis=1)
    k = locate(result.areas, centres)
    assert np.all(k >= 0)
    b = result.boxes[k]
    assert np.all((b[:, 0] <= ii) & (ii < b[:, 2]) & (b[:, 1] <= jj) & (jj < b[:, 3]))


def test_to_json_has_the_design_fields():
    result = build_map([box(1.0, 1.0, 0.3, 0.2, 0.5)], [0, 0, 2, 2], inflation=0.2)
    doc = json.loads(json.dumps(result.to_json()))
    assert set(doc) == {"grid", "leaves", "rects", "edges", "timing_ms"}
    assert doc["grid"] == {"resolution": 0.05, "origin": [0.0, 0.0], "shape": [40, 40], "inflation": 0.2}
    assert doc["leaves"] == {"free": result.leaves.n_free, "occupied": result.leaves.n_occupied}
    assert len(doc["rects"]) == len(result.areas.rects) and len(doc["rects"][0]) == 4
    assert all(len(e) == 3 and isinstance(e[0], int) for e in doc["edges"])
    assert list(doc["timing_ms"]) == ["rasterise", "quadtree", "merge", "graph", "total"]
    assert all(v >= 0 for v in doc["timing_ms"].values())
    stages = build_safe_areas(result.grid).timing_ms
    assert list(stages) == ["quadtree", "merge", "graph", "total"]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(resolution=0.0), "resolution"),
        (dict(resolution=float("inf")), "resolution"),
        (dict(min_cell=0), "min_cell"),
        (dict(min_cell=2.0), "min_cell"),
        (dict(merge="greedy"), "merge"),
    ],
)
def test_map_config_validation(kwargs, message):
    with pytest.raises(ValueError, match=message):
        MapConfig(**kwargs)


def test_merge_and_graph_reject_bad_input():
    with pytest.raises(ValueError, match="method"):
        merge_rects(np.zeros((0, 4), dtype=int), method="greedy")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="integer"):
        merge_rects(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="i0 < i1"):
        connectivity(np.array([[0, 0, 0, 1]]), [0, 0], 0.1)
    with pytest.raises(ValueError, match="merge"):
        build_safe_areas(rasterise_free_grid(np.zeros((2, 2), bool)), merge="greedy")  # type: ignore[arg-type]
