"""Merged safe rectangles and their connectivity graph (paper Sec. III-A/B, Algorithm 1).

Pipeline (all in grid cells until the graph, which is in world metres):

1. :func:`merge_rects` merges the free quadtree leaves exactly as the paper: two free
   rectangles merge when they share a complete edge and their union is a rectangle,
   repeated until no such pair is left. The order, which the paper leaves open and which
   decides the result, is fixed as follows. Passes alternate, starting along x:

   * x-pass: rectangles with the same row span ``[i0, i1)`` that follow each other along x
     with no gap (``j1`` of one equals ``j0`` of the next) form a chain; each chain is merged
     into one rectangle (a sequence of pairwise merges, each of which is a full-edge merge).
   * y-pass: the same along y for rectangles with the same column span ``[j0, j1)``.

   After an x-pass no x-merge is possible, so the process stops at the first pass (after
   the first one) that merges nothing; then no pair shares a complete edge.
2. :func:`connectivity` links two rectangles when they share a boundary segment of positive
   length (touching at a corner only is not an edge), weights the edge by the distance
   between their centres and keeps the shared segment (the portal).

Every pass is a sort and a few array operations, so the work grows with the number of
rectangles, not with the number of cells.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.quadtree import QuadtreeLeaves, build_quadtree

MergeMethod = Literal["paper"]
MERGE_METHODS: tuple[str, ...] = ("paper",)


@dataclass(frozen=True)
class SafeAreas:
    """Axis-aligned safe rectangles (free space for the robot centre) and their adjacency.

    Attributes:
        rects: (R, 4) float [m] world-frame ``xmin, ymin, xmax, ymax`` of each safe area.
        edges: (E, 2) int, pairs ``i < j`` of areas sharing a boundary segment of positive length.
        weights: (E,) [m] distance between the two areas' centres.
        portals: (E, 2, 2) [m] the shared boundary segment of each edge, endpoints ``[[x0, y0], [x1, y1]]``.
        free: optional :class:`~sanav_mj.mapping.grow.FreeCells` of the grid the areas were
            cut from; when set, SA-MPC's corridor chain grows its boxes to maximal free
            rectangles of that grid (:meth:`sanav_mj.control.stages.CorridorChain.build`).
            None (default): the chain uses the areas as they are.
    """

    rects: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    portals: np.ndarray
    free: Any = None


def _check_boxes(boxes) -> np.ndarray:
    b = np.asarray(boxes)
    if b.ndim != 2 or b.shape[1] != 4 or not np.issubdtype(b.dtype, np.integer):
        raise ValueError(f"boxes must be an (n, 4) integer array [i0, j0, i1, j1), got {b.dtype} {b.shape}")
    b = b.astype(np.int64, copy=False)
    if b.size and (np.any(b[:, 2] <= b[:, 0]) or np.any(b[:, 3] <= b[:, 1]) or np.any(b < 0)):
        raise ValueError("boxes must satisfy 0 <= i0 < i1 and 0 <= j0 < j1")
    return b


def _merge_chains(b: np.ndarray, axis: int, base: int) -> np.ndarray:
    """One pass: merge every chain of boxes that follow each other along ``axis`` (0: y, 1: x).

    Boxes in a chain share the span across ``axis`` and each one's far side is the next
    one's near side. ``base`` exceeds every coordinate. Returns the new (m, 4) boxes.
    """
    if axis == 1:  # along x: same rows [i0, i1), consecutive in j
        span0, span1, lo, hi = b[:, 0], b[:, 2], b[:, 1], b[:, 3]
    else:  # along y: same columns [j0, j1), consecutive in i
        span0, span1, lo, hi = b[:, 1], b[:, 3], b[:, 0], b[:, 2]
    span = span0 * base + span1
    order = np.argsort(span * base + lo)  # keys are unique: the boxes are disjoint
    span, lo, hi = span[order], lo[order], hi[order]
    link = (span[1:] == span[:-1]) & (lo[1:] == hi[:-1])
    if not link.any():
        return b
    first = np.flatnonzero(np.concatenate(([True], ~link)))
    last = np.concatenate((first[1:], [len(order)])) - 1
    s0, s1 = np.divmod(span[first], base)
    if axis == 1:
        return np.stack([s0, lo[first], s1, hi[last]], axis=1)
    return np.stack([lo[first], s0, hi[last], s1], axis=1)


def merge_rects(boxes: np.ndarray, method: MergeMethod = "paper") -> np.ndarray:
    """Merge disjoint free rectangles (the paper's ``merge_adjacent_nodes``).

    Args:
        boxes: (n, 4) int cell boxes ``[i0, j0, i1, j1)`` with disjoint interiors
            (e.g. the free quadtree leaves).
        method: ``"paper"``: full-edge merges in alternating x / y chain passes, starting
            with x (see the module docstring for the exact order).

    Returns:
        (R, 4) int64 merged boxes sorted by ``(i0, j0)``; no two of them share a complete
        edge, and they cover exactly the cells of ``boxes``.
    """
    if method not in MERGE_METHODS:
        raise ValueError(f"method must be one of {MERGE_METHODS}, got {method!r}")
    b = _check_boxes(boxes)
    base = int(b[:, 2:].max()) + 1 if len(b) else 1
    axis, passes = 1, 0
    while len(b) > 1:
        merged = _merge_chains(b, axis, base)
        changed = len(merged) != len(b)
        b = merged
        passes += 1
        if not changed and passes > 1:
            break
        axis = 1 - axis
    return b[np.argsort(b[:, 0] * base + b[:, 1])]


def _touching(a_far: np.ndarray, a_s0: np.ndarray, a_s1: np.ndarray,
              b_near: np.ndarray, b_s0: np.ndarray, b_s1: np.ndarray, base: int):
    """Pairs (a, b) with ``a_far == b_near`` and spans ``[s0, s1)`` overlapping by > 0.

    The near sides at one coordinate belong to rectangles with disjoint interiors, so their
    spans are disjoint and, sorted by start, also sorted by end: the partners of ``a`` are a
    contiguous run found with two binary searches.
    """
    key = b_near * base + b_s0
    order = np.argsort(key)
    key_start = key[order]
    key_end = key_start + (b_s1 - b_s0)[order]
    # Queries in sorted order make the binary searches cache-friendly.
    query = a_far * base + a_s0
    a_order = np.argsort(query)
    query = query[a_order]
    lo = np.searchsorted(key_end, query, side="right")
    hi = np.searchsorted(key_start, query + (a_s1 - a_s0)[a_order], side="left")
    n = np.maximum(hi - lo, 0)
    total = int(n.sum())
    a = np.repeat(a_order, n)
    pos = np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(total)
    return a, order[pos]


def connectivity(boxes: np.ndarray, origin, resolution: float) -> SafeAreas:
    """Connectivity graph of disjoint rectangles, in world coordinates.

    Args:
        boxes: (R, 4) int cell boxes ``[i0, j0, i1, j1)`` with disjoint interiors.
        origin: (2,) [m] world x, y of the grid's lower-left corner.
        resolution: [m] cell edge length.

    Returns:
        :class:`SafeAreas` with ``rects[k]`` the world rectangle of ``boxes[k]`` and one
        edge for each pair sharing a boundary segment of positive length, sorted
        lexicographically; ``weights`` are centre distances [m]; each portal runs along the
        shared segment, from its lower-left end.
    """
    b = _check_boxes(boxes)
    h = float(resolution)
    ox, oy = (float(v) for v in np.asarray(origin, dtype=float))
    i0, j0, i1, j1 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    base = int(max(b[:, 2].max(), b[:, 3].max()) + 1) if len(b) else 1
    # Side by side along x: a's right side is b's left side.
    ax, bx = _touching(j1, i0, i1, j0, i0, i1, base)
    # One above the other: a's top side is b's bottom side.
    ay, by = _touching(i1, j0, j1, i0, j0, j1, base)
    px = np.empty((len(ax), 2, 2))
    px[:, :, 0] = (ox + h * j1[ax])[:, None]
    px[:, 0, 1] = oy + h * np.maximum(i0[ax], i0[bx])
    px[:, 1, 1] = oy + h * np.minimum(i1[ax], i1[bx])
    py = np.empty((len(ay), 2, 2))
    py[:, :, 1] = (oy + h * i1[ay])[:, None]
    py[:, 0, 0] = ox + h * np.maximum(j0[ay], j0[by])
    py[:, 1, 0] = ox + h * np.minimum(j1[ay], j1[by])
    first = np.concatenate([ax, ay])
    second = np.concatenate([bx, by])
    edges = np.stack([np.minimum(first, second), np.maximum(first, second)], axis=1)
    portals = np.concatenate([px, py])
    order = np.argsort(edges[:, 0] * max(len(b), 1) + edges[:, 1])
    edges, portals = edges[order], portals[order]
    rects = np.stack([ox + h * j0, oy + h * i0, ox + h * j1, oy + h * i1], axis=1).astype(float)
    centre = 0.5 * (rects[:, :2] + rects[:, 2:])
    weights = np.linalg.norm(centre[edges[:, 0]] - centre[edges[:, 1]], axis=1)
    return SafeAreas(rects=rects, edges=edges.astype(np.int64), weights=weights, portals=portals)


def locate(areas: SafeAreas, points, tol: float = 0.0) -> np.ndarray:
    """Index of a safe area containing each point.

    Args:
        areas: the safe areas.
        points: (K, 2) [m] world x, y (a single (2,) point is accepted too).
        tol: [m] >= 0; a point counts as inside a rectangle grown by ``tol`` on every side.

    Returns:
        (K,) int64 index of the lowest-numbered rectangle (closed) containing each point,
        -1 where none does (or the point is not finite); a plain ``int`` for a (2,) point.
    """
    p = np.asarray(points, dtype=float)
    single = p.ndim == 1
    p = p.reshape(-1, 2)
    if not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"tol must be finite and >= 0 [m], got {tol!r}")
    r = np.asarray(areas.rects, dtype=float)
    out = np.full(len(p), -1, dtype=np.int64)
    if len(r) and len(p):
        chunk = max(1, 1_000_000 // len(r))
        for s in range(0, len(p), chunk):
            q = p[s:s + chunk]
            inside = ((q[:, None, 0] >= r[None, :, 0] - tol) & (q[:, None, 0] <= r[None, :, 2] + tol)
                      & (q[:, None, 1] >= r[None, :, 1] - tol) & (q[:, None, 1] <= r[None, :, 3] + tol))
            hit = inside.any(axis=1)
            out[s:s + chunk] = np.where(hit, inside.argmax(axis=1), -1)
    return int(out[0]) if single else out


@dataclass(frozen=True)
class SafeAreaMap:
    """Everything the mapping stage produces from one occupancy grid.

    Attributes:
        grid: the occupancy grid the map was built from.
        leaves: the quadtree leaves.
        boxes: (R, 4) int64 cell boxes ``[i0, j0, i1, j1)`` of the merged safe areas
            (``areas.rects[k]`` is ``boxes[k]`` in metres).
        areas: the merged safe rectangles and their connectivity graph.
        min_cell: [cells] quadtree minimum node size used.
        merge: merge method used.
        timing_ms: [ms] wall time of each stage: ``quadtree``, ``merge``, ``graph``, ``total``,
            plus ``rasterise`` when the grid was rasterised by :func:`sanav_mj.mapping.build_map`
            (``total`` then includes it).
    """

    grid: OccupancyGrid
    leaves: QuadtreeLeaves
    boxes: np.ndarray
    areas: SafeAreas
    min_cell: int
    merge: str
    timing_ms: dict[str, float] = field(default_factory=dict)

    @property
    def rects(self) -> np.ndarray:
        """(R, 4) [m] the merged safe rectangles ``[xmin, ymin, xmax, ymax]`` (``areas.rects``)."""
        return self.areas.rects

    def to_json(self) -> dict:
        """The mapping part of the ``areas --json`` document (docs/outputs.md): plain Python types.

        Keys: ``grid`` (resolution, origin, shape, inflation), ``leaves`` (free, occupied),
        ``rects`` [[xmin, ymin, xmax, ymax], ...] [m], ``edges`` [[i, j, weight_m], ...],
        ``timing_ms``.
        """
        g = self.grid
        return {
            "grid": {
                "resolution": float(g.resolution),
                "origin": [float(v) for v in g.origin],
                "shape": [int(v) for v in g.shape],
                "inflation": float(g.inflation),
            },
            "leaves": {"free": self.leaves.n_free, "occupied": self.leaves.n_occupied},
            "rects": self.areas.rects.tolist(),
            "edges": [[int(i), int(j), float(w)] for (i, j), w in zip(self.areas.edges, self.areas.weights)],
            "timing_ms": {k: float(v) for k, v in self.timing_ms.items()},
        }


def build_safe_areas(grid: OccupancyGrid, min_cell: int = 1, merge: MergeMethod = "paper") -> SafeAreaMap:
    """Quadtree, merge and connectivity graph of an occupancy grid (paper Algorithm 1).

    Args:
        grid: the occupancy grid.
        min_cell: [cells] quadtree minimum node size (see :func:`build_quadtree`).
        merge: merge method (see :func:`merge_rects`).

    Returns:
        The safe-area map; ``timing_ms`` has keys ``quadtree``, ``merge``, ``graph``, ``total``.
    """
    if merge not in MERGE_METHODS:
        raise ValueError(f"merge must be one of {MERGE_METHODS}, got {merge!r}")
    t0 = time.perf_counter()
    leaves = build_quadtree(grid.occupied, min_cell)
    t1 = time.perf_counter()
    boxes = merge_rects(leaves.boxes[leaves.free], merge)
    t2 = time.perf_counter()
    areas = connectivity(boxes, grid.origin, grid.resolution)
    t3 = time.perf_counter()
    timing = {
        "quadtree": 1e3 * (t1 - t0),
        "merge": 1e3 * (t2 - t1),
        "graph": 1e3 * (t3 - t2),
        "total": 1e3 * (t3 - t0),
    }
    return SafeAreaMap(grid=grid, leaves=leaves, boxes=boxes, areas=areas,
                       min_cell=int(min_cell), merge=merge, timing_ms=timing)
