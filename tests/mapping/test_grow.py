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
