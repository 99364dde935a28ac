"""A plan from a pose path (:mod:`sanav_mj.planning.pose_search`): corridor and reference.

The pose path is a chain of lattice poses joined by forward / backward moves and turns on
the spot. From it:

- **Dense poses.** Each move is cut into pieces of at most ``spacing`` [m] of disc-centre
  travel (position and yaw interpolated linearly, the motion the search checked), and the
  dense poses are kept only if every disc centre of each is in the search's free set.
- **Timing.** Runs of moves of one kind (forward, backward, on the spot) are timed rest to
  rest: translations with :func:`sanav_mj.planning.timing.speed_profile` on the dense poses
  (curvature = yaw change / arc length; speed cap ``v_cap`` forwards, ``v_rev_cap``
  backwards), turns with the time-optimal trapezoid of the yaw rate (``w_cap``,
  ``alpha_cap``). The reference samples the timed poses at ``dt``; its inputs are the
  finite differences (speed: the displacement projected on the heading, so it is negative
  when reversing; yaw rate: the yaw change), the last one (0, 0). Its yaw is the pose
  path's yaw, not the path tangent: it keeps the footprint where the search found room.
- **A chain per disc.** SA-MPC holds each disc centre of every predicted state in a stage
  box of a chain of convex boxes (each a safe area or a bridge across the portal of two
  adjacent areas, shrunk by ``box_margin``; consecutive ones overlap) with its own
  monotone assignment. Each disc centre's dense trajectory gives its chain
  (:func:`member_chain`): the member boxes it walks, staying on one while inside its
  shrunk box and moving on where it lies in the shrunk intersection with the next.
  One chain for all discs does not work on a diagonal staircase of small areas: the discs
  of an arcing body pass through different areas, and no single sequence of areas holds
  every disc's as a contiguous run (measured on barn_0003). Nor does a chain of *areas*
  per disc: a centre that grazes the bridge region of a portal without crossing it (inside
  the area, within the margin of its side) fits no area-to-area chain (barn_0026: the MPC
  held the robot 3 cm off the route there and stalled). ``Plan.disc_corridors`` holds the
  member indices into ``member_boxes(areas, 0)`` (areas first, then one bridge per edge);
  ``Plan.corridor`` is the sequence of areas the disc nearest the body origin passes
  (for the reference's ``area`` and the controller's other uses of the corridor).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.pose_search import (
    REVERSE,
    SPIN,
    PointRaster,
    PoseRoute,
    disc_points,
    member_boxes,
    poses_free,
)
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.planning.timing import speed_profile

CONTAIN_TOL = 1e-9


def densify(route: PoseRoute, offsets: np.ndarray, spacing: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Dense poses (Q, 3) and the kind of the move each dense piece belongs to (Q-1,).

    Each move is cut into ``ceil(travel / spacing)`` pieces, ``travel`` [m] the largest
    disc-centre displacement of the move (straight-line bound: translation + offset x yaw).
    """
    reach = float(np.hypot(*np.asarray(offsets, float).T).max()) if len(offsets) else 0.0
    out, kinds = [route.poses[:1]], []
    for a, b, kind in zip(route.poses[:-1], route.poses[1:], route.kinds):
        travel = float(np.hypot(*(b[:2] - a[:2]))) + reach * abs(float(b[2] - a[2]))
        n = max(1, int(math.ceil(travel / spacing)))
        t = (np.arange(1, n + 1) / n)[:, None]
        out.append(a + t * (b - a))
        kinds.extend([int(kind)] * n)
    return np.vstack(out), np.array(kinds, dtype=int)


def _tangent_yaw(p: np.ndarray, i: int, sign: int, ref: float) -> float:
    """Yaw [rad] of the chord ``p[i+1] - p[i-1]`` (+pi when reversing), unwrapped near ``ref``."""
    d = p[i + 1] - p[i - 1]
    y = math.atan2(d[1], d[0]) + (math.pi if sign == REVERSE else 0.0)
    return y + 2 * math.pi * round((ref - y) / (2 * math.pi))


