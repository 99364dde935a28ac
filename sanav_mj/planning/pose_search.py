"""Footprint-aware route search in (x, y, yaw) over the safe areas (SA-MPC's ``"discs"`` mode).

The robot's footprint is covered by discs whose centres lie on its long axis at body offsets
``o_d`` (:meth:`sanav_mj.footprint.Footprint.discs`); in a map inflated by the disc radius a
pose is clear when every disc centre lies in the safe areas. SA-MPC's hard rows ask for more:
each centre in a stage box, i.e. a safe area (or a bridge across a portal) shrunk by
``box_margin``. This module searches a pose path whose every sampled pose keeps every disc
centre in that set, so the corridor and the reference it gives agree with the MPC's rows.

**Free set of a point.** SA-MPC's stage boxes are chain members shrunk by ``margin``: safe
areas and the bridge boxes across the portals of adjacent areas
(:func:`member_boxes`). Their union is rasterised on a fine grid (``raster`` [m]; a cell is
free only when it lies inside one box), so a point in a free cell lies in a box a disc
centre may be held to. (The union of the areas merely eroded by the margin is larger: it
keeps the corner where four areas meet, which no shrunk box holds, and a path through it
cannot be followed under the MPC's rows.)

**Lattice.** Positions are the map's cell centres (spacing ``h``); headings are the 16
directions of the 16-connected neighbourhood ``(1,0), (2,1), (1,1), (1,2), ...`` (0, 26.6,
45, 63.4, ... deg), so a straight move along a heading ends exactly on a lattice point.
A node ``(ix, iy, k)`` exists when every disc centre of its pose is free. Moves:

- straight forward / backward by the heading's lattice vector ``d_k`` (length ``|d_k| h``);
- arcs forward / backward to the neighbouring heading ``k +- 1`` by ``d_k + d_{k+-1}``
  (the chord of an arc turning from one heading to the other, radius about 0.3-0.5 m at
  5 cm cells);
- turns on the spot to ``k +- 1``, only where the circle of radius ``sweep`` (the largest
  disc-centre offset) about the position fits in one safe area shrunk by ``margin``: the
  rule of SA-MPC's ``turn_allowed`` (every centre stays in that one stage box while turning,
  so the per-disc stage assignment stays monotone).

A translating move is accepted when its end nodes exist and the disc centres of the poses
sampled along it (position and yaw interpolated linearly, at most ``check_spacing`` of
disc-centre travel apart) are free. Costs: length
(x ``reverse_factor`` backwards) + ``arc_cost`` per radian of an arc + a clearance term
``clearance_weight * length * max(0, 1 - c / clearance_ref)`` with ``c`` the smallest
distance of the end pose's disc centres to the boundary of the free set; turns on the spot
cost ``spin_cost`` per radian. Dijkstra (``scipy.sparse.csgraph``) from a virtual start
node joined to the headings at the start's cell (cost: the turn from the start yaw), to the
cheapest node within ``goal_radius`` of the goal.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

#: the 16 lattice directions (dx, dy) in cells, counter-clockwise from +x.
DIRECTIONS = np.array([(1, 0), (2, 1), (1, 1), (1, 2), (0, 1), (-1, 2), (-1, 1), (-2, 1),
                       (-1, 0), (-2, -1), (-1, -1), (-1, -2), (0, -1), (1, -2), (1, -1), (2, -1)], dtype=int)
#: (16,) [rad] the lattice headings, in (-pi, pi].
HEADINGS = np.arctan2(DIRECTIONS[:, 1], DIRECTIONS[:, 0]).astype(float)

#: move kinds of a pose path's edges.
FORWARD, REVERSE, SPIN = 1, -1, 0


def wrap(a):
    """Angles wrapped to [-pi, pi) [rad]."""
    return (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class PoseSearchConfig:
    """Settings of the pose search (all validated on construction).

    Attributes:
        raster: [m] cell of the fine raster of the free set of a disc centre.
        margin: [m] SA-MPC's ``box_margin``: the free set is the union of the safe areas
            and portal bridges shrunk by this (:func:`member_boxes`).
        reverse_factor: cost factor of driving backwards (>= 1).
        spin_cost: [m/rad] cost of turning on the spot.
        arc_cost: [m/rad] cost of turning while driving (on top of the length).
        clearance_ref: [m] disc centres closer than this to the free set's boundary make a
            move dearer ...
        clearance_weight: ... by up to this times its length (at zero clearance).
        goal_radius: [m] the path ends at the cheapest node within this of the goal.
        start_radius: [m] the path starts at a node within this of the start.
        spin_anywhere: also turn on the spot by one heading step where the disc centres of
            the poses sampled along the turn are free (a partial turn, e.g. to align with a
            passage); False: only where the whole sweep circle fits in one area.
        check_spacing: [m] a move is checked at poses whose disc centres are at most this
            far apart (position and yaw interpolated linearly).
    """

    raster: float = 0.005
    margin: float = 0.02
    reverse_factor: float = 3.0
    spin_cost: float = 0.5
    arc_cost: float = 0.05
    clearance_ref: float = 0.1
    clearance_weight: float = 1.0
    goal_radius: float = 0.1
    start_radius: float = 0.1
    spin_anywhere: bool = True
    check_spacing: float = 0.02

    def __post_init__(self) -> None:
        for name in ("raster", "clearance_ref", "goal_radius", "start_radius", "check_spacing"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"PoseSearchConfig.{name} must be a finite number > 0 [m], got {v!r}")
        for name in ("margin", "spin_cost", "arc_cost", "clearance_weight"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"PoseSearchConfig.{name} must be a finite number >= 0, got {v!r}")
        if not (isinstance(self.reverse_factor, (int, float)) and math.isfinite(self.reverse_factor)
                and self.reverse_factor >= 1):
            raise ValueError(f"PoseSearchConfig.reverse_factor must be a finite number >= 1, got {self.reverse_factor!r}")


@dataclass(frozen=True)
class PointRaster:
    """Where a disc centre may be: a boolean raster and its clearance.

    Attributes:
        origin: (2,) [m] lower-left corner.
        cell: [m] cell edge.
        free: (ny, nx) bool, True where every point of the cell is in the free set.
        clearance: (ny, nx) [m] distance from the cell to the nearest non-free cell (0 when
            not free).
    """

    origin: np.ndarray
    cell: float
    free: np.ndarray
    clearance: np.ndarray

    @staticmethod
    def build(rects: np.ndarray, origin, extent, cell: float, margin: float = 0.0) -> PointRaster:
        """Rasterise the union of ``rects`` (R, 4) [m] over ``origin`` (2,) + ``extent`` (2,) [m]
        at ``cell`` [m] (a cell is free when it lies inside one rectangle) and erode it by
        ``margin`` [m] (a cell stays free when every cell within ``ceil(margin / cell)``
        cells in x and y is free)."""
        origin = np.asarray(origin, dtype=float)
        nx = int(math.ceil(float(extent[0]) / cell - 1e-9))
        ny = int(math.ceil(float(extent[1]) / cell - 1e-9))
        free = np.zeros((ny, nx), dtype=bool)
        eps = 1e-6
        for x0, y0, x1, y1 in np.asarray(rects, dtype=float).reshape(-1, 4):
            i0 = max(0, int(math.ceil((x0 - origin[0]) / cell - eps)))
            i1 = min(nx, int(math.floor((x1 - origin[0]) / cell + eps)))
            j0 = max(0, int(math.ceil((y0 - origin[1]) / cell - eps)))
            j1 = min(ny, int(math.floor((y1 - origin[1]) / cell + eps)))
            if i1 > i0 and j1 > j0:
                free[j0:j1, i0:i1] = True
        k = int(math.ceil(margin / cell - 1e-9))
        if k > 0:
            free = ndimage.minimum_filter(free.view(np.uint8), size=2 * k + 1, mode="constant", cval=0).astype(bool)
        clearance = ndimage.distance_transform_edt(free) * cell if free.any() else np.zeros(free.shape)
        return PointRaster(origin, float(cell), free, clearance)

    @staticmethod
    def of_free(cells) -> PointRaster:
        """The free cells of a grid's :class:`~sanav_mj.mapping.grow.FreeCells` (the cells of
        the map inflated for a disc, where the safe areas and every box grown from them lie)
        as a raster at the grid's own cells, with its clearance."""
        sat = np.asarray(cells.sat)
        occ = sat[1:, 1:] - sat[:-1, 1:] - sat[1:, :-1] + sat[:-1, :-1]
        free = occ == 0
        clearance = ndimage.distance_transform_edt(free) * cells.resolution if free.any() else np.zeros(free.shape)
        return PointRaster(np.asarray(cells.origin, dtype=float).copy(), float(cells.resolution), free, clearance)

    def index(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices (iy, ix) of points (..., 2) [m] and whether they are on the raster."""
        q = np.floor((np.asarray(pts, dtype=float) - self.origin) / self.cell)
        ix, iy = q[..., 0], q[..., 1]
        ny, nx = self.free.shape
        inb = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        ix = np.where(inb, ix, 0).astype(np.int64)
        iy = np.where(inb, iy, 0).astype(np.int64)
        return iy, ix, inb

    def is_free(self, pts: np.ndarray) -> np.ndarray:
        """(...) bool: whether each point (..., 2) [m] is in the free set."""
        iy, ix, inb = self.index(pts)
        return self.free[iy, ix] & inb

    def clearance_at(self, pts: np.ndarray) -> np.ndarray:
        """(...) [m] clearance of each point (..., 2) (0 off the raster)."""
        iy, ix, inb = self.index(pts)
        return np.where(inb, self.clearance[iy, ix], 0.0)


def member_boxes(areas, margin: float, grow: float = 0.0) -> np.ndarray:
    """(R + E, 4) [m] the safe areas and the bridge boxes across their portals, each shrunk
    by ``margin`` [m] per side (at most a quarter of its width), as SA-MPC's corridor chain
    builds them (:class:`sanav_mj.control.stages.CorridorChain`): a bridge across the portal
    ``x = c, y in [y0, y1]`` of areas a, b is ``[min(xmin), max(xmax)] x [y0, y1]`` (inside
    a ∪ b), and likewise for a horizontal portal. With ``grow`` > 0 [m] and ``areas.free``
    set (:class:`~sanav_mj.mapping.grow.FreeCells`), every box is first grown to a maximal
    free rectangle of the grid, at most ``grow`` per side
    (:func:`~sanav_mj.mapping.grow.grow_rect`, as the corridor chain grows its members: only
    free cells, as safe as a safe area)."""
    rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
    boxes = [rects]
    edges = np.asarray(areas.edges, dtype=int).reshape(-1, 2)
    if edges.size:
        a, b = rects[edges[:, 0]], rects[edges[:, 1]]
        lo = np.maximum(a[:, :2], b[:, :2])
        hi = np.minimum(a[:, 2:], b[:, 2:])
        vertical = (hi[:, 0] - lo[:, 0]) <= 1e-9
        br = np.empty_like(a)
        br[:, 0] = np.where(vertical, np.minimum(a[:, 0], b[:, 0]), lo[:, 0])
        br[:, 2] = np.where(vertical, np.maximum(a[:, 2], b[:, 2]), hi[:, 0])
        br[:, 1] = np.where(vertical, lo[:, 1], np.minimum(a[:, 1], b[:, 1]))
        br[:, 3] = np.where(vertical, hi[:, 1], np.maximum(a[:, 3], b[:, 3]))
        boxes.append(br)
    out = np.vstack(boxes)
    free = getattr(areas, "free", None)
    if grow > 0 and free is not None:
        from sanav_mj.mapping.grow import grow_rect

        out = np.array([grow_rect(free, b, limit=grow) for b in out]).reshape(-1, 4)
    w = out[:, 2:] - out[:, :2]
    m = np.minimum(margin, 0.25 * np.maximum(w, 0.0))
    return np.concatenate((out[:, :2] + m, out[:, 2:] - m), axis=1)


def disc_points(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """World disc centres (..., D, 2) [m] of poses given by broadcastable x, y, yaw arrays."""
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    px = x[..., None] + offsets[:, 0] * c - offsets[:, 1] * s
    py = y[..., None] + offsets[:, 0] * s + offsets[:, 1] * c
    return np.stack([px, py], axis=-1)


def poses_free(raster: PointRaster, poses: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(P,) bool: whether every disc centre of each pose (P, 3) [m, m, rad] is free."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    pts = disc_points(poses[:, 0], poses[:, 1], poses[:, 2], np.asarray(offsets, float))
    return raster.is_free(pts).all(axis=-1)


def spin_cells(rects: np.ndarray, centres_x: np.ndarray, centres_y: np.ndarray, reach: float) -> np.ndarray:
    """(ny, nx) bool: lattice points ``(centres_x[ix], centres_y[iy])`` [m] inside some
    rectangle of ``rects`` (R, 4) shrunk by ``reach`` [m] (a circle of that radius fits in it)."""
    out = np.zeros((centres_y.size, centres_x.size), dtype=bool)
    for x0, y0, x1, y1 in np.asarray(rects, dtype=float).reshape(-1, 4):
        if x1 - x0 < 2 * reach or y1 - y0 < 2 * reach:
            continue
        i0, i1 = np.searchsorted(centres_x, [x0 + reach, x1 - reach + 1e-12], side="left")
        j0, j1 = np.searchsorted(centres_y, [y0 + reach, y1 - reach + 1e-12], side="left")
        if i1 > i0 and j1 > j0:
            out[j0:j1, i0:i1] = True
    return out


@dataclass(frozen=True)
class PoseRoute:
    """A pose path found by :func:`search_poses`.

    Attributes:
        poses: (P, 3) [m, m, rad] lattice poses from start to goal, yaw unwrapped.
        kinds: (P-1,) int kind of each move: :data:`FORWARD`, :data:`REVERSE`, :data:`SPIN`.
        cost: [m] path cost.
        nodes: number of lattice nodes (poses whose discs are free).
        edges: number of moves in the graph.
        time_ms: [ms] wall time of the search (raster, graph, Dijkstra).
    """

    poses: np.ndarray
    kinds: np.ndarray
    cost: float
    nodes: int
    edges: int
    time_ms: float


@dataclass(frozen=True)
class PoseSearchResult:
    """:func:`search_poses`'s answer: ``route`` (None when there is none), ``detail``, the
    wall time [ms] and the free-set ``raster`` the route was checked on."""

    route: PoseRoute | None
    detail: str
    time_ms: float
    raster: PointRaster | None = None


def search_poses(areas, origin, shape, h: float, offsets: np.ndarray, sweep: float,
                 start: np.ndarray, goal: np.ndarray, config: PoseSearchConfig = PoseSearchConfig()) -> PoseSearchResult:
    """Search a pose path whose disc centres stay in the safe areas (see the module docstring).

    Args:
        areas: the safe areas (:class:`sanav_mj.mapping.safe_areas.SafeAreas`: rects and
            edges) of a map inflated by the disc radius plus a margin.
        origin: (2,) [m] lower-left corner of the map grid; the lattice is its cell centres.
        shape: ``(ny, nx)`` cells of the map grid.
        h: [m] cell edge of the map grid (lattice spacing).
        offsets: (D, 2) [m] disc centres in the body frame (collinear).
        sweep: [m] largest distance of a disc centre from the body origin.
        start: (3,) [m, m, rad] start pose.
        goal: (2,) [m] goal.
        config: costs and rasters.

    Returns:
        :class:`PoseSearchResult`; ``route`` is None when no pose path exists (``detail``
        says where it failed).
    """
    t0 = time.perf_counter()
    offsets = np.asarray(offsets, dtype=float).reshape(-1, 2)
    start = np.asarray(start, dtype=float).reshape(3)
    goal = np.asarray(goal, dtype=float).reshape(2)
    origin = np.asarray(origin, dtype=float).reshape(2)
    ny, nx = int(shape[0]), int(shape[1])
    cx = origin[0] + (np.arange(nx) + 0.5) * h
    cy = origin[1] + (np.arange(ny) + 0.5) * h
    rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
    raster = PointRaster.build(member_boxes(areas, config.margin), origin, (nx * h, ny * h), min(config.raster, h / 4))
    spin_ok = spin_cells(rects, cx, cy, sweep + config.margin)
    K = DIRECTIONS.shape[0]
    X, Y = np.meshgrid(cx, cy)  # (ny, nx)
    valid = np.zeros((K, ny, nx), dtype=bool)
    clear = np.zeros((K, ny, nx))
    for k in range(K):
        pts = disc_points(X, Y, np.full(X.shape, HEADINGS[k]), offsets)
        valid[k] = raster.is_free(pts).all(axis=-1)
        clear[k] = raster.clearance_at(pts).min(axis=-1)
    n_nodes = K * ny * nx

    def node(k, iy, ix):
        return (k * ny + iy) * nx + ix

    src_l, dst_l, w_l = [], [], []
    for k in range(K):
        iy, ix = np.nonzero(valid[k])
        if iy.size == 0:
            continue
        moves = []
        for sign, kind in ((1, FORWARD), (-1, REVERSE)):
            moves.append((k, sign * DIRECTIONS[k], kind))
            for dk in (-1, 1):
                k2 = (k + dk) % K
                moves.append((k2, sign * (DIRECTIONS[k] + DIRECTIONS[k2]), kind))
        for k2, d, kind in moves:
            ty, tx = iy + d[1], ix + d[0]
            inb = (tx >= 0) & (tx < nx) & (ty >= 0) & (ty < ny)
            sy, sx, ty, tx = iy[inb], ix[inb], ty[inb], tx[inb]
            ok = valid[k2, ty, tx]
            sy, sx, ty, tx = sy[ok], sx[ok], ty[ok], tx[ok]
            if sy.size == 0:
                continue
            dyaw = float(wrap(HEADINGS[k2] - HEADINGS[k]))
            travel = float(np.hypot(*d)) * h + sweep * abs(dyaw)
            fr = np.arange(1, int(math.ceil(travel / config.check_spacing))) / math.ceil(travel / config.check_spacing)
            # a disc centre moves at most ``travel`` along the move, so it stays within
            # travel / 2 of one end: ends with more clearance than that (plus two raster
            # cells for the cell-centre distances) need no samples
            mid = (np.minimum(clear[k, sy, sx], clear[k2, ty, tx]) > 0.5 * travel + 2.0 * raster.cell)
            near = np.flatnonzero(~mid)
            px, py = cx[sx[near]][:, None] + fr * d[0] * h, cy[sy[near]][:, None] + fr * d[1] * h
            yaw = HEADINGS[k] + fr * dyaw
            mid[near] = raster.is_free(disc_points(px, py, np.broadcast_to(yaw, px.shape), offsets)).all(axis=(-1, -2))
            sy, sx, ty, tx = sy[mid], sx[mid], ty[mid], tx[mid]
            length = float(np.hypot(*d)) * h
            c = clear[k2, ty, tx]
            cost = length + config.arc_cost * abs(dyaw)
            cost = cost + config.clearance_weight * length * np.maximum(0.0, 1.0 - c / config.clearance_ref)
            if kind == REVERSE:
                cost = cost * config.reverse_factor
            src_l.append(node(k, sy, sx))
            dst_l.append(node(k2, ty, tx))
            w_l.append(cost)
        for dk in (-1, 1):  # turns on the spot
            k2 = (k + dk) % K
            ok = valid[k2, iy, ix]
            dyaw = float(wrap(HEADINGS[k2] - HEADINGS[k]))
            if config.spin_anywhere:
                m = int(math.ceil(sweep * abs(dyaw) / config.check_spacing))
                fr = np.arange(1, m) / m
                free = spin_ok[iy, ix] | (np.minimum(clear[k, iy, ix], clear[k2, iy, ix])
                                          > 0.5 * sweep * abs(dyaw) + 2.0 * raster.cell)
                near = np.flatnonzero(ok & ~free)
                yaw = HEADINGS[k] + fr * dyaw
                pts = disc_points(cx[ix[near]][:, None], cy[iy[near]][:, None], np.broadcast_to(yaw, (near.size, fr.size)),
                                  offsets)
                free[near] = raster.is_free(pts).all(axis=(-1, -2))
                ok &= free
            else:
                ok &= spin_ok[iy, ix]
            dyaw = abs(dyaw)
            src_l.append(node(k, iy[ok], ix[ok]))
            dst_l.append(node(k2, iy[ok], ix[ok]))
            w_l.append(np.full(int(ok.sum()), config.spin_cost * dyaw))
    # the virtual start node
    src_node = n_nodes
    dist_c = np.hypot(X - start[0], Y - start[1])
    near = np.flatnonzero((dist_c <= max(config.start_radius, 0.75 * h)).ravel())
    near = near[np.argsort(dist_c.ravel()[near])]
    start_edges = 0
    for flat in near:
        iy, ix = divmod(int(flat), nx)
        ks = np.flatnonzero(valid[:, iy, ix])
        if ks.size == 0:
            continue
        turn = np.abs(wrap(HEADINGS[ks] - start[2]))
        factor = 1.0 if spin_ok[iy, ix] else 5.0
        src_l.append(np.full(ks.size, src_node))
        dst_l.append(node(ks, iy, ix))
        w_l.append(config.spin_cost * factor * turn + dist_c[iy, ix] + 1e-9)
        start_edges += ks.size
        break  # the nearest cell with a node
    if start_edges == 0:
        ms = (time.perf_counter() - t0) * 1e3
        return PoseSearchResult(None, f"no pose with every disc centre free within {config.start_radius} m of the start", ms)
    src = np.concatenate(src_l)
    dst = np.concatenate(dst_l)
    w = np.concatenate(w_l)
    g = csr_matrix((w, (src, dst)), shape=(n_nodes + 1, n_nodes + 1))
    dist, pred = dijkstra(g, directed=True, indices=src_node, return_predecessors=True)
    gd = np.hypot(X - goal[0], Y - goal[1])
    gcells = np.flatnonzero((gd <= max(config.goal_radius, 0.75 * h)).ravel())
    best, best_node = math.inf, -1
    for flat in gcells[np.argsort(gd.ravel()[gcells])]:
        iy, ix = divmod(int(flat), nx)
        for k in range(K):
            n = node(k, iy, ix)
            if dist[n] < best - 1e-12:
                best, best_node = float(dist[n]), n
    ms = (time.perf_counter() - t0) * 1e3
    if best_node < 0 or not math.isfinite(best):
        return PoseSearchResult(None, "no pose path from the start to the goal keeps every disc centre in the safe areas", ms)
    chain = []
    n = best_node
    while n != src_node and n >= 0:
        chain.append(n)
        n = int(pred[n])
    chain = np.array(chain[::-1], dtype=np.int64)
    k = chain // (ny * nx)
    rem = chain % (ny * nx)
    iy, ix = rem // nx, rem % nx
    yaw = np.unwrap(HEADINGS[k])
    poses = np.column_stack([cx[ix], cy[iy], yaw])
    step = np.diff(poses[:, :2], axis=0)
    head = np.column_stack([np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])])
    along = np.einsum("ij,ij->i", step, head)
    kinds = np.where(np.hypot(*step.T) < 1e-9, SPIN, np.where(along >= 0, FORWARD, REVERSE)).astype(int)
    route = PoseRoute(poses, kinds, best, int(valid.sum()), int(w.size), ms)
    return PoseSearchResult(route, "ok", ms, raster)
