"""Corridor search, goal projection and portal waypoints (paper Sec. III-C, "Waypoints").

Given the merged safe rectangles and their connectivity graph (:class:`SafeAreas`), this
module

1. finds the safe area of the start and of the goal (the containing one, or the nearest by
   point-to-rectangle distance when the point lies outside every area),
2. projects a goal that lies outside the safe areas onto the nearest area *reachable* from
   the start area, moved inwards by a small offset (:func:`project_into_rect`),
3. finds the shortest sequence of adjacent areas (the corridor) through the graph, with
   Dijkstra (``scipy.sparse.csgraph``, the planner's default) or A* (heapq, pure Python) on
   the centre-distance edge weights. Measured (scripts/bench_planning.py): A* is ahead by
   about 0.05 ms on maps of 30-50 areas, Dijkstra by 0.1-0.2 ms at 200-500 areas and by
   about 1 ms at 3000 areas, where A* expands most of the graph,
4. chooses the waypoints: one crossing point on every portal (shared edge) between
   consecutive corridor areas, giving the shortest polyline whose crossings keep a
   clearance from the portal ends (:func:`portal_waypoints`).

Safety of the waypoint polyline: waypoint ``k`` (``1 <= k <= C-1``) lies on the portal
between corridor areas ``k-1`` and ``k``, i.e. on the closed boundary of both; waypoint 0
(start) lies in area 0 and the last waypoint (goal) in area ``C-1``. So segment ``k``
(from waypoint ``k`` to ``k+1``) has both endpoints in the closed, convex rectangle of
corridor area ``k`` and lies entirely inside it. The whole polyline lies in the union of
the corridor's rectangles, whatever crossing points are chosen on the portals; the
optimisation only makes it short.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_array
from scipy.sparse.csgraph import breadth_first_order, dijkstra

from sanav_mj.mapping.safe_areas import SafeAreas

CONTAIN_TOL = 1e-9
"""[m] a point within this distance outside a rectangle's closed boundary counts as inside."""


# --------------------------------------------------------------------------------------
# point / rectangle geometry
# --------------------------------------------------------------------------------------


