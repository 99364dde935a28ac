"""An occupancy grid that grows scan by scan, and the safe grid derived from it incrementally.

The map lives in the world frame on the same cells as the known-map grid
(:func:`sanav_mj.mapping.occupancy.grid_shape`: origin at the workspace's lower-left corner).
Each cell holds a log-odds value ``L`` (0 = never observed), updated by every scan from the
*measured* sensor pose (so pose noise acts on the map, as on a real robot):

* every cell a beam crosses before its end gets ``l_free`` (at most once per scan);
* the cell holding a return's end point gets ``l_occ`` (returns only: a beam with no return
  within the maximum range clears its whole length and marks nothing occupied);
* a cell that is both crossed and hit in one scan counts as hit; ``L`` is clamped to
  ``[l_min, l_max]``.

States: occupied where ``L >= occ_thresh``, free where ``L <= free_thresh``, unknown in
between (so a cell hit once and crossed by one grazing beam afterwards is not free yet).
A cell that reached occupied keeps a floor (``hit_floor``) and is never free again; a cell
seen free many times needs several returns to turn non-free (``l_min``), so the returns the
range noise scatters in front of a surface are outvoted by the beams passing there
(:class:`LiveGridConfig`: ``floor_at``).
Cells that straddle the workspace boundary are occupied from the start, as in the
known-map grid.

Safe grid: a cell is safe iff no *non-free* (occupied or unknown) cell lies within the
inflation radius of it, measured square to square (the closed cell squares, like the
known-map rasteriser measures a cell against an inflated obstacle). Every safe cell is
therefore observed free, and unknown space is never safe. It is kept as a count, per cell,
of the non-free cells within the radius; a scan changes the count only around the cells
whose free / non-free status changed, so the update costs O(changed cells x kernel cells)
and returns exactly the cells whose safe state flipped (input to
:mod:`sanav_mj.mapping.incremental`).

Beam traversal (:func:`traverse`) is exact and vectorised over all beams: each beam is
stepped along its major axis one column (row) at a time; within one column a segment of
slope <= 1 covers one or two cells, the ones holding the segment's entry and exit points.
That is the set of cells whose interior the segment crosses (degenerate exact-corner
passes aside), with no sort.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sanav_mj.mapping.beam_kernel import CommitScratch, commit_cells, expand_columns, free_cells, scan_free_cells
from sanav_mj.mapping.occupancy import OccupancyGrid, grid_shape

UNKNOWN, FREE, OCCUPIED = 0, 1, 2
"""Cell states returned by :meth:`LiveGrid.states`."""

_SIZE_TOL = 1e-6


@dataclass(frozen=True)
class LiveGridConfig:
    """Log-odds occupancy update parameters (dimensionless log-odds).

    Attributes:
        l_free: increment for a cell crossed by a beam, < 0.
        l_occ: increment for a cell holding a return, > 0.
        l_min, l_max: clamping bounds, ``l_min < free_thresh < 0 < occ_thresh < l_max``.
            With ``floor_at`` None also ``l_min + l_occ > free_thresh``: a single return
            makes any cell non-free at once, however often it was seen free before. With
            ``floor_at`` (default) ``l_min`` is the hysteresis: a cell seen free at the
            clamp turns non-free only after ``k`` returns in a row, ``k`` the least with
            ``l_min + k l_occ > free_thresh`` (5 by default), so a free cell the range noise
            hits now and then does not flicker (each flip of a safe cell can force a replan).
        free_thresh: a cell is free when ``L <= free_thresh``.
        occ_thresh: a cell is occupied when ``L >= occ_thresh``.
        hit_floor: a cell whose floor was raised (see ``floor_at``) never drops below this
            log-odds again (default 0: it may fade to unknown but never becomes free, so beams
            grazing a wall between two returns cannot clear the wall's cells; static
            worlds); None: plain clamping at ``l_min``.
        floor_at: a return raises a cell's floor to ``hit_floor`` only when it brings the
            cell's log-odds to ``floor_at`` or above (default 0.5 = ``occ_thresh``: the cell
            is then occupied); None: every return raises it. The sensor model behind it, for
            one beam at normal incidence with range noise ``sigma`` on cells of edge ``c``
            (:func:`beam_hit_fraction`): of the beams reaching a cell, a fraction
            ``Phi((c - x)/sigma) - Phi(-x/sigma)`` over ``Phi(x/sigma)`` end in it, ``x`` the
            surface's depth behind the cell's front edge. With the lidar's 0.02 m on 0.025 m
            cells that is 0.44-0.79 for every cell holding obstacle material (``0 <= x <
            c``) and the cell just in front of it, 0.24 at 1.5 cells in front and 0.10 at 2
            cells. The log-odds walk drifts down exactly where the fraction of scans with a
            return is below ``f* = -l_free / (l_occ - l_free)`` (0.29 by default): cells one
            and a half cells or more in front of the surface, which the minimum of many
            noisy ranges hits now and then, end free; cells with material drift up, reach
            ``floor_at`` and are locked non-free by ``hit_floor``. With ``floor_at`` None
            the first such stray return locked the cell, fattening every obstacle by up to
            3 cells (7.5 cm) and closing gaps the known map passes through.
            ``f*`` is kept well below 0.44: at ``l_occ`` 0.7 (``f*`` 0.36) the offline
            measurement (scripts/lidar_map_fidelity.py) found safe cells the known map calls
            occupied; at the default none (docs/results.md).
        noise_cells: extra inflation [cells] of the safe and route kernels (radius
            ``inflation + noise_cells * resolution``), for a classification that could call
            free a cell holding obstacle material further than the kernel's slack from a
            non-free cell. Default 0: measured on BARN-like worlds at the default
            ``floor_at``, no safe cell lies within the inflation of an obstacle
            (docs/results.md), while one cell more narrows every passage by 0.05 m.
        route_kernel: how the *route* counts (:meth:`LiveGrid.route_safe`) measure the
            inflation radius from a blocking cell: ``"square"`` (default) square to square
            as the safe grid does (:func:`inflation_offsets`), ``"centre"`` centre to centre
            (:func:`centre_offsets`, up to one cell less on each side of every return). The
            return cells sit up to a few cells in front of the true surface (range noise, the
            end point's cell), so the square kernel can close gaps the known map passes
            through; the centre kernel reopens them in the route, which only guides and never
            constrains the MPC (the safe grid always uses the square kernel). Opt-in: on the
            BARN-like worlds with the lidar in the discs mode it did not help (67 against 73
            of 100 reached, docs/results.md), the robot then stops at passages whose safe
            cells stay closed.
        sub_cells: sub-cells per cell edge [1] of the *material evidence* of return cells
            (cells whose floor was raised; :class:`~sanav_mj.mapping.subcell_grid.SubcellGrid`,
            built by :class:`~sanav_mj.mapping.sensed_map.SensedMap` when 2). 1 (default):
            every non-free cell counts against the safe grid with its whole square. 2: a
            second log-odds grid of half the edge, updated by the same scans with the same
            rules, tells which quarters of a return cell may hold material, and the safe grid
            measures from those quarters' squares only (other non-free cells still with their
            whole square; safe cells still observed free). A plain :class:`LiveGrid` ignores
            it.
        sub_tail: [m] with ``sub_cells`` 2, the sub-cell grid counts each beam as crossing
            only the sub-cells of its last ``sub_tail`` metres (:meth:`LiveGrid.integrate_tails`;
            None: whole beams, as the cell grid). A beam grazing an obstacle's silhouette
            crosses the empty part of the sub-cells holding slivers of it and usually ends far
            behind; with whole beams such sub-cells were called free and one safe cell came
            6 mm inside the known map's inflation (barn_0060, scripts/lidar_map_fidelity.py);
            with 0.3 m (default) or 0.15 m none in 14 worlds. 0.3 m kept more of the free
            evidence near surfaces than 0.15 m (5 against 1 of the 11 BARN-like worlds of
            docs/results.md); it also makes the sub-cell grid cheaper than whole beams.
        sub_margin: [m] with ``sub_cells`` 2, the not-free sub-cells of a return cell count
            as their squares grown by this much (the inflation radius plus ``sub_margin`` from
            them), >= 0, at most half a cell. Default 0: with ``sub_free_thresh`` -1.2 the
            offline check found no safe cell within the known map's inflation of an obstacle
            without it (docs/results.md, where 6.25 mm is measured too).
        sub_free_thresh: with ``sub_cells`` 2, a sub-cell counts as free of material only at
            log-odds ``<= sub_free_thresh`` (stricter than ``free_thresh``: one crossing makes a
            cell free, and a beam whose range noise overshoots a surface crosses sub-cells
            inside the obstacle before any return lands there; measured: a sub-cell wholly
            inside a cylinder called free after one crossing). Default -1.2: three crossings
            more than 2.5 times the returns.
    """

    l_free: float = -0.4
    l_occ: float = 1.0
    l_min: float = -5.0
    l_max: float = 3.5
    free_thresh: float = -0.35
    occ_thresh: float = 0.5
    hit_floor: float | None = 0.0
    route_kernel: str = "square"
    noise_cells: int = 0
    floor_at: float | None = 0.5
    sub_cells: int = 1
    sub_tail: float | None = 0.3
    sub_margin: float = 0.0
    sub_free_thresh: float = -1.2

    def __post_init__(self) -> None:
        if self.sub_tail is not None and not (isinstance(self.sub_tail, (int, float)) and math.isfinite(self.sub_tail)
                                              and self.sub_tail > 0):
            raise ValueError(f"LiveGridConfig.sub_tail must be None or a finite number > 0 [m], got {self.sub_tail!r}")
        if not (isinstance(self.sub_margin, (int, float)) and math.isfinite(self.sub_margin)
                and self.sub_margin >= 0):
            raise ValueError(f"LiveGridConfig.sub_margin must be a finite number >= 0 [m], got {self.sub_margin!r}")
        if self.sub_cells == 2 and not (isinstance(self.sub_free_thresh, (int, float))
                                        and self.l_min <= self.sub_free_thresh <= self.free_thresh):
            raise ValueError(f"LiveGridConfig.sub_free_thresh must be in [l_min, free_thresh] = [{self.l_min}, "
                             f"{self.free_thresh}], got {self.sub_free_thresh!r}")
        if isinstance(self.sub_cells, bool) or self.sub_cells not in (1, 2):
            raise ValueError(f"LiveGridConfig.sub_cells must be 1 or 2 [sub-cells per cell edge], "
                             f"got {self.sub_cells!r}")
        if isinstance(self.noise_cells, bool) or not isinstance(self.noise_cells, int) or self.noise_cells < 0:
            raise ValueError(f"LiveGridConfig.noise_cells must be an integer >= 0 [cells], got {self.noise_cells!r}")
        if self.route_kernel not in ("centre", "square"):
            raise ValueError(f"LiveGridConfig.route_kernel must be 'centre' or 'square', got {self.route_kernel!r}")
        if self.hit_floor is not None and not (isinstance(self.hit_floor, (int, float))
                                               and self.free_thresh < self.hit_floor <= self.l_max):
            raise ValueError(f"LiveGridConfig.hit_floor must be None or in (free_thresh, l_max] = "
                             f"({self.free_thresh}, {self.l_max}], got {self.hit_floor!r}")
        if self.floor_at is not None and not (isinstance(self.floor_at, (int, float)) and not isinstance(
                self.floor_at, bool) and self.free_thresh < self.floor_at <= self.l_max):
            raise ValueError(f"LiveGridConfig.floor_at must be None or in (free_thresh, l_max] = "
                             f"({self.free_thresh}, {self.l_max}], got {self.floor_at!r}")
        vals = (self.l_free, self.l_occ, self.l_min, self.l_max, self.free_thresh, self.occ_thresh)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
            raise ValueError(f"LiveGridConfig fields must be finite numbers, got {vals}")
        if not (self.l_free < 0 < self.l_occ):
            raise ValueError(f"LiveGridConfig needs l_free < 0 < l_occ, got {self.l_free}, {self.l_occ}")
        if not (self.l_min <= self.free_thresh < 0 < self.occ_thresh <= self.l_max):
            raise ValueError("LiveGridConfig needs l_min <= free_thresh < 0 < occ_thresh <= l_max, got "
                             f"{self.l_min}, {self.free_thresh}, {self.occ_thresh}, {self.l_max}")
        if not (self.l_min + self.l_occ > self.free_thresh or self.floor_at is not None):
            raise ValueError("LiveGridConfig needs l_min + l_occ > free_thresh (one return makes a cell non-free) "
                             f"unless floor_at is set, got {self.l_min} + {self.l_occ} <= {self.free_thresh} "
                             f"with floor_at None")


@dataclass(frozen=True)
class MapUpdate:
    """What one scan changed.

    Attributes:
        state_changed: (K,) int64 flat indices (``i * nx + j``) of cells whose state
            (unknown / free / occupied) changed, each once.
        safe_changed: (S,) int64 flat indices of cells whose safe state flipped, each once.
        route_changed: (T,) int64 flat indices of cells whose route state
            (:meth:`LiveGrid.route_safe`) flipped, each once.
    """

    state_changed: np.ndarray
    safe_changed: np.ndarray
    route_changed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def beam_hit_fraction(depth, resolution: float, sigma: float):
    """Of the beams that reach a cell, the fraction that end in it (one beam, normal
    incidence, Gaussian range noise).

    The cell spans ``[0, resolution]`` along the beam; the surface lies ``depth`` behind
    its front edge (``depth < 0``: the whole cell is ``-depth`` inside the obstacle;
    ``0 <= depth < resolution``: the cell holds material; ``depth >= resolution``: the
    cell is in front of the surface). A beam reaches the cell when its range exceeds the
    front edge and ends in it when its range falls inside the cell:
    ``(Phi((resolution - depth) / sigma) - Phi(-depth / sigma)) / Phi(depth / sigma)``.

    Args:
        depth: [m] scalar or array.
        resolution: [m] cell edge, > 0.
        sigma: [m] range noise standard deviation, > 0.

    Returns:
        The fraction in [0, 1], shaped as ``depth``.
    """
    from scipy.special import ndtr

    if not (resolution > 0 and sigma > 0):
        raise ValueError(f"resolution and sigma must be > 0 [m], got {resolution!r}, {sigma!r}")
    d = np.asarray(depth, dtype=float)
    reach = ndtr(d / sigma)
    return np.divide(ndtr((resolution - d) / sigma) - ndtr(-d / sigma), reach, out=np.zeros_like(reach),
                     where=reach > 0)


def inflation_offsets(inflation: float, resolution: float) -> np.ndarray:
    """Cell offsets ``(di, dj)`` whose closed squares lie within ``inflation`` of the centre cell's.

    The distance between the squares of cells offset by ``(di, dj)`` is
    ``hypot(max(|di|-1, 0), max(|dj|-1, 0)) * resolution``; an offset is kept when it is
    ``<= inflation`` (ties within 1e-9 m kept, the conservative side).

    Returns:
        (K, 2) int64, including ``(0, 0)``.
    """
    r = int(math.floor(inflation / resolution + 1e-9)) + 1
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    gap = np.hypot(np.maximum(np.abs(di) - 1, 0), np.maximum(np.abs(dj) - 1, 0)) * resolution
    keep = gap <= inflation + 1e-9
    return np.stack([di[keep], dj[keep]], axis=1).astype(np.int64)


def centre_offsets(inflation: float, resolution: float) -> np.ndarray:
    """Cell offsets ``(di, dj)`` whose centres lie within ``inflation`` of the centre cell's.

    An offset is kept when ``hypot(di, dj) * resolution <= inflation`` (ties within 1e-9 m
    kept). A subset of :func:`inflation_offsets` (the square-to-square distance is never
    larger than the centre-to-centre one).

    Returns:
        (K, 2) int64, including ``(0, 0)``.
    """
    r = int(math.floor(inflation / resolution + 1e-9))
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    keep = np.hypot(di, dj) * resolution <= inflation + 1e-9
    return np.stack([di[keep], dj[keep]], axis=1).astype(np.int64)


def dilate_count(mask: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """For every cell, the number of ``mask`` cells at the given offsets from it (out of grid: 0).

    Args:
        mask: (ny, nx) bool.
        offsets: (K, 2) int cell offsets (symmetric sets give the usual dilation count).

    Returns:
        (ny, nx) int32.
    """
    ny, nx = mask.shape
    r = int(np.abs(offsets).max()) if len(offsets) else 0
    pad = np.zeros((ny + 2 * r, nx + 2 * r), dtype=np.int32)
    pad[r:r + ny, r:r + nx] = mask
    out = np.zeros((ny, nx), dtype=np.int32)
    for di, dj in offsets:
        out += pad[r + di:r + di + ny, r + dj:r + dj + nx]
    return out


def traverse(u0: np.ndarray, v0: np.ndarray, u1: np.ndarray, v1: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells crossed by segments, in cell coordinates (cell ``(i, j)`` is ``[j, j+1) x [i, i+1)``).

    Each segment is stepped along its major axis: the minor coordinate at each boundary
    between consecutive major-axis columns is ``base + k * inc`` (one multiply-add per
    column); a column holds the cells of its entry and exit points (one, or two adjacent).

    Args:
        u0, v0, u1, v1: (B,) float start and end points, x (column) and y (row) in cell units.

    Returns:
        beam: (M,) int64 segment index of each crossed cell.
        i, j: (M,) int64 row and column. Each segment's cells appear once each (grouped by
        kind, not in travel order); its start and end cells are included. Cells may lie
        outside any grid.
    """
    u0, v0, u1, v1 = (np.asarray(a, dtype=float) for a in (u0, v0, u1, v1))
    xmajor = np.abs(u1 - u0) >= np.abs(v1 - v0)
    a0 = np.where(xmajor, u0, v0)  # major axis
    b0 = np.where(xmajor, v0, u0)
    a1 = np.where(xmajor, u1, v1)
    b1 = np.where(xmajor, v1, u1)
    c0 = np.floor(a0)
    c1 = np.floor(a1)
    step = np.where(c1 >= c0, 1.0, -1.0)
    n = (np.abs(c1 - c0) + 1).astype(np.int64)
    da = a1 - a0
    slope = np.divide(b1 - b0, da, out=np.zeros_like(da), where=da != 0)
    # minor coordinate at the far boundary of column k: b0 + (c0 + k*step + [step > 0] - a0) * slope
    base = b0 + (c0 + (step > 0) - a0) * slope
    inc = step * slope
    start = np.cumsum(n) - n
    total = int(n.sum())
    beam = np.repeat(np.arange(len(a0)), n)
    k = np.arange(total, dtype=float) - np.repeat(start.astype(float), n)
    exit_ = np.floor(np.repeat(base, n) + k * np.repeat(inc, n))
    last = start + n - 1
    exit_[last] = np.floor(b1)  # the last column ends at the segment's end point
    entry = np.empty_like(exit_)
    entry[1:] = exit_[:-1]
    entry[start] = np.floor(b0)
    col = np.repeat(c0, n) + k * np.repeat(step, n)
    two = entry != exit_
    beam = np.concatenate([beam, beam[two]])
    col = np.concatenate([col, col[two]]).astype(np.int64)
    minor = np.concatenate([entry, exit_[two]]).astype(np.int64)
    xm = xmajor[beam]
    return beam, np.where(xm, minor, col), np.where(xm, col, minor)


