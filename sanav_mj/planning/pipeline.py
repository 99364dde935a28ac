"""The planning pipeline: safe areas + start + goal -> :class:`~sanav_mj.planning.reference.Plan`.

:func:`plan` composes the stages (paper Sec. III-C), each a function of its own here:

1. :func:`_corridor`, :func:`_waypoints`: start / goal areas, goal projection, graph
   search, portal waypoints (:mod:`sanav_mj.planning.corridor`);
2. :func:`_smooth`: uniform arc-length interpolation and the B-spline smoothing kept inside
   the corridor (:mod:`sanav_mj.planning.smoothing`);
3. :func:`_time_parametrise_inside`: the speed profile sampled at ``dt``, every sample
   checked against the corridor, the fallback widened around samples that leave it
   (:mod:`sanav_mj.planning.timing`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.corridor import build_graph, oriented_portals, path_length, portal_waypoints, select_corridor
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.planning.smoothing import (SafeCurve, SmoothingResult, blend_until_inside, corridor_assignment,
                                         interpolate_uniform, safe_curve)
from sanav_mj.planning.timing import PathProfile, TimedSamples, time_parametrise
from sanav_mj.scene import RobotParams

__all__ = ["PlannerConfig", "plan", "plan_document", "route_points"]


@dataclass(frozen=True)
class PlannerConfig:
    """Planner settings (all validated on construction).

    Attributes:
        dt: [s] reference sampling period (the MPC step).
        spacing: [m] arc-length spacing h of the interpolated path (eq. 5-6).
        knot_spacing: [m] B-spline knot interval (>= spacing).
        lam: [m^4] smoothing weight of eq. 7 in arc-length form (see
            :mod:`sanav_mj.planning.smoothing`; ``lam ** 0.25`` is the smoothing length scale;
            the paper's ``lambda = lam / (spacing * L^3)`` for a path of length L).
        portal_clearance: [m] distance kept between a portal crossing and the portal's ends
            (short portals are crossed at their midpoint).
        goal_offset: [m] inward offset of a goal (or start) projected into a safe area.
        max_projection: [m] a goal (or start) farther than this from every reachable safe
            area gives ``no_path``; ``math.inf`` always projects, as the paper.
        check_spacing: [m] spacing of the dense safety check of the smoothed curve, and of
            the nodes of the speed profile.
        lambda_factor: in (0, 1): when the smoothed curve leaves the corridor, ``lam`` is
            multiplied by this within ``lambda_window`` of each violation (by weighting the
            data there) and the spline refitted ...
        max_lambda_steps: ... at most this many times, before the local fallback to the
            interpolated path over the offending stretches.
        lambda_window: [m] half-width of the stretch around a violation where ``lam`` is
            reduced; ``math.inf`` reduces it along the whole path.
        blend_margin: [m] half-width of the first fallback stretch around a violation.
        blend_ramp: [m] length of the smooth transition between spline and fallback.
        speed_fraction: fraction of ``RobotParams.v_max`` used as the reference top speed.
        yaw_rate_fraction: fraction of ``RobotParams.w_max`` used as the yaw-rate limit.
        accel_fraction: fraction of ``RobotParams.a_max`` used as the acceleration limit.
        lateral_accel: [m/s^2] lateral acceleration limit ``v^2 |kappa|``.
        open_speed_fraction: None (default: one speed limit everywhere, the paper's) or a
            fraction of ``RobotParams.v_max`` used as the top speed at the path's nodes in
            open space: where the square of half-side ``open_room`` around the node holds
            only free cells of the grid the areas were cut from (``SafeAreas.free``; without
            it the option does nothing). Elsewhere ``speed_fraction`` holds, and the
            profile's backward pass slows the reference down to it before a narrow place.
        open_room: [m] half-side of that square (the room the robot's centre has in every
            direction, in the inflated map).
        search: graph search, ``"astar"`` (heapq) or ``"dijkstra"`` (scipy.sparse.csgraph).
    """

    dt: float = 0.1
    spacing: float = 0.1
    knot_spacing: float = 0.2
    lam: float = 0.01
    portal_clearance: float = 0.25
    goal_offset: float = 0.1
    max_projection: float = 1.0
    check_spacing: float = 0.02
    lambda_factor: float = 0.1
    max_lambda_steps: int = 5
    lambda_window: float = 0.5
    blend_margin: float = 0.1
    blend_ramp: float = 0.3
    speed_fraction: float = 0.8
    yaw_rate_fraction: float = 0.8
    accel_fraction: float = 0.8
    lateral_accel: float = 1.0
    open_speed_fraction: float | None = None
    open_room: float = 0.25
    search: str = "dijkstra"

    def __post_init__(self) -> None:
        positive = ("dt", "spacing", "knot_spacing", "lam", "check_spacing", "lateral_accel")
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"PlannerConfig.{name} must be a finite number > 0, got {v!r}")
        if not (isinstance(self.lambda_window, (int, float)) and self.lambda_window > 0):
            raise ValueError(f"PlannerConfig.lambda_window must be a number > 0 (inf allowed), got {self.lambda_window!r}")
        for name in ("portal_clearance", "goal_offset", "blend_margin", "blend_ramp"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"PlannerConfig.{name} must be a finite number >= 0, got {v!r}")
        if not (isinstance(self.max_projection, (int, float)) and self.max_projection >= 0):
            raise ValueError(f"PlannerConfig.max_projection must be a number >= 0 (inf allowed), got {self.max_projection!r}")
        for name in ("speed_fraction", "yaw_rate_fraction", "accel_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v <= 1):
                raise ValueError(f"PlannerConfig.{name} must be in (0, 1], got {v!r}")
        osf = self.open_speed_fraction
        if osf is not None and not (isinstance(osf, (int, float)) and 0 < osf <= 1):
            raise ValueError(f"PlannerConfig.open_speed_fraction must be None or in (0, 1], got {osf!r}")
        if not (isinstance(self.open_room, (int, float)) and math.isfinite(self.open_room) and self.open_room >= 0):
            raise ValueError(f"PlannerConfig.open_room must be a finite number >= 0 [m], got {self.open_room!r}")
        if not (isinstance(self.max_lambda_steps, int) and self.max_lambda_steps >= 0):
            raise ValueError(f"PlannerConfig.max_lambda_steps must be an int >= 0, got {self.max_lambda_steps!r}")
        if not (isinstance(self.lambda_factor, (int, float)) and 0 < self.lambda_factor < 1):
            raise ValueError(f"PlannerConfig.lambda_factor must be in (0, 1), got {self.lambda_factor!r}")
        if self.knot_spacing < self.spacing:
            raise ValueError(
                f"PlannerConfig.knot_spacing must be >= spacing ({self.spacing}), got {self.knot_spacing!r}"
            )
        if self.search not in ("astar", "dijkstra"):
            raise ValueError(f"PlannerConfig.search must be 'astar' or 'dijkstra', got {self.search!r}")


#: rounds of widening the fallback around reference samples outside the corridor before
#: the whole curve falls back to the polyline
_MAX_SAMPLE_ROUNDS = 8


class _NoPlan(Exception):
    """A stage found no safe plan: ``reason`` (``no_path`` / ``unsafe_reference``) and ``detail``."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason, self.detail = reason, detail


def _fail(reason: str, detail: str, goal: np.ndarray, info: dict[str, Any]) -> Plan:
    info = dict(info, detail=detail)
    return Plan(
        ok=False,
        reason=reason,
        corridor=np.zeros(0, dtype=np.int64),
        goal=np.asarray(goal, dtype=float).copy(),
        waypoints=np.zeros((0, 2)),
        path=np.zeros((0, 2)),
        smoothed=np.zeros((0, 2)),
        reference=None,
        info=info,
    )


def _vector(name: str, value: Any, n: int) -> np.ndarray:
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"plan: {name} must be {n} finite numbers, got {value!r}")
    return a


def _check_robot(robot: RobotParams) -> None:
    for name in ("v_max", "w_max", "a_max"):
        v = getattr(robot, name)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"plan: robot.{name} must be finite and > 0, got {v!r}")


