"""One scenario from file to result: load, map, plan, control in MuJoCo, measure.

This is the composition of the whole data flow (scene -> mapping -> planning -> control ->
sim); the CLI, ``demo``, ``bench`` and ``robustness`` all go through :func:`prepare` and
:func:`run_scenario`, so every controller runs in the same harness and yields the same JSON.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sanav_mj.control.base import Controller
from sanav_mj.control.spec import ControllerSpec
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.quadtree import QuadtreeLeaves
from sanav_mj.mapping.safe_areas import SafeAreaMap, SafeAreas
from sanav_mj.planning.reference import Plan
from sanav_mj.scene import Scenario, check_timestep, load_scenario
from sanav_mj.sim.mismatch import Mismatch
from sanav_mj.sim.runner import Episode, RunConfig

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
    """

    scenario: Scenario
    map: SafeAreaMap
    plan: Plan
    timing_ms: dict[str, float] = field(default_factory=dict)

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


@dataclass
class RunOutcome:
    """A finished run: its preparation, the episode, the ``run --json`` document and the
    controller spec it ran with; ``sensed`` is the
    :class:`~sanav_mj.control.sensing.SensingSAMPC` of a lidar run (its map, records and
    replans), None in map mode; ``sensing_log`` its :class:`SensingLog` when kept
    (``record_sensing=True``, or ``rrd`` given)."""

    prepared: Prepared
    controller: str
    start: np.ndarray
    episode: Episode
    document: dict[str, Any]
    spec: ControllerSpec = ControllerSpec()
    sensed: Any = None
    sensing_log: SensingLog | None = None


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


def planning_areas(areas: SafeAreas, scenario: Scenario, spec: ControllerSpec = ControllerSpec()) -> SafeAreas:
    """The safe areas the corridor search runs on: ``areas`` itself, or in ``"discs"`` mode
    the same areas with ``footprint_narrow_penalty`` added to every edge through a place
    narrower than what the circumscribed-disc map loses, ``2 (R + DEFAULT_MARGIN_M -
    inflation)`` (:func:`sanav_mj.planning.corridor.penalise_narrow`)."""
    mpc = spec.sa_mpc
    if mpc.footprint != "discs" or mpc.footprint_narrow_penalty == 0:
        return areas
    from sanav_mj.planning.corridor import penalise_narrow

    width = 2.0 * max(0.0, scenario.robot.footprint_radius + DEFAULT_MARGIN_M - map_inflation(scenario, spec))
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
    try:
        m = build_map(scenario.obstacles, scenario.bounds, inflation, map_config(controller, resolution, merge))
    except MapMemoryError as err:  # name the file too (ScenarioError: exit 2)
        raise MapMemoryError(f"{scenario.path}: {err}") from None
    m = with_free_cells(m, controller)
    t0 = time.perf_counter()
    pose = scenario.start if start is None else np.asarray(start, dtype=float)
    plan = make_plan(planning_areas(m.areas, scenario, controller), pose, scenario.goal, scenario.robot,
                     planner_config(scenario.robot, controller))
    plan = footprint_route_plan(plan, m.areas, m.grid, scenario, pose, controller)
    timing = dict(m.timing_ms)
    timing["plan"] = (time.perf_counter() - t0) * 1e3
    timing["total"] = timing.get("total", 0.0) + timing["plan"]
    return Prepared(scenario, m, plan, timing)


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


