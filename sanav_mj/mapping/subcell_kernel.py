"""Compiled spreading of material-square counts for :class:`~sanav_mj.mapping.subcell_grid.SubcellGrid`.

After a scan a few hundred cells change their material items (the whole square, or some of
its four sub-cells); each added (removed) item adds one (subtracts one) at every cell of
its kernel, and the cells whose count crossed zero are the safe flips. In NumPy this is one
index array of (changed items x kernel cells) and a bincount (the reference and the
fallback, :meth:`SubcellGrid._apply_numpy`); this kernel runs the same additions in place
and collects the cells whose count crossed zero, integer arithmetic only (the same counts
and flips; tested). Compiled by :func:`sanav_mj.native.load_c_kernel` as the other map
kernels; without a compiler, when compiling fails, or with ``SANAV_MJ_NO_CKERNEL=1``, the
NumPy path runs.
"""

from __future__ import annotations

import ctypes

import numpy as np

from sanav_mj.mapping.beam_kernel import NO_KERNEL_ENV, address, buffer_address
from sanav_mj.native import kernel_loader

__all__ = ["kernel_available", "spread_items"]

_SOURCE = r"""
#include <stdint.h>

/* n changed cells (centre: padded flat index), per cell I item deltas (d[i * I + k] in
   {-1, 0, +1}); item k's kernel is koff[ks[k] .. ks[k+1]) (padded flat offsets). Adds each
   delta over its kernel into pad and writes to out the padded indices whose count went from
   zero to non-zero or back (each once, unsorted); returns their number. seen (padded size,
   all 0 on entry and exit) and list (room for every distinct index touched) are scratch. */
int64_t sanav_spread_items(int64_t n, const int64_t *centre, const int8_t *d, int64_t I, const int64_t *koff,
                           const int64_t *ks, int32_t *pad, int8_t *seen, int64_t *list, int64_t *out)
{
    int64_t L = 0;
    for (int64_t i = 0; i < n; ++i) {
        for (int64_t k = 0; k < I; ++k) {
            const int32_t di = d[i * I + k];
            if (!di) continue;
            const int64_t c = centre[i];
            for (int64_t q = ks[k]; q < ks[k + 1]; ++q) {
                const int64_t idx = c + koff[q];
                if (!seen[idx]) { seen[idx] = (int8_t)(1 + (pad[idx] == 0)); list[L++] = idx; }
                pad[idx] += di;
            }
        }
    }
    int64_t m = 0;
    for (int64_t l = 0; l < L; ++l) {
        const int64_t idx = list[l];
        const int was_zero = seen[idx] == 2;
        seen[idx] = 0;
        if (was_zero != (pad[idx] == 0)) out[m++] = idx;
    }
    return m;
}
"""

_i64, _ptr = ctypes.c_int64, ctypes.c_void_p
_load = kernel_loader("subcells", _SOURCE, "the sub-cell count kernel", NO_KERNEL_ENV, {
    "sanav_spread_items": (_i64, [_i64, _ptr, _ptr, _i64, _ptr, _ptr, _ptr, _ptr, _ptr, _ptr]),
})


def kernel_available() -> bool:
    """Whether the compiled spreading is in use (else the NumPy path)."""
    return _load() is not None


class SpreadScratch:
    """Work arrays of :func:`spread_items` for one count array of ``padded_size`` cells."""

    def __init__(self, padded_size: int) -> None:
        self.seen = np.zeros(int(padded_size), dtype=np.int8)  # all 0 between calls
        self.list = np.empty(int(padded_size), dtype=np.int64)
        self.out = np.empty(int(padded_size), dtype=np.int64)


def spread_items(centre: np.ndarray, delta: np.ndarray, koff: np.ndarray, starts: np.ndarray, pad: np.ndarray,
                 scratch: SpreadScratch) -> np.ndarray | None:
    """Add item deltas over their kernels into ``pad`` in place; None without the kernel.

    Args:
        centre: (n,) int64 padded flat indices of the changed cells.
        delta: (n, I) int8 per cell and item -1, 0 or +1.
        koff: (sum K_k,) int64 the items' kernels, concatenated (padded flat offsets; every
            ``centre + koff`` must lie in ``pad``).
        starts: (I + 1,) int64 where item k's offsets start in ``koff`` (and the end).
        pad: (P,) int32 counts, long-lived (its address is cached).
        scratch: work arrays of size P.

    Returns:
        (M,) int64 padded flat indices whose count crossed zero, each once, unsorted.
    """
    lib = _load()
    if lib is None:
        return None
    for name, a, dt in (("centre", centre, np.int64), ("delta", delta, np.int8), ("koff", koff, np.int64),
                        ("starts", starts, np.int64), ("pad", pad, np.int32)):
        if a.dtype != dt or not a.flags.c_contiguous:
            raise ValueError(f"spread_items: {name} must be a contiguous {np.dtype(dt)} array, got {a.dtype}")
    if delta.shape != (len(centre), len(starts) - 1) or len(pad) != len(scratch.seen):
        raise ValueError(f"spread_items: delta must be ({len(centre)}, {len(starts) - 1}) and pad "
                         f"{len(scratch.seen)} cells, got {delta.shape}, {len(pad)}")
    m = lib.sanav_spread_items(len(centre), address(centre), address(delta), len(starts) - 1, buffer_address(koff),
                               buffer_address(starts), buffer_address(pad), buffer_address(scratch.seen),
                               buffer_address(scratch.list), buffer_address(scratch.out))
    return scratch.out[:m].copy()
