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

from sanav_mj.mapping.incremental import IncrementalSafeAreas
from sanav_mj.mapping.live_grid import LiveGrid, LiveGridConfig
from sanav_mj.mapping.safe_areas import SafeAreas


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
    """

    resolution: float = 0.05
    min_cell: int = 1
    tile: int = 32
    grid: LiveGridConfig = field(default_factory=LiveGridConfig)
    route: bool = True

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
        boxes: (R, 4) int64 cell boxes of the safe areas, sorted by ``(i0, j0)``.
        areas: the safe areas and their graph (world metres).
        route_changed: whether any cell's route state changed.
        route_boxes, route_areas: the route areas (``None`` when the map keeps none, or
            when the update was asked without them: :meth:`SensedMap.route_areas`).
        timing_ms: [ms] ``map`` (grid update and inflation), ``areas`` (incremental
            quadtree / merge / graph), ``snapshot`` (compact arrays), ``route`` (the same two
            for the route areas; the snapshot only when asked for), ``total``.
    """

    changed: bool
    n_state_changed: int
    n_safe_changed: int
    boxes: np.ndarray
    areas: SafeAreas
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
        self.grid = LiveGrid(bounds, config.resolution, inflation, config.grid)
        self.areas = IncrementalSafeAreas(self.grid.safe_grid(), config.min_cell, config.tile)
        self._snapshot = self.areas.safe_areas()
        self.route = (IncrementalSafeAreas(self.grid.route_grid(), config.min_cell, config.tile)
                      if config.route else None)
        self._route_snapshot = self.route.safe_areas() if self.route is not None else (None, None)
        self._route_stale = False  # route areas updated since the last route snapshot

    def integrate(self, pose, ranges, hit, angles, route_snapshot: bool = True) -> SensedUpdate:
        """Add one scan taken at the measured robot pose.

        Args:
            pose: (3,) [m, m, rad] measured x, y, yaw of the robot base (noise included:
                the map is built where the robot believes it is).
            ranges: (B,) [m] ranges; hit: (B,) bool returns; angles: (B,) [rad] beam
                directions relative to the robot heading.
            route_snapshot: also return the route areas (``route_boxes``, ``route_areas``);
                False leaves them None in the result (the route areas are still updated;
                :meth:`route_areas` gives them when needed, e.g. only at replans).

        Returns:
            What changed and the current safe areas, with timings.
        """
        p = np.asarray(pose, dtype=float).reshape(-1)
        if p.shape != (3,):
            raise ValueError(f"pose must be (3,) [m, m, rad], got shape {p.shape}")
        c, s = math.cos(p[2]), math.sin(p[2])
        ox, oy = self.sensor_offset
        origin = (p[0] + c * ox - s * oy, p[1] + s * ox + c * oy)
        return self._integrate_at(origin, float(p[2]), ranges, hit, angles, route_snapshot)

    def route_areas(self) -> tuple[np.ndarray | None, SafeAreas | None]:
        """The current route areas: (R, 4) int64 cell boxes and :class:`SafeAreas` (as
        :class:`SensedUpdate` ``route_boxes``, ``route_areas``); ``(None, None)`` when the map
        keeps none. The compact snapshot is taken only when the route areas changed since the
        last one."""
        if self.route is not None and self._route_stale:
            self._route_snapshot = self.route.safe_areas()
            self._route_stale = False
        return self._route_snapshot

    def clear_footprint(self, pose, radius: float, beams: int = 64, route_snapshot: bool = True) -> SensedUpdate:
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
            route_snapshot: as :meth:`integrate`.

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
                                  route_snapshot)

    def _integrate_at(self, origin, heading: float, ranges, hit, angles, route_snapshot: bool = True
                      ) -> SensedUpdate:
        t0 = time.perf_counter()
        up = self.grid.integrate(origin, heading, ranges, hit, angles)
        t1 = time.perf_counter()
        cells = up.safe_changed
        if cells.size:
            self.areas.update_cells(cells, ~self.grid.safe_at(cells))
        t2 = time.perf_counter()
        if cells.size:
            self._snapshot = self.areas.safe_areas()
        t3 = time.perf_counter()
        rcells = up.route_changed
        if self.route is not None and rcells.size:
            self.route.update_cells(rcells, ~self.grid.route_safe_at(rcells))
            self._route_stale = True
        route_boxes, route_areas = self.route_areas() if route_snapshot else (None, None)
        t4 = time.perf_counter()
        boxes, areas = self._snapshot
        timing = {"map": 1e3 * (t1 - t0), "areas": 1e3 * (t2 - t1), "snapshot": 1e3 * (t3 - t2),
                  "route": 1e3 * (t4 - t3), "total": 1e3 * (t4 - t0)}
        return SensedUpdate(changed=bool(cells.size), n_state_changed=int(up.state_changed.size),
                            n_safe_changed=int(cells.size), boxes=boxes, areas=areas, timing_ms=timing,
                            route_changed=bool(rcells.size) and self.route is not None,
                            route_boxes=route_boxes, route_areas=route_areas)

    def rects_still_safe(self, rects) -> np.ndarray:
        """Whether each world rectangle still lies entirely in safe cells.

        Args:
            rects: (K, 4) [m] ``xmin, ymin, xmax, ymax`` (e.g. the rectangles of a corridor
                planned earlier; safe rectangles lie on cell boundaries).

        Returns:
            (K,) bool; False where a cell inside the rectangle is no longer safe (replan).
        """
        r = np.asarray(rects, dtype=float).reshape(-1, 4)
        g = self.grid
        h = g.resolution
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