@dataclass(frozen=True)
class _Route:
    """Stage 1's result: the corridor, the start / goal used and the portal waypoints."""

    corridor: np.ndarray  # (C,) int safe-area indices
    goal: np.ndarray  # (2,) [m] goal used (projected when outside every area)
    waypoints: np.ndarray  # (W, 2) [m]
    length: float  # [m] polyline length of the waypoints


def _corridor(areas: SafeAreas, start: np.ndarray, goal: np.ndarray, cfg: PlannerConfig):
    """Stage 1a: start / goal areas (goal projected when needed) and the corridor by graph search.

    Returns:
        ``(graph, choice)`` (see :func:`~sanav_mj.planning.corridor.select_corridor`).

    Raises:
        _NoPlan: ``no_path`` when no corridor connects start and goal.
    """
    graph = build_graph(areas)
    choice = select_corridor(
        areas, graph, start[:2], goal, search=cfg.search, offset=cfg.goal_offset, max_projection=cfg.max_projection
    )
    if choice.corridor is None:
        raise _NoPlan("no_path", choice.detail)
    return graph, choice


def _waypoints(areas: SafeAreas, graph, choice, cfg: PlannerConfig) -> _Route:
    """Stage 1b: waypoints through the corridor's portals, from the start used to the goal used."""
    portals = oriented_portals(areas, graph, choice.corridor)
    waypoints = portal_waypoints(choice.start, choice.goal, portals, cfg.portal_clearance)
    return _Route(choice.corridor, choice.goal, waypoints, path_length(waypoints))


