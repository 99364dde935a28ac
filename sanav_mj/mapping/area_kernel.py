"""Compiled loops of the incremental safe areas (:mod:`sanav_mj.mapping.incremental`), with NumPy fallbacks.

Small C functions do, in one call each, what the NumPy code of
:class:`~sanav_mj.mapping.incremental.IncrementalSafeAreas` does in tens of array calls
per scan (each a few microseconds of overhead on arrays of a few dozen entries):

* :func:`pyramid_add`: ``+-1`` along each changed cell's ancestors in the count pyramid;
* :func:`tile_leaves`: the free quadtree leaves of the dirty tiles, from the pyramid (depth
  first per tile; the NumPy path goes level by level: the same leaves in another order,
  and the merge that follows depends on the set only);
* :func:`link_edges`: the graph edges of new rectangles (sides on one grid line whose
  spans overlap by a positive length) by a double loop over the new and nearby rectangles;
* :func:`slots_meeting`, :func:`clean_pieces`, :func:`merge_boxes`, :func:`snapshot`: the
  rectangles meeting dirty tiles, their parts in clean tiles, the full-edge merge and the
  compact arrays for the planner.

All integer arithmetic, but the snapshot's world coordinates, weights and portals (the same
double operations as NumPy, no fused multiply-add): the results are exactly those of the
NumPy code (tested against it).
The source is compiled once into the solver-code cache by :func:`sanav_mj.native.compile_cached`
(``$SANAV_MJ_CACHE`` or ``~/.cache/sanav-mj``) and loaded with :mod:`ctypes`; without a C
compiler, when compiling fails, or with ``SANAV_MJ_NO_CKERNEL=1``, every function here returns
None and the caller runs its NumPy code.
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.mapping.beam_kernel import NO_KERNEL_ENV, address, buffer_address
from sanav_mj.native import kernel_loader

_SOURCE = r"""
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

/* levels[d] is the (rows >> d, width >> d) int32 count pyramid level d (d = 0 .. L-1). */
void sanav_pyramid_add(int64_t n, const int64_t *cells, const int32_t *delta, int64_t nx, int64_t L,
                       const int64_t *levels, int64_t width)
{
    for (int64_t k = 0; k < n; ++k) {
        const int64_t i = cells[k] / nx, j = cells[k] % nx;
        for (int64_t d = 0; d < L; ++d)
            ((int32_t *)(intptr_t)levels[d])[(i >> d) * (width >> d) + (j >> d)] += delta[k];
    }
}

static int64_t leaves_rec(int64_t i0, int64_t j0, int64_t ls, int64_t ny, int64_t nx, int64_t min_cell,
                          const int64_t *levels, int64_t width, int64_t *out, int64_t m)
{
    const int64_t size = (int64_t)1 << ls;
    const int32_t count = ((const int32_t *)(intptr_t)levels[ls])[(i0 >> ls) * (width >> ls) + (j0 >> ls)];
    const int64_t i1 = i0 + size < ny ? i0 + size : ny, j1 = j0 + size < nx ? j0 + size : nx;
    const int64_t area = (i1 - i0) * (j1 - j0);
    const int leaf = size / 2 >= min_cell ? (count == 0 || count == area) : 1;
    if (leaf) {
        if (count == 0) { out[4 * m] = i0; out[4 * m + 1] = j0; out[4 * m + 2] = i1; out[4 * m + 3] = j1; ++m; }
        return m;
    }
    const int64_t half = size / 2;
    for (int q = 0; q < 4; ++q) {  /* (0,0) (0,1) (1,0) (1,1) as the NumPy path */
        const int64_t ci = i0 + half * (q >> 1), cj = j0 + half * (q & 1);
        if (ci < ny && cj < nx) m = leaves_rec(ci, cj, ls - 1, ny, nx, min_cell, levels, width, out, m);
    }
    return m;
}

