"""Incremental safe areas against a rebuild from the same grid, on seeded random update sequences."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from _mapping_reference import room_scan

from sanav_mj.mapping.incremental import IncrementalSafeAreas
from sanav_mj.mapping.live_grid import LiveGrid
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.safe_areas import build_safe_areas, connectivity


def _grid(occ, h=0.05, origin=(-1.0, 2.0)):
    ny, nx = occ.shape
    o = np.array(origin, dtype=float)
    return OccupancyGrid(occupied=occ, resolution=h, origin=o, inflation=0.0,
                         bounds=np.array([o[0], o[1], o[0] + nx * h, o[1] + ny * h]))


def _paint(boxes, shape):
    out = np.zeros(shape, dtype=np.int64)
    for i0, j0, i1, j1 in boxes.tolist():
        out[i0:i1, j0:j1] += 1
    return out


def _check(inc: IncrementalSafeAreas, occ: np.ndarray, min_cell: int):
    grid = _grid(occ.copy(), h=inc.resolution, origin=inc.origin)
    ref = build_safe_areas(grid, min_cell)
    boxes, areas = inc.safe_areas()
    # same free coverage as the rebuild's quadtree, no overlap, every rectangle free
    paint = _paint(boxes, occ.shape)
    assert paint.max(initial=0) <= 1
    assert np.array_equal(paint, _paint(ref.boxes, occ.shape))
    for i0, j0, i1, j1 in boxes.tolist():
        assert not occ[i0:i1, j0:j1].any()
    # the graph is exactly the touching pairs (connectivity() on the same boxes)
    con = connectivity(boxes, grid.origin, grid.resolution)
    assert np.array_equal(areas.edges, con.edges)
    assert np.array_equal(areas.rects, con.rects)
    np.testing.assert_allclose(areas.weights, con.weights, rtol=0, atol=1e-12)
    np.testing.assert_allclose(areas.portals, con.portals, rtol=0, atol=1e-12)
    return ref, boxes


def _blob(rng, shape, n_cells):
    """Flat indices of a clustered random set of cells (like what one scan changes)."""
    ny, nx = shape
    ci, cj = rng.integers(0, ny), rng.integers(0, nx)
    i = np.clip(ci + rng.normal(0, 6, n_cells).round().astype(int), 0, ny - 1)
    j = np.clip(cj + rng.normal(0, 6, n_cells).round().astype(int), 0, nx - 1)
    return i * nx + j


@pytest.mark.parametrize("shape,min_cell,tile,seed", [
    ((60, 90), 1, 8, 0),
    ((60, 90), 1, 32, 1),
    ((37, 101), 2, 16, 2),
    ((64, 64), 1, 64, 3),
    ((33, 47), 4, 8, 4),
])
def test_random_updates_match_rebuild(shape, min_cell, tile, seed):
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < 0.15
    occ[10:20, 5:40] = True  # a wall
    inc = IncrementalSafeAreas(_grid(occ.copy()), min_cell=min_cell, tile=tile)
    ref, boxes = _check(inc, occ, min_cell)
    n_ref, n_inc = [], []
    for step in range(40):
        cells = _blob(rng, shape, int(rng.integers(1, 300)))
        if step % 3 == 0:  # clear an area (a scan sees free space)
            occ.reshape(-1)[cells] = False
        elif step % 3 == 1:  # new obstacles
            occ.reshape(-1)[cells] = True
        else:  # flip
            occ.reshape(-1)[cells] ^= True
        listed = np.concatenate([cells, rng.integers(0, occ.size, 20)])  # unchanged cells listed too
        inc.update(occ, listed)
        ref, boxes = _check(inc, occ, min_cell)
        n_ref.append(len(ref.boxes))
        n_inc.append(len(boxes))
    # the local merge may leave more rectangles than a global one, but not wildly more
    assert np.mean(n_inc) <= 2.0 * np.mean(n_ref)


def test_no_change_is_a_no_op():
    occ = np.zeros((20, 20), dtype=bool)
    occ[5, 5] = True
    inc = IncrementalSafeAreas(_grid(occ), tile=8)
    before = inc.safe_areas()[0].copy()
    assert inc.update(occ, [0, 1, 2, 105]) == 0
    assert np.array_equal(inc.safe_areas()[0], before)


def test_bad_arguments():
    occ = np.zeros((20, 20), dtype=bool)
    with pytest.raises(ValueError, match="tile"):
        IncrementalSafeAreas(_grid(occ), tile=12)
    with pytest.raises(ValueError, match="smallest quadtree leaf"):
        IncrementalSafeAreas(_grid(occ), min_cell=5, tile=4)
    inc = IncrementalSafeAreas(_grid(occ), tile=8)
    with pytest.raises(ValueError, match="changed cells"):
        inc.update(occ, [400])
    with pytest.raises(ValueError, match="occupied"):
        inc.update(occ[:10], [0])


def test_driven_by_live_grid_scans():
    """The live map's safe-cell changes feed the incremental areas; they match a rebuild."""
    g = LiveGrid((0.0, 0.0, 6.0, 4.0), 0.05, 0.3)
    inc = IncrementalSafeAreas(g.safe_grid(), tile=16)
    angles = np.linspace(-2.356, 2.356, 271)
    rng = np.random.default_rng(5)
    room = (0.3, 0.3, 5.7, 3.7)
    for step in range(12):
        x, y, th = 0.8 + 0.35 * step, 2.0 + 0.3 * np.sin(step), 0.2 * step
        ranges, hit = room_scan((x, y, th), angles, room, 4.0)
        r = np.where(hit, ranges + rng.normal(0, 0.02, len(ranges)), 4.0)
        up = g.integrate((x, y), th, r, hit, angles)
        inc.update(~g.safe(), up.safe_changed)
        _check(inc, ~g.safe(), 1)
    assert len(inc.safe_areas()[0]) > 0


