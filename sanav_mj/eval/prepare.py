"""Everything computed before the closed loop of a known-map run: the map and plan of a
scenario, matched to the controller's settings.

:func:`prepare` loads, maps and plans a scenario; the helpers here turn a
:class:`~sanav_mj.control.spec.ControllerSpec` into the map's inflation and cells, the
planner's settings and the corridor search's areas, so the known-map run
(:mod:`sanav_mj.eval.episode`) and the lidar run (:mod:`sanav_mj.eval.lidar`) size their maps
the same way.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from sanav_mj.control.spec import ControllerSpec
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.quadtree import QuadtreeLeaves
from sanav_mj.mapping.safe_areas import SafeAreaMap, SafeAreas
from sanav_mj.planning.reference import Plan
from sanav_mj.scene import Scenario, load_scenario

#: inflation margin [m] beyond the robot's footprint radius used for the grid.
DEFAULT_MARGIN_M = 0.05


@dataclass
class Prepared:
    """A scenario with its map and plan (everything that is computed before the loop).

    Attributes:
        scenario: the loaded scenario.
        map: the whole mapping-stage result (grid, leaves, cell boxes, areas, timing); its
            parts are also reachable as ``grid``, ``leaves`` and ``areas``.
        plan: planned corridor and reference from the scenario start to its goal.
        timing_ms: [ms] stage times: rasterise, quadtree, merge, graph, plan, total.
        refine_fallback: the map was built with ``MPCConfig.footprint_refine_fallback``
            (the plan at ``footprint_refine`` found no path); its plans then get
            manoeuvres when ``footprint_manoeuvre`` is set (:func:`manoeuvre_plan`).
    """

    scenario: Scenario
    map: SafeAreaMap
    plan: Plan
    timing_ms: dict[str, float] = field(default_factory=dict)
    refine_fallback: bool = False

    @property
    def grid(self) -> OccupancyGrid:
        """The inflated occupancy grid."""
        return self.map.grid

    @property
    def leaves(self) -> QuadtreeLeaves:
        """The quadtree leaves (see :mod:`sanav_mj.mapping.quadtree`)."""
        return self.map.leaves

    @property
    def areas(self) -> SafeAreas:
        """The merged safe areas and their graph."""
        return self.map.areas


def planner_config(robot, spec: ControllerSpec = ControllerSpec()) -> Any:
    """Planner settings matched to the SA-MPC of ``spec``: the reference's speed, yaw-rate and
    acceleration caps are the planner's default fractions (0.8) of the MPC's resolved input
    and rate bounds (``spec.sa_mpc.limits(robot)``), not of the robot's, and its period is
    the MPC's ``dt``. A reference faster than the MPC may drive (1.6 m/s against 1.43 m/s
    for the MuJoCo robot) leaves the robot lagging behind it. In ``"discs"`` mode
    ``MPCConfig.footprint_open_speed`` (a fraction of the resolved ``v_max``) becomes the
    reference's open-space speed (``PlannerConfig.open_speed_fraction``).

    Args:
        robot: the robot's nominal parameters.
        spec: the controller spec (its ``sa_mpc`` settings are used whatever the controller).

    Returns:
        A :class:`sanav_mj.planning.PlannerConfig`.
    """
    from sanav_mj.planning import PlannerConfig

    base = PlannerConfig()
    mpc = spec.sa_mpc
    lim = mpc.limits(robot)
    open_ = mpc.footprint_open_speed if mpc.footprint == "discs" else None
    return PlannerConfig(
        dt=mpc.dt,
        speed_fraction=min(1.0, base.speed_fraction * lim.v_max / robot.v_max),
        yaw_rate_fraction=min(1.0, base.yaw_rate_fraction * lim.w_max / robot.w_max),
        accel_fraction=min(1.0, base.accel_fraction * lim.a_max / robot.a_max),
        open_speed_fraction=None if open_ is None else min(1.0, open_ * lim.v_max / robot.v_max),
        open_room=mpc.footprint_open_room if open_ is not None else base.open_room,
    )


def footprint_fields(spec: ControllerSpec) -> dict[str, Any]:
    """The run document's ``"footprint"`` entry for ``spec``'s SA-MPC footprint mode: empty
    for the default ``"disc"`` mode (its documents are unchanged), else ``{"footprint":
    {"mode", "discs", "margin_m", "route", "refine", "grow_m", "open_speed"}}`` so a discs-mode
    document says which settings made it (as ``"sensing"`` marks a lidar run); ``open_speed``
    is ``MPCConfig.footprint_open_speed`` (None: one reference speed)."""
    mpc = spec.sa_mpc
    if spec.name != "sa-mpc" or mpc.footprint == "disc":
        return {}
    return {"footprint": {"mode": mpc.footprint, "discs": int(mpc.footprint_discs),
                          "margin_m": float(mpc.footprint_margin), "route": mpc.footprint_route,
                          "refine": int(mpc.footprint_refine), "grow_m": float(mpc.footprint_grow),
                          "open_speed": None if mpc.footprint_open_speed is None else float(mpc.footprint_open_speed)}}


def footprint_spec(controller: str = "sa-mpc", footprint: str = "disc") -> ControllerSpec:
    """The default :class:`ControllerSpec` of ``controller`` with SA-MPC's
    :attr:`~sanav_mj.control.config.MPCConfig.footprint` set to ``footprint`` (``"disc"``:
    exactly ``ControllerSpec(controller)``; ``"discs"``: the other footprint settings are
    :class:`~sanav_mj.control.config.MPCConfig`'s defaults). What ``--footprint`` selects."""
    from dataclasses import replace

    spec = ControllerSpec(controller)
    if footprint == "disc":
        return spec
    return replace(spec, sa_mpc=replace(spec.sa_mpc, footprint=footprint))


def map_inflation(scenario: Scenario, spec: ControllerSpec = ControllerSpec()) -> float:
    """[m] obstacle inflation of the map for ``spec``'s SA-MPC footprint mode: the
    circumscribed radius + :data:`DEFAULT_MARGIN_M` (``"disc"``), or the radius of the
    ``footprint_discs``-disc cover of the footprint rectangle + ``footprint_margin``
    (``"discs"``, see :class:`~sanav_mj.control.config.MPCConfig`)."""
    mpc = spec.sa_mpc
    if mpc.footprint == "discs":
        from sanav_mj.footprint import robot_footprint

        return robot_footprint(scenario.model).discs(mpc.footprint_discs)[1] + mpc.footprint_margin
    return scenario.robot.footprint_radius + DEFAULT_MARGIN_M


def map_config(spec: ControllerSpec = ControllerSpec(), resolution: float = 0.05, merge: str = "paper") -> Any:
    """The :class:`~sanav_mj.mapping.MapConfig` of ``spec``'s SA-MPC footprint mode at cell
    ``resolution`` [m]: one grid (``"disc"``, or ``"discs"`` with ``footprint_refine`` 1), or
    ``resolution`` refined locally by ``footprint_refine`` where the free space is narrower
    than ``footprint_refine_width`` (``"discs"``; the map's cells are then
    ``resolution / footprint_refine``)."""
    from sanav_mj.mapping import MapConfig

    mpc = spec.sa_mpc
    if mpc.footprint == "discs" and mpc.footprint_refine > 1:
        return MapConfig(resolution=resolution, merge=merge, refine=mpc.footprint_refine,
                         refine_width=mpc.footprint_refine_width)
    return MapConfig(resolution=resolution, merge=merge)


def with_free_cells(m: Any, spec: ControllerSpec = ControllerSpec()) -> Any:
    """The safe-area map ``m`` as it is, or in ``"discs"`` mode with ``footprint_grow > 0`` with
    its areas carrying the grid's :class:`~sanav_mj.mapping.grow.FreeCells` (growth limit
    ``footprint_grow``, tightening ``footprint_grow_tighten``), so SA-MPC's corridor chain grows its boxes to maximal free
    rectangles (:meth:`sanav_mj.control.stages.CorridorChain.build`)."""
    from dataclasses import replace

    mpc = spec.sa_mpc
    if mpc.footprint != "discs" or mpc.footprint_grow == 0:
        return m
    from sanav_mj.mapping.grow import FreeCells

    return replace(m, areas=replace(m.areas, free=FreeCells.of(m.grid, mpc.footprint_grow, mpc.footprint_grow_tighten)))


def disc_map_loss(scenario: Scenario, spec: ControllerSpec = ControllerSpec()) -> float:
    """[m] how much less ``spec``'s map is inflated than the circumscribed-disc map:
    ``R + DEFAULT_MARGIN_M - map_inflation(scenario, spec)`` (R the footprint's circumscribed
    radius; 0 in the ``"disc"`` mode, may be negative). Places narrower than twice this have
    no room for the circumscribed disc: the corridor search's narrow passages
    (:func:`planning_areas`, :func:`sanav_mj.eval.lidar.sensed_narrow_width`)."""
    return scenario.robot.footprint_radius + DEFAULT_MARGIN_M - map_inflation(scenario, spec)


def planning_areas(areas: SafeAreas, scenario: Scenario, spec: ControllerSpec = ControllerSpec()) -> SafeAreas:
    """The safe areas the corridor search runs on: ``areas`` itself, or in ``"discs"`` mode
    the same areas with ``footprint_narrow_penalty`` added to every edge through a place
    narrower than what the circumscribed-disc map loses, ``2 (R + DEFAULT_MARGIN_M -
    inflation)`` (:func:`sanav_mj.planning.corridor.penalise_narrow`)."""
    mpc = spec.sa_mpc
    if mpc.footprint != "discs" or mpc.footprint_narrow_penalty == 0:
        return areas
    from sanav_mj.planning.corridor import penalise_narrow

    width = 2.0 * max(0.0, disc_map_loss(scenario, spec))
    return penalise_narrow(areas, width, mpc.footprint_narrow_penalty)


def footprint_route_plan(plan: Plan, areas: SafeAreas, grid: OccupancyGrid, scenario: Scenario, start: np.ndarray,
                         spec: ControllerSpec = ControllerSpec()) -> Plan:
    """``"discs"`` mode with ``footprint_route="pose"``: the plan from a search over poses
    whose disc centres stay in the safe areas (:mod:`sanav_mj.planning.pose_search`,
    :func:`sanav_mj.planning.pose_reference.route_plan`), to the goal ``plan`` uses; a
    ``no_path`` plan when no such pose path exists; ``plan`` itself in every other mode, when
    ``plan`` failed, or when the found path's corridor does not cover its discs
    (``info["pose_route_fallback"]`` says why). The reference's caps are the planner's
    (:func:`planner_config`): 0.8 of the MPC's speed, yaw-rate and rate bounds, backwards
    0.8 of its reversing speed.

    Args:
        plan: the corridor plan from ``start``.
        areas: the safe areas it was planned on (unpenalised).
        grid: the map's grid (the search lattice is its cell centres).
        scenario: the scenario (robot and footprint).
        start: (3,) [m, m, rad] start pose.
        spec: the controller spec.
    """
    mpc = spec.sa_mpc
    if mpc.footprint != "discs" or mpc.footprint_route != "pose" or not plan.ok:
        return plan
    from dataclasses import replace as _replace

    from sanav_mj.footprint import robot_footprint
    from sanav_mj.planning.pose_reference import route_plan
    from sanav_mj.planning.pose_search import PoseSearchConfig, search_poses

    offsets, _ = robot_footprint(scenario.model).discs(mpc.footprint_discs)
    sweep = float(np.hypot(*offsets.T).max())
    res = search_poses(areas, grid.origin, grid.occupied.shape, grid.resolution, offsets, sweep,
                       np.asarray(start, float), plan.goal, PoseSearchConfig(margin=mpc.stage_box_margin))
    if res.route is None:
        return _replace(plan, ok=False, reason="no_path", corridor=np.zeros(0, dtype=np.int64),
                        waypoints=np.zeros((0, 2)), path=np.zeros((0, 2)), smoothed=np.zeros((0, 2)), reference=None,
                        info=dict(plan.info, detail=res.detail, pose_search_ms=res.time_ms))
    pc = planner_config(scenario.robot, spec)
    lim = mpc.limits(scenario.robot)
    new, why = route_plan(areas, res.route, plan.goal, offsets, pc.dt, pc.speed_fraction * scenario.robot.v_max,
                          pc.speed_fraction * abs(lim.v_min), pc.yaw_rate_fraction * scenario.robot.w_max,
                          pc.accel_fraction * scenario.robot.a_max, pc.yaw_rate_fraction * lim.alpha_max,
                          pc.lateral_accel, info={"corridor_plan_ms": plan.info.get("timing_ms", {}).get("total")},
                          raster=res.raster, margin=mpc.stage_box_margin)
    if new is None:
        return _replace(plan, info=dict(plan.info, pose_route_fallback=why, pose_search_ms=res.time_ms))
    return new


def manoeuvre_plan(plan: Plan, areas: SafeAreas, scenario: Scenario, spec: ControllerSpec) -> Plan:
    """``plan`` with each stretch of its reference whose disc centres leave the safe areas
    replaced by a manoeuvre (:func:`sanav_mj.planning.manoeuvre.manoeuvre_route`, settings
    ``MPCConfig.footprint_manoeuvre``) and followed as a pose route
    (:func:`sanav_mj.planning.pose_reference.route_plan`, one chain per disc, held at its
    cusps and turns on the spot); ``plan`` itself when no stretch needs one, a stretch has
    none, or the route's chains do not cover its discs (``info["manoeuvre"]`` says which)."""
    from sanav_mj.footprint import robot_footprint
    from sanav_mj.planning.manoeuvre import manoeuvre_route
    from sanav_mj.planning.pose_reference import route_plan
    from sanav_mj.planning.pose_search import PointRaster, PoseRoute, member_boxes

    mpc = spec.sa_mpc
    offsets, _ = robot_footprint(scenario.model).discs(mpc.footprint_discs)
    t0 = time.perf_counter()
    cfg = mpc.footprint_manoeuvre
    found = manoeuvre_route(member_boxes(areas, 0.0, grow=cfg.grow), plan.reference.states, offsets, cfg)
    ms = (time.perf_counter() - t0) * 1e3
    if found is None or found[2] == 0:
        why = "no manoeuvre" if found is None else "none needed"
        return replace(plan, info=dict(plan.info, manoeuvre=why, manoeuvre_ms=ms))
    poses, kinds, n = found
    free = getattr(areas, "free", None)
    raster = PointRaster.of_free(free) if cfg.smooth and free is not None else None
    pc = planner_config(scenario.robot, spec)
    lim = mpc.limits(scenario.robot)
    new, why = route_plan(areas, PoseRoute(poses, kinds, 0.0, 0, 0, ms), plan.goal, offsets, pc.dt,
                          pc.speed_fraction * scenario.robot.v_max, pc.speed_fraction * abs(lim.v_min),
                          pc.yaw_rate_fraction * scenario.robot.w_max, pc.accel_fraction * scenario.robot.a_max,
                          pc.yaw_rate_fraction * lim.alpha_max, pc.lateral_accel, info=dict(plan.info),
                          margin=mpc.stage_box_margin, hold_at_stops=True, grow_members=cfg.grow,
                          sliver_width=cfg.sliver_width, raster=raster,
                          slow_clearance=cfg.slow_clearance)
    if new is None:
        return replace(plan, info=dict(plan.info, manoeuvre=why, manoeuvre_ms=ms))
    return replace(new, info=dict(new.info, manoeuvre=f"{n} stretches", manoeuvre_ms=ms))


def prepare(
    spec: str | Path | Scenario,
    resolution: float = 0.05,
    merge: str = "paper",
    start: np.ndarray | None = None,
    controller: ControllerSpec = ControllerSpec(),
) -> Prepared:
    """Load (if needed), map and plan a scenario.

    Args:
        spec: scenario path, built-in name, or an already loaded :class:`Scenario`.
        resolution: [m] grid cell size.
        merge: merge rule of the safe areas (see ``sanav_mj.mapping.safe_areas.MERGE_METHODS``).
        start: (3,) [m, m, rad] start pose to plan from (default: the scenario's).
        controller: the controller spec the planner is matched to (:func:`planner_config`).
    """
    from sanav_mj.mapping import MapMemoryError, build_map
    from sanav_mj.planning import plan as make_plan

    scenario = spec if isinstance(spec, Scenario) else load_scenario(spec)
    inflation = map_inflation(scenario, controller)
    pose = scenario.start if start is None else np.asarray(start, dtype=float)
    mpc = controller.sa_mpc
    fallback = mpc.footprint_refine_fallback if mpc.footprint == "discs" else 0
    specs = [controller] + ([replace(controller, sa_mpc=replace(mpc, footprint_refine=fallback))] if fallback else [])
    for ctl in specs:
        try:
            m = build_map(scenario.obstacles, scenario.bounds, inflation, map_config(ctl, resolution, merge))
        except MapMemoryError as err:  # name the file too (ScenarioError: exit 2)
            raise MapMemoryError(f"{scenario.path}: {err}") from None
        m = with_free_cells(m, ctl)
        t0 = time.perf_counter()
        plan = make_plan(planning_areas(m.areas, scenario, ctl), pose, scenario.goal, scenario.robot,
                         planner_config(scenario.robot, ctl))
        plan = footprint_route_plan(plan, m.areas, m.grid, scenario, pose, ctl)
        if plan.ok or plan.reason != "no_path":  # footprint_refine_fallback: only where no path
            break
    if ctl is not controller and plan.ok and mpc.footprint_manoeuvre is not None:
        plan = manoeuvre_plan(plan, m.areas, scenario, ctl)
    timing = dict(m.timing_ms)
    timing["plan"] = (time.perf_counter() - t0) * 1e3
    timing["total"] = timing.get("total", 0.0) + timing["plan"]
    return Prepared(scenario, m, plan, timing, refine_fallback=ctl is not controller)


def areas_document(prep: Prepared) -> dict[str, Any]:
    """The ``areas --json`` document (keys, types and units: docs/outputs.md)."""
    from sanav_mj.planning import plan_document

    plan = plan_document(prep.plan)
    doc = {"scenario": prep.scenario.name, **prep.map.to_json()}
    doc["corridor"] = plan.pop("corridor")
    doc["reference"] = plan.pop("reference")
    doc["plan"] = plan
    doc["timing_ms"] = {k: float(v) for k, v in prep.timing_ms.items()}
    return doc


def initial_pose(scenario: Scenario, seed: int, yaw: float | None) -> np.ndarray:
    """Start pose (3,) [m, m, rad]: the scenario's position with ``yaw`` or, when None, a yaw
    drawn uniformly in [-pi, pi) from ``seed`` (the paper randomises the initial orientation)."""
    pose = np.asarray(scenario.start, dtype=float).copy()
    if yaw is None:
        pose[2] = np.random.default_rng(seed).uniform(-np.pi, np.pi)
    else:
        pose[2] = float(yaw)
    return pose


def replan_prepared(prep: Prepared, start: np.ndarray, spec: ControllerSpec) -> Prepared:
    """``prep`` with its plan made again from ``start`` (3,) [m, m, rad] on the same map, for
    ``spec``; ``timing_ms["plan"]`` is the new plan's time [ms]."""
    from sanav_mj.planning import plan as make_plan

    t0 = time.perf_counter()
    robot = prep.scenario.robot
    plan = make_plan(planning_areas(prep.areas, prep.scenario, spec), start, prep.scenario.goal, robot,
                     planner_config(robot, spec))
    plan = footprint_route_plan(plan, prep.areas, prep.grid, prep.scenario, start, spec)
    if prep.refine_fallback and plan.ok and spec.sa_mpc.footprint_manoeuvre is not None:
        plan = manoeuvre_plan(plan, prep.areas, prep.scenario, spec)
    timing = dict(prep.timing_ms)
    timing["plan"] = (time.perf_counter() - t0) * 1e3
    return Prepared(prep.scenario, prep.map, plan, timing, prep.refine_fallback)
