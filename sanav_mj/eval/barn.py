"""BARN metric (Perille et al. 2020; ICRA BARN Challenge) and the world measures it needs.

Per run: ``score = success * t_opt / clip(t, 2 t_opt, 8 t_opt)`` with ``t`` the run's
simulated time to the goal and ``t_opt = L / 2 m/s``; the best possible score is 0.5.

``L`` (:func:`optimal_path_length`) is the length of the shortest path of the robot's
reference point from start to goal that keeps the footprint's **inscribed** disc clear of
every obstacle, found by Dijkstra on a 16-connected grid of cell centres (``resolution``,
default 0.02 m) whose free cells have their centre at least the inscribed radius from every
obstacle and a move is allowed only when the cells it crosses are free too. Every motion of
the real footprint keeps its inscribed disc clear, so up to the grid (16-connected moves are
at most 2.7 % longer than the straight line; the centre test may let a path graze an obstacle
by half a cell) ``L`` is a lower bound of the real shortest path, i.e. ``t_opt`` is not
flattering. The workspace edge counts like an obstacle for the reference point only.

:func:`widest_disc` is the largest disc radius whose centre can travel from start to goal
(bisection on a clearance grid): the passage half-width the world demands of a disc robot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from sanav_mj.scene import Obstacle

#: BARN's nominal speed for the optimal time [m/s].
BARN_SPEED = 2.0


def barn_score(success: bool, time_s: float, t_opt: float) -> float:
    """BARN score of one run: ``success * t_opt / clip(time_s, 2 t_opt, 8 t_opt)``, in [0, 0.5].

    Args:
        success: whether the run reached the goal without collision.
        time_s: [s] time to the goal (ignored when not successful).
        t_opt: [s] optimal time, > 0.
    """
    if not (math.isfinite(t_opt) and t_opt > 0):
        raise ValueError(f"t_opt must be a finite number > 0 [s], got {t_opt!r}")
    if not success:
        return 0.0
    return float(t_opt / min(max(float(time_s), 2.0 * t_opt), 8.0 * t_opt))


def clearance_grid(obstacles: Sequence[Obstacle], bounds, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Distance [m] from each cell centre to the nearest obstacle footprint (exact per geom).

    Args:
        obstacles: obstacles.
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        resolution: [m] cell size.

    Returns:
        dist: (ny, nx) [m] (``inf`` without obstacles); centres: (ny, nx, 2) [m].
    """
    b = np.asarray(bounds, dtype=float)
    nx = max(1, int(math.floor((b[2] - b[0]) / resolution + 1e-9)))
    ny = max(1, int(math.floor((b[3] - b[1]) / resolution + 1e-9)))
    xs = b[0] + (np.arange(nx) + 0.5) * resolution
    ys = b[1] + (np.arange(ny) + 0.5) * resolution
    pts = np.stack(np.meshgrid(xs, ys), axis=-1)
    flat = pts.reshape(-1, 2)
    dist = np.full(flat.shape[0], np.inf)
    by_radius: dict[float, list[np.ndarray]] = {}
    for ob in obstacles:
        if ob.kind in ("cylinder", "capsule"):  # discs: nearest centre via a k-d tree, same value
            by_radius.setdefault(float(ob.half_size[0]), []).append(np.asarray(ob.center, dtype=float))
        else:
            np.minimum(dist, ob.signed_distance(flat), out=dist)
    for r, centres in by_radius.items():
        np.minimum(dist, cKDTree(np.array(centres)).query(flat)[0] - r, out=dist)
    return dist.reshape(ny, nx), pts


def _cell(p, bounds, resolution, shape) -> tuple[int, int]:
    b = np.asarray(bounds, dtype=float)
    j = min(max(int(math.floor((float(p[0]) - b[0]) / resolution)), 0), shape[1] - 1)
    i = min(max(int(math.floor((float(p[1]) - b[1]) / resolution)), 0), shape[0] - 1)
    return i, j


def optimal_path_length(obstacles: Sequence[Obstacle], bounds, start, goal, clearance: float,
                        resolution: float = 0.02) -> float:
    """Shortest start-goal path [m] of a point keeping ``clearance`` from every obstacle
    (see the module docstring); ``inf`` when there is none.

    Args:
        obstacles: obstacles.
        bounds: (4,) [m] workspace.
        start, goal: (2,) [m].
        clearance: [m] the footprint's inscribed radius for the BARN metric.
        resolution: [m] grid cell size.
    """
    dist, _ = clearance_grid(obstacles, bounds, resolution)
    free = dist >= clearance
    ny, nx = free.shape
    idx = np.arange(ny * nx).reshape(ny, nx)
    rows, cols, w = [], [], []
    moves = [(0, 1), (1, 0), (1, 1), (1, -1), (1, 2), (2, 1), (1, -2), (2, -1)]
    for di, dj in moves:
        # cells (i, j) -> (i + di, j + dj); crossed cells: those of the straight segment
        i0, i1 = 0, ny - di
        j0, j1 = max(0, -dj), nx - max(0, dj)
        ok = free[i0:i1, j0:j1] & free[i0 + di:i1 + di, j0 + dj:j1 + dj]
        if abs(di) + abs(dj) > 1:
            # the segment also passes through these cells (no corner cutting)
            crossed = {(1, 1): [(0, 1), (1, 0)], (1, -1): [(0, -1), (1, 0)],
                       (1, 2): [(0, 1), (1, 1)], (2, 1): [(1, 0), (1, 1)],
                       (1, -2): [(0, -1), (1, -1)], (2, -1): [(1, 0), (1, -1)]}[(di, dj)]
            for ci, cj in crossed:
                ok &= free[i0 + ci:i1 + ci, j0 + cj:j1 + cj]
        a = idx[i0:i1, j0:j1][ok]
        rows.append(a)
        cols.append(a + di * nx + dj)
        w.append(np.full(a.size, resolution * math.hypot(di, dj)))
    r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
    graph = sparse.csr_matrix((ww, (r, c)), shape=(ny * nx, ny * nx))
    s = _cell(start, bounds, resolution, free.shape)
    g = _cell(goal, bounds, resolution, free.shape)
    if not (free[s] and free[g]):
        return math.inf
    d = dijkstra(graph, directed=False, indices=int(idx[s]))
    length = float(d[idx[g]])
    if not math.isfinite(length):
        return math.inf
    # the grid path runs between cell centres; add the endpoint offsets
    _, pts = clearance_grid((), bounds, resolution)
    return length + float(np.hypot(*(pts[s] - np.asarray(start[:2])))) + float(np.hypot(*(pts[g] - np.asarray(goal[:2]))))


def widest_disc(obstacles: Sequence[Obstacle], bounds, start, goal, resolution: float = 0.01,
                tol: float = 1e-3) -> float:
    """Largest disc radius [m] (within ``tol`` and the grid) whose centre can move from start
    to goal along 4-connected cell centres keeping that distance from every obstacle."""
    dist, _ = clearance_grid(obstacles, bounds, resolution)
    s = _cell(start, bounds, resolution, dist.shape)
    g = _cell(goal, bounds, resolution, dist.shape)
    lo, hi = 0.0, float(min(dist[s], dist[g], 10.0))
    if hi <= 0:
        return 0.0
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        labels, _ = ndimage.label(dist >= mid)
        if labels[s] and labels[s] == labels[g]:
            lo = mid
        else:
            hi = mid
    return lo
