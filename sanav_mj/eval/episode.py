"""One scenario from file to result: load, map, plan, control in MuJoCo, measure.

This is the composition of the whole data flow (scene -> mapping -> planning -> control ->
sim); the CLI, ``demo``, ``bench`` and ``robustness`` all go through :func:`prepare` and
:func:`run_scenario`, so every controller runs in the same harness and yields the same JSON.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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
    controller spec it ran with."""

    prepared: Prepared
    controller: str
    start: np.ndarray
    episode: Episode
    document: dict[str, Any]
    spec: ControllerSpec = ControllerSpec()


def planner_config(robot, spec: ControllerSpec = ControllerSpec()) -> Any:
    """Planner settings matched to the SA-MPC of ``spec``: the reference's speed, yaw-rate and
    acceleration caps are the planner's default fractions (0.8) of the MPC's resolved input
    and rate bounds (``spec.sa_mpc.limits(robot)``), not of the robot's, and its period is
    the MPC's ``dt``. A reference faster than the MPC may drive (1.6 m/s against 1.43 m/s
    for the MuJoCo robot) leaves the robot lagging behind it.

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
    return PlannerConfig(
        dt=mpc.dt,
        speed_fraction=min(1.0, base.speed_fraction * lim.v_max / robot.v_max),
        yaw_rate_fraction=min(1.0, base.yaw_rate_fraction * lim.w_max / robot.w_max),
        accel_fraction=min(1.0, base.accel_fraction * lim.a_max / robot.a_max),
    )


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
    from sanav_mj.mapping import MapConfig, MapMemoryError, build_map
    from sanav_mj.planning import plan as make_plan

    scenario = spec if isinstance(spec, Scenario) else load_scenario(spec)
    inflation = map_inflation(scenario, controller)
    try:
        m = build_map(scenario.obstacles, scenario.bounds, inflation, MapConfig(resolution=resolution, merge=merge))
    except MapMemoryError as err:  # name the file too (ScenarioError: exit 2)
        raise MapMemoryError(f"{scenario.path}: {err}") from None
    t0 = time.perf_counter()
    pose = scenario.start if start is None else np.asarray(start, dtype=float)
    plan = make_plan(planning_areas(m.areas, scenario, controller), pose, scenario.goal, scenario.robot,
                     planner_config(scenario.robot, controller))
    timing = dict(m.timing_ms)
    timing["plan"] = (time.perf_counter() - t0) * 1e3
    timing["total"] = timing.get("total", 0.0) + timing["plan"]
    return Prepared(scenario, m, plan, timing)


def areas_document(prep: Prepared) -> dict[str, Any]:
    """The ``areas --json`` document of the design contract."""
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

    Raises:
        ValueError: unknown controller name, or ``controller_spec.name`` differs from ``controller``.
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
                              on_step=recorder.log_step if recorder else None,
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
    if recorder is not None:
        recorder.finish(episode, doc)
    return RunOutcome(prep, controller, start, episode, doc, cspec)


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
    timing = dict(prep.timing_ms)
    timing["plan"] = (time.perf_counter() - t0) * 1e3
    return Prepared(prep.scenario, prep.map, plan, timing)


def _no_path_episode(plant, start: np.ndarray) -> Episode:
    from sanav_mj.sim.runner import EpisodeTrace

    plant.reset(start)
    return Episode(
        success=False,
        reason="no_path",
        steps=0,
        sim_time_s=0.0,
        collisions=0,
        solver_failures=0,
        final_pose=plant.pose(),
        trace=EpisodeTrace(),
        wall_time_s=0.0,
    )
