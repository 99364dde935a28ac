"""Occupancy grid rasterised exactly from the scenario's obstacle geoms, inflated by the robot.

Rasterisation is exact and conservative: cell ``(i, j)`` is occupied iff its closed square
meets an obstacle footprint grown by ``inflation`` (the Minkowski sum with a disc), or if
any part of the cell lies outside the workspace.

How it is computed (exact, vectorised over all obstacles at once):

* A closed square ``S`` of half-width ``h/2`` centred at ``c`` meets a convex set ``O`` iff
  ``c`` lies in ``O (+) Q`` with ``Q`` the axis-aligned square ``[-h/2, h/2]^2``. So a cell is
  occupied iff its centre lies in ``K = P (+) D(rho)``, where for a box ``P = box (+) Q``
  (a convex octagon: a rectangle at any yaw summed with an axis-aligned square) and
  ``rho = inflation``, and for an upright cylinder or capsule ``P = Q`` placed at the
  centre and ``rho = radius + inflation``.
* ``K`` is convex, so each grid row (a horizontal line through the cell centres) meets it in
  one interval. Its endpoints are found exactly among the intersections of the row with
  the edges of ``P`` offset outwards by ``rho`` and with the circles of radius ``rho`` around
  the vertices of ``P``. The cells whose centres fall in the interval are occupied.

Work per obstacle is one small computation per grid row it spans, plus writing its cells.
Ties (a cell that exactly touches an inflated obstacle) count as occupied, with a
tolerance of :data:`TOLERANCE` metres in the conservative direction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from math import ceil, floor, isfinite, log10, sqrt

import numpy as np

from sanav_mj.mapping.quadtree import pyramid_bytes
from sanav_mj.scene import Obstacle, ScenarioError

TOLERANCE = 1e-9
"""[m] geometric ties within this distance are resolved as occupied (conservative)."""

MEMORY_BUDGET_BYTES = 2 * 1024**3
"""[bytes] default memory budget of one map (2 GiB): a grid whose estimate
(:func:`map_memory_bytes`) exceeds it is refused before anything is allocated."""

_RUN_CHUNK = 1 << 18
"""[cells] occupied cells written per batch (the index temporaries of one batch are
3 int64 arrays of at most ``max(_RUN_CHUNK, nx)`` elements)."""

_PAIR_CHUNK = 1 << 12
"""(obstacle, grid row) pairs whose row intervals are computed per batch."""

_PAIR_BYTES = 1024
"""[bytes] upper bound on the temporaries per (obstacle, row) pair in :func:`_row_intervals`
(about a dozen (8, M) float64 / bool arrays: 8 candidates x 8 bytes x 12 < 1024)."""


class MapMemoryError(ScenarioError):
    """The grid of a workspace at the requested resolution would exceed the memory budget."""


_SIZE_TOL = 1e-6
"""[cells] a workspace extent within this fraction of a cell of a whole number of cells is
taken as that whole number (so 10.0 m / 0.05 m gives 200 cells despite rounding)."""


@dataclass(frozen=True)
class OccupancyGrid:
    """A conservative, inflated occupancy grid.

    Cell ``(i, j)`` (row i along y, column j along x) covers
    ``[x0 + j*res, x0 + (j+1)*res] x [y0 + i*res, y0 + (i+1)*res]``.

    Attributes:
        occupied: (ny, nx) bool, True where any part of the cell meets an inflated obstacle
            or lies outside the workspace.
        resolution: [m] cell edge length.
        origin: (2,) [m] world x, y of the grid's lower-left corner.
        inflation: [m] obstacle inflation (footprint radius + margin).
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
    """

    occupied: np.ndarray
    resolution: float
    origin: np.ndarray
    inflation: float
    bounds: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) cells."""
        return self.occupied.shape


def _check_bounds(bounds) -> np.ndarray:
    b = np.asarray(bounds, dtype=float)
    if b.shape != (4,) or not np.all(np.isfinite(b)):
        raise ValueError(f"bounds must be 4 finite numbers xmin, ymin, xmax, ymax, got {bounds!r}")
    if not (b[2] > b[0] and b[3] > b[1]):
        raise ValueError(f"bounds must satisfy xmax > xmin and ymax > ymin, got {b.tolist()}")
    return b


def _check_positive(name: str, value: float, allow_zero: bool = False) -> float:
    v = float(value)
    ok = isfinite(v) and (v >= 0.0 if allow_zero else v > 0.0)
    if not ok:
        rule = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {rule} [m], got {value!r}")
    return v