def smooth_route(route: PoseRoute, raster: PointRaster, offsets: np.ndarray, iterations: int = 30,
                 step: float = 0.4) -> PoseRoute:
    """The route with its translating runs smoothed where the footprint stays free.

    Each interior pose of a run of moves of one kind (forward or backward; the poses where
    a run starts or ends, turns on the spot included, stay put) is moved ``step`` of the way
    towards the mean of its neighbours, its yaw and its neighbours' set to the chord
    tangents (a unicycle drives along its heading), ``iterations`` sweeps of Gauss-Seidel; a
    move is kept only if the poses it changes and 7 poses evenly along each of the four
    moves around them keep every disc centre free (``raster``); the result is checked
    densely by the caller (:func:`route_plan`). Smoother paths drive faster
    (the reference's speed is capped by its curvature) and jerk the MPC less.

    Args:
        route: a route from :func:`sanav_mj.planning.pose_search.search_poses`.
        raster: the free set of a disc centre it was searched on.
        offsets: (D, 2) [m] disc centres in the body frame.
        iterations: sweeps.
        step: in (0, 1], the fraction of the way to the neighbours' mean.

    Returns:
        A :class:`PoseRoute` with the same kinds, cost and counts and the smoothed poses.
    """
    P = route.poses.copy()
    kinds = route.kinds
    n = P.shape[0]
    if n < 3:
        return route
    fixed = np.zeros(n, dtype=bool)
    fixed[0] = fixed[-1] = True
    fixed[1:-1] = (kinds[:-1] != kinds[1:]) | (kinds[:-1] == SPIN)
    movable = np.flatnonzero(~fixed)
    frac = (np.arange(1, 8) / 8.0)[:, None]

    def ok(Q: np.ndarray, lo: int, hi: int) -> bool:
        a, b = Q[lo:hi], Q[lo + 1:hi + 1]
        mids = (a[None] + frac[..., None] * (b - a)[None]).reshape(-1, 3)
        return bool(poses_free(raster, np.vstack([Q[lo:hi + 1], mids]), offsets).all())

    for _ in range(iterations):
        moved = False
        for i in movable:
            target = 0.5 * (P[i - 1, :2] + P[i + 1, :2])
            if float(np.hypot(*(target - P[i, :2]))) < 1e-4:
                continue
            Q = P[max(0, i - 2):min(n, i + 3)].copy()
            j = i - max(0, i - 2)
            Q[j, :2] = P[i, :2] + step * (target - P[i, :2])
            for m in (j - 1, j, j + 1):
                gi = i + m - j
                if 0 < gi < n - 1 and not fixed[gi] and 0 < m < len(Q) - 1:
                    Q[m, 2] = _tangent_yaw(Q[:, :2], m, int(kinds[gi]), float(Q[m, 2]))
            if ok(Q, 0, len(Q) - 1):
                P[max(0, i - 2):min(n, i + 3)] = Q
                moved = True
        if not moved:
            break
    return PoseRoute(P, kinds, route.cost, route.nodes, route.edges, route.time_ms)


def _bad_moves(route: PoseRoute, raster: PointRaster, offsets: np.ndarray, spacing: float = 0.02) -> np.ndarray:
    """Indices of the moves of ``route`` whose dense poses (:func:`densify`) are not all free."""
    dense, _ = densify(route, offsets, spacing)
    free = poses_free(raster, dense, offsets)
    if free.all():
        return np.zeros(0, dtype=int)
    reach = float(np.hypot(*np.asarray(offsets, float).T).max())
    counts = [max(1, int(math.ceil((float(np.hypot(*(b[:2] - a[:2]))) + reach * abs(float(b[2] - a[2]))) / spacing)))
              for a, b in zip(route.poses[:-1], route.poses[1:])]
    edge_of = np.concatenate([[0], np.repeat(np.arange(len(counts)), counts)])
    return np.unique(edge_of[~free])