def run_scenario(
    spec: str | Path | Scenario | Prepared,
    controller: str = "sa-mpc",
    seed: int = 0,
    yaw: float | None = None,
    resolution: float = 0.05,
    mismatch: Mismatch = Mismatch(),
    time_limit_s: float = 60.0,
    rrd: Path | None = None,
    run_config: RunConfig | None = None,
    controller_obj: Controller | None = None,
    controller_spec: ControllerSpec | None = None,
    sensing: str = "map",
    on_step: Callable[[int, Any], None] | None = None,
    record_sensing: bool = False,
) -> RunOutcome:
    """Run one closed-loop episode of ``controller`` on a scenario and measure it.

    Args:
        spec: scenario path / name / :class:`Scenario`, or a :class:`Prepared` to reuse.
        controller: ``"sa-mpc"``, ``"mpc"``, ``"dwa"`` or ``"dqn"``.
        seed: seeds the initial yaw (when ``yaw`` is None), noise and jitter.
        yaw: [rad] explicit initial yaw.
        resolution: [m] grid cell size (ignored when ``spec`` is Prepared).
        mismatch: plant-vs-model differences.
        time_limit_s: [s] simulated time limit.
        rrd: write a rerun recording of the run here.
        run_config: episode settings (``time_limit_s`` overrides its time limit).
        controller_obj: use this controller instance instead of building one by name
            (tests inject failing solvers this way).
        controller_spec: the controller and its settings (default:
            ``ControllerSpec(controller)``); its name must equal ``controller`` when both are
            given (``controller`` may then be left at its default).
        sensing: ``"map"`` (the grid from the scenario's true geoms, planned once) or
            ``"lidar"`` (the robot's lidar builds the map during the run and SA-MPC replans
            on it, :class:`~sanav_mj.control.sensing.SensingSAMPC`; SA-MPC only). With
            ``"lidar"`` the document gains ``"sensing"``, ``"map_update_ms"`` {mean, max,
            p99}, ``"replans"`` and the ``p50`` / ``p99`` of ``pipeline_ms``; map-mode
            documents are unchanged. ``controller_obj`` may then be a
            :class:`~sanav_mj.control.sensing.SensingSAMPC` built by the caller.
        on_step: optional ``f(step, trace)`` called after each control step (see
            :func:`sanav_mj.sim.runner.run_episode`), after the recorder's.
        record_sensing: (lidar) keep the scans, map frames and safe areas of the run in
            ``RunOutcome.sensing_log`` for a recording made afterwards (always when ``rrd``
            is given).

    Raises:
        ValueError: unknown controller name, ``controller_spec.name`` differs from
            ``controller``, unknown ``sensing``, or ``sensing="lidar"`` with a controller
            other than SA-MPC.
    """
    from dataclasses import replace

    from sanav_mj.control.factory import make_controller
    from sanav_mj.eval.metrics import episode_json
    from sanav_mj.sim.mismatch import mismatched_model
    from sanav_mj.sim.plant import Plant
    from sanav_mj.sim.runner import run_episode

    source = spec
    if controller_spec is None:
        cspec = ControllerSpec(controller)
    elif controller_spec.name != controller and controller != "sa-mpc":
        raise ValueError(f"controller_spec: names controller {controller_spec.name!r} but controller={controller!r}")
    else:
        cspec = controller_spec
    controller = cspec.name
    if sensing not in SENSING_MODES:
        raise ValueError(f"sensing: expected one of {', '.join(SENSING_MODES)}, got {sensing!r}")
    if sensing == "lidar" and controller != "sa-mpc":
        raise ValueError(f"sensing lidar: supported for controller sa-mpc only, got {controller!r}")
    if sensing == "lidar":
        return _run_lidar(source, cspec, seed, yaw, resolution, mismatch, time_limit_s, run_config,
                          controller_obj, on_step, rrd, record_sensing or rrd is not None)
    if isinstance(source, Prepared):
        prep0 = source
        scenario = source.scenario
    else:
        scenario = source if isinstance(source, Scenario) else load_scenario(source)
        prep0 = None
    start = initial_pose(scenario, seed, yaw)
    # <option timestep> against the control period, before any output is created (ScenarioError, exit 2).
    # The period: the injected controller's dt, else the built controllers' (the reference step).
    check_timestep(scenario, getattr(controller_obj, "dt", None) or planner_config(scenario.robot).dt)
    t0 = time.perf_counter()
    # The plan starts from the actual start pose; the map does not depend on it.
    prep = prepare(scenario, resolution=prep0.grid.resolution if prep0 else resolution, start=start,
                   controller=cspec) if prep0 is None else _replan(prep0, start, cspec)
    setup_ms = (time.perf_counter() - t0) * 1e3 if prep0 is None else prep.timing_ms.get("plan", 0.0)
    model = mismatched_model(scenario, mismatch) if mismatch.physical else None
    plant = Plant(scenario, model=model)
    cfg = replace(run_config or RunConfig(), time_limit_s=time_limit_s)
    rng = np.random.default_rng(seed + 1)
    recorder = None
    if rrd is not None:
        from sanav_mj.record import Recorder

        recorder = Recorder(rrd, prep, controller)
    if not prep.plan.ok and controller == "sa-mpc" and controller_obj is None:
        # SA-MPC needs a corridor; the baselines drive without one and may still try.
        episode = _no_path_episode(plant, start)
    else:
        ctrl = controller_obj if controller_obj is not None else make_controller(
            cspec, prep.scenario, prep.grid, prep.areas, prep.plan, solve_budget_ms=mismatch.solve_budget_ms
        )
        episode = run_episode(plant, ctrl, start, scenario.goal, cfg, mismatch, rng,
                              on_step=_chain(recorder.log_step if recorder else None, on_step),
                              route=planned_route(prep.plan, scenario.goal) if controller in ROUTE_FOLLOWERS else None)
    doc = episode_json(
        episode,
        scenario=scenario.name,
        controller=controller,
        seed=seed,
        start=start,
        goal=scenario.goal,
        rects=prep.areas.rects,
        mismatch=mismatch.changed(),
        setup_ms=setup_ms,
    )
    doc.update(footprint_fields(cspec))
    if recorder is not None:
        recorder.finish(episode, doc)
    return RunOutcome(prep, controller, start, episode, doc, cspec)


