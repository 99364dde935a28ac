"""Compiled stage assignment of the footprint's disc centres along one corridor chain
(SA-MPC's ``"discs"`` mode, :func:`sanav_mj.control.sa_mpc._assign_shared`).

Every step assigns each disc centre of the guessed horizon to a chain member: squared
distances of all centres outside all stay / advance boxes (:func:`~sanav_mj.control.stages._outside_sq`),
zeroed below the tolerance; the members as bits (:func:`~sanav_mj.control.stages.assign_feasible`);
stage 0's candidates around the previous anchor (:func:`~sanav_mj.control.stages.first_candidates`,
used when the nearest candidate lies within the re-anchoring distance); the assignment from
the bit sets (:func:`~sanav_mj.control.stages.feasible_from_bits`); the stage boxes. In NumPy
and Python that is some 40 small array calls and two bit loops per disc (about 0.08 ms a
step); this kernel does the same in one C call.

Exactness: the distances are the same IEEE operations in the same order (``max``, products,
one sum; compiled without FMA contraction, :data:`sanav_mj.native.KERNEL_FLAGS`), so every
zero test and the re-anchoring test decide alike; the rest is integer bit logic and copying
boxes. A disc whose centres fit no assignment with zero violation is reported back and
assigned by the dynamic programme of :func:`~sanav_mj.control.stages.assign_stages` (the
reference's fallback too). Without a C compiler, when compiling fails, with
``SANAV_MJ_NO_CKERNEL=1``, more than 62 members or a non-finite centre, :func:`assign_discs`
returns None and the NumPy path runs: it is the reference
(``tests/control/test_assign_kernel.py`` compares both).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.mapping.beam_kernel import address
from sanav_mj.native import NO_KERNEL_ENV, kernel_loader

__all__ = ["assign_discs", "kernel_available", "relax_discs"]

_SOURCE = r"""
#include <math.h>
#include <stddef.h>
#include <stdint.h>

/* np.maximum(np.maximum(a, b), 0.0) for finite a, b */
static double max3(double a, double b)
{
    double m = a > b ? a : b;
    return m > 0.0 ? m : 0.0;
}

/* pts (n1, nd, 2) disc centres; both (2L, 4) stay then advance boxes; stay/adv views of both.
   s_prev (nd, n1) or NULL. For each disc d: ss[d, :] and status[d] = 1 (assigned, boxes in
   plain[d]) or 0 (no zero-violation assignment: the caller runs the dynamic programme with
   the candidates lo[d]..hi[d] (hi exclusive; lo = hi = -1: none)). Returns -1 when a centre
   or a box is not finite (nothing written that the caller reads), else 0. */
int64_t sanav_assign_discs(int64_t n1, int64_t nd, int64_t L, const double *pts, const double *both,
                           const int64_t *s_prev, double tol2, double reanchor2, int64_t *ss,
                           double *plain, uint8_t *status, int64_t *cand_lo, int64_t *cand_hi)
{
    for (int64_t i = 0; i < n1 * nd * 2; ++i)
        if (!isfinite(pts[i])) return -1;
    for (int64_t i = 0; i < 8 * L; ++i)
        if (!isfinite(both[i])) return -1;
    uint64_t stay[256], adv[256], reach[256];
    if (n1 > 256 || L > 62) return -1;
    for (int64_t d = 0; d < nd; ++d) {
        double dmin = INFINITY;
        int64_t lo = -1, hi = -1;
        if (s_prev != NULL) {
            int64_t anchor = s_prev[d * n1 + 1];
            lo = anchor - 2 > 0 ? anchor - 2 : 0;
            hi = anchor + 3 < L ? anchor + 3 : L;
        }
        for (int64_t k = 0; k < n1; ++k) {
            double px = pts[(k * nd + d) * 2], py = pts[(k * nd + d) * 2 + 1];
            uint64_t bs = 0, ba = 0;
            for (int64_t j = 0; j < 2 * L; ++j) {
                const double *b = both + 4 * j;
                double dx = max3(b[0] - px, px - b[2]);
                double dy = max3(b[1] - py, py - b[3]);
                double d2 = dx * dx + dy * dy;
                if (d2 < tol2) d2 = 0.0;
                if (d2 == 0.0) {
                    if (j < L) bs |= (uint64_t)1 << j; else ba |= (uint64_t)1 << (j - L);
                }
                if (k == 0 && j >= lo && j < hi && d2 < dmin) dmin = d2;
            }
            stay[k] = bs;
            adv[k] = ba;
        }
        cand_lo[d] = lo;
        cand_hi[d] = hi;
        /* feasible_from_bits */
        uint64_t r = stay[n1 - 1];
        reach[n1 - 1] = r;
        for (int64_t k = n1 - 2; k >= 0; --k) {
            r = (stay[k + 1] & r) | ((adv[k + 1] & r) >> 1);
            reach[k] = r;
        }
        uint64_t first = stay[0] & reach[0];
        if (lo >= 0 && dmin <= reanchor2) {
            uint64_t mask = (((uint64_t)1 << hi) - 1) ^ (((uint64_t)1 << lo) - 1);
            first &= mask;
        }
        if (first == 0) {
            status[d] = 0;
            continue;
        }
        status[d] = 1;
        int64_t j = 63 - __builtin_clzll(first);
        int64_t *s = ss + d * n1;
        s[0] = j;
        for (int64_t k = 1; k < n1; ++k) {
            if ((adv[k] >> (j + 1)) & (reach[k] >> (j + 1)) & 1) ++j;
            s[k] = j;
        }
        /* stage boxes: stay[s_k], advance[s_k] where the assignment advances */
        for (int64_t k = 0; k < n1; ++k) {
            const double *b = both + 4 * (s[k] + ((k > 0 && s[k] > s[k - 1]) ? L : 0));
            double *o = plain + (d * n1 + k) * 4;
            o[0] = b[0]; o[1] = b[1]; o[2] = b[2]; o[3] = b[3];
        }
    }
    return 0;
}

