"""The whole mapping stage in one call: obstacles -> grid -> quadtree -> safe areas + graph."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from math import isfinite

from sanav_mj.mapping.occupancy import MEMORY_BUDGET_BYTES, rasterise
from sanav_mj.mapping.refine import refine_narrow
from sanav_mj.mapping.safe_areas import MERGE_METHODS, SafeAreaMap, build_safe_areas
from sanav_mj.scene import Obstacle

#: [m] the cell sizes the command line (``--resolution``) and the Python API accept.
RESOLUTION_RANGE_M = (0.005, 1.0)

__all__ = ["MapConfig", "build_map"]


@dataclass(frozen=True)
class MapConfig:
    """Mapping settings.

    Attributes:
        resolution: [m] occupancy cell edge length, > 0 (CLI ``--resolution``).
        min_cell: [cells] quadtree minimum node size, integer >= 1.
        merge: merge method, one of :data:`~sanav_mj.mapping.safe_areas.MERGE_METHODS`.
        refine: integer >= 1; > 1 rasterises a second exact grid at ``resolution / refine``
            and uses its cells where the free space is narrow
            (:func:`~sanav_mj.mapping.refine.refine_narrow`); the map's cells are then
            ``resolution / refine``. 1 (default): one grid at ``resolution``.
        refine_width: [m] with ``refine > 1``: a fine cell is used where its free run along x
            or y is at most this long (>= 0).
        memory_budget_bytes: [bytes] a grid whose estimate
            (:func:`~sanav_mj.mapping.occupancy.map_memory_bytes`, about 1.34 bytes per cell)
            exceeds this is refused before allocating, naming a ``--resolution`` that fits
            (default 2 GiB: a 1 km x 1 km workspace at 0.05 m needs 0.5 GiB).
    """

    resolution: float = 0.05
    min_cell: int = 1
    merge: str = "paper"
    memory_budget_bytes: int = MEMORY_BUDGET_BYTES
    refine: int = 1
    refine_width: float = 0.25

    def __post_init__(self) -> None:
        if not (isinstance(self.resolution, (int, float)) and isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"MapConfig.resolution must be a finite number > 0 [m], got {self.resolution!r}")
        if isinstance(self.min_cell, bool) or not isinstance(self.min_cell, int) or self.min_cell < 1:
            raise ValueError(f"MapConfig.min_cell must be an integer >= 1 [cells], got {self.min_cell!r}")
        if isinstance(self.memory_budget_bytes, bool) or not (
            isinstance(self.memory_budget_bytes, int) and self.memory_budget_bytes > 0
        ):
            raise ValueError(
                f"MapConfig.memory_budget_bytes must be an integer > 0 [bytes], got {self.memory_budget_bytes!r}"
            )
        if isinstance(self.refine, bool) or not isinstance(self.refine, int) or not 1 <= self.refine <= 16:
            raise ValueError(f"MapConfig.refine must be an integer in [1, 16], got {self.refine!r}")
        rw = self.refine_width
        if isinstance(rw, bool) or not (isinstance(rw, (int, float)) and isfinite(rw) and rw >= 0):
            raise ValueError(f"MapConfig.refine_width must be a finite number >= 0 [m], got {rw!r}")
        if self.merge not in MERGE_METHODS:
            raise ValueError(f"MapConfig.merge must be one of {MERGE_METHODS}, got {self.merge!r}")


def build_map(
    obstacles: Sequence[Obstacle],
    bounds,
    inflation: float,
    config: MapConfig = MapConfig(),
) -> SafeAreaMap:
    """Rasterise, decompose, merge and link: the whole mapping stage.

    Args:
        obstacles: static obstacles in the world frame (``Scenario.obstacles``).
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax (``Scenario.bounds``).
        inflation: [m] obstacle inflation, >= 0 (robot footprint radius + margin).
        config: resolution, quadtree minimum cell, merge method, memory budget, local refinement.

    Raises:
        MapMemoryError: the grid's estimate exceeds ``config.memory_budget_bytes`` (nothing allocated).

    Returns:
        The safe-area map; ``timing_ms`` has keys ``rasterise``, ``quadtree``, ``merge``,
        ``graph`` and ``total`` (the sum of the four stages plus glue).
    """
    t0 = time.perf_counter()
    grid = rasterise(obstacles, bounds, config.resolution, inflation=inflation,
                     memory_budget_bytes=config.memory_budget_bytes)
    if config.refine > 1:
        fine = rasterise(obstacles, bounds, config.resolution / config.refine, inflation=inflation,
                         memory_budget_bytes=config.memory_budget_bytes)
        grid = refine_narrow(grid, fine, config.refine_width)
    t1 = time.perf_counter()
    result = build_safe_areas(grid, config.min_cell, config.merge)
    t2 = time.perf_counter()
    timing = {"rasterise": 1e3 * (t1 - t0), **result.timing_ms, "total": 1e3 * (t2 - t0)}
    return replace(result, timing_ms=timing)
