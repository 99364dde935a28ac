"""Compiled candidate search of :func:`sanav_mj.control.disc_stages.footprint_reference`.

For each reference pose whose disc centres leave the corridor chain, ``footprint_reference``
takes the first pose of a lattice (11 x 11 positions, 89 yaws), in a fixed cost order, whose
disc centres all lie in a chain member. Its NumPy path (``disc_stages._acceptable``) tests
every candidate at once, per axis; this kernel runs the same per-axis tests in C and stops at
the first acceptable candidate in cost order (compiled by :func:`sanav_mj.native.load_c_kernel`).

Exactness: the candidates' positions and the cosines and sines of their yaws are computed by
NumPy and passed in (C's libm may round differently); the kernel computes each disc centre
with the same IEEE operations in the same order as :func:`sanav_mj.control.footprint.disc_centres`
(``x + ox c - oy s``, ``y + ox s + oy c``; no FMA contraction, see
:data:`sanav_mj.native.KERNEL_FLAGS`) and tests each member's slack ``>= 0`` on both sides of
both axes, so every decision, and the first acceptable candidate, is the NumPy path's.

Without a C compiler, when compiling fails, or with ``SANAV_MJ_NO_CKERNEL=1``, the NumPy path
runs instead: it is the reference (``tests/control/test_disc_reference_exact.py`` compares
both, and both with the search as first written).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.native import NO_KERNEL_ENV, kernel_loader

__all__ = ["kernel_available", "first_acceptable"]

_SOURCE = r"""
#include <stdint.h>

/* For each of nb states: the position j in `order` (L entries, indices into the (ix, iy, k)
   ravel order of an nx x nx x na lattice) of the first candidate every disc centre of which
   lies in one member box of that disc's chain, or -1.
   xs, ys: (nb, nx) candidate x and y; c, s: (nb, na) cosine and sine of the candidate yaws;
   off: (nd, 2) disc offsets in the body frame; boxes: the discs' member boxes one disc after
   the other, (xmin, ymin, xmax, ymax) each; nbox: (nd) member counts; acc: nx * na words of
   workspace (bit ix of acc[iy * na + k]: candidate (ix, iy, k) acceptable so far). nx <= 32. */