def _spin_times(dyaw: np.ndarray, w_cap: float, alpha: float) -> np.ndarray:
    """Times (n,) [s] at which a rest-to-rest turn of total ``|dyaw[-1]|`` reaches ``|dyaw|``."""
    th = np.abs(dyaw)
    total = float(th[-1])
    wp = min(w_cap, math.sqrt(alpha * total))
    ta, tha = wp / alpha, wp * wp / (2 * alpha)
    T = 2 * ta + (total - 2 * tha) / wp
    return np.where(th <= tha, np.sqrt(2 * th / alpha),
                    np.where(th >= total - tha, T - np.sqrt(np.maximum(2 * (total - th) / alpha, 0.0)),
                             ta + (th - tha) / wp))


def time_poses(dense: np.ndarray, kinds: np.ndarray, v_cap: float, v_rev_cap: float, w_cap: float,
               a_cap: float, alpha_cap: float, a_lat: float, v_scale: np.ndarray | None = None) -> np.ndarray:
    """Times (Q,) [s] of the dense poses (Q, 3): runs of one kind of move timed rest to rest;
    ``v_scale`` (Q,) in (0, 1] scales the speed cap per pose (None: 1)."""
    t = np.zeros(dense.shape[0])
    q = dense.shape[0] - 1
    i = 0
    while i < q:
        j = i
        while j < q and kinds[j] == kinds[i]:
            j += 1
        seg = dense[i:j + 1]
        if kinds[i] == SPIN:
            tt = _spin_times(seg[:, 2] - seg[0, 2], w_cap, alpha_cap)
        else:
            ds = np.hypot(*np.diff(seg[:, :2], axis=0).T)
            ke = np.abs(np.diff(seg[:, 2])) / np.maximum(ds, 1e-12)
            kn = np.zeros(seg.shape[0])
            kn[:-1] = ke
            kn[1:] = np.maximum(kn[1:], ke)
            vc = v_rev_cap if kinds[i] == REVERSE else v_cap
            if v_scale is not None:
                vc = vc * v_scale[i:j + 1]
            v = speed_profile(ds, kn, vc, w_cap, a_lat, a_cap)
            tt = np.zeros(seg.shape[0])
            np.cumsum(2.0 * ds / np.maximum(v[:-1] + v[1:], 1e-12), out=tt[1:])
        t[i:j + 1] = t[i] + tt
        i = j
    return t


