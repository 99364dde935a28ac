"""A compiled loop for the beam traversal of :mod:`sanav_mj.mapping.live_grid`, with a NumPy fallback.

:func:`free_cells` visits the cells each beam crosses, exactly as
:func:`~sanav_mj.mapping.live_grid.crossed_cells` expands them (same per-segment parameters,
same floating-point operations per column: ``floor(base + k * inc)`` clamped to the
segment's minor-cell range, the last column ending at the end point's cell), and keeps each
cell once, marking it in the caller's scratch array. In C the cells already marked cost one
load; in NumPy every crossing is materialised first (cells near the sensor are crossed by
hundreds of beams of a scan).

The C source below is compiled once with the system C compiler into the solver-code cache
folder by :func:`sanav_mj.native.compile_cached` (``$SANAV_MJ_CACHE`` or
``~/.cache/sanav-mj``; the file name hashes the source, flags and processor) and loaded with
:mod:`ctypes`. The flags keep IEEE arithmetic as NumPy does it
(``-ffp-contract=off``: no fused multiply-add, so ``base + k * inc`` rounds twice, as in
NumPy; no ``-march=native``, no fast-math). Without a compiler, when compiling fails, or with
``SANAV_MJ_NO_CKERNEL=1`` in the environment, the NumPy path is used; both return the same
cells (tested).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.native import NO_KERNEL_ENV, kernel_loader


_SOURCE = r"""
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

/* floor(x) without a libm call (no SSE4.1 rounding instruction at the portable flags): the
   same value for every finite |x| < 2^62 (a -0.0 result compares and converts as 0.0). */
static inline double floor_exact(double x)
{
    if (!(fabs(x) < 4.0e18)) return floor(x);  /* huge, infinite or NaN: the library's */
    const double t = (double)(int64_t)x;  /* rounds toward zero: exact below 2^62 */
    return t > x ? t - 1.0 : t;
}

/* Cells crossed by B segments in major/minor form (see sanav_mj/mapping/beam_kernel.py).
   Column k of segment b (k = 0 .. n[b]-1) holds the cells of its entry and exit minor
   coordinates; exit = floor(base + k * inc) clamped to [lo, hi], the last exit = fb1, the
   first entry = fb0. Flat cell = major0 + k * major_step + minor * minor_stride. Each cell
   not yet marked is marked 1 and appended to out; returns the number appended, or -1 when
   a cell falls outside [0, size) (a caller's error: segments must be clipped to the grid).
   With skip_lo (else NULL), cells whose skip_lo value equals skip_at are neither marked nor
   appended (LiveGrid: free cells saturated at l_min, which one more crossing leaves as they are). */
int64_t sanav_free_cells(int64_t B, const double *base, const double *inc, const double *lo,
                         const double *hi, const double *fb0, const double *fb1, const int64_t *n,
                         const int64_t *major0, const int64_t *major_step,
                         const int64_t *minor_stride, int64_t size, int8_t *mark, int64_t *out,
                         const float *skip_lo, float skip_at)
{
    int64_t m = 0;
    for (int64_t b = 0; b < B; ++b) {
        double entry = fb0[b];
        const int64_t nb = n[b];
        for (int64_t k = 0; k < nb; ++k) {
            double ex;
            if (k == nb - 1) {
                ex = fb1[b];
            } else {
                double t = (double)k * inc[b];
                ex = floor_exact(base[b] + t);
                if (ex < lo[b]) ex = lo[b];
                if (ex > hi[b]) ex = hi[b];
            }
            const int64_t major = major0[b] + k * major_step[b];
            int64_t c = major + (int64_t)entry * minor_stride[b];
            if (c < 0 || c >= size) return -1;
            if (!mark[c] && !(skip_lo && skip_lo[c] == skip_at)) { mark[c] = 1; out[m++] = c; }
            if (ex != entry) {
                c = major + (int64_t)ex * minor_stride[b];
                if (c < 0 || c >= size) return -1;
                if (!mark[c] && !(skip_lo && skip_lo[c] == skip_at)) { mark[c] = 1; out[m++] = c; }
            }
            entry = ex;
        }
    }
    return m;
}

/* Liang-Barsky on one axis, as segment_columns: p the segment's extent, q its start, the
   slab [eps, hi]; narrows [t0, t1]. */