def segment_columns(u0, v0, u1, v1, ny: int, nx: int) -> dict[str, np.ndarray]:
    """Segments clipped to an (ny, nx) grid, in the per-column form of the traversal.

    Each segment is clipped to the grid (Liang-Barsky, to ``[eps, n - eps]`` with
    ``eps = 1e-9`` cell, so ``floor`` of the clipped points stays inside the grid) and
    stepped along its major axis: column ``k`` (``0 <= k < n``) ends at minor coordinate
    ``floor(base + k * inc)`` clamped to ``[lo, hi]`` (the minor cells of the clipped end
    points: rounding at the grid edge is clipped away), the last column at ``fb1``, the first
    starts at ``fb0``; its flat cell index is ``major0 + k * major_step + minor * minor_stride``.

    Args:
        u0, v0, u1, v1: (B,) float segment end points in cell units (x = column, y = row).
        ny, nx: grid shape.

    Returns:
        dict of (B',) arrays, B' <= B the segments meeting the grid: float64 ``base``,
        ``inc``, ``lo``, ``hi``, ``fb0``, ``fb1``; int64 ``n``, ``major0``, ``major_step``,
        ``minor_stride``.
    """
    u0, v0, u1, v1 = (np.asarray(a, dtype=float) for a in (u0, v0, u1, v1))
    du, dv = u1 - u0, v1 - v0
    t0 = np.zeros(len(u0))
    t1 = np.ones(len(u0))
    eps = 1e-9
    for p, q, hi in ((du, u0, nx - eps), (dv, v0, ny - eps)):
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (eps - q) / p
            tb = (hi - q) / p
        inside = (q >= eps) & (q <= hi)
        lo_t = np.where(p > 0, ta, np.where(p < 0, tb, np.where(inside, -np.inf, np.inf)))
        hi_t = np.where(p > 0, tb, np.where(p < 0, ta, np.where(inside, np.inf, -np.inf)))
        t0 = np.maximum(t0, lo_t)
        t1 = np.minimum(t1, hi_t)
    keep = t1 >= t0
    if not keep.all():
        u0, v0, du, dv, t0, t1 = u0[keep], v0[keep], du[keep], dv[keep], t0[keep], t1[keep]
    cu0, cv0 = u0 + t0 * du, v0 + t0 * dv
    cu1, cv1 = u0 + t1 * du, v0 + t1 * dv
    xmajor = np.abs(du) >= np.abs(dv)
    a0 = np.where(xmajor, cu0, cv0)
    b0 = np.where(xmajor, cv0, cu0)
    a1 = np.where(xmajor, cu1, cv1)
    b1 = np.where(xmajor, cv1, cu1)
    c0, c1 = np.floor(a0), np.floor(a1)
    step = np.where(c1 >= c0, 1.0, -1.0)
    n = (np.abs(c1 - c0) + 1).astype(np.int64)
    da = a1 - a0
    slope = np.divide(b1 - b0, da, out=np.zeros_like(da), where=da != 0)
    base = b0 + (c0 + (step > 0) - a0) * slope
    major_stride = np.where(xmajor, 1.0, float(nx))
    minor_stride = np.where(xmajor, float(nx), 1.0)
    fb0, fb1 = np.floor(b0), np.floor(b1)
    return {"base": base, "inc": step * slope, "lo": np.minimum(fb0, fb1), "hi": np.maximum(fb0, fb1),
            "fb0": fb0, "fb1": fb1, "n": n, "major0": (c0 * major_stride).astype(np.int64),
            "major_step": (step * major_stride).astype(np.int64), "minor_stride": minor_stride.astype(np.int64)}