def rect_distance(rects: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Euclidean distance from ``point`` to each closed rectangle (0 inside).

    Args:
        rects: (R, 4) [m] ``xmin, ymin, xmax, ymax``.
        point: (2,) [m].

    Returns:
        (R,) [m] distances.
    """
    r = np.asarray(rects, dtype=float)
    dx = np.maximum(np.maximum(r[:, 0] - point[0], point[0] - r[:, 2]), 0.0)
    dy = np.maximum(np.maximum(r[:, 1] - point[1], point[1] - r[:, 3]), 0.0)
    return np.hypot(dx, dy)


def contains(rects: np.ndarray, points: np.ndarray, tol: float = CONTAIN_TOL) -> np.ndarray:
    """Membership of points in closed rectangles (grown by ``tol``).

    Args:
        rects: (R, 4) [m].
        points: (K, 2) [m].
        tol: [m] tolerance added on every side.

    Returns:
        (K, R) bool, True where point k lies in rectangle r.
    """
    p = np.asarray(points, dtype=float)
    r = np.asarray(rects, dtype=float)
    x = p[:, 0:1]
    y = p[:, 1:2]
    return (x >= r[:, 0] - tol) & (x <= r[:, 2] + tol) & (y >= r[:, 1] - tol) & (y <= r[:, 3] + tol)


def find_area(rects: np.ndarray, point: np.ndarray, allowed: np.ndarray | None = None) -> tuple[int, float]:
    """The safe area of a point: a containing rectangle, else the nearest one.

    Among containing rectangles (a point on a shared edge lies in several) the lowest index
    is returned. With ``allowed`` (R,) bool only those rectangles are candidates.

    Args:
        rects: (R, 4) [m].
        point: (2,) [m].
        allowed: (R,) bool mask of candidate rectangles, or None for all.

    Returns:
        ``(index, distance)``: the rectangle index (-1 when there is no candidate) and the
        distance [m] from the point to it (0 when it contains the point).
    """
    d = rect_distance(rects, point)
    if allowed is not None:
        d = np.where(allowed, d, np.inf)
    if d.size == 0:
        return -1, math.inf
    i = int(np.argmin(d))
    if not math.isfinite(d[i]):
        return -1, math.inf
    return i, float(d[i]) if d[i] > CONTAIN_TOL else 0.0


def project_into_rect(rect: np.ndarray, point: np.ndarray, offset: float) -> np.ndarray:
    """Closest point of ``rect`` shrunk by ``offset`` on every side (paper: goal projection).

    For a point outside the rectangle this is its projection onto the closest boundary point
    moved inwards by ``offset`` along the edge normal(s); a point already deeper than
    ``offset`` inside is returned unchanged. Along an axis where the rectangle is narrower
    than ``2 * offset`` the rectangle's centre line is used.

    Args:
        rect: (4,) [m] ``xmin, ymin, xmax, ymax``.
        point: (2,) [m].
        offset: [m] inward offset, >= 0.

    Returns:
        (2,) [m] the projected point (inside the closed rectangle).
    """
    lo = np.array([rect[0], rect[1]], dtype=float) + offset
    hi = np.array([rect[2], rect[3]], dtype=float) - offset
    mid = 0.5 * (np.array([rect[0], rect[1]]) + np.array([rect[2], rect[3]]))
    narrow = lo > hi
    lo = np.where(narrow, mid, lo)
    hi = np.where(narrow, mid, hi)
    return np.minimum(np.maximum(np.asarray(point, dtype=float), lo), hi)


# --------------------------------------------------------------------------------------
# graph search
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AreaGraph:
    """The connectivity graph in compressed sparse row form (both directions of each edge).

    Attributes:
        n: number of areas R.
        indptr: (R+1,) int row pointers.
        nbr: (2E,) int neighbour area of each directed edge, sorted within each row.
        edge: (2E,) int index into ``SafeAreas.edges`` of each directed edge.
        weight: (2E,) [m] edge weight.
        key: (2E,) int ``src * R + dst``, sorted (for vectorised edge lookup).
        centres: (R, 2) [m] rectangle centres (A* heuristic).
    """

    n: int
    indptr: np.ndarray
    nbr: np.ndarray
    edge: np.ndarray
    weight: np.ndarray
    key: np.ndarray
    centres: np.ndarray

    def edge_between(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Edge indices (into ``SafeAreas.edges``) between area pairs ``(a[k], b[k])``.

        Args:
            a, b: (K,) int area indices; every pair must be adjacent.

        Returns:
            (K,) int edge indices; -1 where the pair is not adjacent.
        """
        k = np.asarray(a, dtype=np.int64) * self.n + np.asarray(b, dtype=np.int64)
        pos = np.searchsorted(self.key, k)
        pos = np.minimum(pos, max(self.key.size - 1, 0))
        if self.key.size == 0:
            return np.full(k.shape, -1, dtype=np.int64)
        return np.where(self.key[pos] == k, self.edge[pos], -1)


def build_graph(areas: SafeAreas) -> AreaGraph:
    """Build the CSR adjacency of ``areas`` (vectorised, O(E log E)).

    Args:
        areas: the safe areas; ``edges`` (E, 2) and ``weights`` (E,).

    Returns:
        The :class:`AreaGraph`.
    """
    rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
    n = rects.shape[0]
    edges = np.asarray(areas.edges, dtype=np.int64).reshape(-1, 2)
    w = np.asarray(areas.weights, dtype=float).reshape(-1)
    e_ids = np.arange(edges.shape[0], dtype=np.int64)
    src = np.concatenate([edges[:, 0], edges[:, 1]])
    dst = np.concatenate([edges[:, 1], edges[:, 0]])
    key = src * n + dst
    order = np.argsort(key, kind="stable")
    key = key[order]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
    centres = 0.5 * (rects[:, :2] + rects[:, 2:])
    return AreaGraph(
        n=n,
        indptr=indptr,
        nbr=dst[order],
        edge=np.concatenate([e_ids, e_ids])[order],
        weight=np.concatenate([w, w])[order],
        key=key,
        centres=centres,
    )


def shortest_corridor_astar(graph: AreaGraph, src: int, dst: int) -> np.ndarray | None:
    """Shortest area sequence from ``src`` to ``dst`` by A* (heapq, pure Python).

    The heuristic is the straight distance between area centres; it is admissible and
    consistent for the design's centre-distance edge weights (triangle inequality). For
    other non-negative weights it may not be, and the result is then a valid but possibly
    longer path (use :func:`shortest_corridor_dijkstra`).

    Args:
        graph: adjacency from :func:`build_graph`.
        src, dst: area indices.

    Returns:
        (C,) int area indices from ``src`` to ``dst``, or None when ``dst`` is unreachable.
    """
    if src == dst:
        return np.array([src], dtype=np.int64)
    indptr = graph.indptr.tolist()
    nbr = graph.nbr.tolist()
    wt = graph.weight.tolist()
    cx = graph.centres[:, 0].tolist()
    cy = graph.centres[:, 1].tolist()
    gx, gy = cx[dst], cy[dst]
    best = {src: 0.0}
    parent = {src: -1}
    closed = set()
    heap = [(math.hypot(cx[src] - gx, cy[src] - gy), 0.0, src)]
    hypot = math.hypot
    while heap:
        _, g, u = heapq.heappop(heap)
        if u in closed:
            continue
        if u == dst:
            path = [u]
            while parent[u] >= 0:
                u = parent[u]
                path.append(u)
            return np.array(path[::-1], dtype=np.int64)
        closed.add(u)
        for k in range(indptr[u], indptr[u + 1]):
            v = nbr[k]
            if v in closed:
                continue
            ng = g + wt[k]
            if ng < best.get(v, math.inf):
                best[v] = ng
                parent[v] = u
                heapq.heappush(heap, (ng + hypot(cx[v] - gx, cy[v] - gy), ng, v))
    return None


def _csgraph(graph: AreaGraph) -> csr_array:
    # Zero weights would be dropped by the sparse format (read as "no edge"); keep them tiny.
    w = np.maximum(graph.weight, 1e-12)
    return csr_array((w, graph.nbr, graph.indptr), shape=(graph.n, graph.n))


def shortest_corridor_dijkstra(graph: AreaGraph, src: int, dst: int) -> np.ndarray | None:
    """Shortest area sequence from ``src`` to ``dst`` by Dijkstra (``scipy.sparse.csgraph``).

    Args:
        graph: adjacency from :func:`build_graph`.
        src, dst: area indices.

    Returns:
        (C,) int area indices from ``src`` to ``dst``, or None when ``dst`` is unreachable.
    """
    if src == dst:
        return np.array([src], dtype=np.int64)
    dist, pred = dijkstra(_csgraph(graph), directed=True, indices=src, return_predecessors=True)
    if not np.isfinite(dist[dst]):
        return None
    path = [dst]
    u = dst
    while u != src:
        u = int(pred[u])
        path.append(u)
    return np.array(path[::-1], dtype=np.int64)


def reachable_from(graph: AreaGraph, src: int) -> np.ndarray:
    """Areas connected to ``src`` (breadth-first search in ``scipy.sparse.csgraph``).

    Args:
        graph: adjacency from :func:`build_graph`.
        src: area index.

    Returns:
        (R,) bool, True for every area reachable from ``src`` (including ``src``).
    """
    order = breadth_first_order(_csgraph(graph), src, directed=True, return_predecessors=False)
    mask = np.zeros(graph.n, dtype=bool)
    mask[order] = True
    return mask


# --------------------------------------------------------------------------------------
# portals and waypoints
# --------------------------------------------------------------------------------------


def oriented_portals(areas: SafeAreas, graph: AreaGraph, corridor: np.ndarray) -> np.ndarray:
    """The portals crossed by the corridor, each oriented (left end, right end) as seen when
    travelling from corridor area ``k`` into area ``k+1``.

    Args:
        areas: the safe areas (``portals`` (E, 2, 2) are the shared segments).
        graph: adjacency from :func:`build_graph`.
        corridor: (C,) int area indices, consecutive ones adjacent.

    Returns:
        (C-1, 2, 2) [m] ``[[left_x, left_y], [right_x, right_y]]`` per crossing.

    Raises:
        ValueError: if two consecutive corridor areas are not adjacent.
    """
    corridor = np.asarray(corridor, dtype=np.int64)
    if corridor.size < 2:
        return np.zeros((0, 2, 2))
    a, b = corridor[:-1], corridor[1:]
    e = graph.edge_between(a, b)
    if np.any(e < 0):
        k = int(np.flatnonzero(e < 0)[0])
        raise ValueError(f"corridor: areas {int(a[k])} and {int(b[k])} are not adjacent")
    por = np.asarray(areas.portals, dtype=float).reshape(-1, 2, 2)[e]
    d = graph.centres[b] - graph.centres[a]  # travel direction across the portal
    v = por[:, 1] - por[:, 0]
    # p1 is the left end when (d x (p1 - p0)) > 0.
    left_is_1 = (d[:, 0] * v[:, 1] - d[:, 1] * v[:, 0]) > 0
    out = np.where(left_is_1[:, None, None], por[:, ::-1], por)
    return out


def shrink_portals(portals: np.ndarray, clearance: float) -> np.ndarray:
    """Shrink each portal segment by ``clearance`` at both ends (to its midpoint when shorter
    than ``2 * clearance``).

    Args:
        portals: (P, 2, 2) [m] segment endpoints.
        clearance: [m] >= 0.

    Returns:
        (P, 2, 2) [m] shrunk segments, same orientation.
    """
    p0, p1 = portals[:, 0], portals[:, 1]
    length = np.linalg.norm(p1 - p0, axis=1)
    mid = 0.5 * (p0 + p1)
    safe_len = np.where(length > 0, length, 1.0)
    u = (p1 - p0) / safe_len[:, None]
    short = length <= 2.0 * clearance
    q0 = np.where(short[:, None], mid, p0 + clearance * u)
    q1 = np.where(short[:, None], mid, p1 - clearance * u)
    return np.stack([q0, q1], axis=1)


def _cross(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """z of (b - a) x (c - a): > 0 when c is left of the ray a -> b."""
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def funnel_path(start: np.ndarray, goal: np.ndarray, portals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shortest polyline from ``start`` to ``goal`` through oriented portal segments in order
    (the funnel / string-pulling algorithm).

    The funnel (apex, left ray, right ray) is narrowed portal by portal; when one side
    crosses over the other, that side's end point becomes a vertex of the path and the new
    apex. The result is the exact minimum-length path through the segments.

    Args:
        start: (2,) [m].
        goal: (2,) [m].
        portals: (P, 2, 2) [m] ``(left, right)`` ends, oriented for the travel direction.

    Returns:
        ``(vertices, portal_index)``: (V, 2) [m] path vertices from start to goal and (V,)
        int the portal each vertex lies on (-1 for start, P for goal).
    """
    pts_l = [(float(start[0]), float(start[1]))]
    pts_r = [(float(start[0]), float(start[1]))]
    for p in portals:
        pts_l.append((float(p[0, 0]), float(p[0, 1])))
        pts_r.append((float(p[1, 0]), float(p[1, 1])))
    g = (float(goal[0]), float(goal[1]))
    pts_l.append(g)
    pts_r.append(g)
    n = len(pts_l)

    ax, ay = pts_l[0]
    lx, ly = pts_l[0]
    rx, ry = pts_r[0]
    apex_i = left_i = right_i = 0
    verts = [(ax, ay)]
    vidx = [-1]
    i = 1
    while i < n:
        nlx, nly = pts_l[i]
        nrx, nry = pts_r[i]
        # right side: tighten when the new right end is left of (or on) the right ray
        if _cross(ax, ay, rx, ry, nrx, nry) >= 0.0:
            if (ax == rx and ay == ry) or _cross(ax, ay, lx, ly, nrx, nry) < 0.0:
                rx, ry, right_i = nrx, nry, i
            else:  # right crosses over left: left end becomes a path vertex
                ax, ay, apex_i = lx, ly, left_i
                verts.append((ax, ay))
                vidx.append(apex_i - 1)
                lx, ly, rx, ry = ax, ay, ax, ay
                left_i = right_i = apex_i
                i = apex_i + 1
                continue
        # left side: tighten when the new left end is right of (or on) the left ray
        if _cross(ax, ay, lx, ly, nlx, nly) <= 0.0:
            if (ax == lx and ay == ly) or _cross(ax, ay, rx, ry, nlx, nly) > 0.0:
                lx, ly, left_i = nlx, nly, i
            else:  # left crosses over right: right end becomes a path vertex
                ax, ay, apex_i = rx, ry, right_i
                verts.append((ax, ay))
                vidx.append(apex_i - 1)
                lx, ly, rx, ry = ax, ay, ax, ay
                left_i = right_i = apex_i
                i = apex_i + 1
                continue
        i += 1
    verts.append(g)
    vidx.append(n - 2)
    return np.array(verts, dtype=float), np.array(vidx, dtype=np.int64)


def portal_crossings(vertices: np.ndarray, vertex_portal: np.ndarray, portals: np.ndarray) -> np.ndarray:
    """Where a polyline through the portals crosses each portal.

    Args:
        vertices: (V, 2) [m] from :func:`funnel_path`.
        vertex_portal: (V,) int portal index of each vertex (-1 start, P goal).
        portals: (P, 2, 2) [m] the (shrunk) portal segments.

    Returns:
        (P, 2) [m] one point per portal, on the portal segment.
    """
    P = portals.shape[0]
    if P == 0:
        return np.zeros((0, 2))
    idx = np.arange(P)
    # vertex k covers portals in (vertex_portal[k], vertex_portal[k+1]]
    seg = np.searchsorted(vertex_portal, idx, side="left") - 1  # segment (k, k+1) with vp[k] < p <= vp[k+1]
    seg = np.clip(seg, 0, vertices.shape[0] - 2)
    a = vertices[seg]
    b = vertices[seg + 1]
    p0 = portals[:, 0]
    p1 = portals[:, 1]
    # intersection of segment a->b with the portal's line: solve a + s (b-a) = p0 + t (p1-p0)
    d = b - a
    e = p1 - p0
    den = d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0]
    w = p0 - a
    t_num = d[:, 0] * w[:, 1] - d[:, 1] * w[:, 0]  # t = (d x w) / (d x e) ... sign below
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -t_num / den
    # fallback for parallel / degenerate cases: project a onto the segment
    elen2 = np.einsum("ij,ij->i", e, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_proj = np.where(elen2 > 0, np.einsum("ij,ij->i", a - p0, e) / elen2, 0.5)
    t = np.where(np.abs(den) > 1e-12, t, t_proj)
    t = np.clip(np.nan_to_num(t, nan=0.5), 0.0, 1.0)
    out = p0 + t[:, None] * e
    # a vertex lying on this portal is the crossing itself
    on_vertex = vertex_portal[np.clip(np.searchsorted(vertex_portal, idx), 0, len(vertex_portal) - 1)]
    hit = on_vertex == idx
    if np.any(hit):
        vpos = np.searchsorted(vertex_portal, idx[hit])
        out[hit] = vertices[vpos]
    return out


def portal_waypoints(start: np.ndarray, goal: np.ndarray, portals: np.ndarray, clearance: float) -> np.ndarray:
    """Waypoints start, one crossing per portal, goal: the shortest such polyline with every
    crossing on its portal shrunk by ``clearance`` (see the module docstring for safety).

    Args:
        start: (2,) [m] inside the first corridor area.
        goal: (2,) [m] inside the last corridor area.
        portals: (C-1, 2, 2) [m] oriented portals from :func:`oriented_portals`.
        clearance: [m] distance kept from each portal end (midpoint on short portals).

    Returns:
        (C+1, 2) [m] waypoints; segment k lies in corridor area k.
    """
    shrunk = shrink_portals(portals, clearance) if portals.shape[0] else portals
    verts, vp = funnel_path(start, goal, shrunk)
    cross = portal_crossings(verts, vp, shrunk)
    return np.vstack([np.asarray(start, dtype=float)[None], cross, np.asarray(goal, dtype=float)[None]])


def path_length(points: np.ndarray) -> float:
    """Length [m] of the polyline through (W, 2) points."""
    if len(points) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


# --------------------------------------------------------------------------------------
# start / goal areas, goal projection and corridor in one call
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CorridorChoice:
    """Result of :func:`select_corridor`.

    Attributes:
        corridor: (C,) int area indices from the start area to the goal area, or None.
        start: (2,) [m] start point used (projected inwards when it was outside every area).
        goal: (2,) [m] goal point used (projected into the nearest reachable area when it
            was outside every area).
        detail: why there is no corridor ("" when there is one).
    """

    corridor: np.ndarray | None
    start: np.ndarray
    goal: np.ndarray
    detail: str = ""


def _candidates(areas: SafeAreas, rects: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Areas containing ``point``: the one ``locate`` gives first, then any others (a point on
    a shared edge or corner lies in several)."""
    # one membership scan: ``locate``'s first area is the lowest-numbered one containing the
    # point under the same closed tests grown by CONTAIN_TOL, so the hits are already in
    # that order (a non-finite point is in none: every comparison is False)
    return np.flatnonzero(contains(rects, point[None])[0]).astype(np.int64)


def select_corridor(
    areas: SafeAreas,
    graph: AreaGraph,
    start: np.ndarray,
    goal: np.ndarray,
    search: str = "astar",
    offset: float = 0.1,
    max_projection: float = math.inf,
) -> CorridorChoice:
    """Start and goal areas, goal projection and the shortest corridor (paper Sec. III-C).

    * Start: the area containing it (``mapping.safe_areas.locate``); when it is outside
      every area, the nearest area, with the start projected into it (inward ``offset``).
    * Goal inside a safe area: the shortest corridor to it; if that area is not connected
      to the start's, there is no path (a walled-off goal is never silently replaced).
    * Goal outside every area: projected to the closest boundary point of the nearest area
      reachable from the start area and moved inwards by ``offset``
      (:func:`project_into_rect`), as the paper; farther than ``max_projection`` from every
      reachable area means no path.

    Args:
        areas: safe areas; graph: their adjacency (:func:`build_graph`).
        start, goal: (2,) [m].
        search: ``"astar"`` or ``"dijkstra"``.
        offset: [m] inward offset of projected points.
        max_projection: [m] largest accepted projection distance (start or goal).

    Returns:
        A :class:`CorridorChoice`; ``corridor`` is None when there is no path.
    """
    rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
    run = shortest_corridor_astar if search == "astar" else shortest_corridor_dijkstra
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    s_cands = _candidates(areas, rects, start)
    start_used = start.copy()
    if s_cands.size == 0:
        s_area, s_dist = find_area(rects, start)
        if s_area < 0 or s_dist > max_projection:
            return CorridorChoice(None, start, goal, f"start is {s_dist:.3f} m from the nearest safe area")
        start_used = project_into_rect(rects[s_area], start, offset)
        s_cands = np.array([s_area], dtype=np.int64)

    g_cands = _candidates(areas, rects, goal)
    if g_cands.size:
        for s in s_cands:
            for g in g_cands:
                cor = run(graph, int(s), int(g))
                if cor is not None:
                    return CorridorChoice(cor, start_used, goal.copy())
        return CorridorChoice(None, start_used, goal, "the goal's safe area is not connected to the start's")

    best = (-1, math.inf, -1)
    for s in s_cands:
        g, d = find_area(rects, goal, allowed=reachable_from(graph, int(s)))
        if g >= 0 and d < best[1]:
            best = (g, d, int(s))
    g, d, s = best
    if g < 0 or d > max_projection:
        return CorridorChoice(None, start_used, goal, f"goal is {d:.3f} m from the nearest reachable safe area")
    goal_used = project_into_rect(rects[g], goal, offset)
    return CorridorChoice(run(graph, s, g), start_used, goal_used)


def penalise_narrow(areas: SafeAreas, width: float, penalty: float) -> SafeAreas:
    """The same areas with ``penalty`` [m] added to the weight of every edge that crosses a
    narrow place: its portal is shorter than ``width`` [m], or either area's short side is.

    For a map inflated by a footprint disc radius r_d rather than the circumscribed radius R,
    ``width = 2 (R - r_d)`` marks the passages where the circumscribed disc does not fit (the
    robot can drive along them but cannot turn on the spot, and their staircases of
    slivers stall the MPC): the corridor search then takes them only where a wider way is
    longer by more than the penalty per such edge. The penalty keeps A*'s centre-distance
    heuristic consistent (weights only grow).

    Args:
        areas: safe areas with portals (E, 2, 2) [m].
        width: [m] >= 0.
        penalty: [m] >= 0 added per narrow edge.

    Raises:
        ValueError: negative or non-finite ``width`` or ``penalty``.
    """
    from dataclasses import replace

    for name, v in (("width", width), ("penalty", penalty)):
        if not (np.isfinite(v) and v >= 0):
            raise ValueError(f"penalise_narrow: {name} must be a finite number >= 0 m, got {v!r}")
    if width == 0 or penalty == 0 or len(areas.weights) == 0:
        return areas
    rects = np.asarray(areas.rects, dtype=float)
    short = np.minimum(rects[:, 2] - rects[:, 0], rects[:, 3] - rects[:, 1])
    por = np.asarray(areas.portals, dtype=float)
    plen = np.hypot(*(por[:, 1] - por[:, 0]).T)
    e = np.asarray(areas.edges, dtype=int)
    narrow = (plen < width) | (short[e[:, 0]] < width) | (short[e[:, 1]] < width)
    return replace(areas, weights=np.asarray(areas.weights, dtype=float) + penalty * narrow)
