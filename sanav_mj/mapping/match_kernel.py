"""Compiled inner loop of the scan matcher (:mod:`sanav_mj.mapping.scan_match`).

One Gauss-Newton iteration of :meth:`ScanMatcher._refine` spends most of its time in some
twenty NumPy calls on arrays of about 120 points: the scan turned and moved to the pose,
the nearest map point of each return among the hit cells within reach of its cell
(:meth:`LikelihoodField.correspond`), the inlier test, the point-to-line residuals and the
Jacobian rows. This kernel does that element-wise part in one C call per iteration, with
the same floating-point operations in the same order as the NumPy code (compiled with
``-ffp-contract=off``, no fast-math, by :func:`sanav_mj.native.load_c_kernel`), so it gives
bit-identical results; the sums over points (``J^T J``, ``J^T r``) stay in NumPy.

The likelihood field's update per scan (:meth:`LikelihoodField.add_points`: the returns'
cells, the per-cell sums and counts in ``np.add.at`` order, the new hit cells, and the
spreading of new hit points over the cells around them) is compiled the same way
(:func:`accumulate`, :func:`spread`); the exponentials stay NumPy's, so the field is the
same bit for bit. So is the element-wise part of
:func:`~sanav_mj.mapping.scan_match.scan_points` (:func:`scan_surface`; the beam angles'
cosines and sines from NumPy, reused while a lidar's angles repeat).

Without a C compiler, when compiling fails, or with ``SANAV_MJ_NO_CKERNEL=1``, the NumPy
code of :mod:`~sanav_mj.mapping.scan_match` runs instead: it is the reference
(``tests/mapping/test_scan_match.py`` compares both on seeded random inputs).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.mapping.beam_kernel import NO_KERNEL_ENV, address, buffer_address
from sanav_mj.native import kernel_loader

__all__ = ["accumulate", "correspond", "kernel_available", "pair_rows", "scan_surface", "spread"]

_SOURCE = r"""
#include <math.h>
#include <stdint.h>

/* floor(v) as int64 the way NumPy's astype(int64) gives it on x86 (INT64_MIN when out of range). */
static int64_t to_i64(double v)
{
    double f = floor(v);
    if (!(f >= -9.2e18 && f <= 9.2e18)) return INT64_MIN;
    return (int64_t)f;
}

/* Nearest hit point of (x, y) among the cells koff[0..K) around its (clamped) cell: argmin
   with NumPy's rule (first minimum; a NaN is a minimum). */
static void nearest(double x, double y, const double *px, const double *py, const int64_t *koff, int64_t K,
                    double ox, double oy, double h, int64_t pad, int64_t ny, int64_t nx,
                    double *qx, double *qy, double *best)
{
    int64_t r = pad - 2;
    int64_t j = to_i64((x - ox) / h);
    int64_t i = to_i64((y - oy) / h);
    if (j != INT64_MIN) j += pad;
    if (i != INT64_MIN) i += pad;
    if (j < r) j = r;
    if (j > nx - 1 - r) j = nx - 1 - r;
    if (i < r) i = r;
    if (i > ny - 1 - r) i = ny - 1 - r;
    int64_t c = i * nx + j;
    double bd = 0.0;
    int64_t bk = 0;
    for (int64_t k = 0; k < K; ++k) {
        int64_t idx = c + koff[k];
        double dx = x - px[idx];
        double dy = y - py[idx];
        double d2 = dx * dx + dy * dy;
        if (k == 0) { bd = d2; bk = idx; continue; }
        if (isnan(bd)) continue;
        if (isnan(d2) || d2 < bd) { bd = d2; bk = idx; }
    }
    *best = bd;
    if (isfinite(bd)) { *qx = px[bk]; *qy = py[bk]; }
    else { *qx = x; *qy = y; }
}

void sanav_correspond(int64_t P, const double *pts, const double *px, const double *py, const int64_t *koff,
                      int64_t K, double ox, double oy, double h, int64_t pad, int64_t ny, int64_t nx,
                      double *q, double *d2)
{
    for (int64_t p = 0; p < P; ++p)
        nearest(pts[2 * p], pts[2 * p + 1], px, py, koff, K, ox, oy, h, pad, ny, nx, &q[2 * p], &q[2 * p + 1],
                &d2[p]);
}

