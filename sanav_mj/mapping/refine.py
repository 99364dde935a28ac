"""Finer cells only where passages are narrow: a coarse grid refined locally, still exact.

The rasteriser (:func:`sanav_mj.mapping.occupancy.rasterise`) is exact for the geometry at
its cell size: a cell is occupied iff its closed square meets an inflated obstacle (or lies
partly outside the workspace). What it still costs is up to a cell of passage width per
side. Finer cells everywhere win that back but turn every diagonal boundary into a
staircase of thin rectangles (slivers); :func:`refine_narrow` uses the fine cells only where
the free space is narrow.

Construction. ``coarse`` is the exact grid at cell ``h``, ``fine`` the exact grid at
``h / f`` over the same workspace (same origin; fine cell ``(i, j)`` lies inside coarse cell
``(i // f, j // f)``). A fine cell is free in the refined grid iff

* it is free in ``fine``, and
* its coarse cell is free (a fine cell inside a closed square that meets no inflated
  obstacle is free anyway), or it is narrow: the run of consecutive fine-free cells through it
  along its row or along its column is at most ``width`` [m] long
  (:func:`free_run_lengths`).

Every free refined cell is therefore free in the exact fine grid: the refined grid is as
provably free as ``fine`` (no new tie rule, no tolerance). It differs from ``fine`` only at
the boundary of wide free space (runs longer than ``width`` both ways), where the coarse
cells stay and no staircase of fine cells is made.
"""

from __future__ import annotations

import numpy as np

from sanav_mj.mapping.occupancy import OccupancyGrid

__all__ = ["free_run_lengths", "refine_narrow"]


def free_run_lengths(free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Length of the run of consecutive free cells through each cell, along rows and columns.

    Args:
        free: (ny, nx) bool, True where free.

    Returns:
        ``(along_x, along_y)``, each (ny, nx) int64 [cells]: for a free cell the number of
        free cells in its maximal run of its row (``along_x``) or column (``along_y``);
        0 for occupied cells.
    """
    f = np.asarray(free)
    if f.ndim != 2 or f.dtype != bool:
        raise ValueError(f"free must be a 2-D bool array (ny, nx), got {f.dtype} {f.shape}")
    return _runs_along_rows(f), _runs_along_rows(f.T).T


def _runs_along_rows(f: np.ndarray) -> np.ndarray:
    ny, nx = f.shape
    flat = np.zeros((ny, nx + 1), dtype=bool)  # a False column separates the rows
    flat[:, :nx] = f
    flat = flat.ravel()
    start = flat & ~np.concatenate(([False], flat[:-1]))
    run_id = np.cumsum(start) - 1
    lengths = np.bincount(run_id[flat], minlength=int(start.sum()))
    out = np.zeros(flat.size, dtype=np.int64)
    out[flat] = lengths[run_id[flat]]
    return out.reshape(ny, nx + 1)[:, :nx]


def refine_narrow(coarse: OccupancyGrid, fine: OccupancyGrid, width: float) -> OccupancyGrid:
    """The coarse grid at the fine cell size, with fine cells where the free space is narrow.

    Args:
        coarse: exact grid at cell ``h`` (:func:`~sanav_mj.mapping.occupancy.rasterise`).
        fine: exact grid of the same obstacles, workspace and inflation at cell ``h / f``,
            ``f`` an integer >= 2.
        width: [m] a fine-free cell under an occupied coarse cell is freed when its free run
            along x or along y (in ``fine``) is at most this long; >= 0 (0: the coarse grid
            at the fine cell size).

    Returns:
        An :class:`OccupancyGrid` with ``fine``'s shape, resolution, origin, inflation and
        bounds (see the module docstring for which cells are free; each is free in ``fine``).

    Raises:
        ValueError: the grids do not share origin, bounds and inflation, the ratio of the cell
            sizes is not an integer >= 2, or ``width`` is negative / not finite.
    """
    if not (np.isfinite(width) and width >= 0):
        raise ValueError(f"width must be finite and >= 0 [m], got {width!r}")
    ratio = coarse.resolution / fine.resolution
    f = int(round(ratio))
    if f < 2 or abs(ratio - f) > 1e-9 * f:
        raise ValueError(f"coarse / fine cell sizes must be an integer >= 2, got {coarse.resolution!r} / "
                         f"{fine.resolution!r} = {ratio!r}")
    if (not np.array_equal(coarse.origin, fine.origin) or not np.array_equal(coarse.bounds, fine.bounds)
            or coarse.inflation != fine.inflation):
        raise ValueError("coarse and fine grids must share origin, bounds and inflation, got "
                         f"{coarse.origin.tolist()}/{fine.origin.tolist()}, {coarse.bounds.tolist()}/"
                         f"{fine.bounds.tolist()}, {coarse.inflation!r}/{fine.inflation!r}")
    ny, nx = fine.shape
    cny, cnx = coarse.shape
    if cny * f < ny or cnx * f < nx:
        raise ValueError(f"fine grid {fine.shape} is larger than the coarse one {coarse.shape} x {f}")
    up = np.repeat(np.repeat(coarse.occupied, f, axis=0), f, axis=1)[:ny, :nx]
    free_fine = ~fine.occupied
    along_x, along_y = free_run_lengths(free_fine)
    limit = width / fine.resolution * (1 + 1e-12)
    narrow = free_fine & (np.minimum(along_x, along_y) <= limit)
    occupied = fine.occupied | (up & ~narrow)  # every free cell is free in ``fine``, by construction
    return OccupancyGrid(occupied=occupied, resolution=fine.resolution, origin=fine.origin.copy(),
                         inflation=fine.inflation, bounds=fine.bounds.copy())