def _smooth(route: _Route, crect: np.ndarray, cfg: PlannerConfig) -> SmoothingResult:
    """Stage 2: interpolation (eq. 5-6) and smoothing (eq. 7) kept inside the corridor rectangles ``crect``.

    Raises:
        _NoPlan: ``unsafe_reference`` if even the polyline left the corridor (a guard).
    """
    sm = safe_curve(
        route.waypoints,
        np.arange(route.corridor.size, dtype=np.int64),
        crect,
        spacing=cfg.spacing,
        knot_spacing=cfg.knot_spacing,
        lam=cfg.lam,
        check_spacing=cfg.check_spacing,
        lambda_factor=cfg.lambda_factor,
        max_lambda_steps=cfg.max_lambda_steps,
        lambda_window=cfg.lambda_window,
        blend_margin=cfg.blend_margin,
        blend_ramp=cfg.blend_ramp,
    )
    if not sm.safe:
        raise _NoPlan("unsafe_reference", "the smoothed curve left the corridor even on the polyline")
    return sm


@dataclass(frozen=True)
class _Timed:
    """Stage 3's result: the final curve, its dense nodes and the reference samples inside the corridor."""

    curve: SafeCurve
    nodes: np.ndarray  # (N, 2) [m] dense samples of the final curve
    profile: PathProfile
    samples: TimedSamples
    positions: np.ndarray  # (K, 2) [m]
    corridor_pos: np.ndarray  # (K,) int corridor position of each sample
    rounds: int  # fallback widenings needed


def _speed_caps(nodes: np.ndarray, robot: RobotParams, cfg: PlannerConfig, free: Any) -> float | np.ndarray:
    """The speed limit [m/s] of the profile: ``speed_fraction * v_max`` (a float), or per node
    (N,) with ``open_speed_fraction * v_max`` where the node has ``open_room`` of free cells
    around it in ``free`` (:class:`~sanav_mj.mapping.grow.FreeCells`, or None: the float)."""
    v_cap = cfg.speed_fraction * robot.v_max
    if cfg.open_speed_fraction is None or free is None:
        return v_cap
    open_ = free.squares_free(nodes, cfg.open_room)
    return np.where(open_, cfg.open_speed_fraction * robot.v_max, v_cap)


def _time_parametrise_inside(sm: SmoothingResult, crect: np.ndarray, robot: RobotParams, cfg: PlannerConfig,
                             v_start: float = 0.0, free: Any = None) -> _Timed:
    """Stage 3: speed profile and samples at ``dt``; every sample checked against the corridor,
    the fallback to the polyline widened around the samples outside (at most
    ``_MAX_SAMPLE_ROUNDS`` rounds, then the whole polyline). ``free``: the grid's
    :class:`~sanav_mj.mapping.grow.FreeCells` for the open-space speed (:func:`_speed_caps`).

    Raises:
        _NoPlan: ``unsafe_reference`` if even the polyline's samples left the corridor (a guard).
    """
    w_cap = cfg.yaw_rate_fraction * robot.w_max
    a_cap = cfg.accel_fraction * robot.a_max
    curve, u_nodes, nodes = sm.curve, sm.u_nodes, sm.nodes
    rounds = 0
    while True:
        v_cap = _speed_caps(nodes, robot, cfg, free)
        prof, smp, pos_xy = time_parametrise(
            curve, u_nodes, cfg.dt, v_cap, w_cap, cfg.lateral_accel, a_cap, points=nodes, v_start=v_start
        )
        pos, ok = corridor_assignment(crect, pos_xy, curve.hint(smp.u))
        if ok.all():
            return _Timed(curve, nodes, prof, smp, pos_xy, pos, rounds)
        if curve.blend.covered >= curve.length:  # the polyline itself failed: never hand it out
            raise _NoPlan("unsafe_reference", "reference samples left the corridor on the polyline")
        rounds += 1
        if rounds >= _MAX_SAMPLE_ROUNDS:
            curve = curve.as_polyline()
            nodes = curve(u_nodes)
        else:  # fall back around the offending samples, keeping every dense node inside too
            curve, nodes, safe = blend_until_inside(
                curve, u_nodes, sm.hint, crect, smp.u[~ok], cfg.blend_margin * 2.0**rounds
            )
            if not safe:
                raise _NoPlan("unsafe_reference", "the smoothed curve left the corridor even on the polyline")