void sanav_repair_first(int64_t nb, int64_t nx, int64_t na, const double *xs, const double *ys,
                        const double *c, const double *s, int64_t nd, const double *off,
                        const double *boxes, const int64_t *nbox, int64_t L, const int64_t *order,
                        uint32_t *acc, int64_t *first)
{
    double px[32], py[32];
    uint32_t row[32];
    const uint32_t full = (nx >= 32) ? 0xffffffffu : ((1u << nx) - 1u);
    for (int64_t b = 0; b < nb; ++b) {
        const double *xb = xs + b * nx, *yb = ys + b * nx, *cb = c + b * na, *sb = s + b * na;
        for (int64_t q = 0; q < nx * na; ++q) acc[q] = full;
        const double *bx = boxes;
        uint32_t alive = 1;
        for (int64_t d = 0; d < nd && alive; ++d) {
            const double ox = off[2 * d], oy = off[2 * d + 1];
            alive = 0;
            for (int64_t k = 0; k < na; ++k) {
                const double ck = cb[k], sk = sb[k];
                for (int64_t i = 0; i < nx; ++i) {
                    px[i] = xb[i] + ox * ck - oy * sk;   /* as disc_centres: (x + ox c) - oy s */
                    py[i] = yb[i] + ox * sk + oy * ck;   /* (y + ox s) + oy c */
                    row[i] = 0u;
                }
                for (int64_t m = 0; m < nbox[d]; ++m) {
                    const double *q = bx + 4 * m;
                    /* px, py are non-decreasing in the offset index (xs, ys are, and rounding
                       is monotone): a member beyond the first or last centre passes none */
                    if (px[nx - 1] - q[0] < 0.0 || q[2] - px[0] < 0.0) continue;
                    if (py[nx - 1] - q[1] < 0.0 || q[3] - py[0] < 0.0) continue;
                    uint32_t xm = 0u;
                    for (int64_t i = 0; i < nx; ++i)
                        if (px[i] - q[0] >= 0.0 && q[2] - px[i] >= 0.0) xm |= 1u << i;
                    if (!xm) continue;
                    for (int64_t i = 0; i < nx; ++i)
                        if (py[i] - q[1] >= 0.0 && q[3] - py[i] >= 0.0) row[i] |= xm;
                }
                for (int64_t i = 0; i < nx; ++i) {
                    acc[i * na + k] &= row[i];
                    alive |= acc[i * na + k];
                }
            }
            bx += 4 * nbox[d];
        }
        first[b] = -1;
        if (!alive) continue;
        for (int64_t j = 0; j < L; ++j) {
            const int64_t idx = order[j], ix = idx / (nx * na), rem = idx - ix * nx * na;
            const int64_t iy = rem / na, k = rem - iy * na;
            if ((acc[iy * na + k] >> ix) & 1u) { first[b] = j; break; }
        }
    }
}
"""

_i64, _ptr = ctypes.c_int64, ctypes.c_void_p
_load = kernel_loader("repair", _SOURCE, "the footprint reference search kernel", NO_KERNEL_ENV, {
    "sanav_repair_first": (None, [_i64, _i64, _i64, _ptr, _ptr, _ptr, _ptr, _i64, _ptr, _ptr, _ptr, _i64, _ptr,
                                  _ptr, _ptr]),
})


def kernel_available() -> bool:
    """Whether the compiled search is in use (else the NumPy path)."""
    return _load() is not None


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def first_acceptable(xs: np.ndarray, ys: np.ndarray, cos: np.ndarray, sin: np.ndarray, offsets: np.ndarray,
                     boxes: list[np.ndarray], order: np.ndarray) -> np.ndarray | None:
    """Per state, the position in ``order`` of its first candidate whose every disc centre
    lies in a member box of that disc's chain (-1: none), or None when the kernel is not
    available or the lattice has more than 32 positions per axis.

    Args:
        xs, ys: (B, n) [m] the candidates' x and y (state plus offset, as NumPy adds them).
        cos, sin: (B, a) the cosine and sine of the candidates' yaws (computed by NumPy).
        offsets: (D, 2) [m] disc centres in the body frame.
        boxes: D arrays (M_d, 4) [m], the member boxes of each disc's chain.
        order: (L,) int, candidate indices in the ``(x, y, yaw)`` ravel order of the
            ``n x n x a`` lattice, in the order to search.

    Returns:
        (B,) int64.
    """
    lib = _load()
    nb, nx = xs.shape
    na = cos.shape[1]
    if lib is None or nx > 32:
        return None
    xs, ys, cos, sin, off = _f64(xs), _f64(ys), _f64(cos), _f64(sin), _f64(offsets)
    bx = _f64(np.concatenate([np.asarray(b, dtype=np.float64).reshape(-1, 4) for b in boxes]))
    nbox = np.array([len(b) for b in boxes], dtype=np.int64)
    order = np.ascontiguousarray(order, dtype=np.int64)
    if len(off) != len(boxes) or ys.shape != xs.shape or cos.shape != (nb, na) or sin.shape != (nb, na):
        raise ValueError(f"first_acceptable: expected xs, ys (B, n), cos, sin (B, a) and one box set per offset, "
                         f"got {xs.shape}, {ys.shape}, {cos.shape}, {sin.shape}, {len(off)} offsets, "
                         f"{len(boxes)} box sets")
    acc = np.empty(nx * na, dtype=np.uint32)
    first = np.empty(nb, dtype=np.int64)
    lib.sanav_repair_first(nb, nx, na, xs.ctypes.data, ys.ctypes.data, cos.ctypes.data, sin.ctypes.data,
                           len(off), off.ctypes.data, bx.ctypes.data, nbox.ctypes.data, order.size,
                           order.ctypes.data, acc.ctypes.data, first.ctypes.data)
    return first