static void clip_axis(double p, double q, double hi, double *t0, double *t1)
{
    const double eps = 1e-9;
    const double ta = (eps - q) / p, tb = (hi - q) / p;
    const int inside = q >= eps && q <= hi;
    const double lo_t = p > 0 ? ta : (p < 0 ? tb : (inside ? -INFINITY : INFINITY));
    const double hi_t = p > 0 ? tb : (p < 0 ? ta : (inside ? INFINITY : -INFINITY));
    if (lo_t > *t0) *t0 = lo_t;
    if (hi_t < *t1) *t1 = hi_t;
}

/* segment_columns (sanav_mj/mapping/live_grid.py, the same operations in the same order,
   per segment) and sanav_free_cells in one call, for B beams from (u0, v0) to (u1[b], v1[b])
   [cells] on an ny x nx grid. Returns the number of cells appended to out, or -1. */
static int cmp_i64(const void *a, const void *b);

int64_t sanav_scan_cells(int64_t B, double u0, double v0, const double *u1, const double *v1, int64_t ny,
                         int64_t nx, int8_t *mark, int64_t *out, const float *skip_lo, float skip_at,
                         const uint8_t *hit)
{
    const double eps = 1e-9;
    const int64_t size = ny * nx;
    int64_t m = 0;
    for (int64_t b = 0; b < B; ++b) {
        const double du = u1[b] - u0, dv = v1[b] - v0;
        double t0 = 0.0, t1 = 1.0;
        clip_axis(du, u0, (double)nx - eps, &t0, &t1);
        clip_axis(dv, v0, (double)ny - eps, &t0, &t1);
        if (!(t1 >= t0)) continue;
        const double cu0 = u0 + t0 * du, cv0 = v0 + t0 * dv, cu1 = u0 + t1 * du, cv1 = v0 + t1 * dv;
        const int xmajor = fabs(du) >= fabs(dv);
        const double a0 = xmajor ? cu0 : cv0, b0 = xmajor ? cv0 : cu0;
        const double a1 = xmajor ? cu1 : cv1, b1 = xmajor ? cv1 : cu1;
        const double c0 = floor(a0), c1 = floor(a1);
        const double step = c1 >= c0 ? 1.0 : -1.0;
        const int64_t n = (int64_t)(fabs(c1 - c0) + 1.0);
        const double da = a1 - a0;
        const double slope = da != 0 ? (b1 - b0) / da : 0.0;
        const double base = b0 + ((c0 + (step > 0 ? 1.0 : 0.0)) - a0) * slope;
        const double major_stride = xmajor ? 1.0 : (double)nx;
        const int64_t minor_stride = xmajor ? nx : 1;
        const double fb0 = floor(b0), fb1 = floor(b1);
        const double inc = step * slope;
        const double lo = fb0 < fb1 ? fb0 : fb1, hi = fb0 > fb1 ? fb0 : fb1;
        const int64_t major0 = (int64_t)(c0 * major_stride), major_step = (int64_t)(step * major_stride);
        double entry = fb0;
        for (int64_t k = 0; k < n; ++k) {
            double ex;
            if (k == n - 1) {
                ex = fb1;
            } else {
                double t = (double)k * inc;
                ex = floor_exact(base + t);
                if (ex < lo) ex = lo;
                if (ex > hi) ex = hi;
            }
            const int64_t major = major0 + k * major_step;
            int64_t c = major + (int64_t)entry * minor_stride;
            if (c < 0 || c >= size) return -1;
            if (!mark[c] && !(skip_lo && skip_lo[c] == skip_at)) { mark[c] = 1; out[m++] = c; }
            if (ex != entry) {
                c = major + (int64_t)ex * minor_stride;
                if (c < 0 || c >= size) return -1;
                if (!mark[c] && !(skip_lo && skip_lo[c] == skip_at)) { mark[c] = 1; out[m++] = c; }
            }
            entry = ex;
        }
    }
    if (hit) {  /* the cells of the returns: marked 2; those no beam crossed appended, sorted */
        const int64_t m0 = m;
        for (int64_t b = 0; b < B; ++b) {
            if (!hit[b]) continue;
            const int64_t ei = (int64_t)floor(v1[b]), ej = (int64_t)floor(u1[b]);
            if (ei < 0 || ei >= ny || ej < 0 || ej >= nx) continue;
            const int64_t c = ei * nx + ej;
            if (mark[c] == 0) out[m++] = c;
            mark[c] = 2;
        }
        qsort(out + m0, (size_t)(m - m0), sizeof(int64_t), cmp_i64);
    }
    return m;
}