/* np.maximum / np.minimum of two finite doubles (NumPy's scalar loop: the first operand
   when it is not the smaller / larger one) */
static double npmax(double a, double b) { return a >= b ? a : b; }
static double npmin(double a, double b) { return a <= b ? a : b; }

/* sa_mpc._relax_all: plain (nd, n1, 4) stage boxes, pts0 (nd, 2) stage-0 centres; tighten 0
   (relax only) or 1 (shrink by delta when delta > 0, then relax; capped at plain unless
   follow). out (nd, n1, 4); *excursion the largest distance of a stage-0 centre beyond its
   plain stage-0 box (0 inside). Returns -1 (nothing read) when an input is not finite. */
int64_t sanav_relax_discs(int64_t nd, int64_t n1, const double *plain, const double *pts0, int64_t tighten,
                          double delta, int64_t follow, double *out, double *excursion)
{
    for (int64_t i = 0; i < nd * n1 * 4; ++i)
        if (!isfinite(plain[i])) return -1;
    for (int64_t i = 0; i < nd * 2; ++i)
        if (!isfinite(pts0[i])) return -1;
    if (tighten && !isfinite(delta)) return -1;
    double exc = 0.0;
    for (int64_t d = 0; d < nd; ++d) {
        const double *p = plain + d * n1 * 4;
        double *o = out + d * n1 * 4;
        double px = pts0[2 * d], py = pts0[2 * d + 1];
        double bx = npmax(p[0] - px, 0.0), by = npmax(p[1] - py, 0.0);
        double ax = npmax(px - p[2], 0.0), ay = npmax(py - p[3], 0.0);
        double e = hypot(bx + ax, by + ay);
        if (e > exc) exc = e;
        if (tighten && delta > 0.0) {
            for (int64_t k = 0; k < n1; ++k)
                for (int64_t a = 0; a < 2; ++a) {
                    double lo = p[4 * k + a], hi = p[4 * k + 2 + a];
                    double m = npmin(delta, 0.25 * npmax(hi - lo, 0.0));
                    o[4 * k + a] = lo + m;
                    o[4 * k + 2 + a] = hi - m;
                }
        } else {
            for (int64_t i = 0; i < n1 * 4; ++i) o[i] = p[i];
        }
        if (tighten) {
            bx = npmax(o[0] - px, 0.0); by = npmax(o[1] - py, 0.0);
            ax = npmax(px - o[2], 0.0); ay = npmax(py - o[3], 0.0);
        }
        if (bx != 0.0 || by != 0.0 || ax != 0.0 || ay != 0.0) {
            for (int64_t k = 1; k < n1; ++k) {
                o[4 * k] -= bx; o[4 * k + 1] -= by; o[4 * k + 2] += ax; o[4 * k + 3] += ay;
            }
        }
        if (tighten && !follow) {
            for (int64_t k = 1; k < n1; ++k) {
                o[4 * k] = npmax(o[4 * k], p[4 * k]);
                o[4 * k + 1] = npmax(o[4 * k + 1], p[4 * k + 1]);
                o[4 * k + 2] = npmin(o[4 * k + 2], p[4 * k + 2]);
                o[4 * k + 3] = npmin(o[4 * k + 3], p[4 * k + 3]);
            }
        }
    }
    *excursion = exc;
    return 0;
}
"""

_i64, _ptr = ctypes.c_int64, ctypes.c_void_p
_load = kernel_loader("disc_assign", _SOURCE, "the disc assignment kernel", NO_KERNEL_ENV, {
    "sanav_assign_discs": (_i64, [_i64, _i64, _i64, _ptr, _ptr, _ptr, ctypes.c_double, ctypes.c_double,
                                  _ptr, _ptr, _ptr, _ptr, _ptr]),
    "sanav_relax_discs": (_i64, [_i64, _i64, _ptr, _ptr, _i64, ctypes.c_double, _i64, _ptr, _ptr]),
})


def kernel_available() -> bool:
    """Whether the compiled assignment is in use (else the NumPy path)."""
    return _load() is not None


def assign_discs(both: np.ndarray, n_members: int, pts: np.ndarray, s_prev: np.ndarray | None, tol: float,
                 reanchor: float):
    """The zero-violation assignments of every disc along one chain, or None (kernel not
    available, more than 62 members, more than 256 stages, or a non-finite centre or box).

    Args:
        both: (2L, 4) [m] the chain's stay boxes then its advance boxes (C-contiguous float64).
        n_members: L.
        pts: (N+1, D, 2) [m] disc centres per stage.
        s_prev: (D, N+1) int previous assignments, or None (cold start: every member may
            take stage 0).
        tol: [m] distances below this count as zero.
        reanchor: [m] the candidates around ``s_prev[d, 1]`` restrict stage 0 only when one
            of them lies within this distance of the stage-0 centre.

    Returns:
        ``(ss, plain, ok, cand)``: assignments (D, N+1) int64, their stage boxes (D, N+1, 4)
        [m] (rows of discs with ``ok`` False unset), ``ok`` (D,) bool (False: no
        zero-violation assignment; the caller runs the dynamic programme) and per disc the
        candidate range ``(lo, hi)`` of stage 0 (``(-1, -1)``: None).
    """
    lib = _load()
    n1, nd = pts.shape[:2]
    if lib is None or n_members > 62 or n1 > 256:
        return None
    p = np.ascontiguousarray(pts, dtype=np.float64)
    b = np.ascontiguousarray(both, dtype=np.float64)
    sp = None if s_prev is None else np.ascontiguousarray(s_prev, dtype=np.int64)
    ss = np.empty((nd, n1), dtype=np.int64)
    plain = np.empty((nd, n1, 4))
    ok = np.empty(nd, dtype=np.uint8)
    lo = np.empty(nd, dtype=np.int64)
    hi = np.empty(nd, dtype=np.int64)
    rc = lib.sanav_assign_discs(n1, nd, n_members, p.ctypes.data, b.ctypes.data, None if sp is None else sp.ctypes.data,
                                tol * tol, reanchor**2, address(ss), address(plain), address(ok), address(lo),
                                address(hi))
    if rc != 0:
        return None
    return ss, plain, ok.view(bool), np.stack((lo, hi), axis=1)


def relax_discs(plain: np.ndarray, pts0: np.ndarray, tighten: tuple[float, bool] | None):
    """:func:`sanav_mj.control.sa_mpc._relax_all` in one C call: the stage boxes (D, N+1, 4)
    [m] of ``plain`` (D, N+1, 4) [m] relaxed around the stage-0 centres ``pts0`` (D, 2) [m]
    (shrunk by ``delta`` first and capped at ``plain`` unless ``follow``, for ``tighten =
    (delta, follow)``) and the largest stage-0 excursion [m]; None when the kernel is not
    available or an input is not finite (the NumPy path then runs).

    The same IEEE operations in the same order as the NumPy path (``np.maximum`` /
    ``np.minimum`` as NumPy's scalar loop takes them, ``hypot`` from the C library as
    ``np.hypot``); NumPy's vectorised max/min may return the other zero where both operands
    are zeros of opposite sign, so a box side at exactly 0 m could differ in the sign of
    its zero, which no comparison, sum with a non-zero or product with it tells apart.
    """
    lib = _load()
    if lib is None:
        return None
    p = np.ascontiguousarray(plain, dtype=np.float64)
    c = np.ascontiguousarray(pts0, dtype=np.float64)
    nd, n1 = p.shape[:2]
    out = np.empty((nd, n1, 4))
    exc = np.empty(1)
    delta, follow = (0.0, False) if tighten is None else tighten
    rc = lib.sanav_relax_discs(nd, n1, p.ctypes.data, c.ctypes.data, int(tighten is not None), float(delta),
                               int(bool(follow)), address(out), address(exc))
    return None if rc != 0 else (out, float(exc[0]))
