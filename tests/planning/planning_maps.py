"""Hand-built safe-area maps for the planning tests (no dependency on the mapping stage).

``areas_from_rects`` finds adjacency by brute force over all rectangle pairs;
``grid_to_rects`` merges the free cells of a boolean grid into rectangles greedily (row runs
extended upwards), which is all the tests need: disjoint rectangles covering the free cells.
"""

from __future__ import annotations

import numpy as np

from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.scene import RobotParams

ROBOT = RobotParams(
    wheel_radius=0.1, track=0.38, footprint_radius=0.33, wheel_speed_max=20.0,
    v_max=2.0, w_max=3.0, a_max=1.5, alpha_max=6.0,
)


def areas_from_rects(rects) -> SafeAreas:
    """SafeAreas for (R, 4) rectangles: edges where two share a boundary segment of positive
    length, weights = centre distance, portals = the shared segment (low end first)."""
    r = np.asarray(rects, dtype=float).reshape(-1, 4)
    edges, weights, portals = [], [], []
    for i in range(len(r)):
        for j in range(i + 1, len(r)):
            a, b = r[i], r[j]
            seg = None
            if a[2] == b[0] or b[2] == a[0]:
                x = a[2] if a[2] == b[0] else a[0]
                lo, hi = max(a[1], b[1]), min(a[3], b[3])
                if hi > lo:
                    seg = [[x, lo], [x, hi]]
            if seg is None and (a[3] == b[1] or b[3] == a[1]):
                y = a[3] if a[3] == b[1] else a[1]
                lo, hi = max(a[0], b[0]), min(a[2], b[2])
                if hi > lo:
                    seg = [[lo, y], [hi, y]]
            if seg is not None:
                edges.append([i, j])
                ca = 0.5 * (a[:2] + a[2:])
                cb = 0.5 * (b[:2] + b[2:])
                weights.append(float(np.hypot(*(ca - cb))))
                portals.append(seg)
    return SafeAreas(
        rects=r,
        edges=np.asarray(edges, dtype=np.int64).reshape(-1, 2),
        weights=np.asarray(weights, dtype=float),
        portals=np.asarray(portals, dtype=float).reshape(-1, 2, 2),
    )


def grid_to_rects(free: np.ndarray, res: float = 1.0, origin=(0.0, 0.0)) -> np.ndarray:
    """Greedy rectangle cover of the True cells of ``free`` (ny, nx); (R, 4) [m]."""
    free = np.asarray(free, dtype=bool)
    ny, nx = free.shape
    used = np.zeros_like(free)
    out = []
    for i in range(ny):
        for j in range(nx):
            if not free[i, j] or used[i, j]:
                continue
            j2 = j
            while j2 + 1 < nx and free[i, j2 + 1] and not used[i, j2 + 1]:
                j2 += 1
            i2 = i
            while i2 + 1 < ny and np.all(free[i2 + 1, j : j2 + 1]) and not np.any(used[i2 + 1, j : j2 + 1]):
                i2 += 1
            used[i : i2 + 1, j : j2 + 1] = True
            out.append([origin[0] + j * res, origin[1] + i * res, origin[0] + (j2 + 1) * res, origin[1] + (i2 + 1) * res])
    return np.asarray(out, dtype=float).reshape(-1, 4)


def in_union(rects: np.ndarray, pts: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """(K,) bool: point k lies in some rectangle."""
    r = np.asarray(rects)[None]
    p = np.asarray(pts)[:, None]
    return np.any(
        (p[..., 0] >= r[..., 0] - tol) & (p[..., 0] <= r[..., 2] + tol)
        & (p[..., 1] >= r[..., 1] - tol) & (p[..., 1] <= r[..., 3] + tol),
        axis=1,
    )


def clutter_areas(seed: int, side: float = 6.0, count: int = 6, resolution: float = 0.05):
    """Safe areas of the real mapping stage on a seeded random box/cylinder clutter map.

    Returns ``(areas, free_points)``: the SafeAreas and (K, 2) [m] centres of its rectangles
    (points that are certainly free, to draw start and goal from)."""
    from sanav_mj.mapping import MapConfig, build_map
    from sanav_mj.scene import Obstacle

    rng = np.random.default_rng(seed)
    obstacles = []
    for k in range(count):
        c = rng.uniform(0.0, side, 2)
        if rng.random() < 0.7:
            obstacles.append(Obstacle(f"b{k}", "box", c, float(rng.uniform(-np.pi, np.pi)), rng.uniform(0.1, 0.7, 2), 0.5, -1))
        else:
            r = float(rng.uniform(0.1, 0.5))
            obstacles.append(Obstacle(f"c{k}", "cylinder", c, 0.0, np.array([r, r]), 0.5, -1))
    m = build_map(obstacles, np.array([0.0, 0.0, side, side]), 0.35, MapConfig(resolution=resolution))
    rects = np.asarray(m.areas.rects)
    return m.areas, 0.5 * (rects[:, :2] + rects[:, 2:])
