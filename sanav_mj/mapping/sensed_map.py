"""The map a robot builds from its own scans: live grid + incremental safe areas, per scan.

:class:`SensedMap` ties :class:`~sanav_mj.mapping.live_grid.LiveGrid` (log-odds grid and
inflated safe grid) to :class:`~sanav_mj.mapping.incremental.IncrementalSafeAreas` and
times both. It takes plain arrays (the measured robot pose and a scan's ranges), so it sits
in the mapping stage and knows nothing of MuJoCo; ``sanav_mj.sim.lidar`` produces the scans.

Optionally (default) it also keeps *route* areas, where only occupied cells are inflated
and unknown space counts as passable: a route to a goal in unexplored space is planned on
those, while the MPC's constraints use the safe areas alone.

Every safe rectangle it returns is observed free space with no occupied or unknown cell
within the inflation radius; :meth:`SensedMap.rects_still_safe` tells whether rectangles
handed out earlier (a corridor) are still entirely safe after the latest scans, the test
for replanning.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from sanav_mj.mapping import rect_kernel
from sanav_mj.mapping.incremental import IncrementalSafeAreas
from sanav_mj.mapping.live_grid import LiveGrid, LiveGridConfig
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.mapping.subcell_grid import SubcellGrid
from sanav_mj.mapping.scan_match import LikelihoodField, MatchResult, ScanMatchConfig, ScanMatcher, scan_points


@dataclass(frozen=True)
class SensedMapConfig:
    """Settings of the sensed map.

    Attributes:
        resolution: [m] cell edge, > 0.
        min_cell: [cells] quadtree minimum node size, integer >= 1.
        tile: [cells] incremental-update tile edge, a power of two >= the smallest leaf.
        grid: log-odds parameters.
        route: also keep the *route* areas (:meth:`LiveGrid.route_safe`: unknown counts as
            passable, only occupied cells are inflated), on which a route towards a goal in
            unexplored space can be planned; the MPC's constraints use the safe areas only.
        match: the scan matcher's settings (:meth:`SensedMap.match`).
    """

    resolution: float = 0.05
    min_cell: int = 1
    tile: int = 32
    grid: LiveGridConfig = field(default_factory=LiveGridConfig)
    route: bool = True
    match: ScanMatchConfig = field(default_factory=ScanMatchConfig)

    def __post_init__(self) -> None:
        if not (isinstance(self.resolution, (int, float)) and math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"SensedMapConfig.resolution must be a finite number > 0 [m], got {self.resolution!r}")


@dataclass(frozen=True)
class SensedUpdate:
    """The result of one scan.

    Attributes:
        changed: whether any cell's safe state changed (the safe areas may differ).
        n_state_changed: cells whose unknown / free / occupied state changed.
        n_safe_changed: cells whose safe state changed.
        boxes: (R, 4) int64 cell boxes of the safe areas, sorted by ``(i0, j0)`` (None when
            the update was asked without the snapshot: :meth:`SensedMap.areas_now`).
        areas: the safe areas and their graph (world metres; None as ``boxes``).
        route_changed: whether any cell's route state changed.
        route_boxes, route_areas: the route areas (``None`` when the map keeps none, or
            when the update was asked without them: :meth:`SensedMap.route_areas`).
        timing_ms: [ms] ``map`` (grid update and inflation), ``areas`` (incremental
            quadtree / merge / graph), ``snapshot`` (compact arrays; only when asked for), ``route`` (the same two
            for the route areas; the snapshot only when asked for), ``total``.
    """

    changed: bool
    n_state_changed: int
    n_safe_changed: int
    boxes: np.ndarray | None
    areas: SafeAreas | None
    timing_ms: dict[str, float]
    route_changed: bool = False
    route_boxes: np.ndarray | None = None
    route_areas: SafeAreas | None = None


class SensedMap:
    """A map grown scan by scan, with safe areas kept up to date incrementally.

    Args:
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        inflation: [m] robot footprint radius + margin, >= 0.
        sensor_offset: (2,) [m] sensor position in the robot base frame (x forward, y left).
        config: resolution, quadtree and log-odds settings.
    """

    def __init__(self, bounds, inflation: float, sensor_offset=(0.0, 0.0),
                 config: SensedMapConfig = SensedMapConfig()) -> None:
        off = np.asarray(sensor_offset, dtype=float).reshape(-1)
        if off.shape != (2,) or not np.all(np.isfinite(off)):
            raise ValueError(f"sensor_offset must be 2 finite numbers [m], got {sensor_offset!r}")
        self.config = config
        self.sensor_offset = off
        # the sub-cell evidence of occupied cells (LiveGridConfig.sub_cells == 2): SubcellGrid
        self.grid = (SubcellGrid if config.grid.sub_cells == 2 else LiveGrid)(bounds, config.resolution, inflation,
                                                                              config.grid)
        self.areas = IncrementalSafeAreas(self.grid.safe_grid(), config.min_cell, config.tile)
        self._snapshot = self.areas.safe_areas()
        self._safe_stale = False  # safe areas updated since the last safe snapshot
        self.route = (IncrementalSafeAreas(self.grid.route_grid(), config.min_cell, config.tile)
                      if config.route else None)
        self._route_snapshot = self.route.safe_areas() if self.route is not None else (None, None)
        self._route_stale = False  # route areas updated since the last route snapshot
        g = self.grid
        self.field = LikelihoodField(g.shape, g.origin, g.resolution, config.match.sigma, config.match.radius_cells)
        self.matcher = ScanMatcher(self.field, config.match)

    def match(self, prior, ranges, hit, angles, anchor=None, anchor_sigma=(math.inf, math.inf), check=None
              ) -> MatchResult:
        """Match a scan against the map's returns so far (:mod:`sanav_mj.mapping.scan_match`).

        Args:
            prior: (3,) [m, m, rad] predicted robot pose (e.g. odometry).
            ranges: (B,) [m]; hit: (B,) bool; angles: (B,) [rad] relative to the heading, in
                scan order.
            anchor, anchor_sigma: an absolute pose measurement and its standard deviations
                ([m], [rad]); check: a pose to test against the match; as
                :meth:`ScanMatcher.match`.

        Returns:
            The match (``status == "empty"`` while the map holds no return, or when the scan
            has fewer than ``min_inliers`` usable returns: nothing to match against).
        """
        pts, normals = scan_points(ranges, hit, angles, self.sensor_offset, self.config.match.max_points)
        if len(pts) < self.config.match.min_inliers:
            pts, normals = pts[:0], normals[:0]
        return self.matcher.match(prior, pts, normals, anchor, anchor_sigma, check)

    def integrate(self, pose, ranges, hit, angles, route_snapshot: bool = True, snapshot: bool = True
                  ) -> SensedUpdate:
        """Add one scan taken at the measured robot pose.

        Args:
            pose: (3,) [m, m, rad] measured x, y, yaw of the robot base (noise included:
                the map is built where the robot believes it is).
            ranges: (B,) [m] ranges; hit: (B,) bool returns; angles: (B,) [rad] beam
                directions relative to the robot heading.
            route_snapshot: also return the route areas (``route_boxes``, ``route_areas``);
                False leaves them None in the result (the route areas are still updated;
                :meth:`route_areas` gives them when needed, e.g. only at replans).
            snapshot: also return the safe areas' compact snapshot (``boxes``, ``areas``);
                False leaves them None in the result (the safe areas are still updated;
                :meth:`areas_now` and :meth:`boxes_now` take the snapshot when read).

        Returns:
            What changed and the current safe areas, with timings.
        """
        p = np.asarray(pose, dtype=float).reshape(-1)
        if p.shape != (3,):
            raise ValueError(f"pose must be (3,) [m, m, rad], got shape {p.shape}")
        c, s = math.cos(p[2]), math.sin(p[2])
        ox, oy = self.sensor_offset
        origin = (p[0] + c * ox - s * oy, p[1] + s * ox + c * oy)
        up = self._integrate_at(origin, float(p[2]), ranges, hit, angles, route_snapshot, snapshot)
        # the returns also feed the scan matcher's field (first return per cell)
        r = np.asarray(ranges, dtype=float)
        a = np.asarray(angles, dtype=float) + p[2]
        h = np.asarray(hit, dtype=bool) & np.isfinite(r) & np.isfinite(a)
        self.field.add_points(np.stack([origin[0] + r[h] * np.cos(a[h]), origin[1] + r[h] * np.sin(a[h])], axis=1))
        return up

    def route_areas(self) -> tuple[np.ndarray | None, SafeAreas | None]:
        """The current route areas: (R, 4) int64 cell boxes and :class:`SafeAreas` (as
        :class:`SensedUpdate` ``route_boxes``, ``route_areas``); ``(None, None)`` when the map
        keeps none. The compact snapshot is taken only when the route areas changed since the
        last one."""
        if self.route is not None and self._route_stale:
            self._route_snapshot = self.route.safe_areas()
            self._route_stale = False
        return self._route_snapshot

    def clear_footprint(self, pose, radius: float, beams: int = 64, route_snapshot: bool = True,
                        snapshot: bool = True) -> SensedUpdate:
        """Observe the disc the robot's body covers as free (nothing else can be there).

        A 2-D lidar ahead of the axle never sees the cells under and just behind the robot
        (its field of view leaves a cone behind the sensor); the robot itself tells they are
        free. Cast as ``beams`` return-less beams of length ``radius`` from the measured
        base position (the log-odds rules apply as for a scan: a cell that ever held a return
        never becomes free).

        Args:
            pose: (3,) [m, m, rad] measured robot pose.
            radius: [m] footprint radius (the circumscribed disc), >= 0.
            beams: number of beams over the full circle, >= 8.
            route_snapshot, snapshot: as :meth:`integrate`.

        Returns:
            The update, as :meth:`integrate`.
        """
        p = np.asarray(pose, dtype=float).reshape(-1)
        if p.shape != (3,):
            raise ValueError(f"pose must be (3,) [m, m, rad], got shape {p.shape}")
        if not (math.isfinite(radius) and radius >= 0) or beams < 8:
            raise ValueError(f"radius must be finite >= 0 [m] and beams >= 8, got {radius!r}, {beams!r}")
        angles = np.linspace(-math.pi, math.pi, int(beams), endpoint=False)
        ranges = np.full(int(beams), float(radius))
        return self._integrate_at((p[0], p[1]), float(p[2]), ranges, np.zeros(int(beams), bool), angles,
                                  route_snapshot, snapshot)

    def clear_box(self, pose, box, shrink: float, route_snapshot: bool = True, snapshot: bool = True
                  ) -> SensedUpdate:
        """Observe free the cells that lie entirely inside the robot's body rectangle, shrunk.

        The robot's body covers ``box`` (its footprint rectangle in the base frame); with the
        pose known to within a position error ``e_p`` and a yaw error ``e_y``, every point of
        the body is within ``e_p + rho * e_y`` of where ``pose`` puts it (``rho``: the largest
        distance of a body point from the base origin). A cell whose closed square lies
        inside the rectangle shrunk by ``shrink >= e_p + rho * e_y`` therefore lies inside
        the true body, where no obstacle can be (short of a collision). Those cells get one
        free observation (:meth:`LiveGrid.observe_free`: a cell that ever held a return is
        not made free).

        Args:
            pose: (3,) [m, m, rad] estimated robot pose.
            box: (xmin, xmax, ymin, ymax) [m] body rectangle in the base frame.
            shrink: [m] distance by which the rectangle is shrunk, >= 0.
            route_snapshot, snapshot: as :meth:`integrate`.

        Returns:
            The update, as :meth:`integrate`.
        """
        p = np.asarray(pose, dtype=float).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"pose must be 3 finite numbers [m, m, rad], got {pose!r}")
        x0, x1, y0, y1 = (float(v) for v in box)
        if not (x1 > x0 and y1 > y0 and math.isfinite(shrink) and shrink >= 0):
            raise ValueError(f"box must be (xmin, xmax, ymin, ymax) with xmin < xmax, ymin < ymax and shrink "
                             f"finite >= 0 [m], got {box!r}, {shrink!r}")
        return self._integrate_cells(self.box_cells(p, (x0, x1, y0, y1), shrink), route_snapshot, snapshot)

    def box_cells(self, pose, box, shrink: float) -> np.ndarray:
        """(K,) int64 flat indices of the cells whose closed squares lie inside the rectangle
        ``box`` (xmin, xmax, ymin, ymax) [m] of the base frame at ``pose`` (3,), shrunk by
        ``shrink`` [m] (see :meth:`clear_box`)."""
        g = self.grid
        h = g.resolution
        ny, nx = g.shape
        x0, x1, y0, y1 = box
        x0, x1, y0, y1 = x0 + shrink, x1 - shrink, y0 + shrink, y1 - shrink
        if x1 < x0 or y1 < y0:
            return np.zeros(0, np.int64)
        rho = max(math.hypot(x, y) for x in (x0, x1) for y in (y0, y1))
        j0 = max(0, int(math.floor((pose[0] - rho - g.origin[0]) / h)))
        j1 = min(nx, int(math.ceil((pose[0] + rho - g.origin[0]) / h)))
        i0 = max(0, int(math.floor((pose[1] - rho - g.origin[1]) / h)))
        i1 = min(ny, int(math.ceil((pose[1] + rho - g.origin[1]) / h)))
        if j1 <= j0 or i1 <= i0:
            return np.zeros(0, np.int64)
        ii, jj = np.mgrid[i0:i1, j0:j1]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        inside = np.ones(ii.shape, dtype=bool)
        for di in (0, 1):  # a square is inside the (convex) rectangle iff its four corners are
            for dj in (0, 1):
                wx = g.origin[0] + (jj + dj) * h - pose[0]
                wy = g.origin[1] + (ii + di) * h - pose[1]
                bx = c * wx + s * wy
                by = -s * wx + c * wy
                inside &= (bx >= x0) & (bx <= x1) & (by >= y0) & (by <= y1)
        return (ii[inside] * nx + jj[inside]).astype(np.int64)

    def _integrate_cells(self, cells, route_snapshot: bool, snapshot: bool = True) -> SensedUpdate:
        t0 = time.perf_counter()
        up = self.grid.observe_free(cells)
        return self._areas_after(up, t0, time.perf_counter(), route_snapshot, snapshot)

    def _integrate_at(self, origin, heading: float, ranges, hit, angles, route_snapshot: bool = True,
                      snapshot: bool = True) -> SensedUpdate:
        t0 = time.perf_counter()
        up = self.grid.integrate(origin, heading, ranges, hit, angles)
        return self._areas_after(up, t0, time.perf_counter(), route_snapshot, snapshot)

    def _areas_after(self, up, t0: float, t1: float, route_snapshot: bool, snapshot: bool = True
                     ) -> SensedUpdate:
        """Bring the safe and route areas up to date after the grid update ``up`` (timed from
        ``t0``; the grid update ended at ``t1``); the safe snapshot only when ``snapshot``."""
        cells = up.safe_changed
        if cells.size:
            self.areas.update_cells(cells, ~self.grid.safe_at(cells))
            self._safe_stale = True
        t2 = time.perf_counter()
        boxes = areas = None
        if snapshot:
            boxes, areas = self._safe_now()
        t3 = time.perf_counter()
        rcells = up.route_changed
        if self.route is not None and rcells.size:
            self.route.update_cells(rcells, ~self.grid.route_safe_at(rcells))
            self._route_stale = True
        route_boxes, route_areas = self.route_areas() if route_snapshot else (None, None)
        t4 = time.perf_counter()
        timing = {"map": 1e3 * (t1 - t0), "areas": 1e3 * (t2 - t1), "snapshot": 1e3 * (t3 - t2),
                  "route": 1e3 * (t4 - t3), "total": 1e3 * (t4 - t0)}
        return SensedUpdate(changed=bool(cells.size), n_state_changed=int(up.state_changed.size),
                            n_safe_changed=int(cells.size), boxes=boxes, areas=areas, timing_ms=timing,
                            route_changed=bool(rcells.size) and self.route is not None,
                            route_boxes=route_boxes, route_areas=route_areas)

    def _safe_now(self) -> tuple[np.ndarray, SafeAreas]:
        """The current safe areas' compact snapshot, taken only when they changed since the
        last one (the snapshot reads the areas' state and changes nothing, so taking it
        later gives the same arrays)."""
        if self._safe_stale:
            self._snapshot = self.areas.safe_areas()
            self._safe_stale = False
        return self._snapshot

    def areas_now(self) -> SafeAreas:
        """The current safe areas (the snapshot is taken here when an update left it out)."""
        return self._safe_now()[1]

    def boxes_now(self) -> np.ndarray:
        """(R, 4) int64 cell boxes of the current safe areas (as :meth:`areas_now`)."""
        return self._safe_now()[0]

    def rects_still_safe(self, rects, use_kernel: bool = True) -> np.ndarray:
        """Whether each world rectangle still lies entirely in safe cells.

        Args:
            rects: (K, 4) [m] ``xmin, ymin, xmax, ymax`` (e.g. the rectangles of a corridor
                planned earlier; safe rectangles lie on cell boundaries).

            use_kernel: False forces the Python loop (else the compiled test of
                :mod:`~sanav_mj.mapping.rect_kernel` when available; the same answers).

        Returns:
            (K,) bool; False where a cell inside the rectangle is no longer safe (replan).
        """
        r = np.asarray(rects, dtype=float).reshape(-1, 4)
        g = self.grid
        h = g.resolution
        if use_kernel:
            fast = rect_kernel.rects_free(r, g.blocked, g.origin, h)
            if fast is not None:
                return fast
        ny, nx = g.shape
        j0 = np.clip(np.floor((r[:, 0] - g.origin[0]) / h + 1e-9), 0, nx).astype(int)
        i0 = np.clip(np.floor((r[:, 1] - g.origin[1]) / h + 1e-9), 0, ny).astype(int)
        j1 = np.clip(np.ceil((r[:, 2] - g.origin[0]) / h - 1e-9), 0, nx).astype(int)
        i1 = np.clip(np.ceil((r[:, 3] - g.origin[1]) / h - 1e-9), 0, ny).astype(int)
        blocked = g.blocked
        out = np.empty(len(r), dtype=bool)
        for k in range(len(r)):
            inside = (i1[k] > i0[k]) and (j1[k] > j0[k])
            out[k] = inside and not blocked[i0[k]:i1[k], j0[k]:j1[k]].any()
        return out
