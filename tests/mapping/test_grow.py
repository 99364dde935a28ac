"""Tests for sanav_mj.mapping.grow: maximal free rectangles of a grid, exact known answers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sanav_mj.mapping.grow import FreeCells, grow_rect
from sanav_mj.mapping.occupancy import OccupancyGrid


def grid(occupied, h=0.1, origin=(0.0, 0.0)) -> OccupancyGrid:
    occ = np.asarray(occupied, dtype=bool)
    ny, nx = occ.shape
    return OccupancyGrid(occ, h, np.array(origin, float), 0.0,
                         np.array([origin[0], origin[1], origin[0] + nx * h, origin[1] + ny * h]))


# rows are y (row 0 at the bottom), columns x
STAIRS = [[0, 0, 0, 1, 1, 1],
          [1, 0, 0, 0, 1, 1],
          [1, 1, 0, 0, 0, 1],
          [1, 1, 1, 0, 0, 0]]


def test_staircase_cells_grow_along_their_step():
    cells = FreeCells.of(grid(STAIRS))
    # cell (row 1, column 2): -x to column 1, +x to column 3 in the first round; -y (column 3 of
    # row 0) and +y (column 1 of row 2) are blocked; the second round moves nothing
    np.testing.assert_allclose(grow_rect(cells, [0.2, 0.1, 0.3, 0.2]), [0.1, 0.1, 0.4, 0.2])
    # the top step: columns 3-5 of row 3 (the grid's top edge stops +y)
    np.testing.assert_allclose(grow_rect(cells, [0.4, 0.3, 0.5, 0.4]), [0.3, 0.3, 0.6, 0.4])
    # the union of two touching steps is not free, so neither grows into the other's row
    assert cells.occupied_in(1, 1, 3, 4) > 0


def test_known_answers_and_limits():
    occ = np.zeros((5, 7), dtype=bool)
    occ[0, :] = True
    occ[:, 6] = True
    occ[4, 0] = True
    cells = FreeCells.of(grid(occ))
    # from cell (row 2, column 3), rounds of -x +x -y +y: round 1 gives columns 2-4, rows 1-3;
    # round 2 columns 1-5 and row 4 (free in columns 1-5); round 3: column 0 is blocked by
    # (row 4, column 0), column 6 and row 0 are occupied. The order decides: column 0 first
    # would have blocked row 4 instead.
    np.testing.assert_allclose(grow_rect(cells, [0.3, 0.2, 0.4, 0.3]), [0.1, 0.1, 0.6, 0.5])
    # limit: each side moves at most 0.1 m (one cell)
    np.testing.assert_allclose(grow_rect(cells, [0.3, 0.2, 0.4, 0.3], limit=0.1), [0.2, 0.1, 0.5, 0.4])
    np.testing.assert_allclose(grow_rect(cells, [0.3, 0.2, 0.4, 0.3], limit=0.0), [0.3, 0.2, 0.4, 0.3])
    # the limit stored in the table is the default
    np.testing.assert_allclose(grow_rect(FreeCells.of(grid(occ), 0.1), [0.3, 0.2, 0.4, 0.3]), [0.2, 0.1, 0.5, 0.4])


def test_bad_rectangles_are_refused():
    cells = FreeCells.of(grid(STAIRS))
    with pytest.raises(ValueError, match="occupied"):
        grow_rect(cells, [0.0, 0.0, 0.4, 0.1])
    with pytest.raises(ValueError, match="whole cells"):
        grow_rect(cells, [0.05, 0.1, 0.3, 0.2])
    with pytest.raises(ValueError, match="whole cells"):
        grow_rect(cells, [0.5, 0.3, 0.7, 0.4])
    with pytest.raises(ValueError, match="limit"):
        grow_rect(cells, [0.2, 0.1, 0.3, 0.2], limit=-1.0)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.1, 0.7))
def test_grown_rectangle_is_free_contains_the_input_and_is_maximal(seed, fill):
    rng = np.random.default_rng(seed)
    occ = rng.random((9, 11)) < fill
    free = np.argwhere(~occ)
    if len(free) == 0:
        return
    i, j = free[rng.integers(len(free))]
    g = grid(occ, h=0.05, origin=(-1.0, 2.0))
    cells = FreeCells.of(g)
    r = grow_rect(cells, [-1.0 + 0.05 * j, 2.0 + 0.05 * i, -1.0 + 0.05 * (j + 1), 2.0 + 0.05 * (i + 1)])
    i0, j0, i1, j1 = cells.cells_of(r)
    assert i0 <= i < i1 and j0 <= j < j1
    assert not occ[i0:i1, j0:j1].any()  # every cell free (direct check, not the table)
    ny, nx = occ.shape
    for blocked in ((j0 == 0 or occ[i0:i1, j0 - 1].any()), (j1 == nx or occ[i0:i1, j1].any()),
                    (i0 == 0 or occ[i0 - 1, j0:j1].any()), (i1 == ny or occ[i1, j0:j1].any())):
        assert blocked  # no side can move out by one more cell


def test_squares_free_known_answers():
    occ = np.zeros((6, 8), dtype=bool)
    occ[2, 5] = True  # the cell x in [0.5, 0.6), y in [0.2, 0.3)
    cells = FreeCells.of(grid(occ))
    pts = np.array([[0.25, 0.25],   # 0.1 m square: cells x 1-3, y 1-3, free
                    [0.35, 0.25],   # x 2-4: free (column 5 not reached: 0.45 is inside column 4)
                    [0.41, 0.25],   # x up to 0.51: touches column 5, row 2: occupied
                    [0.05, 0.25],   # x down to -0.05: beyond the grid, not free
                    [0.65, 0.45]])  # x 0.55-0.75, y 0.35-0.55: rows 3-5, free
    np.testing.assert_array_equal(cells.squares_free(pts, 0.1), [True, True, False, False, True])
    np.testing.assert_array_equal(cells.squares_free(pts, 0.0), [True, True, True, True, True])
    with pytest.raises(ValueError, match="half"):
        cells.squares_free(pts, -0.1)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), half=st.floats(0.0, 0.35))
def test_squares_free_matches_the_cells_it_touches(seed, half):
    rng = np.random.default_rng(seed)
    occ = rng.random((9, 11)) < 0.08
    h = 0.1
    cells = FreeCells.of(grid(occ, h, origin=(-0.3, 0.2)))
    pts = rng.uniform([-0.5, 0.0], [1.0, 1.3], size=(30, 2))
    got = cells.squares_free(pts, half)
    for p, g in zip(pts, got):
        lo, hi = p - half, p + half
        # reference: every cell whose open interior meets the closed square, by brute force
        ok = lo[0] >= -0.3 - 1e-12 and lo[1] >= 0.2 - 1e-12 and hi[0] <= -0.3 + 11 * h + 1e-12 \
            and hi[1] <= 0.2 + 9 * h + 1e-12
        for i in range(9):
            for j in range(11):
                x0, y0 = -0.3 + j * h, 0.2 + i * h
                if occ[i, j] and x0 <= hi[0] and x0 + h >= lo[0] and y0 <= hi[1] and y0 + h >= lo[1]:
                    ok = False
        if g:  # a True is a proof: no occupied cell touches the square, inside the grid
            assert ok, (p, half)


def test_compiled_growth_equals_the_python_loop():
    """grow_rect's compiled loop (sanav_mj.mapping.grow_kernel) gives the box the Python loop
    gives: random grids of several fills and cell sizes, every free cell as the seed and
    random free seed boxes, with growth limits from 0 to beyond the grid."""
    from sanav_mj.mapping import grow_kernel

    if not grow_kernel.kernel_available():
        pytest.skip("no C compiler: only the Python loop exists")
    rng = np.random.default_rng(7)
    compared = 0
    for k in range(24):
        ny, nx = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        h = (0.025, 0.05, 0.1)[k % 3]
        occ = rng.random((ny, nx)) < (0.02, 0.1, 0.3, 0.6)[k % 4]
        cells = FreeCells.of(grid(occ, h=h, origin=(-1.3, 0.7)))
        seeds = [(i, j, i + 1, j + 1) for i, j in zip(*np.nonzero(~occ))]
        for _ in range(30):  # larger free boxes: grown by the reference from a free cell
            if not seeds:
                break
            i, j, _, _ = seeds[int(rng.integers(len(seeds)))]
            r = grow_rect(cells, [-1.3 + h * j, 0.7 + h * i, -1.3 + h * (j + 1), 0.7 + h * (i + 1)],
                          limit=h * int(rng.integers(0, 4)), use_kernel=False)
            seeds.append(tuple(int(v) for v in np.rint([(r[1] - 0.7) / h, (r[0] + 1.3) / h,
                                                          (r[3] - 0.7) / h, (r[2] + 1.3) / h])))
        for i0, j0, i1, j1 in seeds:
            rect = [-1.3 + h * j0, 0.7 + h * i0, -1.3 + h * j1, 0.7 + h * i1]
            for limit in (0.0, h, 3.3 * h, 1.0, 50.0):
                fast = grow_rect(cells, rect, limit)
                ref = grow_rect(cells, rect, limit, use_kernel=False)
                assert np.array_equal(fast, ref), (k, rect, limit, fast, ref)
                compared += 1
    assert compared > 5000


def test_compiled_summed_area_table_equals_the_cumsums():
    """FreeCells.of's one-pass compiled table (grow_kernel.summed_area) holds the integers of
    the NumPy reference (two cumsums): random grids of 0-300 rows / columns at several fills,
    C and Fortran order and strided views, all free and all occupied."""
    from sanav_mj.mapping import grow_kernel

    if not grow_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy tables exist")
    rng = np.random.default_rng(16)
    shapes = [(0, 0), (0, 5), (4, 0), (1, 1), (1, 17), (23, 1), (320, 480)]
    shapes += [(int(rng.integers(1, 300)), int(rng.integers(1, 300))) for _ in range(20)]
    for k, (ny, nx) in enumerate(shapes):
        fill = (0.0, 1.0, 0.02, 0.3, 0.7)[k % 5]
        occ = rng.random((ny, nx)) < fill
        for view in (occ, np.asfortranarray(occ), np.asarray(rng.random((2 * ny, nx)) < fill)[::2]):
            g = grid(np.zeros((max(ny, 1), max(nx, 1))))  # replaced below: any shape, incl. empty
            object.__setattr__(g, "occupied", view)
            fast = FreeCells.of(g).sat
            ref = FreeCells.of(g, use_kernel=False).sat
            assert fast.dtype == ref.dtype == np.int64 and fast.shape == (ny + 1, nx + 1)
            assert np.array_equal(fast, ref), (ny, nx, fill)
            assert fast.flags.c_contiguous
    # a non-bool grid takes the reference path: the same table
    g = grid(STAIRS)
    object.__setattr__(g, "occupied", np.asarray(STAIRS, dtype=np.uint8))
    assert grow_kernel.summed_area(g.occupied) is None
    assert np.array_equal(FreeCells.of(g).sat, FreeCells.of(grid(STAIRS)).sat)


def _diagonal(n: int = 8, width: int = 3) -> np.ndarray:
    """(n, n) occupancy: a diagonal strip of free cells, free where 0 <= column - row <= width."""
    r, c = np.mgrid[0:n, 0:n]
    return ~((c - r >= 0) & (c - r <= width))


def test_grow_point_diagonal_strip_known_answer():
    from sanav_mj.mapping.grow import grow_point

    cells = FreeCells.of(grid(_diagonal()))
    # the point in cell (row 3, column 5): round 1 moves -x to column 4, +x to column 6, not -y
    # (row 2, column 6 is 4 off the diagonal), +y to row 4; round 2 moves nothing
    box = grow_point(cells, [0.55, 0.32], limit=1.0)
    np.testing.assert_allclose(box, [0.4, 0.3, 0.7, 0.5], atol=1e-12)
    occ = _diagonal()
    i0, j0, i1, j1 = 3, 4, 5, 7
    assert not occ[i0:i1, j0:j1].any()  # every cell of the box is free
    # maximal: each side blocked by an occupied cell next to it
    assert occ[i0:i1, j0 - 1].any() and occ[i0:i1, j1].any()
    assert occ[i0 - 1, j0:j1].any() and occ[i1, j0:j1].any()


def test_grow_point_contains_point_and_is_maximal_everywhere():
    from sanav_mj.mapping.grow import grow_point

    occ = _diagonal(10, 3)
    cells = FreeCells.of(grid(occ))
    ny, nx = occ.shape
    for i in range(ny):
        for j in range(nx):
            p = np.array([0.1 * j + 0.03, 0.1 * i + 0.07])
            box = grow_point(cells, p, limit=1.0)
            if occ[i, j]:
                assert box is None
                continue
            assert box[0] <= p[0] <= box[2] and box[1] <= p[1] <= box[3]
            i0, j0, i1, j1 = cells.cells_of(box)
            assert not occ[i0:i1, j0:j1].any()
            assert j0 == 0 or occ[i0:i1, j0 - 1].any()
            assert j1 == nx or occ[i0:i1, j1].any()
            assert i0 == 0 or occ[i0 - 1, j0:j1].any()
            assert i1 == ny or occ[i1, j0:j1].any()


def test_grow_point_outside_grid_or_limited():
    from sanav_mj.mapping.grow import grow_point

    cells = FreeCells.of(grid(np.zeros((4, 4), dtype=bool)))
    assert grow_point(cells, [-0.01, 0.2], limit=1.0) is None
    assert grow_point(cells, [0.2, 0.41], limit=1.0) is None
    # limit 0.1 m: one cell out per side from cell (1, 1)
    np.testing.assert_allclose(grow_point(cells, [0.15, 0.15], limit=0.1), [0.0, 0.0, 0.3, 0.3], atol=1e-12)
    with pytest.raises(ValueError, match="point"):
        grow_point(cells, [0.1, np.nan], limit=1.0)
