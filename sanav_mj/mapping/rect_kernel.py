"""Compiled test of rectangles against a grid of blocked counts
(:meth:`SensedMap.rects_still_safe <sanav_mj.mapping.sensed_map.SensedMap.rects_still_safe>`).

The sensing loop asks at every scan that changed the safe areas whether each rectangle of
the corridor it follows still lies in safe cells: some 10-30 rectangles, each a slice of the
grid tested with ``.any()`` in a Python loop (a few microseconds of call overhead per
rectangle). This kernel runs the same test (the same cell bounds, then cell by cell) in one C call (compiled by
:func:`sanav_mj.native.load_c_kernel`); the answer is the same boolean per rectangle.

Without a C compiler, when compiling fails, or with ``SANAV_MJ_NO_CKERNEL=1``, the Python
loop runs instead: it is the reference (``tests/mapping/test_sensed_map.py`` compares both).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.mapping.beam_kernel import NO_KERNEL_ENV, address
from sanav_mj.native import kernel_loader

__all__ = ["kernel_available", "rects_free"]

_SOURCE = r"""
#include <math.h>
#include <stdint.h>

/* floor / ceil of v, clipped to [0, n], as an integer (np.clip then astype(int)); v finite. */
static int64_t clip_cell(double v, int64_t n)
{
    if (v < 0.0) v = 0.0;
    if (v > (double)n) v = (double)n;
    return (int64_t)v;
}

/* out[k] = 1 when the cells of world rectangle k (xmin, ymin, xmax, ymax; rows of the grid
   stride cells apart) form a non-empty box with every count 0, else 0: the cells are
   [floor((ymin - oy) / h + 1e-9), ceil((ymax - oy) / h - 1e-9)) x (the same in x), clipped
   to the grid, as SensedMap.rects_still_safe computes them. */
void sanav_rects_free(int64_t K, const double *r, double ox, double oy, double h, int64_t ny, int64_t nx,
                      const int32_t *grid, int64_t stride, uint8_t *out)
{
    for (int64_t k = 0; k < K; ++k) {
        int64_t j0 = clip_cell(floor((r[4 * k] - ox) / h + 1e-9), nx);
        int64_t i0 = clip_cell(floor((r[4 * k + 1] - oy) / h + 1e-9), ny);
        int64_t j1 = clip_cell(ceil((r[4 * k + 2] - ox) / h - 1e-9), nx);
        int64_t i1 = clip_cell(ceil((r[4 * k + 3] - oy) / h - 1e-9), ny);
        int ok = i1 > i0 && j1 > j0;
        for (int64_t i = i0; ok && i < i1; ++i) {
            const int32_t *row = grid + i * stride;
            for (int64_t j = j0; j < j1; ++j)
                if (row[j] != 0) { ok = 0; break; }
        }
        out[k] = (uint8_t)ok;
    }
}
"""

_i64, _ptr = ctypes.c_int64, ctypes.c_void_p
_load = kernel_loader("rects", _SOURCE, "the rectangle test kernel", NO_KERNEL_ENV, {
    "sanav_rects_free": (None, [_i64, _ptr, ctypes.c_double, ctypes.c_double, ctypes.c_double, _i64, _i64, _ptr,
                                _i64, _ptr]),
})


def kernel_available() -> bool:
    """Whether the compiled rectangle test is in use (else the Python loop)."""
    return _load() is not None


def rects_free(rects: np.ndarray, grid: np.ndarray, origin, resolution: float) -> np.ndarray | None:
    """Whether the cells of each world rectangle form a non-empty box of zero counts, or
    None when the kernel is not available, ``grid`` is not a row-strided int32 array or a
    rectangle is not finite.

    Args:
        rects: (K, 4) [m] ``xmin, ymin, xmax, ymax``; the cells are those
            :meth:`SensedMap.rects_still_safe
            <sanav_mj.mapping.sensed_map.SensedMap.rects_still_safe>` takes (edges within
            1e-9 cell of a cell boundary snap to it), clipped to the grid.
        grid: (ny, nx) int32 counts (a view with unit column stride, e.g. a padded grid's
            interior); origin: (2,) [m] its lower-left corner; resolution: [m] cell size.

    Returns:
        (K,) bool.
    """
    lib = _load()
    if lib is None or grid.dtype != np.int32 or grid.ndim != 2 or grid.strides[1] != 4 or grid.strides[0] % 4:
        return None
    r = np.ascontiguousarray(rects, dtype=np.float64).reshape(-1, 4)
    if not np.isfinite(r).all():
        return None
    out = np.zeros(len(r), dtype=bool)
    if len(r):
        ny, nx = grid.shape
        lib.sanav_rects_free(len(r), address(r), float(origin[0]), float(origin[1]), float(resolution), ny, nx,
                             grid.ctypes.data, grid.strides[0] // 4, address(out))
    return out