/* Free quadtree leaves [i0, j0, i1, j1) of the tiles (tile edge 2^lt) into out (4 per leaf). */
int64_t sanav_tile_leaves(int64_t n, const int64_t *tiles, int64_t ntx, int64_t lt, int64_t ny, int64_t nx,
                          int64_t min_cell, const int64_t *levels, int64_t width, int64_t *out)
{
    int64_t m = 0;
    for (int64_t k = 0; k < n; ++k)
        m = leaves_rec((tiles[k] / ntx) << lt, (tiles[k] % ntx) << lt, lt, ny, nx, min_cell, levels, width,
                       out, m);
    return m;
}

/* Slots (ascending) of the alive boxes meeting a dirty tile (dirty: nty x ntx bytes, tile
   edge 2^lt cells), into out; returns their number. */
int64_t sanav_meeting(int64_t cap, const uint8_t *alive, const int64_t *boxes, int64_t lt, const uint8_t *dirty,
                      int64_t ntx, int64_t *out)
{
    int64_t m = 0;
    for (int64_t s = 0; s < cap; ++s) {
        if (!alive[s]) continue;
        const int64_t *b = boxes + 4 * s;
        const int64_t a0 = b[0] >> lt, a1 = (b[2] - 1) >> lt, c0 = b[1] >> lt, c1 = (b[3] - 1) >> lt;
        int hit = 0;
        for (int64_t a = a0; a <= a1 && !hit; ++a)
            for (int64_t c = c0; c <= c1; ++c)
                if (dirty[a * ntx + c]) { hit = 1; break; }
        if (hit) out[m++] = s;
    }
    return m;
}

/* The parts of the n boxes in clean tiles, cut along tile lines, into out (4 per part). */
int64_t sanav_pieces(int64_t n, const int64_t *boxes, int64_t lt, const uint8_t *dirty, int64_t ntx, int64_t *out)
{
    int64_t m = 0;
    const int64_t t = (int64_t)1 << lt;
    for (int64_t k = 0; k < n; ++k) {
        const int64_t *b = boxes + 4 * k;
        const int64_t a0 = b[0] >> lt, a1 = (b[2] - 1) >> lt, c0 = b[1] >> lt, c1 = (b[3] - 1) >> lt;
        for (int64_t a = a0; a <= a1; ++a)
            for (int64_t c = c0; c <= c1; ++c) {
                if (dirty[a * ntx + c]) continue;
                int64_t *o = out + 4 * m++;
                o[0] = b[0] > a * t ? b[0] : a * t;
                o[1] = b[1] > c * t ? b[1] : c * t;
                o[2] = b[2] < (a + 1) * t ? b[2] : (a + 1) * t;
                o[3] = b[3] < (c + 1) * t ? b[3] : (c + 1) * t;
            }
    }
    return m;
}

/* The edges of the n new slots: every alive slot whose box meets the new boxes' bounding
   box grown by one cell is a candidate; a new box and a candidate touch when a side of one
   and the opposite side of the other lie on one grid line with spans overlapping by > 0.
   Pairs (low slot, high slot) into out, each once; pos (cap, all -1) and cand (cap) are
   scratch (pos left all -1). Returns the number of pairs. */