/* Add d[i] (+-1) to the counts pad[] at every kernel offset around cells[i] (grid flat
   indices, nx columns; pad is the grid padded by r cells on every side, pw columns).
   Writes to out the grid flat indices, sorted, whose count went from zero to non-zero or
   back over the whole call (a cell that leaves zero and comes back is not listed); returns
   their number. seen (padded size, all 0) and list (padded size) are scratch; seen is left
   all 0. */
static int cmp_i64(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* As spread below, for many cells: over the cells' bounding window grown by r at once, the
   kernel as row runs (rows[2q] = row offset, rows[2q+1] = half width), each run a +d / -d
   pair in a per-row difference array, then one prefix sum per window row. Returns -1 when
   the work buffer cannot be allocated (the caller then spreads cell by cell). */
static int64_t spread_dense(int64_t n, const int64_t *cells, const int8_t *d, int64_t ny, int64_t nx, int64_t r,
                            int64_t pw, int64_t nrows, const int64_t *rows, int32_t *pad, int64_t *out,
                            int64_t h0, int64_t h1, int64_t w0, int64_t w1)
{
    const int64_t hh = h1 - h0 + 2 * r, ww = w1 - w0 + 2 * r;  /* padded rows h0 .. h0+hh, cols w0 .. w0+ww */
    int32_t *diff = calloc((size_t)(hh * (ww + 1)), sizeof(int32_t));
    if (!diff) return -1;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t ci = cells[i] / nx - h0 + r, cj = cells[i] % nx - w0 + r;  /* window coordinates */
        for (int64_t q = 0; q < nrows; ++q) {
            int32_t *row = diff + (ci + rows[2 * q]) * (ww + 1);
            row[cj - rows[2 * q + 1]] += d[i];
            row[cj + rows[2 * q + 1] + 1] -= d[i];
        }
    }
    int64_t m = 0;
    for (int64_t a = 0; a < hh; ++a) {
        int32_t acc = 0;
        const int32_t *row = diff + a * (ww + 1);
        int32_t *p = pad + (h0 + a) * pw + w0;
        for (int64_t b = 0; b < ww; ++b) {
            acc += row[b];
            if (!acc) continue;
            const int32_t before = p[b];
            p[b] = before + acc;
            if ((before == 0) != (p[b] == 0)) {
                const int64_t pr = h0 + a - r, pc = w0 + b - r;
                if (pr >= 0 && pr < ny && pc >= 0 && pc < nx) out[m++] = pr * nx + pc;
            }
        }
    }
    free(diff);
    return m;
}

static int64_t spread(int64_t n, const int64_t *cells, const int8_t *d, int64_t ny, int64_t nx, int64_t r,
                      int64_t pw, int64_t K, const int64_t *koff, int32_t *pad, int8_t *seen, int64_t *list,
                      int64_t *out, int64_t nrows, const int64_t *rows)
{
    if (n > 0) {
        int64_t h0 = ny, h1 = 0, w0 = nx, w1 = 0;
        for (int64_t i = 0; i < n; ++i) {
            const int64_t ci = cells[i] / nx, cj = cells[i] % nx;
            if (ci < h0) h0 = ci;
            if (ci + 1 > h1) h1 = ci + 1;
            if (cj < w0) w0 = cj;
            if (cj + 1 > w1) w1 = cj + 1;
        }
        const int64_t area = (h1 - h0 + 2 * r) * (w1 - w0 + 2 * r);
        if (n * K > 2 * (nrows * n + area)) {
            const int64_t m = spread_dense(n, cells, d, ny, nx, r, pw, nrows, rows, pad, out, h0, h1, w0, w1);
            if (m >= 0) return m;
        }
    }
    int64_t L = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t centre = (cells[i] / nx + r) * pw + cells[i] % nx + r;
        const int32_t di = d[i];
        for (int64_t k = 0; k < K; ++k) {
            const int64_t idx = centre + koff[k];
            if (!seen[idx]) { seen[idx] = (int8_t)(1 + (pad[idx] == 0)); list[L++] = idx; }
            pad[idx] += di;
        }
    }
    int64_t m = 0;
    for (int64_t l = 0; l < L; ++l) {
        const int64_t idx = list[l];
        const int was_zero = seen[idx] == 2;
        seen[idx] = 0;
        if (was_zero != (pad[idx] == 0)) {
            const int64_t pr = idx / pw - r, pc = idx % pw - r;
            if (pr >= 0 && pr < ny && pc >= 0 && pc < nx) out[m++] = pr * nx + pc;
        }
    }
    qsort(out, (size_t)m, sizeof(int64_t), cmp_i64);
    return m;
}