def _at_goal(route: _Route, start: np.ndarray, cfg: PlannerConfig, info: dict[str, Any], times: list[float]) -> Plan:
    """The plan when start and goal coincide: a one-sample reference at rest."""
    ref = Reference(
        dt=cfg.dt,
        states=np.array([[route.goal[0], route.goal[1], start[2]]]),
        inputs=np.zeros((1, 2)),
        area=np.array([route.corridor[-1]], dtype=np.int64),
    )
    info.update(lam=cfg.lam, lambda_steps=0, fallback_length_m=0.0, duration_s=0.0, path_length_m=0.0)
    info["timing_ms"] = _timing(*times, times[-1], time.perf_counter())
    wp = route.waypoints
    return Plan(True, "ok", route.corridor, route.goal, wp, wp.copy(), wp.copy(), ref, info)


def plan(
    areas: SafeAreas,
    start: np.ndarray,
    goal: np.ndarray,
    robot: RobotParams,
    config: PlannerConfig | None = None,
    start_speed: float = 0.0,
) -> Plan:
    """Plan a safe reference from ``start`` to ``goal`` through the safe areas.

    Args:
        areas: merged safe rectangles, connectivity graph and portals.
        start: (3,) [m, m, rad] start pose (the yaw is not used: the first reference yaw is
            the path tangent; the controller turns the robot).
        goal: (2,) [m] goal position.
        robot: limits ``v_max`` [m/s], ``w_max`` [rad/s], ``a_max`` [m/s^2].
        config: planner settings (defaults when None).
        start_speed: [m/s] speed of the reference at the start, >= 0 (a robot replanning in
            motion; capped by the start's speed limits); 0: from rest, as the paper.

    Returns:
        A :class:`Plan`. ``ok`` is False with ``reason == "no_path"`` when the goal cannot be
        reached through the graph (``info["detail"]`` says why), or, as a guard that the
        construction excludes, ``"unsafe_reference"`` if even the interpolated polyline
        failed the corridor check. Otherwise every reference sample and every dense sample
        of ``Plan.smoothed`` lies in the union of the corridor's rectangles, the reference
        starts at the start (projected inwards when it was outside every safe area) and
        ends at rest at ``Plan.goal``, and ``Reference.area`` gives a containing corridor
        rectangle per sample, non-decreasing along the corridor.

    Raises:
        ValueError: malformed ``start`` / ``goal`` or non-positive robot limits.
    """
    cfg = PlannerConfig() if config is None else config
    t_begin = time.perf_counter()
    start = _vector("start", start, 3)
    goal = _vector("goal", goal, 2)
    _check_robot(robot)
    if not (isinstance(start_speed, (int, float)) and math.isfinite(start_speed) and start_speed >= 0):
        raise ValueError(f"start_speed must be a finite number >= 0 [m/s], got {start_speed!r}")
    rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
    info: dict[str, Any] = {}
    if rects.shape[0] == 0:
        return _fail("no_path", "no safe areas", goal, info)
    try:
        graph, choice = _corridor(areas, start, goal, cfg)
        t_search = time.perf_counter()
        route = _waypoints(areas, graph, choice, cfg)
        t_way = time.perf_counter()
        info.update(corridor_areas=int(route.corridor.size), waypoint_length_m=route.length)
        if route.length < 1e-9:  # already at the goal: a one-sample reference
            return _at_goal(route, start, cfg, info, [t_begin, t_search, t_way])
        crect = rects[route.corridor]
        sm = _smooth(route, crect, cfg)
        t_smooth = time.perf_counter()
        timed = _time_parametrise_inside(sm, crect, robot, cfg, start_speed, areas.free)
    except _NoPlan as no:
        return _fail(no.reason, no.detail, goal, info)
    t_time = time.perf_counter()

    smp, curve = timed.samples, timed.curve
    ref = Reference(
        dt=cfg.dt,
        states=np.column_stack([timed.positions, smp.yaw]),
        inputs=np.column_stack([smp.v, smp.w]),
        area=route.corridor[timed.corridor_pos],
    )
    info.update(
        lam=curve.spline.lam,
        lambda_steps=curve.lambda_steps,
        fallback_length_m=min(curve.blend.covered, curve.length),
        sample_rounds=timed.rounds,
        path_length_m=float(timed.profile.sigma[-1]),
        duration_s=float(timed.profile.duration),
    )
    info["timing_ms"] = _timing(t_begin, t_search, t_way, t_smooth, t_time)
    return Plan(
        ok=True,
        reason="ok",
        corridor=route.corridor,
        goal=route.goal,
        waypoints=route.waypoints,
        path=sm.path,
        smoothed=timed.nodes,
        reference=ref,
        info=info,
    )