/* One Gauss-Newton iteration's rows: returns the number of inliers m; J (m, 3) and res (m,)
   hold their rows in point order, inl (P,) the inlier flags. */
int64_t sanav_pair_rows(int64_t P, const double *s, const double *nrm, double x0, double x1, double cth,
                        double sth, double max2, const double *px, const double *py, const int64_t *koff,
                        int64_t K, double ox, double oy, double h, int64_t pad, int64_t ny, int64_t nx,
                        double *J, double *res, uint8_t *inl)
{
    int64_t m = 0;
    for (int64_t p = 0; p < P; ++p) {
        double s0 = s[2 * p], s1 = s[2 * p + 1];
        double rx = cth * s0 - sth * s1;
        double ry = sth * s0 + cth * s1;
        double wx = rx + x0, wy = ry + x1;
        double qx, qy, d2;
        nearest(wx, wy, px, py, koff, K, ox, oy, h, pad, ny, nx, &qx, &qy, &d2);
        int in = d2 <= max2;
        inl[p] = (uint8_t)in;
        if (!in) continue;
        double n0 = nrm[2 * p], n1 = nrm[2 * p + 1];
        double nxw = cth * n0 - sth * n1;
        double nyw = sth * n0 + cth * n1;
        res[m] = nxw * (wx - qx) + nyw * (wy - qy);
        J[3 * m] = nxw;
        J[3 * m + 1] = nyw;
        J[3 * m + 2] = (-nxw) * ry + nyw * rx;
        ++m;
    }
    return m;
}

/* LikelihoodField.add_points up to its new cells: the cell of each point, for those inside
   the grid the sums and count of its returns (np.add.at: in point order), the hit point of
   every touched cell (sum / count), and the cells hit for the first time, marked hit and
   written to new_cells in order of first appearance; returns how many. flat: scratch, P. */
int64_t sanav_field_accumulate(int64_t P, const double *pts, double ox, double oy, double h, int64_t ny,
                               int64_t nx, int64_t pad, int64_t pw, double *sx, double *sy, int64_t *n,
                               double *px, double *py, uint8_t *hit, int64_t *flat, int64_t *new_cells)
{
    int64_t m = 0;
    for (int64_t p = 0; p < P; ++p) {
        double x = pts[2 * p], y = pts[2 * p + 1];
        int64_t j = to_i64((x - ox) / h);
        int64_t i = to_i64((y - oy) / h);
        if (!(i >= 0 && i < ny && j >= 0 && j < nx)) continue;
        int64_t f = (i + pad) * pw + (j + pad);
        flat[m++] = f;
        sx[f] += x;
        sy[f] += y;
        n[f] += 1;
    }
    for (int64_t k = 0; k < m; ++k) {
        int64_t f = flat[k];
        px[f] = sx[f] / (double)n[f];
        py[f] = sy[f] / (double)n[f];
    }
    int64_t c = 0;
    for (int64_t k = 0; k < m; ++k) {
        int64_t f = flat[k];
        if (!hit[f]) { hit[f] = 1; new_cells[c++] = f; }
    }
    return c;
}

/* LikelihoodField.add_points, the spreading of the new hit points: for each new cell (in
   order) and each kernel offset (in order), the padded index of the cell around it and the
   squared distance of that cell's centre from the new hit point. */
void sanav_field_around(int64_t K, const int64_t *new_cells, int64_t R, const int64_t *ki, const int64_t *kj,
                        double ox, double oy, double h, int64_t pad, int64_t pw, const double *px,
                        const double *py, int64_t *idx, double *d2)
{
    for (int64_t k = 0; k < K; ++k) {
        int64_t f = new_cells[k];
        int64_t i = f / pw, j = f % pw;
        double qx = px[f], qy = py[f];
        for (int64_t r = 0; r < R; ++r) {
            int64_t ci = i + ki[r], cj = j + kj[r];
            double cx = ox + ((double)(cj - pad) + 0.5) * h;
            double cy = oy + ((double)(ci - pad) + 0.5) * h;
            double dx = cx - qx, dy = cy - qy;
            idx[k * R + r] = ci * pw + cj;
            d2[k * R + r] = dx * dx + dy * dy;
        }
    }
}