/* The log-odds update of the T distinct touched cells (grid flat indices) and the counts
   kept around them, as LiveGrid._commit does it in NumPy (float32 arithmetic throughout):
   new = clamp(old + delta[mark], l_min, l_max), the hit floor raised to hit_floor where
   mark == 2 and applied (max), mark reset to 0; states (L <= free_thresh: free,
   L >= occ_thresh: occupied); the count of non-free cells spread where the free state
   flipped, the count of route-blocking cells (occupied, or ever hit) where that flipped.
   par = {l_free, l_occ, l_min, l_max, free_thresh, occ_thresh, hit_floor, floor_at} (float32): a
   return raises the floor only where the clamped new value is >= floor_at (-inf: every return).
   The route counts use their own kernel (K2, koff2, nrows2, rows2: within radius r as well).
   Outputs: state_out (cells whose state changed, in touched order), safe_out / route_out
   (sorted grid cells whose count crossed zero); n_out = {states, safe, route}.
   Scratch: cells_tmp (T), d_tmp (T), seen and list (padded size). */
void sanav_commit(int64_t T, const int64_t *touched, int8_t *mark, float *lo, float *floor_, const float *par,
                  int64_t has_floor, int64_t ny, int64_t nx, int64_t r, int64_t pw, int64_t K, const int64_t *koff,
                  int32_t *pad, int32_t *route, int64_t *state_out, int64_t *safe_out, int64_t *route_out,
                  int64_t *n_out, int64_t *cells_tmp, int8_t *d_tmp, int8_t *seen, int64_t *list, int64_t nrows,
                  const int64_t *rows, int64_t K2, const int64_t *koff2, int64_t nrows2, const int64_t *rows2)
{
    const float delta[3] = {0.0f, par[0], par[1]};
    const float l_min = par[2], l_max = par[3], ft = par[4], ot = par[5], hf = par[6], fa = par[7];
    int64_t ns = 0, nr = 0;
    for (int64_t t = 0; t < T; ++t) {
        const int64_t c = touched[t];
        const int m = mark[c];
        const float old = lo[c];
        float v = old + delta[m];
        if (v < l_min) v = l_min;
        if (v > l_max) v = l_max;
        int hit_old = 0, hit_new = 0;
        if (has_floor) {
            float f = floor_[c];
            hit_old = f == hf;
            if (m == 2 && v >= fa) { f = hf; floor_[c] = hf; }
            hit_new = f == hf;
            if (v < f) v = f;
        }
        mark[c] = 0;
        lo[c] = v;
        const int s_old = (old <= ft) + 2 * (old >= ot);
        const int s_new = (v <= ft) + 2 * (v >= ot);
        if (s_old != s_new) {
            state_out[ns] = c;
            const int free_old = s_old == 1, free_new = s_new == 1;
            if (free_old != free_new) { cells_tmp[ns] = c; d_tmp[ns] = (int8_t)(free_new ? -1 : 1); }
            else cells_tmp[ns] = -1;
            ++ns;
        }
        const int rb_old = s_old == 2 || hit_old, rb_new = s_new == 2 || hit_new;
        if (rb_old != rb_new) { route_out[nr] = c; d_tmp[T + nr] = (int8_t)(rb_new ? 1 : -1); ++nr; }
    }
    /* compact the free flips (in state order) into the front of cells_tmp / d_tmp */
    int64_t nf = 0;
    for (int64_t i = 0; i < ns; ++i)
        if (cells_tmp[i] >= 0) { cells_tmp[nf] = cells_tmp[i]; d_tmp[nf] = d_tmp[i]; ++nf; }
    n_out[0] = ns;
    n_out[1] = spread(nf, cells_tmp, d_tmp, ny, nx, r, pw, K, koff, pad, seen, list, safe_out, nrows, rows);
    /* the route cells go through cells_tmp as well (safe_out is done with it) */
    for (int64_t i = 0; i < nr; ++i) { cells_tmp[i] = route_out[i]; d_tmp[i] = d_tmp[T + i]; }
    n_out[2] = spread(nr, cells_tmp, d_tmp, ny, nx, r, pw, K2, koff2, route, seen, list, route_out, nrows2,
                      rows2);
}
"""

#: the compiled kernel (compiled on first use into the shared cache, see
#: :func:`sanav_mj.native.compile_cached`), or None: no compiler, a failed compile, an
#: unwritable cache or ``SANAV_MJ_NO_CKERNEL=1``
_load = kernel_loader("beams", _SOURCE, "the beam traversal kernel", NO_KERNEL_ENV, {
    "sanav_free_cells": (ctypes.c_int64, [ctypes.c_int64] + [ctypes.c_void_p] * 10 + [ctypes.c_int64]
                         + [ctypes.c_void_p] * 3 + [ctypes.c_float]),
    "sanav_scan_cells": (ctypes.c_int64, [ctypes.c_int64, ctypes.c_double, ctypes.c_double] + [ctypes.c_void_p] * 2
                         + [ctypes.c_int64] * 2 + [ctypes.c_void_p] * 3 + [ctypes.c_float, ctypes.c_void_p]),
    "sanav_commit": (None, [ctypes.c_int64] + [ctypes.c_void_p] * 5 + [ctypes.c_int64] * 6 + [ctypes.c_void_p] * 11
                     + [ctypes.c_int64, ctypes.c_void_p] * 3),
})


_addresses: dict[int, tuple[np.ndarray, int]] = {}


def address(a: np.ndarray) -> int:
    """The data address of a C-contiguous array for a C call: through a ctypes view of its
    buffer (about 0.3 us; ``a.ctypes.data``, about 1 us, for read-only or empty arrays)."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(a))
    except (TypeError, ValueError, BufferError):
        return a.ctypes.data


