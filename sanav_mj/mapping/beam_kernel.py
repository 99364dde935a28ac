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
import os
from pathlib import Path

import numpy as np

from sanav_mj.native import CompileError, NoCompilerError, compile_cached

#: Environment variable: set to ``1`` to use the NumPy traversal even where C compiles.
NO_KERNEL_ENV = "SANAV_MJ_NO_CKERNEL"

_SOURCE = r"""
#include <math.h>
#include <stdint.h>

/* Cells crossed by B segments in major/minor form (see sanav_mj/mapping/beam_kernel.py).
   Column k of segment b (k = 0 .. n[b]-1) holds the cells of its entry and exit minor
   coordinates; exit = floor(base + k * inc) clamped to [lo, hi], the last exit = fb1, the
   first entry = fb0. Flat cell = major0 + k * major_step + minor * minor_stride. Each cell
   not yet marked is marked 1 and appended to out; returns the number appended, or -1 when
   a cell falls outside [0, size) (a caller's error: segments must be clipped to the grid). */
int64_t sanav_free_cells(int64_t B, const double *base, const double *inc, const double *lo,
                         const double *hi, const double *fb0, const double *fb1, const int64_t *n,
                         const int64_t *major0, const int64_t *major_step,
                         const int64_t *minor_stride, int64_t size, int8_t *mark, int64_t *out)
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
                ex = floor(base[b] + t);
                if (ex < lo[b]) ex = lo[b];
                if (ex > hi[b]) ex = hi[b];
            }
            const int64_t major = major0[b] + k * major_step[b];
            int64_t c = major + (int64_t)entry * minor_stride[b];
            if (c < 0 || c >= size) return -1;
            if (!mark[c]) { mark[c] = 1; out[m++] = c; }
            if (ex != entry) {
                c = major + (int64_t)ex * minor_stride[b];
                if (c < 0 || c >= size) return -1;
                if (!mark[c]) { mark[c] = 1; out[m++] = c; }
            }
            entry = ex;
        }
    }
    return m;
}
"""

_FLAGS = ("-O2", "-fPIC", "-shared", "-std=c99", "-ffp-contract=off", "-fno-fast-math")

_lib: ctypes.CDLL | None = None
_tried = False


def _write_source(folder: Path) -> str:
    """Write the kernel's C source into ``folder``; its path."""
    src = folder / "beams.c"
    src.write_text(_SOURCE)
    return str(src)


def _load() -> ctypes.CDLL | None:
    """The compiled kernel (compiled on first use into the shared cache, see
    :func:`sanav_mj.native.compile_cached`), or None: no compiler, a failed compile, an
    unwritable cache or ``SANAV_MJ_NO_CKERNEL=1``."""
    global _lib, _tried
    if _tried:
        return _lib
    _tried = True
    if os.environ.get(NO_KERNEL_ENV, "") not in ("", "0"):
        return None
    try:
        target, _ = compile_cached("beams", (_SOURCE,), _write_source, _FLAGS, "the beam traversal kernel")
        lib = ctypes.CDLL(str(target))
    except (NoCompilerError, CompileError, OSError):
        return None
    f = lib.sanav_free_cells
    f.restype = ctypes.c_int64
    f.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 10 + [ctypes.c_int64] + [ctypes.c_void_p] * 2
    _lib = lib
    return _lib


def kernel_available() -> bool:
    """Whether the compiled traversal is in use (else the NumPy fallback)."""
    return _load() is not None


def free_cells(seg: dict, mark: np.ndarray, stamp: np.ndarray | None = None, use_kernel: bool = True
               ) -> np.ndarray:
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
        m = lib.sanav_free_cells(B, *(a.ctypes.data for a in arrs), *(a.ctypes.data for a in ints),
                                 mark.size, mark.ctypes.data, out.ctypes.data)
        if m < 0:
            raise IndexError(f"beam traversal left the grid of {mark.size} cells (segments must be clipped)")
        return out[:m]
    cells = expand_columns(seg)
    # each cell once: one occurrence per cell keeps the stamp it wrote, whichever write won
    pos = np.arange(len(cells), dtype=np.int64)
    stamp = np.empty(len(mark), dtype=np.int64) if stamp is None else stamp
    stamp[cells] = pos
    cells = cells[stamp[cells] == pos]
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