@dataclass
class SensingLog:
    """What a lidar run saw, step by step, for recordings (collected outside the timed step).

    Attributes:
        scan_points: per step, the (K, 2) [m] world positions of the scan's returns as the
            robot placed them (at its measured pose), or None on a step without a scan.
        map_frames: (step, states) pairs: the (ny, nx) int8 unknown / free / occupied states
            of the sensed grid, kept when they changed, at most every ``every`` steps (and at
            the last step).
        area_frames: (step, rects (R, 4) [m]) pairs: the safe areas when they changed, on
            the same schedule, and at every replan.
        origin: (2,) [m] grid origin; resolution: [m] cell edge.
        every: [steps] the frame schedule.
    """

    origin: np.ndarray
    resolution: float
    every: int = 5
    scan_points: list[np.ndarray | None] = field(default_factory=list)
    map_frames: list[tuple[int, np.ndarray]] = field(default_factory=list)
    area_frames: list[tuple[int, np.ndarray]] = field(default_factory=list)

    def hook(self, ctrl, offset) -> Callable[[int, Any], None]:
        """The runner's ``on_step`` hook for the :class:`SensingSAMPC` ``ctrl`` whose lidar sits
        at ``offset`` (2,) [m] in the base frame."""
        last_frame = [-10**9]
        last_states: list[np.ndarray | None] = [None]
        ox, oy = float(offset[0]), float(offset[1])

        def on_step(step: int, trace) -> None:
            scan = ctrl.last_scan
            if scan is None:
                self.scan_points.append(None)
            else:
                x, y, yaw = (float(v) for v in trace.measured[step])
                c, s_ = np.cos(yaw), np.sin(yaw)
                sx, sy = x + c * ox - s_ * oy, y + s_ * ox + c * oy
                hit = np.asarray(scan.hit, bool)
                r = np.asarray(scan.ranges, float)[hit]
                a = yaw + np.asarray(scan.angles, float)[hit]
                self.scan_points.append(np.column_stack((sx + r * np.cos(a), sy + r * np.sin(a))))
            rec = ctrl.records[step]
            due = step - last_frame[0] >= self.every
            if due or rec.replan is not None:
                states = ctrl.map.grid.states()
                if last_states[0] is None or not np.array_equal(states, last_states[0]):
                    self.map_frames.append((step, states))
                    last_states[0] = states
                if ctrl.areas is not None:
                    self.area_frames.append((step, np.asarray(ctrl.areas.rects, float).copy()))
                last_frame[0] = step

        return on_step

    def close(self, ctrl, steps: int) -> None:
        """Add the final map and safe areas (after step ``steps - 1``) when they differ."""
        if steps <= 0:
            return
        states = ctrl.map.grid.states()
        if not self.map_frames or not np.array_equal(states, self.map_frames[-1][1]):
            self.map_frames.append((steps - 1, states))
        if ctrl.areas is not None and (not self.area_frames or self.area_frames[-1][0] != steps - 1):
            self.area_frames.append((steps - 1, np.asarray(ctrl.areas.rects, float).copy()))