def route_points(areas: SafeAreas, start: np.ndarray, goal: np.ndarray, config: PlannerConfig | None = None
                 ) -> np.ndarray | None:
    """Stage 1 of :func:`plan` alone: the portal-waypoint polyline from ``start`` to ``goal``
    through the corridor, sampled uniformly by arc length (spacing about ``config.spacing``,
    :func:`~sanav_mj.planning.smoothing.interpolate_uniform`), without smoothing or timing.

    The polyline is the one :func:`plan` smooths (``Plan.waypoints``, the same corridor, start
    and goal used); it lies in the union of the corridor's rectangles (module docstring of
    :mod:`sanav_mj.planning.corridor`). For a route that only has to be checked against a
    map, not followed (the lidar mode's route through unknown space).

    Args:
        areas: the safe areas; start: (2,) or (3,) [m] (a yaw is ignored); goal: (2,) [m].
        config: planner settings (search, projection, portal clearance, spacing).

    Returns:
        (P, 2) [m] samples, P >= 2 (the first at the start used, the last at the goal used),
        or None when :func:`plan` would give ``no_path``.
    """
    cfg = PlannerConfig() if config is None else config
    start = np.asarray(start, dtype=float).reshape(-1)
    if start.shape not in ((2,), (3,)) or not np.all(np.isfinite(start)):
        raise ValueError(f"route_points: start must be 2 or 3 finite numbers, got {start!r}")
    goal = _vector("goal", goal, 2)
    if np.asarray(areas.rects).reshape(-1, 4).shape[0] == 0:
        return None
    try:
        graph, choice = _corridor(areas, start[:2], goal, cfg)
    except _NoPlan:
        return None
    route = _waypoints(areas, graph, choice, cfg)
    return interpolate_uniform(route.waypoints, cfg.spacing)[1]


def _timing(t0: float, t_search: float, t_way: float, t_smooth: float, t_end: float) -> dict[str, float]:
    return {
        "search": (t_search - t0) * 1e3,
        "waypoints": (t_way - t_search) * 1e3,
        "smoothing": (t_smooth - t_way) * 1e3,
        "timing": (t_end - t_smooth) * 1e3,
        "total": (t_end - t0) * 1e3,
    }


def plan_document(p: Plan) -> dict[str, Any]:
    """A JSON-ready summary of a plan for the ``areas`` command and plots.

    Returns:
        ``{"ok", "reason", "corridor": [i, ...], "goal": [x, y], "waypoints": [[x, y], ...],
        "reference": [[x, y, yaw], ...], "inputs": [[v, w], ...], "area": [i, ...], "dt",
        "info"}`` with plain Python numbers (lists empty when there is no plan).
    """
    ref = p.reference
    info = {k: v for k, v in p.info.items()}
    return {
        "ok": bool(p.ok),
        "reason": p.reason,
        "corridor": [int(i) for i in p.corridor],
        "goal": [float(v) for v in p.goal],
        "waypoints": np.asarray(p.waypoints, dtype=float).round(6).tolist(),
        "reference": [] if ref is None else np.asarray(ref.states, dtype=float).round(6).tolist(),
        "inputs": [] if ref is None else np.asarray(ref.inputs, dtype=float).round(6).tolist(),
        "area": [] if ref is None else [int(i) for i in ref.area],
        "dt": None if ref is None else float(ref.dt),
        "info": info,
    }
