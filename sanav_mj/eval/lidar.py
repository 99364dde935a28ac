"""The lidar run: SA-MPC on the map its own lidar builds as it drives (``--sensing lidar``).

:func:`lidar_spec` and :func:`lidar_controller` turn the known-map settings into the lidar
run's (the sensed grid's cells, the scan matcher, what stays off because it was sized on the
known map); :func:`run_lidar` runs one episode and writes its document
(:func:`sanav_mj.eval.episode.run_scenario` with ``sensing="lidar"`` goes here).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sanav_mj.control.spec import ControllerSpec
from sanav_mj.eval.outcome import RunOutcome, SensingLog, chain
from sanav_mj.eval.prepare import (Prepared, disc_map_loss, footprint_fields, initial_pose, map_inflation,
                                   planner_config)
from sanav_mj.scene import Scenario, load_scenario
from sanav_mj.sim.mismatch import Mismatch
from sanav_mj.sim.runner import RunConfig


#: [m] a lidar run's speed derating reaches its floor at no less than this one-step error
#: (:func:`lidar_spec`): 25 / 25 paper-scenario runs with it; the known map's 0.02 m stalled
#: complex seed 2 (2026-11-24, branch h14safe0).
LIDAR_PREDICTION_STOP_M = 0.03


def lidar_spec(cspec: ControllerSpec) -> ControllerSpec:
    """``cspec`` as a lidar run uses it: in ``"discs"`` mode with the stage boxes shrunk by
    ``box_margin`` (not ``footprint_box_margin``), the prediction monitor's box tightening
    off and its derating's ``stop`` at least :data:`LIDAR_PREDICTION_STOP_M`; ``cspec``
    itself otherwise. The open-space speed (``footprint_open_speed``) is kept: the lidar
    run's plans read the open room from the cells safe in the sensed map at the plan
    (unknown cells are never open; on 30 BARN-like worlds it kept 20/30 at the goal, 0
    collisions, and raised the mean BARN metric of the runs reaching the goal in both from
    0.346 to 0.374, 2026-11-25).

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
    used = replace(mpc, footprint_box_margin=mpc.box_margin, footprint_prediction=pred)
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


def lidar_grid(cspec: ControllerSpec, noise_std: float | None = None, resolution: float | None = None):
    """The :class:`~sanav_mj.mapping.live_grid.LiveGridConfig` of a lidar run: the default
    (stray returns outvoted: ``floor_at`` 0.5, ``l_min`` -5) in ``"discs"`` mode, whose
    sensed cells are 0.025 m (:func:`lidar_cell`), the rule that default was derived and
    measured for (range noise 0.02 m, nearly a cell: returns scattered up to 3 cells in front
    of a surface closed gaps; BARN-like worlds 74 -> 85 / 100, paper scenarios seeds 0-4 25 /
    25, the envelope corner seeds 0-3 20 / 20 with 0 steps outside the safe areas); in the
    ``"disc"`` mode
    (0.05 m cells, the noise under half a cell) the previous rule, one return makes a cell
    non-free at once (``l_min`` -1, ``floor_at`` None): with the new one the envelope corner
    lost u_shape seed 0 (stuck), the steps whose true position lay outside that step's safe
    areas rose from 107 to 177 in 16 runs and the smallest clearance fell from 0.166 to 0.112
    m (2026-11-25, docs/results.md).

    In ``"discs"`` mode, given the lidar's range noise ``noise_std`` [m] and the sensed
    cells' edge ``resolution`` [m], occupied cells count against the safe grid with their
    sub-cell evidence (``sub_cells=2``, :mod:`sanav_mj.mapping.subcell_grid`) when that
    noise keeps a sub-cell holding a sliver of material occupied
    (:func:`~sanav_mj.mapping.subcell_grid.subcells_hold`), else with their whole square."""
    from sanav_mj.mapping.live_grid import LiveGridConfig
    from sanav_mj.mapping.subcell_grid import subcells_hold

    if cspec.sa_mpc.footprint == "discs":
        base = LiveGridConfig()
        if noise_std is not None and resolution is not None and subcells_hold(resolution, noise_std, base):
            return LiveGridConfig(sub_cells=2)
        return base
    return LiveGridConfig(l_min=-1.0, floor_at=None)


def lidar_cell(resolution: float, cspec: ControllerSpec) -> float:
    """[m] the sensed grid's cell edge of a lidar run with base cells of ``resolution`` [m]:
    ``resolution / footprint_refine`` in ``"discs"`` mode, ``resolution`` otherwise."""
    mpc = cspec.sa_mpc
    return resolution / mpc.footprint_refine if mpc.footprint == "discs" else resolution