def grid_shape(bounds, resolution: float) -> tuple[int, int]:
    """Number of cells ``(ny, nx)`` of the grid covering ``bounds`` at ``resolution``.

    The grid starts at the lower-left corner of the workspace and covers it entirely; when
    an extent is not a whole number of cells the last row/column straddles the boundary
    (and :func:`rasterise` marks it occupied).

    Args:
        bounds: (4,) [m] xmin, ymin, xmax, ymax.
        resolution: [m] cell edge length, > 0.
    """
    b = _check_bounds(bounds)
    h = _check_positive("resolution", resolution)
    nx = max(1, ceil((b[2] - b[0]) / h - _SIZE_TOL))
    ny = max(1, ceil((b[3] - b[1]) / h - _SIZE_TOL))
    return ny, nx


def map_memory_bytes(ny: int, nx: int) -> int:
    """[bytes] memory the mapping stage allocates for an (ny, nx) grid, from what the code allocates.

    The sum of the per-cell arrays and the bounded temporaries:

    - the occupancy grid, 1 byte per cell (``bool``), kept for the run;
    - the quadtree's count pyramid (:func:`~sanav_mj.mapping.quadtree.pyramid_bytes`: levels
      1 and up, a quarter of the cells each time, uint8 to uint64; about 0.34 byte per cell);
    - the rasteriser's batch temporaries: 3 int64 index arrays of ``max(2^18, nx)`` cells, and
      ``2^12`` (obstacle, row) pairs of at most 1 KiB each.

    Not included: arrays per quadtree leaf / safe area (they grow with the obstacles'
    boundary, not with the workspace's area) and what later stages build per cell (e.g. the
    DWA distance field).
    """
    cells = int(ny) * int(nx)
    return cells + pyramid_bytes(ny, nx) + 3 * 8 * max(_RUN_CHUNK, int(nx)) + _PAIR_CHUNK * _PAIR_BYTES


def _round_up_2(x: float) -> float:
    """``x`` rounded up to two significant digits."""
    step = 10.0 ** (floor(log10(x)) - 1)
    return round(ceil(x / step - 1e-9) * step, 12)


def check_map_memory(bounds, resolution: float, budget_bytes: float = MEMORY_BUDGET_BYTES) -> int:
    """Refuse a grid over the memory budget before allocating it; the estimate [bytes] otherwise.

    Args:
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        resolution: [m] cell edge length, > 0.
        budget_bytes: [bytes] the budget (``MapConfig.memory_budget_bytes``; 2 GiB by default).

    Raises:
        MapMemoryError: one line with the cell count, the estimate, the budget and the
            smallest ``--resolution`` (two significant digits) whose grid fits.
    """
    b = _check_bounds(bounds)
    h = _check_positive("resolution", resolution)
    ny, nx = grid_shape(b, h)
    need = map_memory_bytes(ny, nx)
    if need <= budget_bytes:
        return need
    gib = 1024.0**3
    least = map_memory_bytes(1, 1)  # the batch temporaries: the least any grid needs
    if budget_bytes < least:
        raise MapMemoryError(
            f"memory budget {budget_bytes:g} bytes (MapConfig.memory_budget_bytes) is below the {least} bytes "
            "the mapping needs for any grid"
        )
    fit = _round_up_2(h * sqrt(need / budget_bytes))
    while map_memory_bytes(*grid_shape(b, fit)) > budget_bytes:  # ends: a 1 x 1 grid fits
        fit = _round_up_2(fit * 1.01)
    raise MapMemoryError(
        f"--resolution {h:g} m: the workspace {b[2] - b[0]:g} m x {b[3] - b[1]:g} m is {nx} x {ny} = {nx * ny:.3g} "
        f"cells, about {need / gib:.3g} GiB for the map, over the budget of {budget_bytes / gib:.3g} GiB "
        f"(MapConfig.memory_budget_bytes); use --resolution {fit:g} or coarser"
    )