def buffer_address(a: np.ndarray) -> int:
    """The data address of a long-lived array (a grid's buffers, kept between scans), cached:
    ``a.ctypes.data`` costs about 1-2 us a call, and a scan passes some 40 buffers to C. The
    cache keeps the array alive (so its id is not reused while cached); it is emptied when
    it holds 512 arrays. Not for short-lived arrays: they would be kept alive until then."""
    hit = _addresses.get(id(a))
    if hit is not None and hit[0] is a:
        return hit[1]
    if len(_addresses) >= 512:
        _addresses.clear()
    addr = address(a)
    _addresses[id(a)] = (a, addr)
    return addr


def kernel_available() -> bool:
    """Whether the compiled traversal is in use (else the NumPy fallback)."""
    return _load() is not None


def free_cells(seg: dict, mark: np.ndarray, stamp: np.ndarray | None = None, use_kernel: bool = True,
               skip: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """Flat indices of the cells the segments cross, each once; marks them 1 in ``mark``.

    Args:
        seg: per-segment parameters from
            :func:`~sanav_mj.mapping.live_grid.segment_columns` (float64 ``base``, ``inc``,
            ``lo``, ``hi``, ``fb0``, ``fb1``; int64 ``n``, ``major0``, ``major_step``,
            ``minor_stride``), all (B,).
        mark: (ny * nx,) int8 scratch, 0 on every cell the segments cross (set to 1 there;
            cells already non-zero are skipped, so they must not be crossed cells).
        stamp: (ny * nx,) int64 scratch of the NumPy path (allocated when None).
        use_kernel: False forces the NumPy path (tests).
        skip: ``(values, at)``: (ny * nx,) float32 per-cell values and a float32 value; cells
            whose value equals ``at`` are left out (neither returned nor marked). None: none.

    Returns:
        (U,) int64 distinct flat indices (order: first visit in C, unspecified in NumPy).

    Raises:
        IndexError: a crossed cell lies outside ``mark`` (segments not clipped to the grid).
    """
    lib = _load() if use_kernel else None
    n = seg["n"]
    B = len(n)
    if lib is not None:
        out = np.empty(int(2 * n.sum()), dtype=np.int64)
        arrs = [np.ascontiguousarray(seg[k], dtype=np.float64) for k in ("base", "inc", "lo", "hi", "fb0", "fb1")]
        ints = [np.ascontiguousarray(seg[k], dtype=np.int64) for k in ("n", "major0", "major_step", "minor_stride")]
        if not (mark.dtype == np.int8 and mark.flags.c_contiguous):
            raise ValueError(f"mark must be a contiguous int8 array, got {mark.dtype}")
        if skip is not None and not (skip[0].dtype == np.float32 and skip[0].flags.c_contiguous
                                     and skip[0].size == mark.size):
            raise ValueError(f"skip values must be a contiguous float32 array of {mark.size} cells, got "
                             f"{skip[0].dtype} {skip[0].shape}")
        m = lib.sanav_free_cells(B, *(a.ctypes.data for a in arrs), *(a.ctypes.data for a in ints),
                                 mark.size, mark.ctypes.data, out.ctypes.data,
                                 None if skip is None else skip[0].ctypes.data,
                                 0.0 if skip is None else float(np.float32(skip[1])))
        if m < 0:
            raise IndexError(f"beam traversal left the grid of {mark.size} cells (segments must be clipped)")
        return out[:m]
    cells = expand_columns(seg)
    # each cell once: one occurrence per cell keeps the stamp it wrote, whichever write won
    pos = np.arange(len(cells), dtype=np.int64)
    stamp = np.empty(len(mark), dtype=np.int64) if stamp is None else stamp
    stamp[cells] = pos
    cells = cells[stamp[cells] == pos]
    if skip is not None:
        cells = cells[skip[0][cells] != np.float32(skip[1])]
    mark[cells] = 1
    return cells


def expand_columns(seg: dict) -> np.ndarray:
    """Every crossing of the segments, in NumPy (no deduplication).

    Args:
        seg: per-segment parameters from :func:`~sanav_mj.mapping.live_grid.segment_columns`.

    Returns:
        (M,) int64 flat cell indices, a cell once per segment crossing it.
    """
    n = seg["n"]
    start = np.cumsum(n) - n
    total = int(n.sum())
    k = np.arange(total, dtype=float) - np.repeat(start.astype(float), n)
    exit_ = np.floor(np.repeat(seg["base"], n) + k * np.repeat(seg["inc"], n))
    np.maximum(exit_, np.repeat(seg["lo"], n), out=exit_)  # clip (finite values)
    np.minimum(exit_, np.repeat(seg["hi"], n), out=exit_)
    exit_[start + n - 1] = seg["fb1"]
    entry = np.empty_like(exit_)
    entry[1:] = exit_[:-1]
    entry[start] = seg["fb0"]
    ms = np.repeat(seg["minor_stride"].astype(float), n)
    major = np.repeat(seg["major0"].astype(float), n) + k * np.repeat(seg["major_step"].astype(float), n)
    flat = major + entry * ms
    two = entry != exit_
    return np.concatenate([flat, major[two] + exit_[two] * ms[two]]).astype(np.int64)


def scan_free_cells(u0: float, v0: float, u1: np.ndarray, v1: np.ndarray, shape: tuple[int, int],
                    mark: np.ndarray, skip: tuple[np.ndarray, float] | None = None, out: np.ndarray | None = None,
                    hit: np.ndarray | None = None) -> np.ndarray | None:
    """:func:`free_cells` of :func:`~sanav_mj.mapping.live_grid.segment_columns` for beams
    from one point, in one compiled call (the clipping and set-up per beam in C, with the
    same operations); None without the kernel.

    Args:
        u0, v0: start of every beam [cells] (x = column, y = row).
        u1, v1: (B,) float64 beam ends [cells].
        shape: (ny, nx) grid shape.
        mark, skip: as :func:`free_cells`.
        out: (ny * nx,) int64 buffer for the result (each cell appears at most once), kept
            by the caller between scans; None: allocated.
        hit: (B,) bool, True where the beam returned: the cells of those end points
            (``floor`` of ``v1``, ``u1``, inside the grid) are then marked 2, and those no
            beam crossed (nor skipped) are appended to the result, sorted (as
            :meth:`LiveGrid.integrate <sanav_mj.mapping.live_grid.LiveGrid.integrate>` adds
            them in NumPy). None: no returns.

    Returns:
        (U,) int64 distinct flat indices (a view of ``out``): the crossed cells, marked 1 in
        ``mark``, then the return cells no beam crossed; or None.
    """
    lib = _load()
    if lib is None:
        return None
    ny, nx = shape
    u1 = np.ascontiguousarray(u1, dtype=np.float64)
    v1 = np.ascontiguousarray(v1, dtype=np.float64)
    if u1.shape != v1.shape or u1.ndim != 1:
        raise ValueError(f"u1, v1 must be (B,) arrays of one length, got {u1.shape}, {v1.shape}")
    if not (mark.dtype == np.int8 and mark.flags.c_contiguous and mark.size == ny * nx):
        raise ValueError(f"mark must be a contiguous int8 array of {ny * nx} cells, got {mark.dtype} {mark.shape}")
    if skip is not None and not (skip[0].dtype == np.float32 and skip[0].flags.c_contiguous
                                 and skip[0].size == mark.size):
        raise ValueError(f"skip values must be a contiguous float32 array of {mark.size} cells")
    if out is None:
        out = np.empty(ny * nx, dtype=np.int64)
    elif not (out.dtype == np.int64 and out.flags.c_contiguous and out.size >= ny * nx):
        raise ValueError(f"out must be a contiguous int64 array of >= {ny * nx} cells, got {out.dtype} {out.shape}")
    if hit is not None:
        hit = np.ascontiguousarray(hit, dtype=np.bool_)
        if hit.shape != u1.shape:
            raise ValueError(f"hit must be (B,) = {u1.shape} like u1, got {hit.shape}")
    m = lib.sanav_scan_cells(len(u1), float(u0), float(v0), address(u1), address(v1), ny, nx,
                             buffer_address(mark), buffer_address(out),
                             None if skip is None else buffer_address(skip[0]),
                             0.0 if skip is None else float(np.float32(skip[1])),
                             None if hit is None else address(hit))
    if m < 0:
        raise IndexError(f"beam traversal left the grid of {mark.size} cells")
    return out[:m]


class CommitScratch:
    """Work arrays of :func:`commit_cells` for one grid, kept between scans (grown on demand).

    Args:
        padded_size: cells of the count arrays (the grid padded by the kernel radius).
    """

    def __init__(self, padded_size: int) -> None:
        self.seen = np.zeros(int(padded_size), dtype=np.int8)  # all 0 between calls
        self.padded_size = int(padded_size)
        self.list = np.empty(0, dtype=np.int64)
        self.out = np.empty(0, dtype=np.int64)  # state_out | cells_tmp | safe_out | route_out
        self.d = np.empty(0, dtype=np.int8)
        self.n = np.zeros(3, dtype=np.int64)

    def reserve(self, touched: int, spread: int) -> None:
        """Make room for ``touched`` cells and ``spread`` (<= padded size) count updates."""
        if len(self.list) < spread:
            self.list = np.empty(spread, dtype=np.int64)
        need = 2 * touched + 2 * spread
        if len(self.out) < need:
            self.out = np.empty(need, dtype=np.int64)
        if len(self.d) < 2 * touched:
            self.d = np.empty(2 * touched, dtype=np.int8)


def commit_cells(touched: np.ndarray, mark: np.ndarray, log_odds: np.ndarray, floor: np.ndarray,
                 params: np.ndarray, has_floor: bool, shape: tuple[int, int], r: int, koff: np.ndarray,
                 pad: np.ndarray, route: np.ndarray, scratch: CommitScratch, rows: np.ndarray | None = None,
                 route_koff: np.ndarray | None = None, route_rows: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The log-odds update and count spreading of :meth:`LiveGrid._commit
    <sanav_mj.mapping.live_grid.LiveGrid._commit>` in one compiled call, or None without the
    kernel (the caller then runs the NumPy reference).

    Args:
        touched: (T,) int64 distinct flat grid indices to update.
        mark: (ny * nx,) int8, 1 (crossed) or 2 (hit) on ``touched``; reset to 0 there.
        log_odds, floor: (ny * nx,) or (ny, nx) float32 log-odds and per-cell lower clamp,
            updated in place (long-lived buffers, as ``mark``, ``pad``, ``route``, ``koff``,
            ``params`` and ``rows``: their addresses are cached, :func:`buffer_address`).
        params: (8,) float32 ``l_free, l_occ, l_min, l_max, free_thresh, occ_thresh, hit_floor,
            floor_at`` (a return raises the floor only where the clamped new log-odds is
            ``>= floor_at``; ``-inf``: every return).
        has_floor: apply ``hit_floor`` (False: plain clamping).
        shape: (ny, nx) grid shape.
        r: padding [cells] of the count arrays (the kernel radius).
        koff: (K,) int64 kernel offsets in padded flat indices.
        pad, route: ((ny + 2r) * (nx + 2r),) int32 counts of non-free and of route-blocking
            cells within the kernel, updated in place.
        scratch: work arrays for this grid.
        rows: (Q, 2) int64 the kernel as row runs ``(row offset, half width)`` (the same
            cells as ``koff``): many changed cells are then spread over their bounding
            window by row runs instead of cell by offset. None: always by offset.
        route_koff, route_rows: the kernel of the ``route`` counts, as ``koff`` and ``rows``
            (offsets within radius ``r``); None: the same as ``koff`` and ``rows``.

    Returns:
        (state_changed, safe_changed, route_changed) int64 flat indices as
        :class:`~sanav_mj.mapping.live_grid.MapUpdate` holds them (the first in ``touched``
        order, the others sorted), or None when the compiled kernel is not available.
    """
    lib = _load()
    if lib is None:
        return None
    ny, nx = shape
    T = len(touched)
    for name, a, dt in (("touched", touched, np.int64), ("mark", mark, np.int8), ("log_odds", log_odds, np.float32),
                        ("floor", floor, np.float32), ("params", params, np.float32), ("koff", koff, np.int64),
                        ("pad", pad, np.int32), ("route", route, np.int32)) + (() if rows is None else
                                                                             (("rows", rows, np.int64),)) + (
            () if route_koff is None else (("route_koff", route_koff, np.int64),)) + (
            () if route_rows is None else (("route_rows", route_rows, np.int64),)):
        if a.dtype != dt or not a.flags.c_contiguous:
            raise ValueError(f"commit_cells: {name} must be a contiguous {np.dtype(dt)} array, got {a.dtype}")
    if not (mark.size == log_odds.size == floor.size == ny * nx):
        raise ValueError(f"commit_cells: mark, log_odds and floor must have {ny * nx} cells, got {mark.size}, "
                         f"{log_odds.size}, {floor.size}")
    if len(pad) != scratch.padded_size or len(route) != scratch.padded_size:
        raise ValueError(f"commit_cells: pad and route must have {scratch.padded_size} cells, got "
                         f"{len(pad)}, {len(route)}")
    if route_koff is None:
        route_koff, route_rows = koff, rows
    spread = min(T * max(len(koff), len(route_koff)), scratch.padded_size)
    scratch.reserve(T, spread)
    out = scratch.out
    state_out = out[:T]
    # out[T:2 * T] is the kernel's scratch for the touched cells (base + 8 * T below)
    safe_out = out[2 * T:2 * T + spread]
    route_out = out[2 * T + spread:2 * T + 2 * spread]
    n = scratch.n
    ad = buffer_address
    base = ad(out)  # state_out, cells_tmp, safe_out, route_out: consecutive parts of out
    lib.sanav_commit(T, address(touched), ad(mark), ad(log_odds), ad(floor), ad(params), int(has_floor), ny, nx,
                     r, nx + 2 * r, len(koff), ad(koff), ad(pad), ad(route), base, base + 8 * (2 * T),
                     base + 8 * (2 * T + spread), ad(n), base + 8 * T, ad(scratch.d), ad(scratch.seen),
                     ad(scratch.list), 0 if rows is None else len(rows), None if rows is None else ad(rows),
                     len(route_koff), ad(route_koff), 0 if route_rows is None else len(route_rows),
                     None if route_rows is None else ad(route_rows))
    return state_out[:n[0]].copy(), safe_out[:n[1]].copy(), route_out[:n[2]].copy()