@pytest.mark.parametrize("shape,min_cell,tile,seed", [((60, 90), 1, 8, 10), ((37, 101), 2, 16, 11),
                                                      ((70, 70), 1, 32, 12), ((33, 47), 4, 8, 13)])
def test_compiled_and_numpy_updates_give_the_same_areas(shape, min_cell, tile, seed):
    """The compiled pyramid update, tile leaves and edge search (area_kernel) against the
    NumPy code on the same update sequence: the same pyramid counts, the same leaves of
    random tiles (as sets), and identical compact rectangles, edges, weights and portals."""
    from sanav_mj.mapping import area_kernel

    if not area_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy code exists")
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < 0.15
    occ[10:20, 5:40] = True
    incs = [IncrementalSafeAreas(_grid(occ.copy()), min_cell=min_cell, tile=tile) for _ in range(2)]
    incs[1]._use_kernel = False
    # built the same way from scratch (leaves and edges of every tile)
    assert np.array_equal(incs[0].safe_areas()[0], incs[1].safe_areas()[0])
    for step in range(30):
        cells = _blob(rng, shape, int(rng.integers(1, 300)))
        flat = occ.reshape(-1)
        if step % 3 == 2:
            flat[cells] ^= True
        else:
            flat[cells] = bool(step % 3)
        for inc in incs:
            inc.update(occ, cells)
        for a, b in zip(incs[0]._levels, incs[1]._levels):
            assert np.array_equal(a, b)
        tiles = rng.choice(incs[0]._nty * incs[0]._ntx, size=3, replace=False)
        la, lb = incs[0]._leaves(tiles), incs[1]._leaves(tiles)
        assert len(la) == len(lb) and set(map(tuple, la.tolist())) == set(map(tuple, lb.tolist()))
        (ba, aa), (bb, ab) = incs[0].safe_areas(), incs[1].safe_areas()
        assert np.array_equal(ba, bb)
        assert np.array_equal(aa.edges, ab.edges) and np.array_equal(aa.rects, ab.rects)
        assert np.array_equal(aa.weights, ab.weights) and np.array_equal(aa.portals, ab.portals)
        assert len(np.unique(incs[0].edges, axis=0)) == len(incs[0].edges)  # each edge once
    _check(incs[0], occ, min_cell)