#: the ``sensing`` modes of :func:`run_scenario`.
SENSING_MODES = ("map", "lidar")


def _chain(first, second):
    """One ``on_step`` hook calling ``first`` then ``second`` (either may be None)."""
    if first is None or second is None:
        return first if second is None else second

    def both(step, trace):
        first(step, trace)
        second(step, trace)

    return both


#: [m] a lidar run's speed derating reaches its floor at no less than this one-step error
#: (:func:`lidar_spec`): 25 / 25 paper-scenario runs with it; the known map's 0.02 m stalled
#: complex seed 2 (2026-11-24, branch h14safe0).
LIDAR_PREDICTION_STOP_M = 0.03


def lidar_spec(cspec: ControllerSpec) -> ControllerSpec:
    """``cspec`` as a lidar run uses it: in ``"discs"`` mode with the stage boxes shrunk by
    ``box_margin`` (not ``footprint_box_margin``), no open-space speed
    (``footprint_open_speed`` None: not measured with the lidar), the prediction monitor's
    box tightening off and its derating's ``stop`` at least :data:`LIDAR_PREDICTION_STOP_M`;
    ``cspec`` itself otherwise.

    ``footprint_refine`` and ``footprint_grow`` are kept, with the sensed map's meaning
    (:func:`lidar_controller`): the sensed grid's cells are ``resolution / footprint_refine``
    everywhere (:func:`lidar_cell`; the live grid is one grid, the known map refines only
    where the free space is narrow), and the corridor chain's boxes grow into the sensed
    *safe* cells (``SensingConfig.grow``). The tightening shrinks the
    stage boxes by the measured one-step prediction error, whose bound assumes the measured
    state is the true one; with the lidar the measured state is the localiser's, and its
    scan-match corrections enter that error: with it on, 2 of the 25 paper-scenario runs
    ended ``solver_failure`` / ``stuck`` in the gaps (complex seeds 2 and 4, double_rect
    seeds 3 and 4 at another code state), all four reach the goal with it off (2026-11-24,
    docs/results.md). ``footprint_box_margin`` (0 by default) and the derating's ``stop``
    (0.02 m) are sized on the known map together with the tightening and do not measure the
    localiser's error: the lidar run keeps ``box_margin`` and the derating it was measured
    with (``stop`` 0.03 m; at 0.02 complex seed 2 stalled). The speed derating stays on; the
    lidar mode's own-position safety is the body clearing with its pose bound
    (docs/sensing.md)."""
    from dataclasses import replace

    mpc = cspec.sa_mpc
    if mpc.footprint != "discs":
        return cspec
    pred = mpc.footprint_prediction
    if pred is not None and (pred.tighten or pred.stop < LIDAR_PREDICTION_STOP_M):
        pred = replace(pred, tighten=False, stop=max(pred.stop, LIDAR_PREDICTION_STOP_M))
    used = replace(mpc, footprint_box_margin=mpc.box_margin, footprint_open_speed=None, footprint_prediction=pred)
    return cspec if used == mpc else replace(cspec, sa_mpc=used)


