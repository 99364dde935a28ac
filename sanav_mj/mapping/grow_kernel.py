"""Compiled growth loop of :func:`sanav_mj.mapping.grow.grow_rect`.

``grow_rect`` extends a free rectangle one cell row or column at a time (rounds over the
sides -x, +x, -y, +y), each test four lookups in the summed-area table of occupied cells.
With the discs mode's 1 m growth limit on 0.025 m cells a box takes up to 40 rounds, about
130 tests on average in the lidar runs, each a few NumPy scalar indexings from Python
(0.3-0.6 us): tens of microseconds per box, some 10 boxes per plan. This kernel runs the same
loop (the same tests in the same order, integer arithmetic only) in one C call per box
(compiled by :func:`sanav_mj.native.load_c_kernel`); the grown box is the same.

Without a C compiler, when compiling fails, or with ``SANAV_MJ_NO_CKERNEL=1``, the Python
loop of ``grow_rect`` runs instead: it is the reference (``tests/mapping/test_grow.py``
compares both).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.mapping.beam_kernel import NO_KERNEL_ENV, address
from sanav_mj.native import kernel_loader

__all__ = ["kernel_available", "grow_cells", "summed_area"]

_SOURCE = r"""
#include <stdint.h>

/* occupied cells in rows [i0, i1), columns [j0, j1) of the summed-area table s (rows
   stride apart), as FreeCells.occupied_in */
static int64_t occ(const int64_t *s, int64_t st, int64_t i0, int64_t j0, int64_t i1, int64_t j1)
{
    return s[i1 * st + j1] - s[i0 * st + j1] - s[i1 * st + j0] + s[i0 * st + j0];
}

/* box = (i0, j0, i1, j1) grown in place as grow_rect's loop: rounds of -x, +x, -y, +y, each
   side moved by one cell when the strip beyond it is free and it has not reached its bound
   (lo_i, lo_j, hi_i, hi_j), until a round moves none. */
void sanav_grow_box(const int64_t *s, int64_t st, int64_t *box, int64_t lo_i, int64_t lo_j, int64_t hi_i,
                    int64_t hi_j)
{
    int64_t i0 = box[0], j0 = box[1], i1 = box[2], j1 = box[3];
    int moved = 1;
    while (moved) {
        moved = 0;
        if (j0 > lo_j && !occ(s, st, i0, j0 - 1, i1, j0)) { j0 -= 1; moved = 1; }
        if (j1 < hi_j && !occ(s, st, i0, j1, i1, j1 + 1)) { j1 += 1; moved = 1; }
        if (i0 > lo_i && !occ(s, st, i0 - 1, j0, i0, j1)) { i0 -= 1; moved = 1; }
        if (i1 < hi_i && !occ(s, st, i1, j0, i1 + 1, j1)) { i1 += 1; moved = 1; }
    }
    box[0] = i0; box[1] = j0; box[2] = i1; box[3] = j1;
}

/* summed-area table sat (ny+1, nx+1) of the (ny, nx) 0/1 bytes occ, row 0 and column 0
   zero: sat[i+1][j+1] = sat[i][j+1] + (occupied cells in row i, columns <= j), integers */
void sanav_sat(const uint8_t *occ, int64_t ny, int64_t nx, int64_t *sat)
{
    int64_t st = nx + 1;
    for (int64_t j = 0; j < st; ++j) sat[j] = 0;
    for (int64_t i = 0; i < ny; ++i) {
        const uint8_t *o = occ + i * nx;
        const int64_t *up = sat + i * st;
        int64_t *row = sat + (i + 1) * st;
        int64_t acc = 0;
        row[0] = 0;
        for (int64_t j = 0; j < nx; ++j) {
            acc += o[j] != 0;
            row[j + 1] = up[j + 1] + acc;
        }
    }
}
"""

_i64, _ptr = ctypes.c_int64, ctypes.c_void_p
_load = kernel_loader("grow", _SOURCE, "the rectangle growth kernel", NO_KERNEL_ENV, {
    "sanav_grow_box": (None, [_ptr, _i64, ctypes.POINTER(_i64), _i64, _i64, _i64, _i64]),
    "sanav_sat": (None, [_ptr, _i64, _i64, _ptr]),
})


def kernel_available() -> bool:
    """Whether the compiled growth loop is in use (else the Python loop)."""
    return _load() is not None


def grow_cells(sat: np.ndarray, box: tuple[int, int, int, int], bounds: tuple[int, int, int, int]
               ) -> tuple[int, int, int, int] | None:
    """The cell box ``box`` grown as :func:`~sanav_mj.mapping.grow.grow_rect`'s loop grows it,
    or None when the kernel is not available or ``sat`` is not a C-contiguous 2-D int64 array.

    Args:
        sat: (ny+1, nx+1) int64 summed-area table of occupied cells
            (:attr:`~sanav_mj.mapping.grow.FreeCells.sat`).
        box: ``(i0, j0, i1, j1)`` cells, rows ``[i0, i1)`` and columns ``[j0, j1)``, free.
        bounds: ``(lo_i, lo_j, hi_i, hi_j)`` how far the sides may move (within the grid).

    Returns:
        ``(i0, j0, i1, j1)`` of the grown box.
    """
    lib = _load()
    if lib is None or sat.dtype != np.int64 or sat.ndim != 2 or not sat.flags.c_contiguous:
        return None
    b = (ctypes.c_int64 * 4)(*box)
    lib.sanav_grow_box(address(sat), sat.shape[1], b, *bounds)
    return b[0], b[1], b[2], b[3]


def summed_area(occupied: np.ndarray) -> np.ndarray | None:
    """The (ny+1, nx+1) int64 summed-area table of a (ny, nx) bool grid of occupied cells
    (``sat[i, j]``: occupied cells in rows < i, columns < j), computed in one C pass (integer
    sums: the same table as :meth:`~sanav_mj.mapping.grow.FreeCells.of`'s two ``cumsum``), or
    None when the kernel is not available or ``occupied`` is not a 2-D bool array."""
    lib = _load()
    occ = np.asarray(occupied)
    if lib is None or occ.dtype != np.bool_ or occ.ndim != 2:
        return None
    occ = np.ascontiguousarray(occ)
    ny, nx = occ.shape
    sat = np.empty((ny + 1, nx + 1), dtype=np.int64)
    lib.sanav_sat(occ.ctypes.data if occ.size else None, ny, nx, address(sat))
    return sat