int64_t sanav_link(int64_t n, const int64_t *slots, int64_t cap, const uint8_t *alive, const int64_t *boxes,
                   int64_t *pos, int64_t *cand, int64_t *out)
{
    if (n == 0) return 0;
    int64_t lo_i = INT64_MAX, hi_i = INT64_MIN, lo_j = INT64_MAX, hi_j = INT64_MIN;
    for (int64_t x = 0; x < n; ++x) {
        const int64_t *p = boxes + 4 * slots[x];
        if (p[0] < lo_i) lo_i = p[0];
        if (p[2] > hi_i) hi_i = p[2];
        if (p[1] < lo_j) lo_j = p[1];
        if (p[3] > hi_j) hi_j = p[3];
        pos[slots[x]] = x;
    }
    int64_t nc = 0;
    for (int64_t s = 0; s < cap; ++s) {
        if (!alive[s]) continue;
        const int64_t *q = boxes + 4 * s;
        if (q[0] <= hi_i && q[2] >= lo_i && q[1] <= hi_j && q[3] >= lo_j) cand[nc++] = s;
    }
    int64_t m = 0;
    for (int64_t x = 0; x < n; ++x) {
        const int64_t sa = slots[x];
        const int64_t *p = boxes + 4 * sa;
        for (int64_t y = 0; y < nc; ++y) {
            const int64_t sb = cand[y];
            if (pos[sb] >= 0 && pos[sb] <= x) continue;  /* a new pair: from its lower index only */
            const int64_t *q = boxes + 4 * sb;
            const int side = (p[3] == q[1] || p[1] == q[3]) && p[0] < q[2] && q[0] < p[2];
            const int over = (p[2] == q[0] || p[0] == q[2]) && p[1] < q[3] && q[1] < p[3];
            if (side || over) { out[2 * m] = sa < sb ? sa : sb; out[2 * m + 1] = sa < sb ? sb : sa; ++m; }
        }
    }
    for (int64_t x = 0; x < n; ++x) pos[slots[x]] = -1;
    return m;
}

/* Apply the n cell values (0/1) to the occupied grid; each cell that changes adds +-1 along
   its pyramid ancestors and makes its tile dirty (dirty: nty x ntx bytes, all 0 on entry).
   A cell listed twice must have one value (the later entries then change nothing). Writes
   the dirty tiles, ascending, to tiles; returns their number. */
static int cmp_i64(const void *x, const void *y)
{
    const int64_t a = *(const int64_t *)x, b = *(const int64_t *)y;
    return (a > b) - (a < b);
}

int64_t sanav_apply_cells(int64_t n, const int64_t *cells, const uint8_t *values, uint8_t *occupied, int64_t nx,
                          int64_t L, const int64_t *levels, int64_t width, int64_t ntx, uint8_t *dirty,
                          int64_t *tiles)
{
    const int64_t lt = L - 1;
    int64_t m = 0;
    for (int64_t k = 0; k < n; ++k) {
        const int64_t c = cells[k];
        const uint8_t v = values[k] != 0;
        if (occupied[c] == v) continue;
        occupied[c] = v;
        const int32_t d = v ? 1 : -1;
        const int64_t i = c / nx, j = c % nx;
        for (int64_t l = 0; l < L; ++l)
            ((int32_t *)(intptr_t)levels[l])[(i >> l) * (width >> l) + (j >> l)] += d;
        const int64_t t = (i >> lt) * ntx + (j >> lt);
        if (!dirty[t]) { dirty[t] = 1; tiles[m++] = t; }
    }
    qsort(tiles, (size_t)m, sizeof(int64_t), cmp_i64);
    return m;
}

/* Keep the E edges whose two slots are alive (in place, order kept); returns their number. */
int64_t sanav_drop_edges(int64_t E, int64_t *edges, const uint8_t *alive)
{
    int64_t m = 0;
    for (int64_t k = 0; k < E; ++k)
        if (alive[edges[2 * k]] && alive[edges[2 * k + 1]]) {
            edges[2 * m] = edges[2 * k];
            edges[2 * m + 1] = edges[2 * k + 1];
            ++m;
        }
    return m;
}

typedef struct { int64_t i0, j0, i1, j1; } box_t;