/* S[idx[m]] += w[m] in order (np.add.at); the distinct indices, in order of first
   appearance, to uniq (mark: a zeroed scratch byte per cell, left zeroed); returns how many. */
int64_t sanav_field_add(int64_t M, const int64_t *idx, const double *w, double *S, uint8_t *mark, int64_t *uniq)
{
    int64_t u = 0;
    for (int64_t m = 0; m < M; ++m) {
        int64_t c = idx[m];
        S[c] += w[m];
        if (!mark[c]) { mark[c] = 1; uniq[u++] = c; }
    }
    for (int64_t k = 0; k < u; ++k) mark[uniq[k]] = 0;
    return u;
}

/* scan_points up to the pick: the returns in the base frame (px, py, B each) and the returns
   with a surface normal (beam index, chord tx, ty and its length, to out_*); returns how many. */
int64_t sanav_scan_surface(int64_t B, const double *r, const double *a, const uint8_t *hit, const double *ca,
                           const double *sa, double off0, double off1, int64_t k, double max_gap, double *px,
                           double *py, int64_t *out_idx, double *out_tx, double *out_ty, double *out_len)
{
    for (int64_t b = 0; b < B; ++b) {
        int good = hit[b] && isfinite(r[b]) && isfinite(a[b]);
        double rr = good ? r[b] : 0.0;
        px[b] = off0 + rr * ca[b];
        py[b] = off1 + rr * sa[b];
    }
    int64_t m = 0;
    for (int64_t i = k; i < B - k; ++i) {
        int g0 = hit[i] && isfinite(r[i]) && isfinite(a[i]);
        int gp = hit[i + k] && isfinite(r[i + k]) && isfinite(a[i + k]);
        int gm = hit[i - k] && isfinite(r[i - k]) && isfinite(a[i - k]);
        double tx = px[i + k] - px[i - k];
        double ty = py[i + k] - py[i - k];
        double len = hypot(tx, ty);
        double limit = max_gap + 3.0 * (g0 ? r[i] : 0.0) * fabs(a[i + k] - a[i - k]);
        if (g0 && gp && gm && len <= limit && len > 0) {
            out_idx[m] = i; out_tx[m] = tx; out_ty[m] = ty; out_len[m] = len;
            ++m;
        }
    }
    return m;
}
"""

_i64, _dbl, _ptr = ctypes.c_int64, ctypes.c_double, ctypes.c_void_p
#: the compiled kernel (on first use, into the shared cache), or None: no compiler, a failed
#: compile, an unwritable cache or ``SANAV_MJ_NO_CKERNEL=1``
_load = kernel_loader("match", _SOURCE, "the scan-match kernel", NO_KERNEL_ENV, {
    "sanav_correspond": (None, [_i64] + [_ptr] * 4 + [_i64, _dbl, _dbl, _dbl, _i64, _i64, _i64, _ptr, _ptr]),
    "sanav_pair_rows": (_i64, [_i64, _ptr, _ptr] + [_dbl] * 5 + [_ptr] * 3
                        + [_i64, _dbl, _dbl, _dbl, _i64, _i64, _i64, _ptr, _ptr, _ptr]),
    "sanav_field_accumulate": (_i64, [_i64, _ptr, _dbl, _dbl, _dbl, _i64, _i64, _i64, _i64] + [_ptr] * 8),
    "sanav_field_around": (None, [_i64, _ptr, _i64, _ptr, _ptr, _dbl, _dbl, _dbl, _i64, _i64, _ptr, _ptr, _ptr, _ptr]),
    "sanav_field_add": (_i64, [_i64, _ptr, _ptr, _ptr, _ptr, _ptr]),
    "sanav_scan_surface": (_i64, [_i64] + [_ptr] * 5 + [_dbl, _dbl, _i64, _dbl] + [_ptr] * 6),
})


def kernel_available() -> bool:
    """Whether the compiled matcher loop is in use (else the NumPy reference)."""
    return _load() is not None


def _field_args(field) -> tuple:
    ny, nx = field.values.shape
    return (buffer_address(field._px), buffer_address(field._py), buffer_address(field._koff), len(field._koff),
            float(field.origin[0]), float(field.origin[1]), field.resolution, field.pad, ny, nx)


def correspond(field, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """:meth:`LikelihoodField.correspond` compiled (same results, bit for bit), or None when
    the kernel is not available.

    Args:
        field: the :class:`~sanav_mj.mapping.scan_match.LikelihoodField`.
        pts: (P, 2) [m] query points.

    Returns:
        q (P, 2) [m] nearest hit points (the query point where none is in reach) and d2 (P,)
        [m^2] squared distances (inf where none), or None.
    """
    lib = _load()
    if lib is None:
        return None
    p = np.ascontiguousarray(pts, dtype=np.float64)
    P = len(p)
    q = np.empty((P, 2))
    d2 = np.empty(P)
    if P:
        lib.sanav_correspond(P, address(p), *_field_args(field), address(q), address(d2))
    return q, d2


def pair_rows(field, s: np.ndarray, normals: np.ndarray, x0: float, x1: float, cth: float, sth: float,
              max2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The element-wise part of one Gauss-Newton iteration of
    :meth:`~sanav_mj.mapping.scan_match.ScanMatcher._refine` (scan at the pose, pairs, inliers,
    residuals, Jacobian rows), or None when the kernel is not available.

    Args:
        field: the likelihood field; s, normals: (P, 2) C-contiguous float64 return points
            and normals in the base frame [m]; x0, x1 [m] the pose's position; cth, sth:
            cosine and sine of its yaw; max2 [m^2]: the squared pairing distance.

    Returns:
        J (m, 3) Jacobian rows and res (m,) [m] residuals of the m inliers in point order,
        inl (P,) bool inlier flags.
    """
    lib = _load()
    if lib is None:
        return None
    P = len(s)
    J = np.empty((P, 3))
    res = np.empty(P)
    inl = np.empty(P, dtype=bool)
    m = lib.sanav_pair_rows(P, address(s), address(normals), x0, x1, cth, sth, max2, *_field_args(field),
                            address(J), address(res), address(inl)) if P else 0
    return J[:m], res[:m], inl


