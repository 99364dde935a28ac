"""Tests for sanav_mj.mapping.quadtree: leaves partition the grid, states, known answers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from _mapping_reference import grids
from sanav_mj.mapping.quadtree import build_quadtree, count_pyramid, quadtree_recursive, sort_leaves


def check_partition(occ: np.ndarray, leaves, min_cell: int) -> None:
    ny, nx = occ.shape
    cover = np.zeros((ny, nx), dtype=int)
    for (i0, j0, i1, j1), free, depth in zip(leaves.boxes, leaves.free, leaves.depth):
        assert 0 <= i0 < i1 <= ny and 0 <= j0 < j1 <= nx
        cover[i0:i1, j0:j1] += 1
        block = occ[i0:i1, j0:j1]
        # Each leaf is an aligned quadtree node (side 2^k at depth d), clipped to the grid.
        size = 1 << (max(ny, nx) - 1).bit_length() >> int(depth)
        assert i0 % size == 0 and j0 % size == 0
        assert (i1 - i0, j1 - j0) == (min(size, ny - i0), min(size, nx - j0))
        if free:
            assert not block.any()
        else:
            # Occupied leaves are uniform, or mixed nodes that min_cell forbids splitting.
            assert block.all() or (block.any() and size // 2 < min_cell)
        if depth > 0:
            # The parent was split, so it was mixed: otherwise this would not be a leaf.
            p = 2 * size
            pi, pj = i0 // p * p, j0 // p * p
            parent = occ[pi:pi + p, pj:pj + p]
            assert parent.any() and not parent.all()
    assert np.all(cover == 1), "leaves must cover every cell exactly once"


@settings(max_examples=150, deadline=None)
@given(grids(), st.integers(1, 5))
def test_leaves_partition_the_grid(occ, min_cell):
    leaves = build_quadtree(occ, min_cell)
    check_partition(occ, leaves, min_cell)
    assert leaves.n_free + leaves.n_occupied == len(leaves)
    # Documented order: by depth, then Z (Morton) order of the node index within a depth.
    size = (1 << (max(occ.shape) - 1).bit_length()) >> leaves.depth
    a, b = leaves.boxes[:, 0] // size, leaves.boxes[:, 1] // size
    morton = sum(((a >> k) & 1) << (2 * k + 1) | ((b >> k) & 1) << (2 * k) for k in range(12))
    key = list(zip(leaves.depth.tolist(), morton.tolist()))
    assert key == sorted(key)


@settings(max_examples=150, deadline=None)
@given(grids(), st.integers(1, 5))
def test_vectorised_equals_recursive(occ, min_cell):
    fast = sort_leaves(build_quadtree(occ, min_cell))
    slow = sort_leaves(quadtree_recursive(occ, min_cell))
    assert np.array_equal(fast.boxes, slow.boxes)
    assert np.array_equal(fast.free, slow.free)
    assert np.array_equal(fast.depth, slow.depth)


@settings(max_examples=60, deadline=None)
@given(grids(max_side=33))
def test_count_pyramid_matches_block_sums(occ):
    levels = count_pyramid(occ)
    ny, nx = occ.shape
    n = 1 << (max(ny, nx) - 1).bit_length()  # the quadtree root's side
    assert len(levels) == n.bit_length() and levels[-1].shape == (1, 1)
    for d, level in enumerate(levels):
        s = 1 << d
        # the levels follow the grid's own shape (no padding to the root square)
        assert level.shape == (-(-ny // s), -(-nx // s))
        for a in range(level.shape[0]):
            for b in range(level.shape[1]):
                assert level[a, b] == occ[a * s:(a + 1) * s, b * s:(b + 1) * s].sum()


def test_count_pyramid_does_not_overflow():
    occ = np.ones((256, 256), dtype=bool)
    levels = count_pyramid(occ)
    assert [int(level[0, 0]) for level in levels] == [4**d for d in range(9)]


@pytest.mark.parametrize("shape", [(1, 1), (8, 8), (100, 60), (5, 3), (1, 17)])
def test_uniform_grid_is_one_leaf(shape):
    free = build_quadtree(np.zeros(shape, dtype=bool))
    assert free.boxes.tolist() == [[0, 0, shape[0], shape[1]]] and free.free.tolist() == [True]
    full = build_quadtree(np.ones(shape, dtype=bool))
    assert full.boxes.tolist() == [[0, 0, shape[0], shape[1]]] and full.free.tolist() == [False]


def test_single_occupied_cell_known_answer():
    """One occupied cell (3, 3) in an 8 x 8 grid.

    The root splits into four 4 x 4 quadrants, three free; the lower-left one splits into
    four 2 x 2 blocks, three free; the one holding (3, 3) splits into four cells: three free,
    one occupied. 3 + 3 + 3 = 9 free leaves and 1 occupied leaf.
    """
    occ = np.zeros((8, 8), dtype=bool)
    occ[3, 3] = True
    leaves = build_quadtree(occ)
    assert (leaves.n_free, leaves.n_occupied) == (9, 1)
    assert leaves.boxes[~leaves.free].tolist() == [[3, 3, 4, 4]]
    sizes = sorted((b[2] - b[0]) for b in leaves.boxes[leaves.free])
    assert sizes == [1, 1, 1, 2, 2, 2, 4, 4, 4]


def test_min_cell_makes_mixed_nodes_occupied():
    """With min_cell = 2 the 2 x 2 block holding the occupied cell is not split: occupied leaf."""
    occ = np.zeros((8, 8), dtype=bool)
    occ[3, 3] = True
    leaves = build_quadtree(occ, min_cell=2)
    assert (leaves.n_free, leaves.n_occupied) == (6, 1)
    assert leaves.boxes[~leaves.free].tolist() == [[2, 2, 4, 4]]
    # min_cell = 3 rounds up to 4: the 4 x 4 quadrant becomes the occupied leaf.
    leaves = build_quadtree(occ, min_cell=3)
    assert leaves.boxes[~leaves.free].tolist() == [[0, 0, 4, 4]]


def test_non_power_of_two_grid_is_split_unevenly():
    """A 6 x 5 grid (root 8 x 8, clipped) with one occupied cell at (0, 4).

    Root -> quadrants clipped to [0:4, 0:4] free, [0:4, 4:5] mixed, [4:6, 0:4] free,
    [4:6, 4:5] free. The mixed 4 x 1 strip -> [0:2, 4:5] mixed, [2:4, 4:5] free; then
    [0:1, 4:5] occupied and [1:2, 4:5] free.
    """
    occ = np.zeros((6, 5), dtype=bool)
    occ[0, 4] = True
    leaves = build_quadtree(occ)
    got = {tuple(b): bool(f) for b, f in zip(leaves.boxes.tolist(), leaves.free)}
    assert got == {
        (0, 0, 4, 4): True, (0, 4, 1, 5): False, (1, 4, 2, 5): True, (2, 4, 4, 5): True,
        (4, 0, 6, 4): True, (4, 4, 6, 5): True,
    }


@pytest.mark.parametrize(
    "occ, min_cell, message",
    [
        (np.zeros((3,), dtype=bool), 1, "2-D"),
        (np.zeros((0, 4), dtype=bool), 1, "2-D"),
        (np.zeros((3, 3), dtype=int), 1, "bool"),
        (np.zeros((3, 3), dtype=bool), 0, "min_cell"),
        (np.zeros((3, 3), dtype=bool), 1.5, "min_cell"),
        (np.zeros((3, 3), dtype=bool), True, "min_cell"),
    ],
)
def test_build_quadtree_rejects_bad_input(occ, min_cell, message):
    with pytest.raises(ValueError, match=message):
        build_quadtree(occ, min_cell)

