"""Manoeuvres where the corridor reference leaves the safe areas (``"discs"`` mode).

The corridor reference's yaw is its path's tangent. Where the path turns from one narrow
passage into another, the reference can ask for poses whose disc centres lie outside every
safe area (barn_0017, barn_0031 at refine 4: it drives straight into a junction and turns on
the spot where the footprint has no room to turn). Pointwise repairs move each such sample
to a nearby admissible pose, but the moved samples need not form a motion the robot can
drive, and SA-MPC stalls at the junction.

:func:`manoeuvre_route` replaces each stretch of such samples by a driven manoeuvre: a
search over poses (:func:`search_manoeuvre`, hybrid A*: continuous poses, one visit per
``cell`` x ``yaw_cell`` cell) with unicycle motion primitives (forward and backward straight
moves and arcs of length ``step``, turns on the spot by ``turn``), every pose sampled along a
primitive keeping every disc centre in a safe area (:func:`union_admissible`), from the
last admissible sample ``back`` before the stretch to the first admissible one ``ahead``
after it. The result is a pose route (poses and move kinds) that
:func:`sanav_mj.planning.pose_reference.route_plan` turns into a plan with one chain of
safe areas per disc, SA-MPC's pose-route mode: the disc rows and their safety argument are
those of that mode, only the route is new.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sanav_mj.planning.pose_search import disc_points


@dataclass(frozen=True)
class ManoeuvreConfig:
    """Settings of :func:`search_manoeuvre` and :func:`manoeuvre_reference`.

    Attributes:
        step: [m] length of a translating primitive (> 0).
        turn: [rad] yaw change of an arc and of a turn on the spot (> 0).
        cell: [m] position cell of the visited set (> 0).
        yaw_cell: [rad] yaw cell of the visited set (> 0; 2 pi / yaw_cell rounded).
        samples: poses checked along each primitive (>= 1, the end pose included).
        reverse_factor: cost factor of backward length (>= 1).
        spin_cost: [m/rad] cost of a turn on the spot per radian.
        arc_cost: [m/rad] extra cost of an arc per radian.
        cusp_cost: [m] cost of a change of driving direction.
        max_expansions: search budget (poses expanded) per stretch.
        goal_tol: [m] position tolerance at the goal pose; goal_yaw_tol: [rad] its yaw.
        back, ahead: [m] reference arc length before / after a stretch of bad samples at
            which the manoeuvre starts / ends (then the nearest admissible sample outward).
        grow: [m] the member boxes (safe areas and portal bridges) of the manoeuvres and of
            the route's per-disc chains are grown to maximal free rectangles, at most this
            per side (:func:`~sanav_mj.planning.pose_search.member_boxes`).
        slack: [m] how far inside a member box every disc centre of a manoeuvre stays (a
            centre passing the corner where four safe areas meet lies in no box with slack,
            so the route's per-disc chains can walk it: they move on through overlaps).
        sliver_width: [m] where a disc centre of the route lies in no member box whose
            sides are all at least this long (a diagonal staircase of slivers), boxes of
            free cells grown around its points are candidates of its chain
            (:func:`~sanav_mj.planning.pose_reference.sliver_boxes`); 0: none.
        smooth: the route (manoeuvres and the reference between them) is smoothed where
            every disc centre stays in free cells of the map
            (:func:`~sanav_mj.planning.pose_reference.smooth_route`; the lattice route
            when the smoothed one's chains do not cover its discs).
        slow_clearance: [m] with ``smooth``, the route's speed cap at a pose is scaled by
            ``clip(c / slow_clearance, 0.3, 1)``, ``c`` the smallest clearance of its disc
            centres in the free cells (:func:`~sanav_mj.planning.pose_reference.route_plan`);
            0: no scaling.
    """

    step: float = 0.02
    turn: float = math.radians(10.0)
    cell: float = 0.01
    yaw_cell: float = math.radians(5.0)
    samples: int = 4
    reverse_factor: float = 2.0
    spin_cost: float = 0.1
    arc_cost: float = 0.05
    cusp_cost: float = 0.3
    max_expansions: int = 60000
    goal_tol: float = 0.02
    goal_yaw_tol: float = math.radians(10.0)
    back: float = 0.3
    ahead: float = 0.3
    slack: float = 0.001
    grow: float = 0.25
    sliver_width: float = 0.06
    smooth: bool = True
    slow_clearance: float = 0.1

    def __post_init__(self) -> None:
        for name in ("step", "turn", "cell", "yaw_cell", "goal_tol", "goal_yaw_tol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"ManoeuvreConfig.{name}: expected a finite number > 0, got {v!r}")
        for name in ("spin_cost", "arc_cost", "cusp_cost", "back", "ahead", "slack", "grow", "sliver_width",
                     "slow_clearance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"ManoeuvreConfig.{name}: expected a finite number >= 0, got {v!r}")
        if not (math.isfinite(self.reverse_factor) and self.reverse_factor >= 1):
            raise ValueError(f"ManoeuvreConfig.reverse_factor: expected >= 1, got {self.reverse_factor!r}")
        for name in ("samples", "max_expansions"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"ManoeuvreConfig.{name}: expected an integer >= 1, got {v!r}")


def primitive_poses(pose, ds: float, dyaw: float, n: int) -> np.ndarray:
    """(n, 3) [m, m, rad] poses at fractions 1/n .. 1 of a unicycle primitive from ``pose``
    (3,): a straight move by ``ds`` [m] (``dyaw`` 0), a turn on the spot by ``dyaw`` [rad]
    (``ds`` 0), or an arc of length ``ds`` turning by ``dyaw`` (radius ``ds / dyaw``)."""
    x, y, th = (float(v) for v in pose)
    t = np.arange(1, n + 1) / n
    yaw = th + dyaw * t
    if dyaw == 0.0:
        return np.stack([x + ds * t * math.cos(th), y + ds * t * math.sin(th), yaw], axis=1)
    if ds == 0.0:
        return np.stack([np.full(n, x), np.full(n, y), yaw], axis=1)
    rr = ds / dyaw
    return np.stack([x + rr * (np.sin(yaw) - math.sin(th)), y - rr * (np.cos(yaw) - math.cos(th)), yaw], axis=1)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def search_manoeuvre(admissible: Callable[[np.ndarray], np.ndarray], start, goal,
                     config: ManoeuvreConfig = ManoeuvreConfig()) -> list[tuple[np.ndarray, float, float]] | None:
    """A unicycle manoeuvre from ``start`` to near ``goal`` through admissible poses.

    Hybrid A* over the primitives of :class:`ManoeuvreConfig` (forward / backward straight
    and arcs, turns on the spot), each accepted when all its ``samples`` poses are
    admissible; cost: length (backward x ``reverse_factor``) + ``arc_cost`` / ``spin_cost``
    per radian + ``cusp_cost`` per change of direction; heuristic: the straight distance
    to the goal. Ends at the first expanded pose within ``goal_tol`` / ``goal_yaw_tol``.

    Args:
        admissible: ``f(poses (K, 3)) -> (K,) bool``.
        start, goal: (3,) [m, m, rad] poses (the start is taken as admissible).
        config: the search settings.

    Returns:
        The edges ``[(pose (3,), ds, dyaw), ...]`` from ``start`` (whose edge is (start, 0,
        0)) to the end pose, each pose reached from the previous by the primitive
        ``(ds, dyaw)``; None when the budget runs out or the reachable set is exhausted.
    """
    c = config
    s0 = np.asarray(start, dtype=float)
    g = np.asarray(goal, dtype=float)
    nyaw = max(1, int(round(2.0 * math.pi / c.yaw_cell)))
    prims = [(c.step, 0.0), (-c.step, 0.0), (c.step, c.turn), (c.step, -c.turn), (-c.step, c.turn),
             (-c.step, -c.turn), (0.0, c.turn), (0.0, -c.turn)]

    def key(p) -> tuple[int, int, int]:
        return (int(round(p[0] / c.cell)), int(round(p[1] / c.cell)),
                int(round((p[2] % (2.0 * math.pi)) / (2.0 * math.pi / nyaw))) % nyaw)

    def sign(ds: float) -> int:
        return 0 if ds == 0.0 else (1 if ds > 0 else -1)

    start_key = key(s0)
    best = {start_key: 0.0}
    parent: dict[tuple[int, int, int], tuple] = {start_key: (None, s0, 0.0, 0.0, 0)}
    heap = [(math.hypot(*(s0[:2] - g[:2])), 0, 0.0, start_key)]
    tie = 0
    for _ in range(c.max_expansions):
        if not heap:
            return None
        _, _, cost, k = heapq.heappop(heap)
        if cost > best.get(k, math.inf):
            continue
        _, pose, _, _, last = parent[k]
        if math.hypot(pose[0] - g[0], pose[1] - g[1]) <= c.goal_tol and abs(_wrap(pose[2] - g[2])) <= c.goal_yaw_tol:
            edges = []
            while k is not None:
                pk, p, ds, dy, _ = parent[k]
                edges.append((p, ds, dy))
                k = pk
            return edges[::-1]
        segs = np.concatenate([primitive_poses(pose, ds, dy, c.samples) for ds, dy in prims])
        ok = np.asarray(admissible(segs), dtype=bool).reshape(len(prims), c.samples).all(axis=1)
        for (ds, dy), good, j in zip(prims, ok, range(len(prims))):
            if not good:
                continue
            q = segs[(j + 1) * c.samples - 1]
            d = sign(ds)
            step_cost = (abs(ds) * (c.reverse_factor if ds < 0 else 1.0)
                         + abs(dy) * (c.spin_cost if ds == 0.0 else c.arc_cost)
                         + (c.cusp_cost if d != 0 and last != 0 and d != last else 0.0))
            nk = key(q)
            nc = cost + step_cost
            if nc < best.get(nk, math.inf):
                best[nk] = nc
                parent[nk] = (k, q, ds, dy, d if d != 0 else last)
                tie += 1
                heapq.heappush(heap, (nc + math.hypot(q[0] - g[0], q[1] - g[1]), tie, nc, nk))
    return None


def bad_stretches(bad: np.ndarray, arc: np.ndarray, back: float, ahead: float) -> list[tuple[int, int]]:
    """Anchor pairs ``(i0, i1)`` around the runs of ``bad`` (K,) bool samples: ``i0`` the last
    good sample at least ``back`` [m] of arc length ``arc`` (K,) before the run, ``i1`` the
    first good one at least ``ahead`` after it (runs whose windows overlap are merged); runs
    without a good sample on either side are left out."""
    bad = np.asarray(bad, dtype=bool)
    good = np.flatnonzero(~bad)
    out: list[tuple[int, int]] = []
    k = len(bad)
    i = 0
    while i < k:
        if not bad[i]:
            i += 1
            continue
        j = i
        while j + 1 < k and bad[j + 1]:
            j += 1
        lo = good[(good < i) & (arc[good] <= arc[i] - back)]
        hi = good[(good > j) & (arc[good] >= arc[j] + ahead)]
        if lo.size and hi.size:
            a, b = int(lo[-1]), int(hi[0])
            if out and a <= out[-1][1]:
                a = out[-1][0]
                out.pop()
            out.append((a, b))
        i = j + 1
    return out


def union_admissible(rects: np.ndarray, offsets: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """``f(poses (K, 3)) -> (K,) bool``: every disc centre (body offsets ``offsets`` (D, 2)
    [m]) of a pose lies in one of the closed rectangles ``rects`` (R, 4) [m] (the safe areas,
    whose portal bridges they contain)."""
    r = np.asarray(rects, dtype=float)
    o = np.asarray(offsets, dtype=float)

    def f(poses: np.ndarray) -> np.ndarray:
        x = np.asarray(poses, dtype=float)
        p = disc_points(x[:, 0], x[:, 1], x[:, 2], o)  # (K, D, 2)
        px, py = p[..., 0:1], p[..., 1:2]
        return ((r[:, 0] <= px) & (px <= r[:, 2]) & (r[:, 1] <= py) & (py <= r[:, 3])).any(axis=-1).all(axis=-1)
    return f


def manoeuvre_route(boxes: np.ndarray, states: np.ndarray, offsets: np.ndarray,
                    config: ManoeuvreConfig = ManoeuvreConfig()) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The poses of a reference with each stretch whose disc centres leave the safe areas
    replaced by a manoeuvre (module docstring), as a pose route.

    Args:
        boxes: (M, 4) [m] the member boxes a disc centre may be held to: the safe areas and
            the bridges across their portals
            (:func:`sanav_mj.planning.pose_search.member_boxes` with margin 0). A sample is
            admissible when every disc centre lies in one of them; a manoeuvre's poses when
            every disc centre lies ``slack`` inside one.
        states: (K, 3) [m, m, rad] the corridor reference's states (driven forwards).
        offsets: (D, 2) [m] disc centres in the body frame.
        config: the search settings.

    Returns:
        ``(poses (P, 3), kinds (P-1,), replaced)``: the route's poses (yaw continuous), the
        kind of each move (:data:`~sanav_mj.planning.pose_search.FORWARD`, ``REVERSE``,
        ``SPIN`` as 1, -1, 0) and how many stretches were replaced; None when a stretch has no
        manoeuvre within the budget (or a bad sample has no admissible one on a side). With
        every sample admissible: the states themselves, all forward, 0.
    """
    states = np.asarray(states, dtype=float)
    rects = np.asarray(boxes, dtype=float)
    inner = np.concatenate((rects[:, :2] + config.slack, rects[:, 2:] - config.slack), axis=1)
    inner = inner[np.all(inner[:, 2:] >= inner[:, :2], axis=1)]
    reach = float(np.hypot(*np.asarray(offsets, float).T).max())
    bad = ~union_admissible(rects, offsets)(states)
    kinds_all = np.ones(max(0, len(states) - 1), dtype=int)
    if not bad.any():
        return states.copy(), kinds_all, 0
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(states[:, :2], axis=0).T))])
    runs = bad_stretches(bad, arc, config.back, config.ahead)
    covered = np.zeros(len(states), dtype=bool)
    for i0, i1 in runs:
        covered[i0:i1 + 1] = True
    if (bad & ~covered).any():
        return None
    poses, into, last = [], [], 0  # into[j]: kind of the move arriving at the pose (the first: unused)
    for i0, i1 in runs:
        pad = reach + config.back + config.ahead + 0.3
        lo = states[i0:i1 + 1, :2].min(axis=0) - pad
        hi = states[i0:i1 + 1, :2].max(axis=0) + pad
        near = inner[(inner[:, 2] >= lo[0]) & (inner[:, 0] <= hi[0]) & (inner[:, 3] >= lo[1]) & (inner[:, 1] <= hi[1])]
        edges = search_manoeuvre(union_admissible(near, offsets), states[i0], states[i1], config)
        if edges is None:
            return None
        poses.append(states[last:i0])
        m = np.array([e[0] for e in edges])
        poses.append(m)
        into.append(np.zeros(0, dtype=int))  # filled from the geometry below
        into.append(np.array([0] + [0 if ds == 0.0 else (1 if ds > 0 else -1) for _, ds, _ in edges[1:]], dtype=int))
        # the reference after it, its yaw continued from the manoeuvre's end (same turn count)
        shift = 2.0 * math.pi * round((m[-1, 2] - states[i1, 2]) / (2.0 * math.pi))
        states = states.copy()
        states[i1 + 1:, 2] += shift
        last = i1 + 1
    poses.append(states[last:])
    into.append(np.zeros(0, dtype=int))
    P = np.concatenate(poses)
    step = np.diff(P, axis=0)
    along = step[:, 0] * np.cos(P[:-1, 2]) + step[:, 1] * np.sin(P[:-1, 2])
    K = np.where(np.hypot(step[:, 0], step[:, 1]) < 1e-9, 0, np.where(along >= 0, 1, -1)).astype(int)
    # a manoeuvre's moves keep the kinds of their primitives (an arc's chord may point aside)
    start = 0
    for chunk, kinds in zip(poses, into):
        if kinds.size:
            K[start: start + len(chunk) - 1] = kinds[1:]
        start += len(chunk)
    return P, K, len(runs)