static int cmp3(int64_t a0, int64_t a1, int64_t a2, int64_t b0, int64_t b1, int64_t b2)
{
    if (a0 != b0) return a0 < b0 ? -1 : 1;
    if (a1 != b1) return a1 < b1 ? -1 : 1;
    return (a2 > b2) - (a2 < b2);
}
static int by_rows(const void *x, const void *y)  /* chains along x: same rows, then j0 */
{
    const box_t *a = x, *b = y;
    return cmp3(a->i0, a->i1, a->j0, b->i0, b->i1, b->j0);
}
static int by_cols(const void *x, const void *y)  /* chains along y: same columns, then i0 */
{
    const box_t *a = x, *b = y;
    return cmp3(a->j0, a->j1, a->i0, b->j0, b->j1, b->i0);
}
static int by_corner(const void *x, const void *y)
{
    const box_t *a = x, *b = y;
    return cmp3(a->i0, a->j0, 0, b->i0, b->j0, 0);
}

/* merge_rects (sanav_mj/mapping/safe_areas.py, method "paper") in place on n disjoint boxes:
   full-edge chain merges in alternating passes, x first, until a pass after the first
   changes nothing; the result sorted by (i0, j0). Returns the number of boxes. */
int64_t sanav_merge(int64_t n, int64_t *boxes)
{
    box_t *b = (box_t *)boxes;
    int axis = 1, passes = 0;
    while (n > 1) {
        qsort(b, (size_t)n, sizeof(box_t), axis == 1 ? by_rows : by_cols);
        int64_t w = 0;
        for (int64_t k = 0; k < n; ++k) {
            if (w > 0) {
                box_t *p = b + w - 1;
                if (axis == 1 && p->i0 == b[k].i0 && p->i1 == b[k].i1 && p->j1 == b[k].j0) {
                    p->j1 = b[k].j1;
                    continue;
                }
                if (axis == 0 && p->j0 == b[k].j0 && p->j1 == b[k].j1 && p->i1 == b[k].i0) {
                    p->i1 = b[k].i1;
                    continue;
                }
            }
            b[w++] = b[k];
        }
        const int changed = w != n;
        n = w;
        ++passes;
        if (!changed && passes > 1) break;
        axis = 1 - axis;
    }
    qsort(b, (size_t)n, sizeof(box_t), by_corner);
    return n;
}

typedef struct { int64_t key, val; } kv_t;
static int by_key(const void *x, const void *y)
{
    const int64_t a = ((const kv_t *)x)->key, b = ((const kv_t *)y)->key;
    return (a > b) - (a < b);
}

/* IncrementalSafeAreas.safe_areas in one pass: the alive boxes sorted by i0 * base + j0
   (out_b, R x 4), their world rectangles (out_r, R x 4: xmin, ymin, xmax, ymax), the edges
   renumbered, each (low, high), sorted by low * max(R, 1) + high (out_e, E x 2), centre
   distances (out_w) and portals (out_p, E x 2 x 2) as the NumPy code computes them.
   kv (max(cap, E) entries) and index (cap) are scratch. Returns R. */