def sample_reference(dense: np.ndarray, times: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """States (K, 3) and inputs (K, 2) at ``k dt`` from timed dense poses (see the module docstring)."""
    T = float(times[-1])
    K = int(math.ceil(T / dt - 1e-9)) + 1
    tk = np.minimum(np.arange(K) * dt, T)
    # strictly increasing time nodes for the interpolation (turns and translations share ends)
    keep = np.concatenate(([True], np.diff(times) > 1e-12))
    tn, dn = times[keep], dense[keep]
    states = np.column_stack([np.interp(tk, tn, dn[:, i]) for i in range(3)])
    inputs = np.zeros((K, 2))
    if K > 1:
        d = np.diff(states, axis=0)
        ym = states[:-1, 2] + 0.5 * d[:, 2]
        inputs[:-1, 0] = (d[:, 0] * np.cos(ym) + d[:, 1] * np.sin(ym)) / dt
        inputs[:-1, 1] = d[:, 2] / dt
    return states, inputs


def _inside(rect: np.ndarray, p: np.ndarray) -> bool:
    return bool(rect[0] - CONTAIN_TOL <= p[0] <= rect[2] + CONTAIN_TOL and rect[1] - CONTAIN_TOL <= p[1] <= rect[3] + CONTAIN_TOL)


def _neighbours(areas: SafeAreas) -> list[set[int]]:
    nb: list[set[int]] = [set() for _ in range(len(areas.rects))]
    for i, j in np.asarray(areas.edges, dtype=int).reshape(-1, 2):
        nb[i].add(int(j))
        nb[j].add(int(i))
    return nb


def _bfs(nb: list[set[int]], src: int, targets: set[int]) -> list[int] | None:
    prev = {src: -1}
    frontier = [src]
    while frontier:
        nxt = []
        for a in frontier:
            if a in targets:
                path = [a]
                while prev[path[-1]] != -1:
                    path.append(prev[path[-1]])
                return path[::-1]
            for b in nb[a]:
                if b not in prev:
                    prev[b] = a
                    nxt.append(b)
        frontier = nxt
    return None


def corridor_of_points(areas: SafeAreas, points: np.ndarray) -> np.ndarray | None:
    """The safe areas (C,) int a dense point sequence (P, 2) [m] passes through, in order (see
    the module docstring); None when a point lies in no safe area."""
    rects = np.asarray(areas.rects, dtype=float)
    nb = _neighbours(areas)
    inside = _in_boxes(points, rects)
    if not inside.any(axis=1).all():
        return None
    P = points.shape[0]
    run = _runs_ahead(inside)
    cur = int(np.argmax(run[0]))
    out = [cur]
    for i in range(1, P):
        if inside[i, cur]:
            continue
        cand = np.flatnonzero(inside[i])
        adj = [c for c in cand if c in nb[cur]]
        if adj:
            nxt = max(adj, key=lambda c: run[i, c])
            out.append(int(nxt))
        else:
            path = _bfs(nb, cur, set(int(c) for c in cand))
            if path is None:
                return None
            out.extend(path[1:])
        cur = out[-1]
    return np.array(out, dtype=np.int64)


def chain_walk(rects: np.ndarray, corridor: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    """Corridor positions (P,) of a monotone walk covering the points (P, 2) [m] (stay while
    inside, else advance one area), or None when a point is neither in its area nor the next."""
    cr = np.asarray(rects, dtype=float)[np.asarray(corridor, dtype=int)]
    pos = np.zeros(points.shape[0], dtype=np.int64)
    j = 0
    for i, p in enumerate(points):
        if _inside(cr[j], p):
            pos[i] = j
            continue
        if j + 1 < len(cr) and _inside(cr[j + 1], p):
            j += 1
            pos[i] = j
            continue
        # the chain joins consecutive areas through their bridge boxes: a point just past a
        # portal into an area two steps ahead is not covered
        return None
    return pos


def _shrink(box: np.ndarray, margin: float) -> np.ndarray:
    """Boxes (..., 4) shrunk by ``margin`` per side, at most a quarter of each width (as
    SA-MPC's :func:`sanav_mj.control.stages.shrink_box`)."""
    w = box[..., 2:] - box[..., :2]
    m = np.minimum(margin, 0.25 * np.maximum(w, 0.0))
    return np.concatenate((box[..., :2] + m, box[..., 2:] - m), axis=-1)


def _runs_ahead(inside: np.ndarray) -> np.ndarray:
    """(P, M) int32: how many consecutive points from point p on lie in box m (``inside``
    (P, M) bool as :func:`_in_boxes` gives)."""
    run = np.zeros(inside.shape, dtype=np.int32)
    run[-1] = inside[-1]
    for i in range(inside.shape[0] - 2, -1, -1):
        run[i] = np.where(inside[i], run[i + 1] + 1, 0)
    return run


def _in_boxes(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(P, M) bool: point p in box m (closed, to 1e-9 m)."""
    return ((points[:, None, 0] >= boxes[None, :, 0] - CONTAIN_TOL) & (points[:, None, 0] <= boxes[None, :, 2] + CONTAIN_TOL)
            & (points[:, None, 1] >= boxes[None, :, 1] - CONTAIN_TOL) & (points[:, None, 1] <= boxes[None, :, 3] + CONTAIN_TOL))


def member_chain(members: np.ndarray, points: np.ndarray, margin: float, tol: float = 0.005,
                 overlap_at: np.ndarray | None = None) -> np.ndarray | None:
    """The chain of member boxes a disc centre's dense trajectory walks, or None.

    Args:
        members: (M, 4) [m] candidate member boxes, unshrunk (safe areas and portal bridges,
            :func:`sanav_mj.planning.pose_search.member_boxes` with margin 0).
        points: (P, 2) [m] the trajectory, dense (consecutive points closer than the margin).
        margin: [m] SA-MPC's ``box_margin``.
        tol: [m] a point may lie this far outside its boxes (the search checks its moves
            every 2 cm of disc travel; the dense points are 1 cm apart and may graze a
            corner between two checked poses by a few mm; SA-MPC's rows are exact).
        overlap_at: None, or (P,) bool: where the walk moves on at a point marked True (a
            point in a sliver), to the candidate whose intersection with the current member
            is largest instead of the one holding the following points longest (in a
            diagonal staircase the longest-holding member meets the current one in a corner
            square a cell wide, which the robot's disc centre must then hit exactly).

    Returns:
        (L,) int member indices such that a monotone walk covers the points the way SA-MPC's
        stage boxes do: each point in its member shrunk by ``margin`` (the stay box), and
        where the walk moves on, the point in the shrunk intersection of the two members
        (the advance box); consecutive members therefore overlap. The walk stays on a member
        as long as the points do and then moves to the member (overlapping the current one)
        that holds the following points longest. None when some point has no such member.
    """
    margin = margin - tol  # below tol: the boxes grown by the rest (membership only)
    shrunk = _shrink(members, margin)
    inside = _in_boxes(points, shrunk)
    P = points.shape[0]
    if not inside.any(axis=1).all():
        return None
    run = _runs_ahead(inside)
    cur = int(np.argmax(run[0]))
    out = [cur]
    for i in range(1, P):
        if inside[i, cur]:
            continue
        # move on at point i - 1 (in the current member) to a member holding points i - 1 and i
        cand = np.flatnonzero(inside[i - 1] & inside[i])
        if cand.size:
            inter = np.concatenate((np.maximum(members[cur, :2], members[cand, :2]),
                                    np.minimum(members[cur, 2:], members[cand, 2:])), axis=1)
            adv = _shrink(inter, min(margin, max(0.0, margin - tol)))  # a corner cut by a few mm between samples
            okc = _in_boxes(points[i - 1:i], adv)[0] & np.all(inter[:, 2:] - inter[:, :2] > 1e-9, axis=1)
            cand = cand[okc]
        if cand.size == 0:
            return None
        if overlap_at is not None and overlap_at[i]:
            inter = np.concatenate((np.maximum(members[cur, :2], members[cand, :2]),
                                    np.minimum(members[cur, 2:], members[cand, 2:])), axis=1)
            area = np.prod(np.maximum(inter[:, 2:] - inter[:, :2], 0.0), axis=1)
            cur = int(cand[np.argmax(area)])
        else:
            cur = int(cand[np.argmax(run[i, cand])])
        out.append(cur)
    return np.array(out, dtype=np.int64)


def _loose_walk(rects: np.ndarray, corridor: np.ndarray, points: np.ndarray, tol: float = 0.01) -> np.ndarray:
    """(P,) int monotone corridor positions of ``points`` (P, 2) [m]: each point's first
    corridor area at or after the previous point's that holds it grown by ``tol`` [m], else
    the previous one (the labels of a reference's samples, ``Reference.area``)."""
    r = np.asarray(rects, dtype=float)[np.asarray(corridor, dtype=int)]
    inside = ((r[None, :, 0] - tol <= points[:, None, 0]) & (points[:, None, 0] <= r[None, :, 2] + tol)
              & (r[None, :, 1] - tol <= points[:, None, 1]) & (points[:, None, 1] <= r[None, :, 3] + tol))
    out, j = np.zeros(len(points), dtype=np.int64), 0
    for i in range(len(points)):
        hit = np.flatnonzero(inside[i, j:])
        if hit.size:
            j += int(hit[0])
        out[i] = j
    return out


def sliver_boxes(members: np.ndarray, points: np.ndarray, free, width: float, limit: float) -> np.ndarray:
    """(X, 4) [m] boxes grown around the points that lie in no wide member (diagonal slivers).

    A point (of a disc centre's dense trajectory) counts as in a sliver when every member
    box holding it has a side shorter than ``width``; around each such point a maximal box
    of free cells is grown from the cell that holds it
    (:func:`~sanav_mj.mapping.grow.grow_point`, each side at most ``limit`` [m] out). In a
    diagonal passage these boxes are squares about the strip's width / sqrt 2 that overlap
    along it, where the partition's areas are a staircase of cell-thin slivers; every box
    holds only free cells, as safe as a safe area.

    Args:
        members: (M, 4) [m] the candidate member boxes.
        points: (P, 2) [m] disc-centre points, in order.
        free: :class:`~sanav_mj.mapping.grow.FreeCells` of the map's inflated grid.
        width: [m] > 0, the smallest side of a member that is not a sliver.
        limit: [m] >= 0 growth limit per side.

    Returns:
        (X, 4) [m] distinct boxes, in the order of the first point that grew each.
    """
    from sanav_mj.mapping.grow import grow_point

    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    mb = np.asarray(members, dtype=float).reshape(-1, 4)
    wide = np.min(mb[:, 2:] - mb[:, :2], axis=1) >= width
    inside = _in_boxes(pts, mb[wide]) if wide.any() else np.zeros((len(pts), 0), dtype=bool)
    out: dict[tuple[float, ...], np.ndarray] = {}
    for p in pts[~inside.any(axis=1)]:
        b = grow_point(free, p, limit)
        if b is not None:
            out.setdefault(tuple(np.round(b, 9).tolist()), b)
    return np.array(list(out.values()), dtype=float).reshape(-1, 4)


def _area_of_boxes(rects: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(X,) int for boxes (X, 4) [m]: the safe area (rects (R, 4)) nearest each box's centre."""
    c = 0.5 * (boxes[:, None, :2] + boxes[:, None, 2:])
    d = np.maximum(np.maximum(rects[None, :, :2] - c, c - rects[None, :, 2:]), 0.0)
    return np.argmin((d * d).sum(axis=2), axis=1).astype(np.int64) if len(boxes) else np.zeros(0, dtype=np.int64)


def route_plan(areas: SafeAreas, route: PoseRoute, goal: np.ndarray, offsets: np.ndarray, dt: float,
               v_cap: float, v_rev_cap: float, w_cap: float, a_cap: float, alpha_cap: float,
               a_lat: float, info: dict[str, Any] | None = None,
               raster: PointRaster | None = None, margin: float = 0.02, slow_clearance: float = 0.0,
               slow_floor: float = 0.3, hold_at_stops: bool = False, grow_members: float = 0.0,
               sliver_width: float = 0.0) -> tuple[Plan | None, str]:
    """A :class:`Plan` following a pose route, or ``(None, why)`` when its corridor does not
    cover every disc centre monotonically (see the module docstring).

    Args:
        areas: the safe areas the route was searched on.
        route: the pose route.
        goal: (2,) [m] the goal the plan reports.
        offsets: (D, 2) [m] disc centres in the body frame.
        dt: [s] reference period.
        v_cap, v_rev_cap: [m/s] speed caps forwards / backwards (> 0).
        w_cap: [rad/s], a_cap: [m/s^2], alpha_cap: [rad/s^2], a_lat: [m/s^2] limits.
        info: diagnostics to start the plan's ``info`` from.
        margin: [m] SA-MPC's ``box_margin`` (the per-disc chains' boxes are shrunk by it).
        slow_clearance, slow_floor: with ``raster``, the speed cap at a pose is scaled by
            ``clip(c / slow_clearance, slow_floor, 1)``, ``c`` [m] the smallest clearance of
            its disc centres in the free set (precise tracking where the footprint barely
            fits); ``slow_clearance = 0`` (default): no scaling. Measured on the 100
            BARN-like worlds with 0.1 m / 0.3: 72 / 100 and mean BARN 0.294 against 73 / 100
            and 0.342 without (one stall fewer, two more, every tight world slower).
        hold_at_stops: give the reference its ``stops`` (the samples where the motion kind
            changes: cusps, turns on the spot), at which SA-MPC holds its horizon until the
            robot arrives. Off by default: measured on the 100 worlds 72 / 100 (BARN 0.339)
            against 73 / 100 (0.342) without (barn_0086 stalls with it; barn_0052 succeeds
            only with it and the slow-down together).
        grow_members: [m] > 0: the per-disc chains' members grown to maximal free
            rectangles, at most this per side
            (:func:`~sanav_mj.planning.pose_search.member_boxes` with ``grow``; the plan's
            ``info["grown_members"]`` tells SA-MPC to build its chains the same way).
        sliver_width: [m] > 0 with ``grow_members`` > 0 and ``areas.free`` set: where a disc
            centre's dense trajectory lies in no member box whose sides are all at least
            this long, boxes grown around its points (:func:`sliver_boxes`) are further
            candidates of its chain (``Plan.extra_members``); 0 (default): none.
        raster: the free set the route was searched on; given, the route is smoothed
            (:func:`smooth_route`) and the smoothed one used when every dense pose of it
            is free (``info["pose_smoothed"]``).
    """
    t0 = time.perf_counter()
    offsets = np.asarray(offsets, dtype=float)
    dense, kinds = densify(route, offsets)
    smoothed = False
    if raster is not None:
        sm = smooth_route(route, raster, offsets)
        for _ in range(6):  # revert the smoothed poses around moves the dense check rejects
            bad = _bad_moves(sm, raster, offsets)
            if bad.size == 0:
                dense, kinds = densify(sm, offsets)
                smoothed = True
                break
            P = sm.poses.copy()
            for e in bad:
                lo, hi = max(0, e - 2), min(len(P), e + 4)
                P[lo:hi] = route.poses[lo:hi]
            sm = PoseRoute(P, sm.kinds, sm.cost, sm.nodes, sm.edges, sm.time_ms)
    rects = np.asarray(areas.rects, dtype=float)
    boxes = member_boxes(areas, 0.0, grow=grow_members)

    free = getattr(areas, "free", None)
    extra = np.zeros((0, 4))

    def disc_chains(dense: np.ndarray) -> tuple[list[np.ndarray] | None, str, np.ndarray]:
        discs = disc_points(dense[:, 0], dense[:, 1], dense[:, 2], offsets)
        ext = np.zeros((0, 4))
        sliver = None
        if sliver_width > 0 and grow_members > 0 and free is not None:
            ext = sliver_boxes(boxes, discs.reshape(-1, 2), free, sliver_width, grow_members)
            wide = boxes[np.min(boxes[:, 2:] - boxes[:, :2], axis=1) >= sliver_width]
            sliver = ~_in_boxes(discs.reshape(-1, 2), wide).any(axis=1).reshape(discs.shape[:2])
        cand = np.vstack((boxes, ext))
        chains = []
        for d in range(discs.shape[1]):
            ch = member_chain(cand, discs[:, d], margin, overlap_at=None if sliver is None else sliver[:, d])
            if ch is None and sliver is not None:  # the overlap rule walked into a dead end
                ch = member_chain(cand, discs[:, d], margin)
            if ch is None:
                return None, f"disc {d} of the pose path has no chain of safe areas and portal bridges", ext
            chains.append(ch)
        return chains, "ok", ext

    c = int(np.argmin(np.hypot(*offsets.T)))

    def centre_corridor(dense: np.ndarray) -> np.ndarray | None:
        discs = disc_points(dense[:, 0], dense[:, 1], dense[:, 2], offsets)
        corridor = corridor_of_points(areas, discs[:, c])
        return None if corridor is None or chain_walk(rects, corridor, discs[:, c]) is None else corridor

    def tries(first: tuple):
        """The smoothed route (when there is one), then the lattice route itself (densified
        only when it is needed)."""
        yield first
        if first[2]:
            yield (*densify(route, offsets), False)

    # the first route whose every disc has a chain and whose centre has a corridor
    for dense, kinds, smoothed in tries((dense, kinds, smoothed)):
        chains, why, extra = disc_chains(dense)
        if chains is None:
            continue
        corridor = centre_corridor(dense)
        if corridor is not None:
            break
        why = "the pose path's centre crosses a corner between safe areas"
    else:
        return None, why
    discs = disc_points(dense[:, 0], dense[:, 1], dense[:, 2], offsets)
    v_scale = None
    if raster is not None and slow_clearance > 0:
        clr = raster.clearance_at(discs).min(axis=-1)
        v_scale = np.clip(clr / slow_clearance, slow_floor, 1.0)
    times = time_poses(dense, kinds, v_cap, v_rev_cap, w_cap, a_cap, alpha_cap, a_lat, v_scale)
    states, inputs = sample_reference(dense, times, dt)
    pos = chain_walk(rects, corridor, disc_points(states[:, 0], states[:, 1], states[:, 2], offsets)[:, c])
    if pos is None and grow_members > 0:  # grown members: the centre may cut a corner of the plain areas
        pos = _loose_walk(rects, corridor, disc_points(states[:, 0], states[:, 1], states[:, 2], offsets)[:, c])
    if pos is None:  # the samples are points of the dense path; guard
        return None, "reference samples not covered by the corridor"
    stops = None
    if hold_at_stops:
        change = np.flatnonzero(kinds[1:] != kinds[:-1]) + 1  # dense poses where the motion kind changes
        stops = np.unique(np.clip(np.rint(times[change] / dt).astype(np.int64), 0, len(states) - 1))
    ref = Reference(dt=dt, states=states, inputs=inputs, area=corridor[pos], stops=stops)
    path_len = float(np.hypot(*np.diff(dense[:, :2], axis=0).T).sum())
    inf = dict(info or {})
    if grow_members > 0:
        inf["grown_members"] = float(grow_members)
    used = np.unique(np.concatenate(chains)) if chains else np.zeros(0, dtype=np.int64)
    n_base = len(boxes)
    if extra.shape[0] and used.max() >= n_base:  # keep the extra boxes a chain uses, renumbered
        keep = used[used >= n_base] - n_base
        renum = np.full(extra.shape[0], -1, dtype=np.int64)
        renum[keep] = n_base + np.arange(keep.size)
        chains = [np.where(ch >= n_base, renum[np.maximum(ch - n_base, 0)], ch) for ch in chains]
        extra = extra[keep]
        inf["sliver_boxes"] = int(keep.size)
    else:
        extra = np.zeros((0, 4))
    inf.update(pose_route=True, pose_smoothed=smoothed, corridor_areas=int(corridor.size), path_length_m=path_len,
               duration_s=float(times[-1]), pose_search_ms=route.time_ms, pose_nodes=route.nodes,
               pose_reverse_m=float(sum(np.hypot(*(b[:2] - a[:2])) for a, b, k in
                                        zip(route.poses[:-1], route.poses[1:], route.kinds) if k == REVERSE)),
               pose_spin_rad=float(sum(abs(b[2] - a[2]) for a, b, k in
                                       zip(route.poses[:-1], route.poses[1:], route.kinds) if k == SPIN)),
               route_ms=(time.perf_counter() - t0) * 1e3)
    wp = route.poses[:, :2].copy()
    return Plan(True, "ok", corridor, np.asarray(goal, float).copy(), wp, dense[:, :2].copy(), dense[:, :2].copy(),
                ref, inf, tuple(chains), extra if extra.shape[0] else None,
                _area_of_boxes(rects, extra) if extra.shape[0] else None), "ok"
