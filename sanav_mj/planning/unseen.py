"""Route weights that prefer space already seen: a route through unknown space is a guess.

The lidar run plans its route on areas where unknown space counts as passable
(:meth:`~sanav_mj.mapping.live_grid.LiveGrid.route_safe`), so the shortest route runs
straight at the goal through whatever has not been seen yet. Among the BARN-like worlds
the largest time lost against the known map is such guesses turning out blocked (the
robot drives into a dead end hidden behind cylinders and comes back; docs/results.md,
"Where the lidar run's time goes"). :func:`penalise_unseen` lengthens every route edge in
proportion to how much of the two areas it joins has not been seen drivable, so a route
through seen free space is taken unless the guess is shorter by more than that.

Only the route's weights change: the route is never followed (the local corridor is
planned on observed-safe areas alone), so the guarantee is untouched.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sanav_mj.mapping.safe_areas import SafeAreas

__all__ = ["unseen_fraction", "penalise_unseen"]


def unseen_fraction(rects: np.ndarray, seen: np.ndarray, origin, resolution: float) -> np.ndarray:
    """Fraction of each rectangle's cells that are not ``seen``.

    Args:
        rects: (R, 4) [m] ``xmin, ymin, xmax, ymax``.
        seen: (ny, nx) bool grid, row = y, column = x, cell (i, j) covering
            ``origin + (j, i) * resolution`` to one cell further.
        origin: (2,) [m] the grid's lower-left corner.
        resolution: [m] cell edge, > 0.

    Returns:
        (R,) float in [0, 1]: the share of the grid cells whose centre lies in the rectangle
        that are not ``seen`` (0 for a rectangle holding no cell centre).
    """
    rects = np.asarray(rects, dtype=float).reshape(-1, 4)
    seen = np.asarray(seen, dtype=bool)
    if seen.ndim != 2:
        raise ValueError(f"unseen_fraction: seen must be a 2-D grid, got shape {seen.shape}")
    if not (np.isfinite(resolution) and resolution > 0):
        raise ValueError(f"unseen_fraction: resolution must be > 0 m, got {resolution!r}")
    ny, nx = seen.shape
    ox, oy = float(origin[0]), float(origin[1])
    # cells whose centre lies inside: j0 = ceil((x0 - ox)/h - 1/2), j1 = floor((x1 - ox)/h - 1/2) + 1
    j0 = np.clip(np.ceil((rects[:, 0] - ox) / resolution - 0.5), 0, nx).astype(np.int64)
    j1 = np.clip(np.floor((rects[:, 2] - ox) / resolution - 0.5) + 1, 0, nx).astype(np.int64)
    i0 = np.clip(np.ceil((rects[:, 1] - oy) / resolution - 0.5), 0, ny).astype(np.int64)
    i1 = np.clip(np.floor((rects[:, 3] - oy) / resolution - 0.5) + 1, 0, ny).astype(np.int64)
    j1, i1 = np.maximum(j1, j0), np.maximum(i1, i0)
    s = np.zeros((ny + 1, nx + 1), dtype=np.int64)
    s[1:, 1:] = np.cumsum(np.cumsum(~seen, axis=0, dtype=np.int64), axis=1)
    unseen = s[i1, j1] - s[i0, j1] - s[i1, j0] + s[i0, j0]
    n = (i1 - i0) * (j1 - j0)
    return np.where(n > 0, unseen / np.maximum(n, 1), 0.0)


def penalise_unseen(areas: SafeAreas, seen: np.ndarray, origin, resolution: float, factor: float) -> SafeAreas:
    """The same areas with each edge's weight multiplied by ``1 + factor * (u_a + u_b) / 2``,
    ``u`` the :func:`unseen_fraction` of the two areas it joins.

    Weights only grow, so A*'s centre-distance heuristic stays admissible and consistent.

    Args:
        areas: route areas with edges and weights [m].
        seen: (ny, nx) bool, True where the cell is seen drivable (e.g. the sensed map's
            safe grid); see :func:`unseen_fraction` for the layout.
        origin: (2,) [m]; resolution: [m].
        factor: >= 0, dimensionless; 0 returns ``areas`` itself. With factor 1 a route edge
            through wholly unseen areas counts twice its length.

    Raises:
        ValueError: negative or non-finite ``factor``.
    """
    if not (isinstance(factor, (int, float)) and np.isfinite(factor) and factor >= 0):
        raise ValueError(f"penalise_unseen: factor must be a finite number >= 0, got {factor!r}")
    if factor == 0 or len(areas.weights) == 0:
        return areas
    u = unseen_fraction(np.asarray(areas.rects, dtype=float), seen, origin, resolution)
    e = np.asarray(areas.edges, dtype=int)
    scale = 1.0 + factor * 0.5 * (u[e[:, 0]] + u[e[:, 1]])
    return replace(areas, weights=np.asarray(areas.weights, dtype=float) * scale)