def accumulate(field, pts: np.ndarray) -> np.ndarray | None:
    """The first part of :meth:`LikelihoodField.add_points
    <sanav_mj.mapping.scan_match.LikelihoodField.add_points>` compiled (the same arithmetic in
    the same order, so the same sums, counts and hit points bit for bit), or None when the
    kernel is not available: each point's cell, the sums and count of the returns in every
    cell inside the grid (in point order, as ``np.add.at``), the hit point of every touched
    cell, and the cells hit for the first time, marked hit.

    Args:
        field: the :class:`~sanav_mj.mapping.scan_match.LikelihoodField` (updated in place).
        pts: (P, 2) [m] world positions of returns.

    Returns:
        (K,) int64 padded flat indices of the new hit cells, sorted ascending (as the NumPy
        code's ``np.unique``), or None.
    """
    lib = _load()
    if lib is None:
        return None
    p = np.ascontiguousarray(pts, dtype=np.float64)
    P = len(p)
    if not P:
        return np.zeros(0, np.int64)
    ny, nx = field.shape
    flat = np.empty(P, dtype=np.int64)
    new = np.empty(P, dtype=np.int64)
    k = lib.sanav_field_accumulate(P, address(p), float(field.origin[0]), float(field.origin[1]), field.resolution,
                                   ny, nx, field.pad, field._pw, buffer_address(field._sx),
                                   buffer_address(field._sy), buffer_address(field._n), buffer_address(field._px),
                                   buffer_address(field._py), buffer_address(field._hit), address(flat), address(new))
    return np.sort(new[:k])