def test_the_areas_fall_back_to_numpy_without_the_kernel(monkeypatch):
    """With the compiled functions unavailable (no compiler, SANAV_MJ_NO_CKERNEL=1) every
    area_kernel function says so and the incremental areas still match a rebuild."""
    from sanav_mj.mapping import area_kernel

    # a fresh load-once loader (restored after the test): the next call compiles or fails anew
    monkeypatch.setattr(area_kernel, "_load", functools.cache(area_kernel._load.__wrapped__))
    monkeypatch.setenv("SANAV_MJ_NO_CKERNEL", "1")
    assert not area_kernel.kernel_available()
    rng = np.random.default_rng(4)
    occ = rng.random((40, 50)) < 0.2
    inc = IncrementalSafeAreas(_grid(occ.copy()), tile=8)
    assert area_kernel.tile_leaves(inc._pyr, np.arange(2), inc._ntx, 8, inc.shape, 1) is None
    assert area_kernel.link_edges(np.zeros(1, np.int64), inc.alive, inc.boxes, {}) is None
    assert area_kernel.merge_boxes(np.zeros((1, 4), np.int64)) is None
    assert area_kernel.snapshot(inc.alive, inc.boxes, inc.edges, 51, (0.0, 0.0), 0.05) is None
    assert not area_kernel.pyramid_add(inc._pyr, np.zeros(1, np.int64), np.ones(1, np.int32), 50)
    for _ in range(5):
        cells = _blob(rng, occ.shape, 80)
        occ.reshape(-1)[cells] ^= True
        inc.update(occ, cells)
        _check(inc, occ, 1)


def test_compiled_merge_slots_and_pieces_equal_the_numpy_code():
    """area_kernel.merge_boxes equals merge_rects on the free quadtree leaves of random grids
    (any input order); slots_meeting and clean_pieces equal the NumPy _slots_meeting and
    _pieces on random dirty tiles."""
    from sanav_mj.mapping import area_kernel
    from sanav_mj.mapping.quadtree import build_quadtree
    from sanav_mj.mapping.safe_areas import merge_rects

    if not area_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy code exists")
    rng = np.random.default_rng(21)
    for k in range(12):
        occ = rng.random((int(rng.integers(5, 70)), int(rng.integers(5, 70)))) < rng.uniform(0.02, 0.4)
        tree = build_quadtree(occ, min_cell=int(rng.integers(1, 3)))
        leaves = tree.boxes[tree.free]
        leaves = leaves[rng.permutation(len(leaves))]
        assert np.array_equal(area_kernel.merge_boxes(leaves), merge_rects(leaves))
    occ = rng.random((90, 120)) < 0.1
    inc = IncrementalSafeAreas(_grid(occ), tile=16)
    ref = IncrementalSafeAreas(_grid(occ), tile=16)
    ref._use_kernel = False
    for _ in range(10):
        tiles = np.unique(rng.integers(0, inc._nty * inc._ntx, int(rng.integers(1, 8))))
        dirty = np.zeros((inc._nty, inc._ntx), dtype=bool)
        dirty.reshape(-1)[tiles] = True
        slots = inc._slots_meeting(tiles)
        ref.alive, ref.boxes = inc.alive, inc.boxes
        assert len(slots) > 0 and np.array_equal(slots, ref._slots_meeting(tiles))
        got, want = inc._pieces(slots, dirty), ref._pieces(slots, dirty)
        assert len(got) > 0 and sorted(map(tuple, got.tolist())) == sorted(map(tuple, want.tolist()))
