"""Mapping stage: obstacles -> occupancy grid -> quadtree leaves -> merged safe areas + graph.

:func:`build_map` (:mod:`.build`) runs the whole stage; the pieces are in :mod:`.occupancy`,
:mod:`.quadtree` and :mod:`.safe_areas`.
"""

from sanav_mj.mapping.build import MapConfig, build_map
from sanav_mj.mapping.occupancy import MapMemoryError, OccupancyGrid, rasterise
from sanav_mj.mapping.quadtree import QuadtreeLeaves, build_quadtree
from sanav_mj.mapping.safe_areas import (
    MERGE_METHODS,
    SafeAreaMap,
    SafeAreas,
    build_safe_areas,
    connectivity,
    locate,
    merge_rects,
)

__all__ = [
    "MERGE_METHODS",
    "MapConfig",
    "MapMemoryError",
    "OccupancyGrid",
    "QuadtreeLeaves",
    "SafeAreaMap",
    "SafeAreas",
    "build_map",
    "build_quadtree",
    "build_safe_areas",
    "connectivity",
    "locate",
    "merge_rects",
    "rasterise",
]