def crossed_cells(u0, v0, u1, v1, ny: int, nx: int) -> np.ndarray:
    """Flat indices ``i * nx + j`` of the cells of an (ny, nx) grid crossed by segments.

    The same cells as :func:`traverse` keeps inside the grid, faster: each segment is first
    clipped to the grid (Liang-Barsky, :func:`segment_columns`), so no work is spent outside
    it, and the flat index is formed directly (major-axis stride plus minor-axis stride).

    Args:
        u0, v0, u1, v1: (B,) float segment end points in cell units (x = column, y = row).
        ny, nx: grid shape.

    Returns:
        (M,) int64 flat indices; a cell crossed by several segments appears once per segment.
    """
    return expand_columns(segment_columns(u0, v0, u1, v1, ny, nx))


def _scan_arrays(origin, heading: float, ranges, hit, angles):
    """A scan's inputs checked (the arguments of :meth:`LiveGrid.integrate`): ``(origin (2,),
    ranges (B',), hit (B',), world angles (B',))`` with the beams of non-finite range or angle
    dropped, or None when the origin is not finite."""
    o = np.asarray(origin, dtype=float).reshape(2)
    r = np.asarray(ranges, dtype=float)
    hit = np.asarray(hit, dtype=bool)
    a = heading + np.asarray(angles, dtype=float)
    if not (r.shape == hit.shape == a.shape and r.ndim == 1):
        raise ValueError(f"ranges, hit, angles must be (B,) arrays of one length, got {r.shape}, "
                         f"{hit.shape}, {a.shape}")
    if not np.all(np.isfinite(o)):
        return None
    ok = np.isfinite(r) & np.isfinite(a)
    return o, r[ok], hit[ok], a[ok]