def obstacle_polygons(
    obstacles: Sequence[Obstacle], half_cell: float, inflation: float
) -> tuple[np.ndarray, np.ndarray]:
    """Convex octagons ``P`` and rounding radii ``rho`` with ``cell occupied <=> centre in P (+) D(rho)``.

    Args:
        obstacles: K obstacles (``box`` at any yaw, upright ``cylinder`` or ``capsule``).
        half_cell: [m] half the cell edge (the half-width of the square ``Q``).
        inflation: [m] obstacle inflation, >= 0.

    Returns:
        verts: (K, 8, 2) [m] counter-clockwise vertices of ``P`` (repeated vertices, i.e.
            zero-length edges, occur for axis-aligned boxes and round obstacles).
        rho: (K,) [m] rounding radius.
    """
    k = len(obstacles)
    centre = np.zeros((k, 2))
    half = np.zeros((k, 2))
    yaw = np.zeros(k)
    rho = np.full(k, float(inflation))
    for n, ob in enumerate(obstacles):
        c = np.asarray(ob.center, dtype=float)
        hs = np.asarray(ob.half_size, dtype=float)
        if c.shape != (2,) or hs.shape != (2,) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(hs))
                                                       and np.isfinite(ob.yaw)):
            raise ValueError(f"obstacle {ob.name!r}: center, half_size must be 2 finite numbers and yaw finite, "
                             f"got center={ob.center!r}, half_size={ob.half_size!r}, yaw={ob.yaw!r}")
        if np.any(hs < 0):
            raise ValueError(f"obstacle {ob.name!r}: half_size must be >= 0 [m], got {hs.tolist()}")
        centre[n] = c
        if ob.kind == "box":
            half[n] = hs
            yaw[n] = ob.yaw
        elif ob.kind in ("cylinder", "capsule"):
            rho[n] += hs[0]
        else:
            raise ValueError(f"obstacle {ob.name!r}: kind must be box, cylinder or capsule, got {ob.kind!r}")
    # A rectangle at yaw t equals the one at t mod pi/2 with the half sizes swapped after an
    # odd number of quarter turns; with t in [0, pi/2) the octagon's edge order is fixed:
    # square 0, box t, square pi/2, box t + pi/2, ... (edge directions increase CCW).
    quarter = np.pi / 2
    turns = np.floor(yaw / quarter)
    t = yaw - turns * quarter
    odd = (turns.astype(np.int64) % 2) == 1
    hx = np.where(odd, half[:, 1], half[:, 0])
    hy = np.where(odd, half[:, 0], half[:, 1])
    c, s = np.cos(t), np.sin(t)
    lx = np.stack([-hx, hx, hx, -hx], axis=1)  # box corners a0..a3, a_k starts box edge k
    ly = np.stack([-hy, -hy, hy, hy], axis=1)
    ax = centre[:, :1] + c[:, None] * lx - s[:, None] * ly
    ay = centre[:, 1:] + s[:, None] * lx + c[:, None] * ly
    q = float(half_cell)
    sx = np.array([-q, q, q, -q])  # square corners s0..s3, s_k starts square edge k
    sy = np.array([-q, -q, q, q])
    # v0 = a0+s0, v1 = a0+s1, v2 = a1+s1, v3 = a1+s2, v4 = a2+s2, v5 = a2+s3, v6 = a3+s3, v7 = a3+s0
    ai = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    si = np.array([0, 1, 1, 2, 2, 3, 3, 0])
    verts = np.stack([ax[:, ai] + sx[si], ay[:, ai] + sy[si]], axis=-1)
    return verts, rho


_FAR = 1e300
"""[m] stands in for +-infinity in masked minima (arithmetic masking is much faster than
``np.where`` on unpredictable masks)."""


