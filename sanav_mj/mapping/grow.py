"""Grow a free rectangle of an occupancy grid to a maximal free one (overlapping safe areas).

The merged safe areas partition the free cells; where the free space runs diagonally the
partition is a staircase of thin rectangles that touch along short edges, and a convex box
per predicted state leaves little room. A rectangle made only of free cells of the exact grid
(:mod:`sanav_mj.mapping.occupancy`) is as safe as any safe area, whether or not it is one of
the partition's: :func:`grow_rect` extends a free rectangle side by side, one cell row or
column at a time, while the new strip holds only free cells, and so returns a free rectangle
that contains the input and overlaps its neighbours in the partition.

The order is fixed: rounds over the sides -x, +x, -y, +y, each extended by one cell if the
strip beyond it is free (and the side has not yet moved ``limit`` from where it started),
until a round extends none. Each test is one lookup in a summed-area table of occupied cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sanav_mj.mapping.grow_kernel import grow_cells, summed_area
from sanav_mj.mapping.occupancy import OccupancyGrid

__all__ = ["FreeCells", "grow_point", "grow_rect"]


@dataclass(frozen=True)
class FreeCells:
    """A grid's occupied-cell counts for O(1) "is this block free" queries.

    Attributes:
        sat: (ny+1, nx+1) int64 summed-area table: ``sat[i, j]`` occupied cells in rows < i, columns < j.
        origin: (2,) [m] world x, y of the grid's lower-left corner.
        resolution: [m] cell edge.
        limit: [m] how far a user of the table (the corridor chain of SA-MPC) lets a side of a
            rectangle move out (:func:`grow_rect`'s ``limit``).
        tighten: [m] how much more than its usual margin that user shrinks the grown
            rectangles (never inside the rectangles they grew from, shrunk as usual).
    """

    sat: np.ndarray
    origin: np.ndarray
    resolution: float
    limit: float = 1.0
    tighten: float = 0.0

    @staticmethod
    def of(grid: OccupancyGrid, limit: float = 1.0, tighten: float = 0.0, use_kernel: bool = True) -> FreeCells:
        """The table of ``grid`` (its ``occupied`` cells), with growth ``limit`` and ``tighten`` [m] (>= 0).

        ``use_kernel``: False forces the NumPy ``cumsum`` reference (else one pass of the
        compiled :func:`~sanav_mj.mapping.grow_kernel.summed_area` when available; the same
        integers)."""
        for name, v in (("limit", limit), ("tighten", tighten)):
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0 [m], got {v!r}")
        sat = summed_area(grid.occupied) if use_kernel else None
        if sat is None:  # the reference (and the path without the compiled kernel)
            occ = np.asarray(grid.occupied, dtype=np.int64)
            sat = np.zeros((occ.shape[0] + 1, occ.shape[1] + 1), dtype=np.int64)
            sat[1:, 1:] = occ.cumsum(axis=0).cumsum(axis=1)
        return FreeCells(sat, np.asarray(grid.origin, dtype=float).copy(), float(grid.resolution), float(limit),
                         float(tighten))

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) cells."""
        return self.sat.shape[0] - 1, self.sat.shape[1] - 1

    def occupied_in(self, i0: int, j0: int, i1: int, j1: int) -> int:
        """Occupied cells in rows ``[i0, i1)`` and columns ``[j0, j1)``."""
        s = self.sat
        return int(s[i1, j1] - s[i0, j1] - s[i1, j0] + s[i0, j0])

    def squares_free(self, points, half: float) -> np.ndarray:
        """Whether the square of half-side ``half`` [m] around each point holds only free cells.

        The square is rounded outwards to whole cells (every cell it touches counts), and a
        square reaching beyond the grid is not free: a ``True`` is a proof, never a guess.

        Args:
            points: (K, 2) [m] world x, y.
            half: [m] half-side of the square (>= 0).

        Returns:
            (K,) bool.
        """
        if not (np.isfinite(half) and half >= 0):
            raise ValueError(f"half must be finite and >= 0 [m], got {half!r}")
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        u = (p - self.origin) / self.resolution  # (K, 2) cell coordinates x (columns), y (rows)
        h = half / self.resolution
        j0 = np.floor(u[:, 0] - h).astype(np.int64)
        i0 = np.floor(u[:, 1] - h).astype(np.int64)
        j1 = np.ceil(u[:, 0] + h).astype(np.int64)
        i1 = np.ceil(u[:, 1] + h).astype(np.int64)
        ny, nx = self.shape
        inside = (i0 >= 0) & (j0 >= 0) & (i1 <= ny) & (j1 <= nx) & (i1 > i0) & (j1 > j0)
        i0, j0 = np.clip(i0, 0, ny), np.clip(j0, 0, nx)
        i1, j1 = np.clip(i1, 0, ny), np.clip(j1, 0, nx)
        s = self.sat
        occ = s[i1, j1] - s[i0, j1] - s[i1, j0] + s[i0, j0]
        return inside & (occ == 0)

    def cells_of(self, rect) -> tuple[int, int, int, int]:
        """Cell box ``(i0, j0, i1, j1)`` of a world rectangle (4,) [m] on the grid's lattice.

        Raises:
            ValueError: the rectangle's sides are not on cell boundaries (within 1e-6 cell)
                or it leaves the grid.
        """
        r = np.asarray(rect, dtype=float).reshape(-1).tolist()
        ox, oy = float(self.origin[0]), float(self.origin[1])
        h = float(self.resolution)
        # the cell coordinates of the sides (the same IEEE operations as on arrays), rounded
        # half to even as np.rint
        u = [(r[1] - oy) / h, (r[0] - ox) / h, (r[3] - oy) / h, (r[2] - ox) / h] if len(r) == 4 else []
        ok = len(u) == 4 and all(math.isfinite(v) for v in u)
        k = [round(v) for v in u] if ok else [0, 0, 0, 0]
        ny, nx = self.shape
        if (not ok or max(abs(v - kv) for v, kv in zip(u, k)) > 1e-6 or k[0] < 0 or k[1] < 0 or k[2] > ny
                or k[3] > nx or k[2] <= k[0] or k[3] <= k[1]):
            r = np.asarray(rect, dtype=float)
            raise ValueError(f"rect {r.tolist()}: expected a rectangle of whole cells of the grid "
                             f"(cell {self.resolution} m, origin {self.origin.tolist()}, {ny} x {nx} cells)")
        return k[0], k[1], k[2], k[3]


def grow_rect(cells: FreeCells, rect, limit: float | None = None, use_kernel: bool = True) -> np.ndarray:
    """A maximal free rectangle containing the free rectangle ``rect`` (module docstring).

    Args:
        cells: the grid's :class:`FreeCells`.
        rect: (4,) [m] ``xmin, ymin, xmax, ymax`` of whole free cells of the grid.
        limit: [m] no side moves farther than this from where it started (>= 0; None:
            ``cells.limit``).

    Returns:
        (4,) [m] the grown rectangle: whole free cells, containing ``rect``; no side can move
        out by one more cell (unless it reached ``limit`` or the grid's edge).

    Raises:
        ValueError: ``rect`` is not whole cells of the grid, or holds an occupied cell, or
            ``limit`` is negative.

    The growth loop runs compiled (:mod:`sanav_mj.mapping.grow_kernel`, the same tests in the
    same order) unless ``use_kernel`` is False or no kernel is available; the Python loop
    here is the reference.
    """
    limit = cells.limit if limit is None else limit
    if not (np.isfinite(limit) and limit >= 0):
        raise ValueError(f"limit must be finite and >= 0 [m], got {limit!r}")
    i0, j0, i1, j1 = cells.cells_of(rect)
    if cells.occupied_in(i0, j0, i1, j1):
        raise ValueError(f"rect {np.asarray(rect, dtype=float).tolist()}: holds occupied cells; only a free rectangle grows")
    ny, nx = cells.shape
    steps = math.floor(limit / cells.resolution + 1e-9)
    lo_i, lo_j, hi_i, hi_j = max(0, i0 - steps), max(0, j0 - steps), min(ny, i1 + steps), min(nx, j1 + steps)
    grown = grow_cells(cells.sat, (i0, j0, i1, j1), (lo_i, lo_j, hi_i, hi_j)) if use_kernel else None
    if grown is not None:
        i0, j0, i1, j1 = grown
    moved = grown is None
    while moved:
        moved = False
        if j0 > lo_j and not cells.occupied_in(i0, j0 - 1, i1, j0):
            j0 -= 1
            moved = True
        if j1 < hi_j and not cells.occupied_in(i0, j1, i1, j1 + 1):
            j1 += 1
            moved = True
        if i0 > lo_i and not cells.occupied_in(i0 - 1, j0, i0, j1):
            i0 -= 1
            moved = True
        if i1 < hi_i and not cells.occupied_in(i1, j0, i1 + 1, j1):
            i1 += 1
            moved = True
    h = cells.resolution
    ox, oy = cells.origin
    return np.array([ox + h * j0, oy + h * i0, ox + h * j1, oy + h * i1])


def grow_point(cells: FreeCells, point, limit: float, use_kernel: bool = True) -> np.ndarray | None:
    """A maximal free rectangle grown around the grid cell that holds ``point``, or None.

    Where the free space runs diagonally, the partition's areas are a staircase of slivers;
    a box grown from one cell, one row or column per side in turn (:func:`grow_rect`'s
    rounds -x, +x, -y, +y), is as wide as the diagonal strip allows in both directions
    (about its width / sqrt 2 for a 45 deg strip), whereas a partition area can be one cell
    thin. It holds only free cells, so it is as safe as any safe area.

    Args:
        cells: the grid's :class:`FreeCells`.
        point: (2,) [m] world x, y.
        limit: [m] no side moves farther than this from the cell (>= 0).

    Returns:
        (4,) [m] ``xmin, ymin, xmax, ymax`` of whole free cells containing ``point`` (closed)
        and maximal (no side can move out by one more cell unless it reached ``limit`` or
        the grid's edge); None when ``point`` lies outside the grid or in an occupied cell.
    """
    p = np.asarray(point, dtype=float).reshape(-1)
    if p.size != 2 or not np.all(np.isfinite(p)):
        raise ValueError(f"point must be 2 finite numbers [m], got {p.tolist()}")
    h = cells.resolution
    j = math.floor((p[0] - cells.origin[0]) / h)
    i = math.floor((p[1] - cells.origin[1]) / h)
    ny, nx = cells.shape
    if not (0 <= i < ny and 0 <= j < nx) or cells.occupied_in(i, j, i + 1, j + 1):
        return None
    ox, oy = cells.origin
    cell = np.array([ox + h * j, oy + h * i, ox + h * (j + 1), oy + h * (i + 1)])
    return grow_rect(cells, cell, limit=limit, use_kernel=use_kernel)