def lidar_match(refine: float):
    """The scan matcher's settings on a sensed grid ``refine`` times finer than the base
    cells: the defaults (``ScanMatchConfig``) with the settings counted in cells
    (``radius_cells``, ``xy_window``) multiplied by ``refine`` (rounded), so the matcher
    reaches as far in metres as on the base grid. On 0.025 m cells with the 0.05 m counts
    the nearest-point search reached 0.05 m instead of 0.1 m, and the turn on the spot of
    single_rect seed 3 saw only ``few_points`` matches (scans not added) for 7 s."""
    from dataclasses import replace

    from sanav_mj.mapping.scan_match import ScanMatchConfig

    m = ScanMatchConfig()
    k = max(1, int(round(refine)))
    return m if k == 1 else replace(m, radius_cells=m.radius_cells * k, xy_window=m.xy_window * k)


def lidar_cell(resolution: float, cspec: ControllerSpec) -> float:
    """[m] the sensed grid's cell edge of a lidar run with base cells of ``resolution`` [m]:
    ``resolution / footprint_refine`` in ``"discs"`` mode, ``resolution`` otherwise."""
    mpc = cspec.sa_mpc
    return resolution / mpc.footprint_refine if mpc.footprint == "discs" else resolution


def sensed_narrow_width(lost: float, resolution: float) -> float:
    """[m] the narrow-passage width of the corridor search on a sensed grid of ``resolution``
    [m] cells, for a map inflated ``lost`` [m] less than the circumscribed-disc map.

    The known map's rule (:func:`planning_areas`) calls a place narrow when it is narrower
    than ``2 lost`` (the circumscribed disc has no room there). On the sensed grid widths
    come in whole cells: with ``2 lost`` = 0.198 m a strip of 0.20 m (4 cells) is not
    narrow by that rule, yet leaves the circumscribed disc 2 mm; the robot drove into such
    strips and stalled at their turns (v_shape seed 3 and complex seed 1, seed 0-4 campaign,
    2026-11-24). So every width of up to ``ceil(2 lost / resolution)`` cells is narrow: the
    returned width is one cell more, compared with ``<``. 0 when ``lost <= 0``.
    """
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution: expected a finite number > 0 [m], got {resolution!r}")
    if not lost > 0:
        return 0.0
    return (math.ceil(2.0 * lost / resolution - 1e-9) + 1) * resolution


def lidar_controller(scenario: Scenario, cspec: ControllerSpec = ControllerSpec(), resolution: float = 0.05,
                     mismatch: Mismatch = Mismatch()):
    """The :class:`~sanav_mj.control.sensing.SensingSAMPC` a lidar run of ``scenario`` uses:
    the known-map mode's inflation (:func:`map_inflation`: circumscribed radius +
    :data:`DEFAULT_MARGIN_M`, or in ``"discs"`` mode the disc cover's radius +
    ``footprint_margin``), the lidar offset of the robot file, the planner matched to the MPC,
    one grid of :func:`lidar_cell` cells (``resolution`` [m], divided by ``footprint_refine``
    in ``"discs"`` mode) and, in ``"discs"`` mode, the known map's narrow-passage penalty of
    the corridor search (:func:`planning_areas`, counted in those cells) and the chain's
    growth into the sensed safe cells (``SensingConfig.grow`` = ``footprint_grow``).

    ``cspec`` is first taken as :func:`lidar_spec` gives it (no box tightening in
    ``"discs"`` mode).

    Raises:
        ValueError: ``"discs"`` with ``footprint_route="pose"`` (a known-map setting: the pose
            search takes about a second per plan).
    """
    from sanav_mj.control.sensing import SensingConfig, SensingSAMPC
    from sanav_mj.footprint import robot_footprint
    from sanav_mj.mapping.sensed_map import SensedMapConfig
    from sanav_mj.sim.lidar import lidar_config

    cspec = lidar_spec(cspec)
    mpc = cspec.sa_mpc
    base, resolution = resolution, lidar_cell(resolution, cspec)
    if mpc.footprint == "discs" and mpc.footprint_route != "corridor":
        raise ValueError(f"sensing lidar with MPCConfig.footprint='discs': expected footprint_route='corridor', "
                         f"got footprint_route={mpc.footprint_route!r}")
    lcfg = lidar_config(scenario.model)
    inflation = map_inflation(scenario, cspec)
    narrow = sensed_narrow_width(scenario.robot.footprint_radius + DEFAULT_MARGIN_M - inflation, resolution) \
        if mpc.footprint == "discs" else 0.0
    spec = cspec.with_solve_budget(mismatch.solve_budget_ms)
    return SensingSAMPC(scenario.robot, scenario.bounds, scenario.goal, inflation, lcfg.offset,
                        spec.sa_mpc, planner_config(scenario.robot, spec),
                        SensingConfig(map=SensedMapConfig(resolution=resolution, match=lidar_match(base / resolution)),
                                      footprint=robot_footprint(scenario.model), narrow_width=narrow,
                                      refresh=mpc.footprint == "discs", straight_brake=mpc.footprint == "discs",
                                      grow=mpc.footprint_grow if mpc.footprint == "discs" else 0.0))


