"""Slow, plainly written reference implementations for the mapping tests.

Each function here is written independently of the fast code in sanav_mj.mapping (plain
loops, different geometry) so that agreement between the two means something.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from sanav_mj.scene import Obstacle


def _point_box_distance(px: float, py: float, ob: Obstacle) -> float:
    """Distance [m] from a point to a (filled) box at any yaw, in the box's own frame."""
    c, s = math.cos(ob.yaw), math.sin(ob.yaw)
    dx, dy = px - ob.center[0], py - ob.center[1]
    lx, ly = c * dx + s * dy, -s * dx + c * dy
    ox = max(abs(lx) - ob.half_size[0], 0.0)
    oy = max(abs(ly) - ob.half_size[1], 0.0)
    return math.hypot(ox, oy)


def _point_square_distance(px: float, py: float, x0: float, y0: float, x1: float, y1: float) -> float:
    ox = max(x0 - px, 0.0, px - x1)
    oy = max(y0 - py, 0.0, py - y1)
    return math.hypot(ox, oy)


def _separated(poly_a: np.ndarray, poly_b: np.ndarray) -> bool:
    """Separating-axis test for two convex polygons given as (n, 2) vertex lists."""
    for poly in (poly_a, poly_b):
        n = len(poly)
        for k in range(n):
            ex, ey = poly[(k + 1) % n] - poly[k]
            ax, ay = -ey, ex
            pa = [ax * p[0] + ay * p[1] for p in poly_a]
            pb = [ax * p[0] + ay * p[1] for p in poly_b]
            if max(pa) < min(pb) or max(pb) < min(pa):
                return True
    return False


def cell_obstacle_distance(ob: Obstacle, x0: float, y0: float, x1: float, y1: float) -> float:
    """Exact distance [m] between the closed cell square and the (un-inflated) obstacle footprint.

    Boxes: 0 if the two convex polygons overlap (separating-axis test), otherwise the
    smallest vertex-to-polygon distance (for disjoint convex polygons the closest pair
    always involves a vertex of one of them). Discs: distance from the centre to the square
    minus the radius.
    """
    if ob.kind == "box":
        square = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        box = ob.corners()
        if not _separated(square, box):
            return 0.0
        d = min(_point_box_distance(px, py, ob) for px, py in square)
        d = min(d, min(_point_square_distance(px, py, x0, y0, x1, y1) for px, py in box))
        return d
    r = float(ob.half_size[0])
    return max(_point_square_distance(ob.center[0], ob.center[1], x0, y0, x1, y1) - r, 0.0)


def cell_distances(obstacles, origin, resolution, shape) -> np.ndarray:
    """(ny, nx) [m] exact distance from each cell square to the nearest obstacle (inf if none)."""
    ny, nx = shape
    out = np.full((ny, nx), np.inf)
    for i in range(ny):
        for j in range(nx):
            x0 = origin[0] + j * resolution
            y0 = origin[1] + i * resolution
            for ob in obstacles:
                d = cell_obstacle_distance(ob, x0, y0, x0 + resolution, y0 + resolution)
                if d < out[i, j]:
                    out[i, j] = d
    return out


def point_obstacle_distance(ob: Obstacle, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Vectorised exact distance [m] from points to an obstacle footprint (0 inside)."""
    if ob.kind == "box":
        c, s = math.cos(ob.yaw), math.sin(ob.yaw)
        dx, dy = px - ob.center[0], py - ob.center[1]
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        ox = np.maximum(np.abs(lx) - ob.half_size[0], 0.0)
        oy = np.maximum(np.abs(ly) - ob.half_size[1], 0.0)
        return np.hypot(ox, oy)
    return np.maximum(np.hypot(px - ob.center[0], py - ob.center[1]) - ob.half_size[0], 0.0)


def merge_reference(boxes) -> list[tuple[int, int, int, int]]:
    """Plain-loop version of the documented merge order of ``merge_rects(method="paper")``.

    Passes alternate x, y, x, ... starting with x. Within a pass, any two rectangles with the
    same span across the pass direction that touch along it (one's far side is the other's
    near side) are merged pairwise, in whatever order they are found, until none is left;
    a full pass therefore merges every chain completely. Stops at the first pass after the
    first that merges nothing.
    """
    rects = [tuple(int(v) for v in b) for b in boxes]
    axis, passes = 1, 0
    while len(rects) > 1:
        merged_any = False
        again = True
        while again:
            again = False
            for a in range(len(rects)):
                for b in range(len(rects)):
                    if a == b:
                        continue
                    i0, j0, i1, j1 = rects[a]
                    k0, l0, k1, l1 = rects[b]
                    if axis == 1 and (i0, i1) == (k0, k1) and j1 == l0:
                        new = (i0, j0, i1, l1)
                    elif axis == 0 and (j0, j1) == (l0, l1) and i1 == k0:
                        new = (i0, j0, k1, j1)
                    else:
                        continue
                    rects = [r for n, r in enumerate(rects) if n not in (a, b)] + [new]
                    merged_any = again = True
                    break
                if again:
                    break
        passes += 1
        if not merged_any and passes > 1:
            break
        axis = 1 - axis
    return sorted(rects)


def edges_reference(boxes) -> dict[tuple[int, int], tuple[tuple[float, float], tuple[float, float]]]:
    """All pairs i < j of cell boxes sharing a boundary segment of positive length, O(R^2).

    Returns a dict mapping each pair to its shared segment in *cell* coordinates
    ``((x0, y0), (x1, y1))`` with x along columns and y along rows.
    """
    out = {}
    for a in range(len(boxes)):
        i0, j0, i1, j1 = (int(v) for v in boxes[a])
        for b in range(a + 1, len(boxes)):
            k0, l0, k1, l1 = (int(v) for v in boxes[b])
            if j1 == l0 or l1 == j0:  # vertical contact line
                x = j1 if j1 == l0 else j0
                lo, hi = max(i0, k0), min(i1, k1)
                if hi > lo:
                    out[(a, b)] = ((x, lo), (x, hi))
            if i1 == k0 or k1 == i0:  # horizontal contact line
                y = i1 if i1 == k0 else i0
                lo, hi = max(j0, l0), min(j1, l1)
                if hi > lo:
                    out[(a, b)] = ((lo, y), (hi, y))
    return out


@st.composite
def grids(draw, max_side=40):
    """Random occupancy grids of any shape: scattered cells plus a few solid blocks."""
    ny = draw(st.integers(1, max_side))
    nx = draw(st.integers(1, max_side))
    density = draw(st.sampled_from([0.0, 0.02, 0.1, 0.5, 0.95, 1.0]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    occ = rng.random((ny, nx)) < density
    for _ in range(draw(st.integers(0, 3))):
        i, j = rng.integers(0, ny), rng.integers(0, nx)
        occ[i:i + rng.integers(1, 12), j:j + rng.integers(1, 12)] = True
    return occ


def room_scan(pose, angles, box, max_range):
    """Noise-free lidar ranges (B,) [m] and hit flags (B,) from ``pose`` (x, y, yaw) inside an
    axis-aligned room ``box`` = [x0, y0, x1, y1] [m]; beams longer than ``max_range`` return it."""
    x, y, th = pose
    a = th + angles
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (box[2] - x) / c, np.where(c < 0, (box[0] - x) / c, np.inf))
        ty = np.where(s > 0, (box[3] - y) / s, np.where(s < 0, (box[1] - y) / s, np.inf))
    t = np.minimum(tx, ty)
    hit = t <= max_range
    return np.where(hit, t, max_range), hit