def sensed_narrow_width(lost: float, resolution: float) -> float:
    """[m] the narrow-passage width of the corridor search on a sensed grid of ``resolution``
    [m] cells, for a map inflated ``lost`` [m] less than the circumscribed-disc map.

    The known map's rule (:func:`~sanav_mj.eval.prepare.planning_areas`) calls a place narrow when it is narrower
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
    :data:`~sanav_mj.eval.prepare.DEFAULT_MARGIN_M`, or in ``"discs"`` mode the disc cover's radius +
    ``footprint_margin``), the lidar offset of the robot file, the planner matched to the MPC,
    one grid of :func:`lidar_cell` cells (``resolution`` [m], divided by ``footprint_refine``
    in ``"discs"`` mode) and, in ``"discs"`` mode, the known map's narrow-passage penalty of
    the corridor search (:func:`~sanav_mj.eval.prepare.planning_areas`, counted in those cells) and the chain's
    growth into the sensed safe cells (``SensingConfig.grow`` = ``footprint_grow``).

    ``cspec`` is first taken as :func:`lidar_spec` gives it (no box tightening in
    ``"discs"`` mode).

    Raises:
        ValueError: ``"discs"`` with ``footprint_route="pose"`` (a known-map setting: the pose
            search takes about a second per plan).
    """
    from sanav_mj.control.sensing import SensingSAMPC
    from sanav_mj.control.sensing_config import SensingConfig
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
    narrow = sensed_narrow_width(disc_map_loss(scenario, cspec), resolution) \
        if mpc.footprint == "discs" else 0.0
    spec = cspec.with_solve_budget(mismatch.solve_budget_ms)
    return SensingSAMPC(scenario.robot, scenario.bounds, scenario.goal, inflation, lcfg.offset,
                        spec.sa_mpc, planner_config(scenario.robot, spec),
                        SensingConfig(map=SensedMapConfig(resolution=resolution, match=lidar_match(base / resolution),
                                                          grid=lidar_grid(cspec, lcfg.noise_std, resolution)),
                                      footprint=robot_footprint(scenario.model), narrow_width=narrow,
                                      refresh=mpc.footprint == "discs", straight_brake=mpc.footprint == "discs",
                                      grow=mpc.footprint_grow if mpc.footprint == "discs" else 0.0))


def outside_safe_areas(ctrl, pose: np.ndarray) -> int:
    """1 when a constrained point of the robot at the true ``pose`` (3,) [m, m, rad] lies
    outside every current safe area of the sensing controller ``ctrl`` (the areas its map
    update of this step left), else 0: every disc centre of the cover in ``"discs"`` mode
    (``ctrl.body.offsets``, the points the hard constraints hold in the safe areas), the
    position in ``"disc"`` mode. 0 before the first plan (the robot turns on the spot where
    it stands) and before the first scan. The run JSON's ``safe_area_violations`` of a
    lidar run is the sum over its steps."""
    from sanav_mj.eval.metrics import step_violations

    if ctrl.mpc is None:
        return 0
    areas = ctrl.areas
    if areas is None:
        return 0
    return step_violations(np.asarray(pose, dtype=float).reshape(1, 3), areas.rects, ctrl.body.offsets)


def run_lidar(source, cspec: ControllerSpec, seed: int, yaw: float | None, resolution: float,
               mismatch: Mismatch, time_limit_s: float, run_config: RunConfig | None,
               controller_obj=None, on_step=None, rrd: Path | None = None, record: bool = False) -> RunOutcome:
    """One SA-MPC run on the map the robot's lidar builds (the arguments as
    :func:`sanav_mj.eval.episode.run_scenario` takes them; ``record``: keep a
    :class:`SensingLog`)."""
    from dataclasses import replace

    from sanav_mj.eval.metrics import episode_json, timing_stats
    from sanav_mj.sim.lidar import Lidar, lidar_config
    from sanav_mj.sim.mismatch import mismatched_model
    from sanav_mj.sim.plant import Plant
    from sanav_mj.sim.runner import run_episode

    if isinstance(source, Prepared):
        # a Prepared of a refined discs map has cells of resolution / footprint_refine
        # (map_config): its base cells, divided again by lidar_controller (lidar_cell)
        mpc = cspec.sa_mpc
        fine = mpc.footprint_refine_fallback if source.refine_fallback else mpc.footprint_refine  # see prepare()
        refine = fine if mpc.footprint == "discs" and fine > 1 else 1
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
        outside.append(outside_safe_areas(ctrl, np.asarray(trace.pose[step])))

    hook = chain(chain(violations, log.hook(ctrl, lcfg.offset) if log is not None else None), on_step)
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
    prep = sensed_prepared(scenario, ctrl)
    if log is not None:
        log.close(ctrl, episode.steps)
    out = RunOutcome(prep, cspec.name, start, episode, doc, cspec, sensed=ctrl, sensing_log=log)
    if rrd is not None:
        from sanav_mj.record import record_episode

        record_episode(rrd, out)
    return out


def sensed_prepared(scenario: Scenario, ctrl) -> Prepared:
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
