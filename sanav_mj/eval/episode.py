"""One scenario from file to result: load, map, plan, control in MuJoCo, measure.

This is the composition of the whole data flow (scene -> mapping -> planning -> control ->
sim); the CLI, ``demo``, ``bench`` and ``robustness`` all go through :func:`~sanav_mj.eval.prepare.prepare` and
:func:`run_scenario`, so every controller runs in the same harness and yields the same JSON.
"""

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sanav_mj.control.base import Controller
from sanav_mj.control.spec import ControllerSpec
from sanav_mj.eval.lidar import run_lidar
from sanav_mj.eval.outcome import RunOutcome, chain, no_path_episode
from sanav_mj.eval.prepare import (Prepared, footprint_fields, initial_pose, planner_config, prepare,
                                   replan_prepared)
from sanav_mj.planning.reference import Plan
from sanav_mj.scene import Scenario, check_timestep, load_scenario
from sanav_mj.sim.mismatch import Mismatch
from sanav_mj.sim.runner import RunConfig

#: the ``sensing`` modes of :func:`run_scenario`.
SENSING_MODES = ("map", "lidar")

#: controllers that track the planned route: their ``stuck`` rule measures progress along it.
#: The penalty MPC (reference straight to the goal), DWA and the DQN drive to the goal
#: without the plan (and the DQN trains in ``NavEnv``, which has no planner), so theirs is
#: the reduction of the straight-line distance to the goal.
ROUTE_FOLLOWERS = ("sa-mpc",)


def constrained_points(scenario: Scenario, cspec: ControllerSpec) -> np.ndarray | None:
    """(P, 2) [m] the body-frame points SA-MPC's hard constraints hold in the safe areas in
    its ``"discs"`` mode (the disc centres of the robot's cover), counted by the run JSON's
    ``safe_area_violations``; None otherwise (the position alone)."""
    if cspec.name != "sa-mpc" or cspec.sa_mpc.footprint != "discs":
        return None
    from sanav_mj.footprint import robot_footprint

    return robot_footprint(scenario.model).discs(cspec.sa_mpc.footprint_discs)[0]


def planned_route(plan: Plan, goal: np.ndarray) -> np.ndarray | None:
    """The route (P, 2) [m] a plan defines for the ``stuck`` rule: the reference positions,
    ended by the scenario goal (2,) [m] when the plan projected it; None without a plan."""
    from sanav_mj.sim.termination import route_of

    if not plan.ok or plan.reference is None:
        return None
    return route_of(plan.reference.states[:, :2], goal)

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
        return run_lidar(source, cspec, seed, yaw, resolution, mismatch, time_limit_s, run_config,
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
                   controller=cspec) if prep0 is None else replan_prepared(prep0, start, cspec)
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
        episode = no_path_episode(plant, start)
    else:
        ctrl = controller_obj if controller_obj is not None else make_controller(
            cspec, prep.scenario, prep.grid, prep.areas, prep.plan, solve_budget_ms=mismatch.solve_budget_ms
        )
        episode = run_episode(plant, ctrl, start, scenario.goal, cfg, mismatch, rng,
                              on_step=chain(recorder.log_step if recorder else None, on_step),
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
        points=constrained_points(scenario, cspec),
    )
    doc.update(footprint_fields(cspec))
    if recorder is not None:
        recorder.finish(episode, doc)
    return RunOutcome(prep, controller, start, episode, doc, cspec)