def _row_intervals(verts: np.ndarray, rho: np.ndarray, k: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x-interval of ``P_k (+) D(rho_k)`` on the line ``y`` for M (polygon, row) pairs.

    Args:
        verts: (K, V, 2) [m] convex counter-clockwise polygons.
        rho: (K,) [m] rounding radii.
        k: (M,) int polygon of each pair.
        y: (M,) [m] row height of each pair.

    Returns:
        lo, hi: (M,) [m]; ``lo > hi`` where the row misses the set.
    """
    tol = TOLERANCE
    # Per-polygon tables, laid out (V, K) so that per-pair arrays are (V, M) and the
    # reductions over the V candidates run along the fast axis.
    vx = np.ascontiguousarray(verts[..., 0].T)
    vy = np.ascontiguousarray(verts[..., 1].T)
    ex = np.roll(vx, -1, axis=0) - vx
    ey = np.roll(vy, -1, axis=0) - vy
    length = np.hypot(ex, ey)
    inv_len = 1.0 / np.where(length > 0, length, 1.0)
    px = vx + rho * ey * inv_len  # edge offset outwards (normal (ey, -ex)/|e| for CCW)
    py = vy - rho * ex * inv_len
    slanted = ey != 0  # horizontal / zero-length edges: covered by the vertex circles
    inv_ey = np.where(slanted, 1.0 / np.where(slanted, ey, 1.0), 0.0)
    e_lo = np.where(slanted, np.minimum(py, py + ey) - tol, _FAR)
    e_hi = np.where(slanted, np.maximum(py, py + ey) + tol, -_FAR)

    yy = y[None, :]
    r = rho[k][None, :]
    # Circles of radius rho around the vertices: x = vx +- sqrt(rho^2 - dy^2) where |dy| <= rho.
    dy = yy - np.take(vy, k, axis=1)
    miss = (np.abs(dy) > r + tol) * _FAR
    chord = np.sqrt(np.maximum(r * r - dy * dy, 0.0))
    x = np.take(vx, k, axis=1)
    lo = (x - chord + miss).min(axis=0)
    hi = (x + chord - miss).max(axis=0)
    # Offset edges crossing the row.
    miss = ((yy < np.take(e_lo, k, axis=1)) | (yy > np.take(e_hi, k, axis=1))) * _FAR
    t = (yy - np.take(py, k, axis=1)) * np.take(inv_ey, k, axis=1)
    np.clip(t, 0.0, 1.0, out=t)
    x = np.take(px, k, axis=1) + t * np.take(ex, k, axis=1)
    np.minimum(lo, (x + miss).min(axis=0), out=lo)
    np.maximum(hi, (x - miss).max(axis=0), out=hi)
    return lo, hi


def rasterise(
    obstacles: Sequence[Obstacle],
    bounds,
    resolution: float = 0.05,
    *,
    inflation: float,
    memory_budget_bytes: float = MEMORY_BUDGET_BYTES,
) -> OccupancyGrid:
    """Rasterise obstacles into a conservative occupancy grid (exact for boxes, cylinders, capsules).

    A cell is occupied iff its closed square meets an obstacle footprint inflated by
    ``inflation`` (Minkowski sum with a disc), or if part of the cell lies outside the
    workspace. The grid's origin is the workspace's lower-left corner; when the workspace is
    not a whole number of cells wide (high), the last column (row) straddles the boundary
    and is occupied. The workspace boundary itself is not inflated: the free cells are where
    the robot *centre* may be.

    Args:
        obstacles: static obstacles in the world frame (boxes at any yaw; cylinders and
            capsules standing upright, taken as discs of their radius).
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        resolution: [m] cell edge length, > 0.
        inflation: [m] growth of every obstacle (robot footprint radius + margin), >= 0.
        memory_budget_bytes: [bytes] a grid whose :func:`map_memory_bytes` estimate exceeds
            this is refused before allocating (:class:`MapMemoryError`).

    Returns:
        The occupancy grid, (ny, nx) cells with ``ny = ceil(height / resolution)``,
        ``nx = ceil(width / resolution)``.
    """
    b = _check_bounds(bounds)
    h = _check_positive("resolution", resolution)
    infl = _check_positive("inflation", inflation, allow_zero=True)
    check_map_memory(b, h, memory_budget_bytes)
    ny, nx = grid_shape(b, h)
    x0, y0 = float(b[0]), float(b[1])
    occ = np.zeros((ny, nx), dtype=bool)
    flat_occ = occ.reshape(-1)
    if len(obstacles):
        verts, rho = obstacle_polygons(obstacles, 0.5 * h, infl)
        tol_c = TOLERANCE / h
        ylo = verts[..., 1].min(axis=1) - rho
        yhi = verts[..., 1].max(axis=1) + rho
        i_lo = np.maximum(np.ceil((ylo - y0) / h - 0.5 - tol_c), 0).astype(np.int64)
        i_hi = np.minimum(np.floor((yhi - y0) / h - 0.5 + tol_c), ny - 1).astype(np.int64)
        rows = np.maximum(i_hi - i_lo + 1, 0)
        ends = np.cumsum(rows)
        total = int(ends[-1])
        # (obstacle, row) pairs in batches, so the temporaries stay bounded on huge grids
        for p0 in range(0, total, _PAIR_CHUNK):
            p = np.arange(p0, min(p0 + _PAIR_CHUNK, total))
            k = np.searchsorted(ends, p, side="right")
            i = i_lo[k] + (p - (ends[k] - rows[k]))
            lo, hi = _row_intervals(verts, rho, k, y0 + (i + 0.5) * h)
            ok = lo <= hi
            i, lo, hi = i[ok], lo[ok], hi[ok]
            j_lo = np.maximum(np.ceil((lo - x0) / h - 0.5 - tol_c), 0).astype(np.int64)
            j_hi = np.minimum(np.floor((hi - x0) / h - 0.5 + tol_c), nx - 1).astype(np.int64)
            n = np.maximum(j_hi - j_lo + 1, 0)
            first = i * nx + j_lo
            cells = np.cumsum(n)
            r0 = 0
            while r0 < len(n):  # runs in batches of at most max(_RUN_CHUNK, nx) cells
                done = int(cells[r0 - 1]) if r0 else 0
                r1 = max(r0 + 1, int(np.searchsorted(cells, done + _RUN_CHUNK, side="right")))
                m = n[r0:r1]
                count = int(cells[r1 - 1]) - done
                if count:
                    run_start = np.cumsum(m) - m
                    flat_occ[np.repeat(first[r0:r1] - run_start, m) + np.arange(count)] = True
                r0 = r1
    # Cells straddling the workspace boundary are partly outside: occupied.
    if nx * h > (b[2] - b[0]) + _SIZE_TOL * h:
        occ[:, -1] = True
    if ny * h > (b[3] - b[1]) + _SIZE_TOL * h:
        occ[-1, :] = True
    return OccupancyGrid(
        occupied=occ,
        resolution=h,
        origin=np.array([x0, y0]),
        inflation=infl,
        bounds=b.copy(),
    )