class LiveGrid:
    """The growing occupancy grid and its inflated safe grid.

    Args:
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax (the grid covers it, as the
            known-map grid does).
        resolution: [m] cell edge.
        inflation: [m] robot footprint radius + margin, >= 0.
        config: log-odds parameters.

    Attributes:
        log_odds: (ny, nx) float32.
        blocked: (ny, nx) int32 number of non-free cells within the inflation radius.
    """

    def __init__(self, bounds, resolution: float, inflation: float,
                 config: LiveGridConfig = LiveGridConfig()) -> None:
        b = np.asarray(bounds, dtype=float)
        ny, nx = grid_shape(b, resolution)
        if not (math.isfinite(inflation) and inflation >= 0):
            raise ValueError(f"inflation must be finite and >= 0 [m], got {inflation!r}")
        self.bounds = b.copy()
        self.resolution = float(resolution)
        self.inflation = float(inflation)
        self.config = config
        self.origin = b[:2].copy()
        self.shape = (ny, nx)
        self.log_odds = np.zeros((ny, nx), dtype=np.float32)
        h = self.resolution
        if nx * h > (b[2] - b[0]) + _SIZE_TOL * h:
            self.log_odds[:, -1] = config.l_max
        if ny * h > (b[3] - b[1]) + _SIZE_TOL * h:
            self.log_odds[-1, :] = config.l_max
        # the safe (and route) kernel: the inflation plus config.noise_cells cells
        self._offsets = inflation_offsets(self.inflation + config.noise_cells * h, h)
        r = max(int(np.abs(self._offsets).max()), self._extra_reach())
        self._r = r
        self._pw = nx + 2 * r  # padded width: neighbourhood updates need no bounds checks
        self._pad = np.zeros((ny + 2 * r) * self._pw, dtype=np.int32)
        self._koff = self._offsets[:, 0] * self._pw + self._offsets[:, 1]
        # the kernel as row runs (di, half-width): the square-to-square distance grows with |dj|
        self._rows = self._row_runs(self._offsets)
        # the route counts' kernel (config.route_kernel), within radius r as well
        self._route_offsets = (centre_offsets(self.inflation + config.noise_cells * h, h)
                               if config.route_kernel == "centre"
                               else self._offsets)
        self._route_koff = self._route_offsets[:, 0] * self._pw + self._route_offsets[:, 1]
        self._route_rows = self._row_runs(self._route_offsets)
        states = self.states()
        self._pad.reshape(ny + 2 * r, self._pw)[r:r + ny, r:r + nx] = dilate_count(states != FREE, self._offsets)
        # route counts: occupied (or ever hit) cells only; unknown counts as passable
        self._route = np.zeros_like(self._pad)
        self._route.reshape(ny + 2 * r, self._pw)[r:r + ny, r:r + nx] = dilate_count(states == OCCUPIED,
                                                                                     self._route_offsets)
        self._mark = np.zeros(ny * nx, dtype=np.int8)
        self._stamp = np.zeros(ny * nx, dtype=np.int64)  # scratch of the NumPy traversal
        self._use_kernel = True  # the compiled traversal when available (False: NumPy, for tests)
        self._use_commit_kernel = True  # the compiled log-odds commit when available (False: NumPy)
        self._floor = np.full(ny * nx, config.l_min, dtype=np.float32)  # per-cell lower clamp
        self._delta = np.array([0.0, config.l_free, config.l_occ], dtype=np.float32)
        # the compiled commit's parameters, float32 as NumPy compares float32 cells with them
        hf = config.l_min if config.hit_floor is None else config.hit_floor
        fa = -np.inf if config.floor_at is None else config.floor_at
        self._params = np.array([config.l_free, config.l_occ, config.l_min, config.l_max, config.free_thresh,
                                 config.occ_thresh, hf, fa], dtype=np.float32)
        self._scratch = CommitScratch(len(self._pad))
        self._cells = np.empty(ny * nx, dtype=np.int64)  # the compiled traversal's output
        self._rows_arr = np.array(self._rows, dtype=np.int64).reshape(-1, 2)
        self._route_rows_arr = np.array(self._route_rows, dtype=np.int64).reshape(-1, 2)

    def _extra_reach(self) -> int:
        """[cells] the least padding of the count arrays beyond the kernel's (subclasses
        whose own kernels reach further; here 0)."""
        return 0

    @staticmethod
    def _row_runs(offsets: np.ndarray) -> list[tuple[int, int]]:
        """A kernel symmetric in ``dj`` as row runs ``(di, half width)`` (the distance grows with |dj|)."""
        return [(int(di), int(np.abs(offsets[offsets[:, 0] == di, 1]).max())) for di in np.unique(offsets[:, 0])]

    @property
    def blocked(self) -> np.ndarray:
        """(ny, nx) int32 view: number of non-free cells within the inflation radius of each cell."""
        ny, nx = self.shape
        r = self._r
        return self._pad.reshape(ny + 2 * r, self._pw)[r:r + ny, r:r + nx]

    def states(self) -> np.ndarray:
        """(ny, nx) int8 cell states: :data:`UNKNOWN`, :data:`FREE` or :data:`OCCUPIED`."""
        return self._state(self.log_odds)

    def _state(self, lo: np.ndarray) -> np.ndarray:
        c = self.config
        # free_thresh < occ_thresh: the two tests never both hold (FREE = 1, OCCUPIED = 2)
        s = (lo <= c.free_thresh).view(np.int8)
        s += (lo >= c.occ_thresh).view(np.int8) * np.int8(OCCUPIED)
        return s

    def safe(self) -> np.ndarray:
        """(ny, nx) bool: observed free and no occupied or unknown cell within the inflation radius."""
        return self.blocked == 0

    def _spread(self, pad: np.ndarray, cells: np.ndarray, delta: np.ndarray, route: bool = False) -> np.ndarray:
        """Add ``delta`` (+-1) of each of ``cells`` (flat) to the counts ``pad`` around it
        (the safe grid's kernel, or the route kernel when ``route``).

        Returns the sorted flat grid indices whose count went from zero to non-zero or back.
        Few cells: per kernel offset; many: by row runs over their bounding window."""
        koff, rows = (self._route_koff, self._route_rows) if route else (self._koff, self._rows)
        ny, nx = self.shape
        if not len(cells):
            return np.zeros(0, np.int64)
        ci, cj = np.divmod(cells, nx)
        r = self._r
        h0, h1 = int(ci.min()), int(ci.max()) + 1
        w0, w1 = int(cj.min()), int(cj.max()) + 1
        area = (h1 - h0 + 2 * r) * (w1 - w0 + 2 * r)
        if len(cells) * len(koff) <= (len(rows) + 4) * area:
            flipped = self._spread_sparse(pad, ci, cj, delta, koff)
        else:
            flipped = self._spread_dense(pad, ci, cj, delta, h0, h1, w0, w1, rows)
        pr, pc = np.divmod(flipped, self._pw)
        pr -= r
        pc -= r
        inside = (pr >= 0) & (pr < ny) & (pc >= 0) & (pc < nx)
        return np.sort(pr[inside] * nx + pc[inside])

    def _spread_sparse(self, pad, ci, cj, delta, koff=None) -> np.ndarray:
        """Add ``delta`` of each changed cell to the counts around it, cell by kernel offset.

        Returns the padded flat indices whose count went from zero to non-zero or back."""
        koff = self._koff if koff is None else koff
        centre = (ci + self._r) * self._pw + (cj + self._r)
        idx = (centre[:, None] + koff[None, :]).ravel()
        was_zero = pad[idx] == 0
        np.add.at(pad, idx, np.repeat(delta, len(koff)))
        now_zero = pad[idx] == 0
        return np.unique(idx[was_zero != now_zero])

    def _spread_dense(self, pad, ci, cj, delta, h0, h1, w0, w1, rows=None) -> np.ndarray:
        """As :meth:`_spread_sparse`, over the changed cells' bounding window at once: the
        kernel is a stack of row runs, each a difference of row-wise prefix sums."""
        rows = self._rows if rows is None else rows
        r = self._r
        hh, ww = h1 - h0 + 2 * r, w1 - w0 + 2 * r  # output window: the bounding box grown by r
        dz = np.zeros((hh + 2 * r, ww + 2 * r + 1), dtype=np.int32)
        np.add.at(dz, (ci - h0 + 2 * r, cj - w0 + 2 * r + 1), delta)  # column 0 stays 0
        csum = np.cumsum(dz, axis=1, dtype=np.int32)
        out = np.zeros((hh, ww), dtype=np.int32)
        for di, w in rows:
            rows_ = csum[r + di:r + di + hh]
            out += rows_[:, r + w + 1:r + w + 1 + ww] - rows_[:, r - w:r - w + ww]
        view = pad.reshape(-1, self._pw)[h0:h0 + hh, w0:w0 + ww]  # padded coords = grid + r
        was_zero = view == 0
        view += out
        a, b = np.nonzero(was_zero != (view == 0))
        return (a + h0) * self._pw + (b + w0)

    def route_safe(self) -> np.ndarray:
        """(ny, nx) bool: no occupied cell, nor one that ever held a return (with
        ``hit_floor``), within the inflation radius (measured as ``config.route_kernel``
        says: square to square as :meth:`safe` by default); unknown space counts as passable. Where
        a route towards the goal may be planned through unexplored space; never for the
        MPC's constraints, which use :meth:`safe`."""
        ny, nx = self.shape
        r = self._r
        return self._route.reshape(ny + 2 * r, self._pw)[r:r + ny, r:r + nx] == 0

    def route_safe_at(self, cells) -> np.ndarray:
        """(K,) bool route state (:meth:`route_safe`) of the cells with flat indices ``cells``."""
        i, j = np.divmod(np.asarray(cells, dtype=np.int64), self.shape[1])
        return self._route[(i + self._r) * self._pw + (j + self._r)] == 0

    def route_grid(self) -> OccupancyGrid:
        """:meth:`route_safe` as an :class:`OccupancyGrid` (``occupied`` = not route-safe)."""
        return OccupancyGrid(occupied=~self.route_safe(), resolution=self.resolution, origin=self.origin.copy(),
                             inflation=self.inflation, bounds=self.bounds.copy())

    def unknown_near(self, cells) -> np.ndarray:
        """(U,) int64 sorted flat indices of the :data:`UNKNOWN` cells within the safe kernel
        (the inflation radius) of the cells with flat indices ``cells``: the unknown cells
        that keep them from being safe (besides non-free cells)."""
        ny, nx = self.shape
        i, j = np.divmod(np.asarray(cells, dtype=np.int64).ravel(), nx)
        ii = (i[:, None] + self._offsets[None, :, 0]).ravel()
        jj = (j[:, None] + self._offsets[None, :, 1]).ravel()
        inside = (ii >= 0) & (ii < ny) & (jj >= 0) & (jj < nx)
        near = np.unique(ii[inside] * nx + jj[inside])
        return near[self._state(self.log_odds.ravel()[near]) == UNKNOWN]

    def safe_at(self, cells) -> np.ndarray:
        """(K,) bool safe state of the cells with flat indices ``cells`` (``i * nx + j``)."""
        i, j = np.divmod(np.asarray(cells, dtype=np.int64), self.shape[1])
        return self._pad[(i + self._r) * self._pw + (j + self._r)] == 0

    def safe_grid(self) -> OccupancyGrid:
        """The safe grid as an :class:`OccupancyGrid` (``occupied`` = not safe), for the quadtree."""
        return OccupancyGrid(occupied=~self.safe(), resolution=self.resolution, origin=self.origin.copy(),
                             inflation=self.inflation, bounds=self.bounds.copy())

    def integrate(self, origin, heading: float, ranges, hit, angles) -> MapUpdate:
        """Add one scan taken at a given sensor pose.

        Args:
            origin: (2,) [m] world x, y of the sensor (from the measured robot pose).
            heading: [rad] world yaw of the sensor.
            ranges: (B,) [m] measured ranges (for beams without a return: the maximum range).
            hit: (B,) bool, True where the beam returned.
            angles: (B,) [rad] beam directions relative to ``heading``.

        Returns:
            The cells whose state and whose safe state changed.
        """
        scan = _scan_arrays(origin, heading, ranges, hit, angles)
        if scan is None:
            return MapUpdate(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
        o, r, hit, a = scan
        h = self.resolution
        ny, nx = self.shape
        u0 = (o[0] - self.origin[0]) / h
        v0 = (o[1] - self.origin[1]) / h
        u1 = u0 + r * np.cos(a) / h
        v1 = v0 + r * np.sin(a) / h
        mark = self._mark
        # the cells crossed before the beams' ends, each once, marked 1 (compiled loop, or NumPy)
        # (compiled path: free cells saturated at l_min are skipped, one more l_free leaves
        # them, their floor, state and counts as they are; a return in them is still added)
        if self._use_kernel:  # compiled: crossed cells, then the return cells no beam crossed
            touched = scan_free_cells(u0, v0, u1, v1, self.shape, mark, (self.log_odds, self.config.l_min),
                                      self._cells, hit)
            if touched is not None:
                return self._commit(touched, None)  # touched: read only during the call
        free = free_cells(segment_columns(np.full(len(r), u0), np.full(len(r), v0), u1, v1, ny, nx), mark,
                          self._stamp, False)
        return self._commit_returns(free, u1[hit], v1[hit])

    def integrate_tails(self, origin, heading: float, ranges, hit, angles, tail: float) -> MapUpdate:
        """As :meth:`integrate`, but each beam counts as crossing only the cells of its last
        ``tail`` [m] (from ``max(range - tail, 0)`` to its end; the return cells as
        :meth:`integrate`). Cells further back along a beam get no free observation from it:
        fewer free observations, never more (the sub-cell grid of
        :class:`~sanav_mj.mapping.subcell_grid.SubcellGrid`, which reads only cells near
        returns).

        Args: as :meth:`integrate`; ``tail`` > 0 [m].

        Returns:
            The cells whose state and whose safe state changed.
        """
        if not (math.isfinite(tail) and tail > 0):
            raise ValueError(f"tail must be a finite number > 0 [m], got {tail!r}")
        scan = _scan_arrays(origin, heading, ranges, hit, angles)
        if scan is None:
            return MapUpdate(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
        o, r, hit, a = scan
        h = self.resolution
        ny, nx = self.shape
        c, s = np.cos(a) / h, np.sin(a) / h
        u0 = (o[0] - self.origin[0]) / h
        v0 = (o[1] - self.origin[1]) / h
        u1, v1 = u0 + r * c, v0 + r * s
        start = np.maximum(r - tail, 0.0)
        mark = self._mark
        skip = (self.log_odds.reshape(-1), self.config.l_min) if self._use_kernel else None
        free = free_cells(segment_columns(u0 + start * c, v0 + start * s, u1, v1, ny, nx), mark, self._stamp,
                          self._use_kernel, skip)
        return self._commit_returns(free, u1[hit], v1[hit])

    def _commit_returns(self, free: np.ndarray, ue: np.ndarray, ve: np.ndarray) -> MapUpdate:
        """Commit a scan: the crossed cells ``free`` (marked 1) and the returns at grid
        coordinates ``ue``, ``ve`` (K,) [cells]; a cell hit in this scan counts as hit, not
        crossed, and a return cell no beam crossed is touched too."""
        ny, nx = self.shape
        mark = self._mark
        ei = np.floor(ve).astype(np.int64)
        ej = np.floor(ue).astype(np.int64)
        ein = (ei >= 0) & (ei < ny) & (ej >= 0) & (ej < nx)
        occ = (ei * nx + ej)[ein]
        extra = np.unique(occ[mark[occ] == 0])  # return cells no beam crossed
        mark[occ] = 2
        return self._commit(np.concatenate([free, extra]), occ)

    def observe_free(self, cells) -> MapUpdate:
        """Observe cells free without a beam (e.g. the cells the robot's own body covers).

        Each cell gets ``l_free`` once, with the rules of a scan: a cell that ever held a
        return never drops below ``hit_floor`` (it is not made free).

        Args:
            cells: (K,) int flat indices ``i * nx + j`` inside the grid (repeats allowed).

        Returns:
            The cells whose state and whose safe state changed, as :meth:`integrate`.
        """
        c = np.unique(np.asarray(cells, dtype=np.int64).reshape(-1))
        if c.size and (c[0] < 0 or c[-1] >= self.shape[0] * self.shape[1]):
            raise ValueError(f"cells must be flat indices in [0, {self.shape[0] * self.shape[1]}), got "
                             f"[{c[0]}, {c[-1]}]")
        self._mark[c] = 1
        return self._commit(c, np.zeros(0, np.int64))

    def _commit(self, touched: np.ndarray, occ: np.ndarray) -> MapUpdate:
        """Apply the log-odds increments ``mark`` selects (1 crossed, 2 hit) to the distinct
        ``touched`` cells (``occ``: the hit cells, repeats allowed; None: those marked 2),
        reset ``mark`` there and update the safe and route counts."""
        mark = self._mark
        if self._use_kernel and self._use_commit_kernel:  # compiled: one pass, no temporaries
            got = commit_cells(touched, mark, self.log_odds, self._floor, self._params,
                               self.config.hit_floor is not None, self.shape, self._r, self._koff, self._pad,
                               self._route, self._scratch, self._rows_arr, self._route_koff, self._route_rows_arr)
            if got is not None:
                return MapUpdate(*got)
        if occ is None:
            occ = touched[mark[touched] == 2]
        lo = self.log_odds.reshape(-1)
        old = lo[touched]
        c = self.config
        new = np.clip(old + self._delta[mark[touched]], c.l_min, c.l_max)
        if c.hit_floor is not None:
            hit_old = self._floor[touched] == c.hit_floor
            if c.floor_at is None:
                self._floor[occ] = c.hit_floor
            else:  # a return raises the floor only where the cell is now at floor_at or above
                self._floor[touched[(mark[touched] == 2) & (new >= np.float32(c.floor_at))]] = c.hit_floor
            floor = self._floor[touched]
            hit_new = floor == c.hit_floor
            np.maximum(new, floor, out=new)
        else:
            hit_old = hit_new = np.zeros(len(touched), dtype=bool)
        mark[touched] = 0
        lo[touched] = new
        s_old = self._state(old)
        s_new = self._state(new)
        ch = s_old != s_new
        state_changed = touched[ch]
        was_free = s_old[ch] == FREE
        is_free = s_new[ch] == FREE
        flip = was_free != is_free
        safe_changed = self._spread(self._pad, state_changed[flip], np.where(is_free[flip], -1, 1).astype(np.int32))
        # route blocking: occupied now, or ever held a return (with hit_floor); cells that
        # faded to unknown after a return keep blocking routes, so routes do not flicker
        rb_old = (s_old == OCCUPIED) | hit_old
        rb_new = (s_new == OCCUPIED) | hit_new
        rch = rb_old != rb_new
        rcells = touched[rch]
        route_changed = self._spread(self._route, rcells, np.where(rb_new[rch], 1, -1).astype(np.int32), route=True)
        return MapUpdate(state_changed, safe_changed, route_changed)