def spread(field, new: np.ndarray) -> bool:
    """The spreading of :meth:`LikelihoodField.add_points
    <sanav_mj.mapping.scan_match.LikelihoodField.add_points>` compiled around NumPy's ``exp``
    (the cells around each new hit cell and their squared distances, then ``S += exp(-d2 /
    (2 sigma^2))`` in the same order as ``np.add.at`` and ``values = 1 - exp(-S)`` on the
    touched cells; the exponentials stay NumPy's, so the field is the same bit for bit);
    False when the kernel is not available (nothing done).

    Args:
        field: the likelihood field (updated in place); new: (K,) int64 padded flat indices
            of the new hit cells, sorted ascending.
    """
    lib = _load()
    if lib is None:
        return False
    new = np.ascontiguousarray(new, dtype=np.int64)
    ki, kj = field._kij
    K, R = len(new), len(ki)
    idx = np.empty(K * R, dtype=np.int64)
    d2 = np.empty(K * R)
    lib.sanav_field_around(K, address(new), R, buffer_address(ki), buffer_address(kj), float(field.origin[0]),
                           float(field.origin[1]), field.resolution, field.pad, field._pw,
                           buffer_address(field._px), buffer_address(field._py), address(idx), address(d2))
    w = np.exp(-d2 * field._inv2s2)
    uniq = np.empty(K * R, dtype=np.int64)
    u = lib.sanav_field_add(K * R, address(idx), address(w), buffer_address(field._S), buffer_address(field._mark),
                            address(uniq))
    u = uniq[:u]
    field.values.reshape(-1)[u] = 1.0 - np.exp(-field._S[u])
    return True


#: (angles, cos, sin) of the last scan: a lidar's beam angles are the same every scan
_last_trig: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


def _trig(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """NumPy's cosines and sines of the angles ``a`` (B,), reused while the angles are the
    same values as the last call's (the same inputs give the same results)."""
    global _last_trig
    last = _last_trig
    if last is not None and last[0].shape == a.shape and np.array_equal(last[0], a):
        return last[1], last[2]
    ca, sa = np.cos(a), np.sin(a)
    _last_trig = (a.copy(), ca, sa)
    return ca, sa


def scan_surface(r: np.ndarray, a: np.ndarray, hit: np.ndarray, off: np.ndarray, k: int, max_gap: float
                 ) -> tuple | None:
    """The element-wise part of :func:`~sanav_mj.mapping.scan_match.scan_points` compiled
    (cosines and sines of the beam angles from NumPy, the rest with the same operations in
    the same order, ``hypot`` from the C library as NumPy's), or None when the kernel is not
    available.

    Args:
        r, a: (B,) float64 ranges [m] and beam angles [rad]; hit: (B,) bool; off: (2,) [m]
            sensor offset; k: stencil half width [beams]; max_gap [m].

    Returns:
        px, py (B,) [m] the returns in the base frame (0 range where not a good return);
        idx (M,) int64 the beams with a surface normal, tx, ty (M,) [m] their chords and
        length (M,) [m] the chords' lengths.
    """
    lib = _load()
    if lib is None:
        return None
    r = np.ascontiguousarray(r, dtype=np.float64)
    a = np.ascontiguousarray(a, dtype=np.float64)
    h = np.ascontiguousarray(hit, dtype=bool)
    B = len(r)
    ca, sa = _trig(a)
    px, py = np.empty(B), np.empty(B)
    m = max(B - 2 * k, 0)
    idx = np.empty(m, dtype=np.int64)
    tx, ty, ln = np.empty(m), np.empty(m), np.empty(m)
    n = lib.sanav_scan_surface(B, address(r), address(a), address(h), address(ca), address(sa), float(off[0]),
                               float(off[1]), int(k), float(max_gap), address(px), address(py), address(idx),
                               address(tx), address(ty), address(ln)) if B else 0
    return px, py, idx[:n], tx[:n], ty[:n], ln[:n]