def _run_lidar(source, cspec: ControllerSpec, seed: int, yaw: float | None, resolution: float,
               mismatch: Mismatch, time_limit_s: float, run_config: RunConfig | None,
               controller_obj=None, on_step=None, rrd: Path | None = None, record: bool = False) -> RunOutcome:
    """One SA-MPC run on the map the robot's lidar builds (see :func:`run_scenario`)."""
    from dataclasses import replace

    from sanav_mj.eval.metrics import episode_json, safe_area_violations, timing_stats
    from sanav_mj.sim.lidar import Lidar, lidar_config
    from sanav_mj.sim.mismatch import mismatched_model
    from sanav_mj.sim.plant import Plant
    from sanav_mj.sim.runner import run_episode

    if isinstance(source, Prepared):
        # a Prepared of a refined discs map has cells of resolution / footprint_refine
        # (map_config): its base cells, divided again by lidar_controller (lidar_cell)
        mpc = cspec.sa_mpc
        refine = mpc.footprint_refine if mpc.footprint == "discs" and mpc.footprint_refine > 1 else 1
        scenario, resolution = source.scenario, source.grid.resolution * refine
    else:
        scenario = source if isinstance(source, Scenario) else load_scenario(source)
    cspec = lidar_spec(cspec)
    start = initial_pose(scenario, seed, yaw)
    model = mismatched_model(scenario, mismatch) if mismatch.physical else None
    plant = Plant(scenario, model=model)
    lcfg = lidar_config(plant.model)
    lidar = Lidar(plant.model, scenario.obstacles, lcfg)
    lidar_rng = np.random.default_rng([seed, 16])
    ctrl = controller_obj if controller_obj is not None else lidar_controller(scenario, cspec, resolution, mismatch)
    cfg = replace(run_config or RunConfig(), time_limit_s=time_limit_s)
    rng = np.random.default_rng(seed + 1)
    log = SensingLog(origin=ctrl.map.grid.origin.copy(), resolution=ctrl.map.grid.resolution) if record else None
    outside: list[int] = []

    def violations(step: int, trace) -> None:
        # the true position of the step against the safe areas the step's map update left
        # (before the first plan the robot turns on the spot where it stands: not counted)
        if ctrl.mpc is not None and ctrl.areas is not None:
            outside.append(safe_area_violations(np.asarray(trace.pose[step])[None, :2], ctrl.areas.rects))

    hook = _chain(_chain(violations, log.hook(ctrl, lcfg.offset) if log is not None else None), on_step)
    from sanav_mj.sim.termination import ReplannedRouteProgress

    episode = run_episode(plant, ctrl, start, scenario.goal, cfg, mismatch, rng,
                          progress=ReplannedRouteProgress(lambda: ctrl.route, scenario.goal),
                          on_step=hook, scan=lambda: lidar.scan(plant.data, lidar_rng),
                          scan_period_s=lcfg.period)
    ctrl.settle()  # a background plan requested at the last step is not used
    doc = episode_json(episode, scenario=scenario.name, controller=cspec.name, seed=seed, start=start,
                       goal=scenario.goal, rects=None, mismatch=mismatch.changed(), setup_ms=0.0)
    doc["safe_area_violations"] = int(sum(outside))
    doc["pipeline_ms"] = timing_stats(episode.trace.pipeline_ms)
    doc["sensing"] = "lidar"
    mu = timing_stats(ctrl.map_update_ms)
    doc["map_update_ms"] = {"mean": mu["mean"], "max": mu["max"], "p99": mu["p99"]}
    doc["replans"] = int(ctrl.replans)
    doc.update(footprint_fields(cspec))
    prep = _sensed_prepared(scenario, ctrl)
    if log is not None:
        log.close(ctrl, episode.steps)
    out = RunOutcome(prep, cspec.name, start, episode, doc, cspec, sensed=ctrl, sensing_log=log)
    if rrd is not None:
        from sanav_mj.record import record_episode

        record_episode(rrd, out)
    return out


