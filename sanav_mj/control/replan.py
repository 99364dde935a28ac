"""Replans in motion that keep the rectangles the robot is using (lidar mode, issue 16).

When the sensed map changes, :class:`~sanav_mj.control.sensing.SensingSAMPC` replans its
corridor on the current safe areas. The incremental safe areas re-cut the rectangles around
every changed cell, so a corridor planned on them from scratch can start with boxes other
than the ones the robot's current plan runs through: the shifted previous plan (the MPC's
warm start, which ends at rest) then leaves the new stage boxes by centimetres, and the
solver runs into its iteration limit before the step brakes (docs/benchmarks.md, "Where the
per-step time goes"). Here the replan keeps them:

1. :func:`kept_prefix`: the rectangles of the corridor being followed that hold the
   predicted positions of the robot's current plan, from the first to the last, each
   re-verified in the current map: kept as it is while every cell is still safe; a
   rectangle with unsafe cells is replaced by safe sub-rectangles covering the predicted
   positions inside it in order (each grown within the old rectangle from the cells of the
   first position the last one misses and of the one before it, so they overlap), and the
   prefix ends at the first position no safe sub-rectangle can hold. Consecutive kept rectangles must overlap
   or share a boundary segment (as corridor areas do).
2. :func:`prefixed_areas`: the current safe areas with the kept rectangles placed first
   (so the planner, which starts in the lowest-numbered area holding the start, starts in
   them), linked as a chain, the last one linked to every current area it overlaps; the
   planner's corridor then runs through the kept rectangles and on through the current
   areas, and the MPC's chain starts with the members the shifted plan lies in.

Safety is unchanged: every kept rectangle holds only cells that are safe in the current map
(observed free, no occupied or unknown cell within the inflation radius), checked here
against the grid's counts, so the MPC's boxes are still observed free space.
"""

from __future__ import annotations

import numpy as np

from sanav_mj.mapping.grow import FreeCells, grow_rect
from sanav_mj.mapping.safe_areas import SafeAreas

__all__ = ["kept_prefix", "prefixed_areas", "rect_cells", "rects_safe"]

_TOL = 1e-9