int64_t sanav_snapshot(int64_t cap, const uint8_t *alive, const int64_t *boxes, int64_t E, const int64_t *edges,
                       int64_t base, double ox, double oy, double h, int64_t *out_b, double *out_r, int64_t *out_e,
                       double *out_w, double *out_p, kv_t *kv, int64_t *index)
{
    int64_t R = 0;
    for (int64_t s = 0; s < cap; ++s)
        if (alive[s]) { kv[R].key = boxes[4 * s] * base + boxes[4 * s + 1]; kv[R].val = s; ++R; }
    qsort(kv, (size_t)R, sizeof(kv_t), by_key);
    for (int64_t s = 0; s < cap; ++s) index[s] = -1;
    for (int64_t k = 0; k < R; ++k) {
        const int64_t *b = boxes + 4 * kv[k].val;
        index[kv[k].val] = k;
        for (int c = 0; c < 4; ++c) out_b[4 * k + c] = b[c];
        out_r[4 * k] = ox + h * (double)b[1];
        out_r[4 * k + 1] = oy + h * (double)b[0];
        out_r[4 * k + 2] = ox + h * (double)b[3];
        out_r[4 * k + 3] = oy + h * (double)b[2];
    }
    const int64_t mr = R > 1 ? R : 1;
    for (int64_t k = 0; k < E; ++k) {
        int64_t a = index[edges[2 * k]], b = index[edges[2 * k + 1]];
        if (a > b) { const int64_t t = a; a = b; b = t; }
        kv[k].key = a * mr + b;
        kv[k].val = k;
    }
    qsort(kv, (size_t)E, sizeof(kv_t), by_key);
    for (int64_t k = 0; k < E; ++k) {
        const int64_t a = kv[k].key / mr, b = kv[k].key % mr;
        out_e[2 * k] = a;
        out_e[2 * k + 1] = b;
        const double *ra = out_r + 4 * a, *rb = out_r + 4 * b;
        const double dx = 0.5 * (ra[0] + ra[2]) - 0.5 * (rb[0] + rb[2]);
        const double dy = 0.5 * (ra[1] + ra[3]) - 0.5 * (rb[1] + rb[3]);
        const double sx = dx * dx, sy = dy * dy;
        out_w[k] = sqrt(sx + sy);
        const int64_t *ba = out_b + 4 * a, *bb = out_b + 4 * b;
        const int side = ba[3] == bb[1] || bb[3] == ba[1];
        const int64_t xline = ba[3] == bb[1] ? ba[3] : bb[3];
        const int64_t yline = ba[2] == bb[0] ? ba[2] : bb[2];
        const int64_t lo_i = ba[0] > bb[0] ? ba[0] : bb[0], hi_i = ba[2] < bb[2] ? ba[2] : bb[2];
        const int64_t lo_j = ba[1] > bb[1] ? ba[1] : bb[1], hi_j = ba[3] < bb[3] ? ba[3] : bb[3];
        double *p = out_p + 4 * k;
        p[0] = ox + h * (double)(side ? xline : lo_j);
        p[2] = ox + h * (double)(side ? xline : hi_j);
        p[1] = oy + h * (double)(side ? lo_i : yline);
        p[3] = oy + h * (double)(side ? hi_i : yline);
    }
    return R;
}
"""

_i64, _ptr = ctypes.c_int64, ctypes.c_void_p
#: the compiled functions, or None (no compiler, failed compile, ``SANAV_MJ_NO_CKERNEL=1``)
_load = kernel_loader("areas", _SOURCE, "the safe-area kernel", NO_KERNEL_ENV, {
    "sanav_pyramid_add": (None, [_i64, _ptr, _ptr, _i64, _i64, _ptr, _i64]),
    "sanav_tile_leaves": (_i64, [_i64, _ptr, _i64, _i64, _i64, _i64, _i64, _ptr, _i64, _ptr]),
    "sanav_meeting": (_i64, [_i64, _ptr, _ptr, _i64, _ptr, _i64, _ptr]),
    "sanav_pieces": (_i64, [_i64, _ptr, _i64, _ptr, _i64, _ptr]),
    "sanav_link": (_i64, [_i64, _ptr, _i64, _ptr, _ptr, _ptr, _ptr, _ptr]),
    "sanav_apply_cells": (_i64, [_i64, _ptr, _ptr, _ptr, _i64, _i64, _ptr, _i64, _i64, _ptr, _ptr]),
    "sanav_drop_edges": (_i64, [_i64, _ptr, _ptr]),
    "sanav_merge": (_i64, [_i64, _ptr]),
    "sanav_snapshot": (_i64, [_i64, _ptr, _ptr, _i64, _ptr, _i64, ctypes.c_double, ctypes.c_double, ctypes.c_double,
                              _ptr, _ptr, _ptr, _ptr, _ptr, _ptr, _ptr]),
})


def kernel_available() -> bool:
    """Whether the compiled safe-area functions are in use (else the NumPy code)."""
    return _load() is not None


class Pyramid:
    """The count pyramid's levels as the compiled functions take them.

    Args:
        levels: the (rows >> d, width >> d) int32 C-contiguous levels d = 0 .. L-1 (kept
            alive and updated in place).
    """

    def __init__(self, levels: list[np.ndarray]) -> None:
        for d, lv in enumerate(levels):
            if lv.dtype != np.int32 or not lv.flags.c_contiguous:
                raise ValueError(f"pyramid level {d} must be a contiguous int32 array, got {lv.dtype}")
        self.levels = levels
        self.width = int(levels[0].shape[1])
        self.ptrs = np.array([address(lv) for lv in levels], dtype=np.int64)
        self.ptrs_address = address(self.ptrs)


def pyramid_add(pyr: Pyramid, cells: np.ndarray, delta: np.ndarray, nx: int) -> bool:
    """Add ``delta[k]`` along the ancestors of cell ``cells[k]`` at every level; False (and
    nothing done) without the kernel.

    Args:
        pyr: the pyramid.
        cells: (K,) int64 flat grid indices ``i * nx + j``; delta: (K,) int32.
        nx: grid columns.
    """
    lib = _load()
    if lib is None:
        return False
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    delta = np.ascontiguousarray(delta, dtype=np.int32)
    lib.sanav_pyramid_add(len(cells), address(cells), address(delta), nx, len(pyr.levels),
                          pyr.ptrs_address, pyr.width)
    return True


def tile_leaves(pyr: Pyramid, tiles: np.ndarray, ntx: int, tile: int, shape: tuple[int, int], min_cell: int
                ) -> np.ndarray | None:
    """(N, 4) int64 free quadtree leaves ``[i0, j0, i1, j1)`` of the tiles (flat tile indices,
    ``ntx`` tiles a row, edge ``tile`` cells), depth first; None without the kernel."""
    lib = _load()
    if lib is None:
        return None
    tiles = np.ascontiguousarray(tiles, dtype=np.int64)
    lt = int(tile).bit_length() - 1
    if len(pyr.levels) != lt + 1:
        raise ValueError(f"the pyramid needs {lt + 1} levels for tiles of {tile} cells, got {len(pyr.levels)}")
    out = np.empty((len(tiles) * tile * tile, 4), dtype=np.int64)
    m = lib.sanav_tile_leaves(len(tiles), address(tiles), ntx, lt, shape[0], shape[1], min_cell,
                              pyr.ptrs_address, pyr.width, address(out))
    return out[:m]


def _dirty_bytes(dirty: np.ndarray) -> np.ndarray:
    if dirty.dtype != np.bool_ or dirty.ndim != 2 or not dirty.flags.c_contiguous:
        raise ValueError(f"dirty must be a contiguous (nty, ntx) bool array, got {dirty.dtype} {dirty.shape}")
    return dirty


def slots_meeting(alive: np.ndarray, boxes: np.ndarray, tile: int, dirty: np.ndarray) -> np.ndarray | None:
    """(S,) int64 ascending slots of the alive boxes that meet a dirty tile; None without the kernel.

    Args:
        alive: (cap,) bool; boxes: (cap, 4) int64 ``[i0, j0, i1, j1)`` (read where alive).
        tile: tile edge [cells], a power of two; dirty: (nty, ntx) bool dirty tiles.
    """
    lib = _load()
    if lib is None:
        return None
    dirty = _dirty_bytes(dirty)
    if alive.dtype != np.bool_ or boxes.dtype != np.int64 or not boxes.flags.c_contiguous or len(boxes) != len(alive):
        raise ValueError(f"alive (cap,) bool and boxes (cap, 4) int64 expected, got {alive.dtype} {alive.shape}, "
                         f"{boxes.dtype} {boxes.shape}")
    out = np.empty(len(alive), dtype=np.int64)
    m = lib.sanav_meeting(len(alive), buffer_address(alive), buffer_address(boxes), int(tile).bit_length() - 1,
                          address(dirty), dirty.shape[1], address(out))
    return out[:m]


def clean_pieces(boxes: np.ndarray, tile: int, dirty: np.ndarray) -> np.ndarray | None:
    """(P, 4) int64 parts of ``boxes`` ((N, 4) int64) lying in clean tiles, cut along tile
    lines (box by box, tile rows then columns); None without the kernel."""
    lib = _load()
    if lib is None:
        return None
    dirty = _dirty_bytes(dirty)
    boxes = np.ascontiguousarray(boxes, dtype=np.int64)
    lt = int(tile).bit_length() - 1
    rows = ((boxes[:, 2] - 1) >> lt) - (boxes[:, 0] >> lt) + 1
    spans = rows * (((boxes[:, 3] - 1) >> lt) - (boxes[:, 1] >> lt) + 1)
    out = np.empty((int(spans.sum()), 4), dtype=np.int64)
    m = lib.sanav_pieces(len(boxes), address(boxes), lt, address(dirty), dirty.shape[1], address(out))
    return out[:m]


def merge_boxes(boxes: np.ndarray) -> np.ndarray | None:
    """:func:`sanav_mj.mapping.safe_areas.merge_rects` (method ``"paper"``) compiled: the
    same (R, 4) int64 boxes sorted by ``(i0, j0)``; None without the kernel.

    Args:
        boxes: (N, 4) int cell boxes ``[i0, j0, i1, j1)`` with disjoint interiors.
    """
    lib = _load()
    if lib is None:
        return None
    b = np.array(boxes, dtype=np.int64, order="C", copy=True).reshape(-1, 4)
    m = lib.sanav_merge(len(b), address(b))
    return b[:m]


def snapshot(alive: np.ndarray, boxes: np.ndarray, edges: np.ndarray, base: int, origin, resolution: float):
    """The compact safe areas of :meth:`IncrementalSafeAreas.safe_areas
    <sanav_mj.mapping.incremental.IncrementalSafeAreas.safe_areas>` in one compiled pass;
    None without the kernel.

    Args:
        alive: (cap,) bool; boxes: (cap, 4) int64 slot boxes; edges: (E, 2) int64 slot pairs.
        base: sort-key base, above every cell coordinate.
        origin: (2,) [m] grid origin; resolution: [m] cell edge.

    Returns:
        boxes (R, 4) int64 sorted by ``(i0, j0)``, rects (R, 4) [m], edges (E, 2) int64
        sorted, weights (E,) [m], portals (E, 2, 2) [m].
    """
    lib = _load()
    if lib is None:
        return None
    if alive.dtype != np.bool_ or boxes.dtype != np.int64 or not boxes.flags.c_contiguous or len(boxes) != len(alive):
        raise ValueError(f"alive (cap,) bool and boxes (cap, 4) int64 expected, got {alive.dtype} {alive.shape}, "
                         f"{boxes.dtype} {boxes.shape}")
    edges = np.ascontiguousarray(edges, dtype=np.int64).reshape(-1, 2)
    cap, E = len(alive), len(edges)
    R = int(np.count_nonzero(alive))
    out_b = np.empty((R, 4), dtype=np.int64)
    out_r = np.empty((R, 4))
    out_e = np.empty((E, 2), dtype=np.int64)
    out_w = np.empty(E)
    out_p = np.empty((E, 2, 2))
    kv = np.empty(2 * max(cap, E), dtype=np.int64)
    index = np.empty(cap, dtype=np.int64)
    lib.sanav_snapshot(cap, buffer_address(alive), buffer_address(boxes), E, address(edges), int(base),
                       float(origin[0]), float(origin[1]), float(resolution), address(out_b), address(out_r),
                       address(out_e), address(out_w), address(out_p), address(kv), address(index))
    return out_b, out_r, out_e, out_w, out_p


def link_edges(slots: np.ndarray, alive: np.ndarray, boxes: np.ndarray, scratch: dict) -> np.ndarray | None:
    """(P, 2) int64 edges (low slot, high slot) between the new ``slots`` and every alive box
    they touch (sides on one grid line, spans overlapping by a positive length), each once;
    None without the kernel.

    Args:
        slots: (N,) int64 slots of the new boxes (alive, in ``boxes``).
        alive: (cap,) bool; boxes: (cap, 4) int64 slot boxes.
        scratch: a dict kept by the caller between calls (work arrays of the slot capacity).
    """
    lib = _load()
    if lib is None:
        return None
    cap = len(alive)
    if alive.dtype != np.bool_ or boxes.dtype != np.int64 or not boxes.flags.c_contiguous or len(boxes) != cap:
        raise ValueError(f"alive (cap,) bool and boxes (cap, 4) int64 expected, got {alive.dtype} {alive.shape}, "
                         f"{boxes.dtype} {boxes.shape}")
    slots = np.ascontiguousarray(slots, dtype=np.int64)
    if scratch.get("cap") != cap:
        scratch["cap"] = cap
        scratch["pos"] = np.full(cap, -1, dtype=np.int64)
        scratch["cand"] = np.empty(cap, dtype=np.int64)
    b = boxes[slots]
    # a box touches at most one neighbour per cell along its sides
    bound = int(2 * ((b[:, 2] - b[:, 0]) + (b[:, 3] - b[:, 1])).sum())
    out = np.empty((bound, 2), dtype=np.int64)
    m = lib.sanav_link(len(slots), address(slots), cap, buffer_address(alive), buffer_address(boxes),
                       buffer_address(scratch["pos"]), buffer_address(scratch["cand"]), address(out))
    return out[:m]


def apply_cells(pyr: Pyramid, cells: np.ndarray, values: np.ndarray, occupied: np.ndarray, nx: int, ntx: int,
                dirty: np.ndarray) -> np.ndarray | None:
    """Write the cells' new values into ``occupied``, update the pyramid along the cells that
    changed and mark their tiles in ``dirty``; None (nothing done) without the kernel.

    Args:
        pyr: the count pyramid (its levels' count is the tile's level + 1).
        cells: (K,) int64 flat indices; values: (K,) bool (a repeated cell: one value).
        occupied: (ny, nx) bool grid, updated in place.
        nx: grid columns; ntx: tiles a row.
        dirty: (nty, ntx) bool, all False on entry.

    Returns:
        (T,) int64 ascending flat indices of the dirty tiles.
    """
    lib = _load()
    if lib is None:
        return None
    dirty = _dirty_bytes(dirty)
    if occupied.dtype != np.bool_ or not occupied.flags.c_contiguous:
        raise ValueError(f"occupied must be a contiguous bool array, got {occupied.dtype}")
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    values = np.ascontiguousarray(values, dtype=np.bool_)
    tiles = np.empty(dirty.size, dtype=np.int64)
    m = lib.sanav_apply_cells(len(cells), address(cells), address(values), buffer_address(occupied), nx,
                              len(pyr.levels), pyr.ptrs_address, pyr.width, ntx, address(dirty),
                              address(tiles))
    return tiles[:m]


def drop_dead_edges(edges: np.ndarray, alive: np.ndarray) -> np.ndarray | None:
    """The rows of ``edges`` ((E, 2) int64 slot pairs, compacted in place) whose slots are
    both alive, as a view; None without the kernel."""
    lib = _load()
    if lib is None:
        return None
    if edges.dtype != np.int64 or not edges.flags.c_contiguous or alive.dtype != np.bool_:
        raise ValueError(f"edges (E, 2) int64 contiguous and alive bool expected, got {edges.dtype}, {alive.dtype}")
    m = lib.sanav_drop_edges(len(edges), address(edges), buffer_address(alive))
    return edges[:m]
