"""Compiled :func:`~sanav_mj.planning.smoothing.corridor_assignment`.

The smoothing's safety check assigns every dense sample of each refit to a corridor
rectangle (a few hundred samples, 3-5 times per :func:`~sanav_mj.planning.plan`); in NumPy
that is some 30 small array calls. This kernel does the same comparisons (``x >= x0 - tol``
and so on, the same double operations) and the same integer logic (earliest containing
rectangle in the band, running maximum, the final containment) in one C call, so the
result is identical. Compiled with the flags of :func:`sanav_mj.native.load_c_kernel`;
without a C compiler, when compiling fails, or with ``SANAV_MJ_NO_CKERNEL=1`` the NumPy
code runs instead (the reference; ``tests/planning/test_smoothing.py`` compares both).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.native import NO_KERNEL_ENV, kernel_loader

__all__ = ["assign", "kernel_available"]

_SOURCE = r"""
#include <stdint.h>

static int inside(double x, double y, const double *r, double tol)
{
    return (x >= r[0] - tol) & (x <= r[2] + tol) & (y >= r[1] - tol) & (y <= r[3] + tol);
}

/* Returns the number of points outside their hint rectangle (0: pos untouched, ok all 1),
   or -1 when a hint is not a corridor position. */
int64_t sanav_assign(int64_t K, const double *pts, const int64_t *hint, const double *rects, int64_t C,
                     int64_t band, double tol, int64_t *pos, uint8_t *ok)
{
    int64_t nbad = 0;
    for (int64_t i = 0; i < K; ++i) {
        int64_t h = hint[i];
        if (h < 0 || h >= C) return -1;
        ok[i] = (uint8_t)inside(pts[2 * i], pts[2 * i + 1], rects + 4 * h, tol);
        nbad += !ok[i];
    }
    if (!nbad) return 0;
    int64_t run = INT64_MIN;
    for (int64_t i = 0; i < K; ++i) {
        double x = pts[2 * i], y = pts[2 * i + 1];
        int64_t first = hint[i];
        if (!ok[i]) {
            int found = 0;
            for (int64_t c = hint[i] - band; c <= hint[i] + band; ++c) {
                if (c < 0 || c >= C) continue;
                if (inside(x, y, rects + 4 * c, tol)) { first = c; found = 1; break; }
            }
            ok[i] = (uint8_t)found;
        }
        if (first > run) run = first;
        pos[i] = run;
        if (run != first) ok[i] = (uint8_t)inside(x, y, rects + 4 * run, tol);
    }
    return nbad;
}
"""

#: the compiled kernel (on first use, into the shared cache), or None: no compiler, a failed
#: compile, an unwritable cache or ``SANAV_MJ_NO_CKERNEL=1``
_load = kernel_loader("assign", _SOURCE, "the corridor assignment kernel", NO_KERNEL_ENV, {
    "sanav_assign": (ctypes.c_int64, [ctypes.c_int64] + [ctypes.c_void_p] * 3
                     + [ctypes.c_int64, ctypes.c_int64, ctypes.c_double] + [ctypes.c_void_p] * 2),
})


def kernel_available() -> bool:
    """Whether the compiled assignment is in use (else the NumPy reference)."""
    return _load() is not None


def assign(corridor_rects: np.ndarray, points: np.ndarray, hint: np.ndarray, band: int, tol: float
           ) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`~sanav_mj.planning.smoothing.corridor_assignment` compiled (same arguments and
    results: (K,) int64 positions, ``hint`` itself when every point lies in its hint
    rectangle, and (K,) bool ok), or None when the kernel is not available or an argument is
    not what it takes (the caller then runs the NumPy reference, which also raises what it
    raises)."""
    lib = _load()
    if lib is None or hint.dtype != np.int64 or hint.ndim != 1:
        return None
    r = np.ascontiguousarray(corridor_rects, dtype=np.float64)
    p = np.ascontiguousarray(points, dtype=np.float64)
    h = np.ascontiguousarray(hint)
    K = len(h)
    if r.ndim != 2 or r.shape[1] != 4 or p.shape != (K, 2):
        return None
    pos = np.empty(K, dtype=np.int64)
    ok = np.empty(K, dtype=bool)
    n = lib.sanav_assign(K, p.ctypes.data, h.ctypes.data, r.ctypes.data, len(r), int(band), float(tol),
                         pos.ctypes.data, ok.ctypes.data)
    if n < 0:
        return None
    return (hint if n == 0 else pos), ok