def rect_cells(rects: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    """(K, 4) int64 cell boxes ``[i0, j0, i1, j1)`` of world rectangles (K, 4) [m] lying on
    the grid's cell boundaries (``origin`` (2,) [m] lower-left corner, ``resolution`` [m])."""
    r = np.asarray(rects, dtype=float).reshape(-1, 4)
    u = np.stack([(r[:, 1] - origin[1]), (r[:, 0] - origin[0]), (r[:, 3] - origin[1]), (r[:, 2] - origin[0])],
                 axis=1) / resolution
    return np.rint(u).astype(np.int64)


def rects_safe(blocked: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(K,) bool: each cell box (K, 4) ``[i0, j0, i1, j1)`` is non-empty, inside the grid and
    holds no cell with a non-zero ``blocked`` count ((ny, nx): non-free cells within the
    inflation radius, :attr:`LiveGrid.blocked`)."""
    ny, nx = blocked.shape
    out = np.zeros(len(cells), dtype=bool)
    for k, (i0, j0, i1, j1) in enumerate(np.asarray(cells, dtype=np.int64).reshape(-1, 4)):
        if 0 <= i0 < i1 <= ny and 0 <= j0 < j1 <= nx:
            out[k] = not blocked[i0:i1, j0:j1].any()
    return out


def _connected(a: np.ndarray, b: np.ndarray) -> bool:
    """Rectangles (4,) [m] overlap with positive area or share a boundary segment of positive length."""
    w = np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2])
    return bool((w > _TOL).all() or (abs(w[0]) <= _TOL < w[1]) or (abs(w[1]) <= _TOL < w[0]))


def _inside(a: np.ndarray, b: np.ndarray) -> bool:
    """Rectangle ``a`` (4,) lies in rectangle ``b`` (4,) (within 1e-9 m)."""
    return bool((a[:2] >= b[:2] - _TOL).all() and (a[2:] <= b[2:] + _TOL).all())


def _shrunk(blocked: np.ndarray, box: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
    """A cell box inside ``box`` (4,) ``[i0, j0, i1, j1)`` holding the cell box ``seed`` (4,)
    with only safe cells (``blocked == 0``): ``seed`` grown side by side within ``box``
    (:func:`~sanav_mj.mapping.grow.grow_rect`); None when ``seed`` itself holds an unsafe cell."""
    i0, j0, i1, j1 = (int(v) for v in box)
    win = np.asarray(blocked[i0:i1, j0:j1] != 0, dtype=np.int64)
    sat = np.zeros((win.shape[0] + 1, win.shape[1] + 1), dtype=np.int64)
    sat[1:, 1:] = win.cumsum(axis=0).cumsum(axis=1)
    cells = FreeCells(sat, np.array([float(j0), float(i0)]), 1.0, limit=float(max(win.shape)))
    s = np.asarray(seed, dtype=np.int64)
    if cells.occupied_in(s[0] - i0, s[1] - j0, s[2] - i0, s[3] - j0):
        return None
    g = grow_rect(cells, np.array([s[1], s[0], s[3], s[2]], dtype=float))  # x = column, y = row
    return np.rint([g[1], g[0], g[3], g[2]]).astype(np.int64)


def _cover(blocked: np.ndarray, box: np.ndarray, pts: np.ndarray, origin: np.ndarray, resolution: float
           ) -> tuple[list[np.ndarray], bool]:
    """Safe cell boxes inside ``box`` (4,) ``[i0, j0, i1, j1)`` covering the points ``pts``
    (M, 2) [m] in order: one box grown from their bounding cells when that holds only safe
    cells, else each box grown (:func:`_shrunk`) from the cells of the first point
    the last box misses and of the point before it (so consecutive boxes overlap); and
    whether every point is covered (False: the cover stops at the first point whose seed
    holds an unsafe cell)."""
    c = np.floor((pts - origin) / resolution).astype(np.int64)[:, ::-1]  # (row, column) per point
    c = np.clip(c, box[:2], box[2:] - 1)
    whole = _shrunk(blocked, box, np.concatenate([c.min(axis=0), c.max(axis=0) + 1])) if len(c) else None
    if whole is not None:  # one box holds them all
        return [whole], True
    out: list[np.ndarray] = []
    prev = None
    for cell in c:
        if out and (cell >= out[-1][:2]).all() and (cell < out[-1][2:]).all():
            prev = cell
            continue
        lo = cell if prev is None else np.minimum(cell, prev)
        hi = cell if prev is None else np.maximum(cell, prev)
        g = _shrunk(blocked, box, np.concatenate([lo, hi + 1]))
        if g is None:
            return out, False
        out.append(g)
        prev = cell
    return out, True


def kept_prefix(corridor_rects: np.ndarray, predicted: np.ndarray, blocked: np.ndarray, origin,
                resolution: float) -> np.ndarray:
    """The rectangles of the corridor being followed to keep at a replan (module docstring).

    Args:
        corridor_rects: (C, 4) [m] the corridor rectangles in use (on cell boundaries).
        predicted: (P, 2) [m] the predicted positions of the robot's current plan (the
            shifted plan the MPC will warm-start from), the robot's position first.
        blocked: (ny, nx) non-free cells within the inflation radius of each cell of the
            current map (0: safe; :attr:`LiveGrid.blocked`).
        origin: (2,) [m] the grid's lower-left corner; resolution: [m] its cell edge.

    Returns:
        (K, 4) [m] rectangles, K >= 0, every one made of cells safe in ``blocked``,
        consecutive ones overlapping or sharing a boundary segment, the first holding the
        first predicted position; empty when nothing can be kept (no predicted position in
        the corridor, or the robot's own rectangle has no safe part holding its positions).
    """
    rects = np.asarray(corridor_rects, dtype=float).reshape(-1, 4)
    pts = np.asarray(predicted, dtype=float).reshape(-1, 2)
    empty = np.zeros((0, 4))
    if len(rects) == 0 or len(pts) == 0 or not np.all(np.isfinite(pts)):
        return empty
    inside = ((pts[:, None, 0] >= rects[None, :, 0] - _TOL) & (pts[:, None, 0] <= rects[None, :, 2] + _TOL)
              & (pts[:, None, 1] >= rects[None, :, 1] - _TOL) & (pts[:, None, 1] <= rects[None, :, 3] + _TOL))
    if not inside[0].any():
        return empty
    a = int(np.argmax(inside[0]))
    used = np.flatnonzero(inside.any(axis=0))
    b = int(used[used >= a].max())
    origin = np.asarray(origin, dtype=float)
    cells = rect_cells(rects[a:b + 1], origin, resolution)
    ok = rects_safe(blocked, cells)
    out: list[np.ndarray] = []
    for k in range(b + 1 - a):
        if ok[k]:
            pieces, whole = [rects[a + k]], True
        else:
            boxes, whole = _cover(blocked, cells[k], pts[inside[:, a + k]], origin, resolution)
            pieces = [np.array([origin[0] + resolution * c[1], origin[1] + resolution * c[0],
                                origin[0] + resolution * c[3], origin[1] + resolution * c[2]]) for c in boxes]
        for r in pieces:
            if out and _inside(r, out[-1]):
                continue  # adds no room the chain does not have (e.g. the same rectangle again)
            if out and _inside(out[-1], r):
                out[-1] = r  # holds the last one, so it meets the one before as that did
                continue
            if out and not _connected(out[-1], r):
                return np.array(out).reshape(-1, 4)
            out.append(r)
        if not whole:
            break
    return np.array(out).reshape(-1, 4)


def _portal(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(2, 2) [m] a segment inside both connected rectangles (4,) crossing from ``a`` to ``b``:
    their shared boundary segment when they only touch; when they overlap, the middle of the
    overlap across the direction from ``a``'s centre to ``b``'s."""
    lo, hi = np.maximum(a[:2], b[:2]), np.minimum(a[2:], b[2:])
    w = hi - lo
    if abs(w[0]) <= _TOL:
        return np.array([[lo[0], lo[1]], [lo[0], hi[1]]])
    if abs(w[1]) <= _TOL:
        return np.array([[lo[0], lo[1]], [hi[0], lo[1]]])
    d = 0.5 * (b[:2] + b[2:]) - 0.5 * (a[:2] + a[2:])
    mid = 0.5 * (lo + hi)
    if abs(d[0]) >= abs(d[1]):  # travelling along x: a vertical segment
        return np.array([[mid[0], lo[1]], [mid[0], hi[1]]])
    return np.array([[lo[0], mid[1]], [hi[0], mid[1]]])


def prefixed_areas(areas: SafeAreas, boxes: np.ndarray, kept: np.ndarray, origin,
                   resolution: float) -> tuple[SafeAreas, np.ndarray]:
    """The current safe areas with the ``kept`` rectangles first (module docstring).

    Args:
        areas: the current safe areas (R rectangles).
        boxes: (R, 4) int64 their cell boxes ``[i0, j0, i1, j1)``.
        kept: (K, 4) [m] rectangles from :func:`kept_prefix`, K >= 1.
        origin: (2,) [m], resolution: [m] the grid's lower-left corner and cell edge.

    Returns:
        ``(areas', boxes')``: K + R rectangles, the kept ones at indices 0..K-1 linked as a
        chain (edge k, k+1), the last kept one linked to every current area it overlaps with
        positive area or shares a boundary segment with, except those inside it (a detour
        through an area that adds no room), the current areas at K..K+R-1 with their own edges; weights are the
        centre distances, portals segments inside both rectangles of each edge
        (:func:`_portal`); and the (K + R, 4) cell boxes.
    """
    kept = np.asarray(kept, dtype=float).reshape(-1, 4)
    k = len(kept)
    rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
    last = kept[-1]
    w = np.minimum(rects[:, 2:], last[2:]) - np.maximum(rects[:, :2], last[:2])
    meet = ((w > _TOL).all(axis=1) | ((np.abs(w[:, 0]) <= _TOL) & (w[:, 1] > _TOL))
            | ((np.abs(w[:, 1]) <= _TOL) & (w[:, 0] > _TOL)))
    within = (rects[:, :2] >= last[:2] - _TOL).all(axis=1) & (rects[:, 2:] <= last[2:] + _TOL).all(axis=1)
    over = np.flatnonzero(meet & ~within)
    pairs = [(i, i + 1) for i in range(k - 1)] + [(k - 1, k + int(j)) for j in over]
    all_rects = np.vstack([kept, rects])
    new_portals = np.array([_portal(all_rects[i], all_rects[j]) for i, j in pairs]).reshape(-1, 2, 2)
    new_edges = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    centres = 0.5 * (all_rects[:, :2] + all_rects[:, 2:])
    new_w = np.linalg.norm(centres[new_edges[:, 0]] - centres[new_edges[:, 1]], axis=1)
    edges = np.vstack([new_edges, np.asarray(areas.edges, dtype=np.int64).reshape(-1, 2) + k])
    weights = np.concatenate([new_w, np.asarray(areas.weights, dtype=float).reshape(-1)])
    portals = np.concatenate([new_portals, np.asarray(areas.portals, dtype=float).reshape(-1, 2, 2)])
    out_boxes = np.vstack([rect_cells(kept, np.asarray(origin, dtype=float), resolution),
                           np.asarray(boxes, dtype=np.int64).reshape(-1, 4)])
    return SafeAreas(all_rects, edges, weights, portals), out_boxes
