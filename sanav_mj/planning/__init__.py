"""Planning: a safe, time-parametrised reference through the safe areas (paper Sec. III-C).

    SafeAreas + start + goal
      -> start / goal areas, goal projection, corridor (graph search)       corridor.py
      -> portal waypoints -> uniform arc-length interpolation (eq. 5-6)      corridor.py, smoothing.py
      -> cubic B-spline smoothing (eq. 7), kept inside the corridor          smoothing.py
      -> speed profile and samples at the MPC step dt                        timing.py
      -> Plan(corridor, goal, waypoints, path, smoothed, Reference)          reference.py

Entry point: :func:`plan`. Configuration: :class:`PlannerConfig`.
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
from sanav_mj.planning.smoothing import blend_until_inside, corridor_assignment, safe_curve
from sanav_mj.planning.timing import time_parametrise
from sanav_mj.scene import RobotParams

__all__ = ["Plan", "PlannerConfig", "Reference", "plan", "plan_document"]


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


_MAX_SAMPLE_ROUNDS = 8


def _fail(reason: str, detail: str, goal: np.ndarray, start: np.ndarray, info: dict[str, Any]) -> Plan:
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


def plan(
    areas: SafeAreas,
    start: np.ndarray,
    goal: np.ndarray,
    robot: RobotParams,
    config: PlannerConfig | None = None,
) -> Plan:
    """Plan a safe reference from ``start`` to ``goal`` through the safe areas.

    Args:
        areas: merged safe rectangles, connectivity graph and portals.
        start: (3,) [m, m, rad] start pose (the yaw is not used: the first reference yaw is
            the path tangent; the controller turns the robot).
        goal: (2,) [m] goal position.
        robot: limits ``v_max`` [m/s], ``w_max`` [rad/s], ``a_max`` [m/s^2].
        config: planner settings (defaults when None).

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
    for name in ("v_max", "w_max", "a_max"):
        v = getattr(robot, name)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"plan: robot.{name} must be finite and > 0, got {v!r}")
    rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
    info: dict[str, Any] = {}
    if rects.shape[0] == 0:
        return _fail("no_path", "no safe areas", goal, start, info)

    # ---- start and goal areas, goal projection, corridor -------------------------------
    graph = build_graph(areas)
    choice = select_corridor(
        areas, graph, start[:2], goal, search=cfg.search, offset=cfg.goal_offset, max_projection=cfg.max_projection
    )
    if choice.corridor is None:
        return _fail("no_path", choice.detail, goal, start, info)
    corridor, p0, goal_used = choice.corridor, choice.start, choice.goal
    t_search = time.perf_counter()

    # ---- waypoints through the portals ----------------------------------------------
    portals = oriented_portals(areas, graph, corridor)
    waypoints = portal_waypoints(p0, goal_used, portals, cfg.portal_clearance)
    length = path_length(waypoints)
    t_way = time.perf_counter()
    crect = rects[corridor]
    info.update(corridor_areas=int(corridor.size), waypoint_length_m=length)

    if length < 1e-9:  # already at the goal: a one-sample reference
        ref = Reference(
            dt=cfg.dt,
            states=np.array([[goal_used[0], goal_used[1], start[2]]]),
            inputs=np.zeros((1, 2)),
            area=np.array([corridor[-1]], dtype=np.int64),
        )
        info.update(lam=cfg.lam, lambda_steps=0, fallback_length_m=0.0, duration_s=0.0, path_length_m=0.0)
        info["timing_ms"] = _timing(t_begin, t_search, t_way, t_way, time.perf_counter())
        return Plan(True, "ok", corridor, goal_used, waypoints, waypoints.copy(), waypoints.copy(), ref, info)

    # ---- interpolation, smoothing, safety ----------------------------------------------
    seg_area = np.arange(corridor.size, dtype=np.int64)
    sm = safe_curve(
        waypoints,
        seg_area,
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
        return _fail("unsafe_reference", "the smoothed curve left the corridor even on the polyline", goal, start, info)
    curve, u_nodes, nodes = sm.curve, sm.u_nodes, sm.nodes
    t_smooth = time.perf_counter()

    # ---- time-parametrisation; every sample checked, fallback widened if needed ----------
    v_cap = cfg.speed_fraction * robot.v_max
    w_cap = cfg.yaw_rate_fraction * robot.w_max
    a_cap = cfg.accel_fraction * robot.a_max
    rounds = 0
    while True:
        prof, smp, pos_xy = time_parametrise(
            curve, u_nodes, cfg.dt, v_cap, w_cap, cfg.lateral_accel, a_cap, points=nodes
        )
        pos, ok = corridor_assignment(crect, pos_xy, curve.hint(smp.u))
        if ok.all():
            break
        if curve.blend.covered >= curve.length:  # the polyline itself failed: never hand it out
            return _fail("unsafe_reference", "reference samples left the corridor on the polyline", goal, start, info)
        rounds += 1
        if rounds >= _MAX_SAMPLE_ROUNDS:
            curve = curve.as_polyline()
            nodes = curve(u_nodes)
        else:  # fall back around the offending samples, keeping every dense node inside too
            curve, nodes, safe = blend_until_inside(
                curve, u_nodes, sm.hint, crect, smp.u[~ok], cfg.blend_margin * 2.0**rounds
            )
            if not safe:
                return _fail("unsafe_reference", "the smoothed curve left the corridor even on the polyline", goal, start, info)
    t_time = time.perf_counter()

    states = np.column_stack([pos_xy, smp.yaw])
    inputs = np.column_stack([smp.v, smp.w])
    ref = Reference(dt=cfg.dt, states=states, inputs=inputs, area=corridor[pos])
    info.update(
        lam=curve.spline.lam,
        lambda_steps=curve.lambda_steps,
        fallback_length_m=min(curve.blend.covered, curve.length),
        sample_rounds=rounds,
        path_length_m=float(prof.sigma[-1]),
        duration_s=float(prof.duration),
    )
    info["timing_ms"] = _timing(t_begin, t_search, t_way, t_smooth, t_time)
    return Plan(
        ok=True,
        reason="ok",
        corridor=corridor,
        goal=goal_used,
        waypoints=waypoints,
        path=sm.path,
        smoothed=nodes,
        reference=ref,
        info=info,
    )


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