def _sensed_prepared(scenario: Scenario, ctrl) -> Prepared:
    """The :class:`Prepared` of a lidar run, for plots and recordings: the grid and quadtree
    of the safe map at the end of the run, the safe areas and plan of the last plan (a failed
    plan when the robot never planned)."""
    from dataclasses import replace

    from sanav_mj.mapping.safe_areas import build_safe_areas
    from sanav_mj.planning.reference import Plan as _Plan

    final = build_safe_areas(ctrl.map.grid.safe_grid())
    if ctrl.mpc is None:
        none = np.zeros((0, 2))
        plan = _Plan(ok=False, reason="no_path", corridor=np.zeros(0, int), goal=scenario.goal, waypoints=none,
                     path=none, smoothed=none, reference=None)
        return Prepared(scenario, final, plan, {})
    return Prepared(scenario, replace(final, boxes=ctrl.plan_boxes, areas=ctrl.mpc.areas), ctrl.mpc.plan, {})


#: controllers that track the planned route: their ``stuck`` rule measures progress along it.
#: The penalty MPC (reference straight to the goal), DWA and the DQN drive to the goal
#: without the plan (and the DQN trains in ``NavEnv``, which has no planner), so theirs is
#: the reduction of the straight-line distance to the goal.
ROUTE_FOLLOWERS = ("sa-mpc",)


def planned_route(plan: Plan, goal: np.ndarray) -> np.ndarray | None:
    """The route (P, 2) [m] a plan defines for the ``stuck`` rule: the reference positions,
    ended by the scenario goal (2,) [m] when the plan projected it; None without a plan."""
    from sanav_mj.sim.termination import route_of

    if not plan.ok or plan.reference is None:
        return None
    return route_of(plan.reference.states[:, :2], goal)


def _replan(prep: Prepared, start: np.ndarray, spec: ControllerSpec) -> Prepared:
    from sanav_mj.planning import plan as make_plan

    t0 = time.perf_counter()
    robot = prep.scenario.robot
    plan = make_plan(planning_areas(prep.areas, prep.scenario, spec), start, prep.scenario.goal, robot,
                     planner_config(robot, spec))
    plan = footprint_route_plan(plan, prep.areas, prep.grid, prep.scenario, start, spec)
    timing = dict(prep.timing_ms)
    timing["plan"] = (time.perf_counter() - t0) * 1e3
    return Prepared(prep.scenario, prep.map, plan, timing)


def _no_path_episode(plant, start: np.ndarray) -> Episode:
    from sanav_mj.sim.runner import EpisodeTrace

    plant.reset(start)
    trace = EpisodeTrace()
    # the robot stays at its start: the run's smallest clearance is the start's (a number, as
    # DESIGN.md's run JSON has it, not null)
    trace.clearance.append(plant.clearance())
    return Episode(
        success=False,
        reason="no_path",
        steps=0,
        sim_time_s=0.0,
        collisions=0,
        solver_failures=0,
        final_pose=plant.pose(),
        trace=trace,
        wall_time_s=0.0,
    )
