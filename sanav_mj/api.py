"""The public Python API: scenario -> map -> plan -> closed-loop run, as the CLI does it.

    import sanav_mj

    scenario = sanav_mj.load_scenario("u_shape")            # built-in name or MJCF path
    safe_map = sanav_mj.build_map(scenario)                 # .rects: (R, 4) [m]
    route = sanav_mj.plan(scenario, safe_map)               # corridor + reference
    result = sanav_mj.run_scenario("u_shape", seed=0)       # .to_dict() == run --json

Every function here wraps the same machinery the command line uses
(:mod:`sanav_mj.eval.episode`), so a run through the API and ``sanav-mj run`` with the same
arguments give the same document (apart from the wall-clock fields ``solve_ms``,
``pipeline_ms``). Errors are ``ValueError`` subclasses whose one-line message names the
argument, the rule and the value received (:class:`~sanav_mj.scene.ScenarioError` for
scenario files, :class:`~sanav_mj.sim.mismatch.MismatchError` for mismatch keys).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sanav_mj.control.spec import CONTROLLER_NAMES, ControllerSpec
from sanav_mj.eval.bench import run_bench
from sanav_mj.eval.robustness import run_robustness
from sanav_mj.eval.prepare import DEFAULT_MARGIN_M, Prepared, planner_config
from sanav_mj.eval import episode as _episode
from sanav_mj.mapping.build import RESOLUTION_RANGE_M
from sanav_mj.mapping.safe_areas import MERGE_METHODS, SafeAreaMap
from sanav_mj.planning import Plan, PlannerConfig
from sanav_mj.scene import Scenario
from sanav_mj.scene import load_scenario as _load_scenario
from sanav_mj.sim.mismatch import Mismatch, MismatchError, mismatch_keys
from sanav_mj.sim.runner import Episode

__all__ = ["ControllerSpec", "Mismatch", "RunResult", "build_map", "load_scenario", "plan", "run_bench",
           "run_robustness", "run_scenario"]

ScenarioLike = Scenario | str | Path


def load_scenario(scenario: ScenarioLike, margin: float = 0.05) -> Scenario:
    """Load a scenario from an MJCF file (see docs/scenarios.md) or a built-in name.

    Args:
        scenario: path to an ``.xml`` file, or a built-in name (``"single_rect"``,
            ``"double_rect"``, ``"u_shape"``, ``"v_shape"``, ``"complex"``); a loaded
            :class:`~sanav_mj.scene.Scenario` is returned as it is.
        margin: [m] clearance beyond the robot's footprint radius that start and goal must
            keep from obstacles and the workspace edge (>= 0).

    Returns:
        The :class:`~sanav_mj.scene.Scenario`: ``start`` (3,) [m, m, rad], ``goal`` (2,) [m],
        ``bounds`` (4,) [m] ``xmin, ymin, xmax, ymax``, ``obstacles``, ``robot``, ``model``.

    Raises:
        ScenarioError: the file or name is unusable (one line naming the file and the rule).
    """
    if isinstance(scenario, Scenario):
        return scenario
    if not isinstance(scenario, (str, Path)):
        raise TypeError(f"scenario: expected a path, a built-in name or a Scenario, got {type(scenario).__name__}")
    return _load_scenario(scenario, margin)


def _scenario(scenario: ScenarioLike) -> Scenario:
    return load_scenario(scenario)


def _resolution(resolution: float) -> float:
    lo, hi = RESOLUTION_RANGE_M
    if isinstance(resolution, bool) or not isinstance(resolution, (int, float)) or not (
        math.isfinite(resolution) and lo <= resolution <= hi
    ):
        raise ValueError(f"resolution: expected {lo} <= metres per cell <= {hi}, got {resolution!r}")
    return float(resolution)


def build_map(scenario: ScenarioLike, resolution: float = 0.05, merge: str = "paper") -> SafeAreaMap:
    """The mapping stage: inflated occupancy grid, quadtree, merged safe areas, graph.

    The obstacles are inflated by the robot's footprint radius plus 0.05 m (the margin
    every run uses).

    Args:
        scenario: a :class:`~sanav_mj.scene.Scenario`, an MJCF path or a built-in name.
        resolution: [m] grid cell edge (0.005 to 1.0; the CLI's ``--resolution``).
        merge: merge rule of the safe areas, one of ``MERGE_METHODS`` (``"paper"``).

    Returns:
        The :class:`~sanav_mj.mapping.safe_areas.SafeAreaMap`: ``rects`` (R, 4) float
        ``[xmin, ymin, xmax, ymax]`` [m] of the safe areas (free space for the robot centre),
        ``areas`` (rectangles, edges (E, 2), weights (E,) [m], portals (E, 2, 2) [m]),
        ``grid`` (the inflated occupancy grid), ``leaves``, ``timing_ms``; ``to_json()`` is
        the mapping part of ``areas --json``.
    """
    from sanav_mj.mapping import MapConfig
    from sanav_mj.mapping import build_map as _build_map

    if merge not in MERGE_METHODS:
        raise ValueError(f"merge: expected one of {', '.join(MERGE_METHODS)}, got {merge!r}")
    sc = _scenario(scenario)
    config = MapConfig(resolution=_resolution(resolution), merge=merge)
    return _build_map(sc.obstacles, sc.bounds, sc.robot.footprint_radius + DEFAULT_MARGIN_M, config)


def plan(
    scenario: ScenarioLike,
    safe_map: SafeAreaMap | None = None,
    start: np.ndarray | None = None,
    goal: np.ndarray | None = None,
    config: PlannerConfig | None = None,
) -> Plan:
    """Plan a corridor and a time-parametrised reference from start to goal (paper Sec. III-C).

    Args:
        scenario: a :class:`~sanav_mj.scene.Scenario`, an MJCF path or a built-in name.
        safe_map: the map to plan in (default: ``build_map(scenario)``).
        start: (3,) [m, m, rad] start pose (default: the scenario's).
        goal: (2,) [m] goal (default: the scenario's).
        config: planner settings (default: the settings runs use, matched to the SA-MPC's
            speed and rate limits).

    Returns:
        The :class:`~sanav_mj.planning.Plan`: ``ok``, ``reason`` (``"no_path"`` when the
        goal cannot be reached), ``corridor`` (C,) safe-area indices, ``waypoints`` (W, 2)
        [m], ``reference.states`` (K, 3) [m, m, rad] and ``reference.inputs`` (K, 2)
        [m/s, rad/s] at ``reference.dt`` [s].
    """
    from sanav_mj.planning import plan as _plan

    sc = _scenario(scenario)
    if safe_map is None:
        safe_map = build_map(sc)
    elif not isinstance(safe_map, SafeAreaMap):
        raise TypeError(f"safe_map: expected the result of build_map, got {type(safe_map).__name__}")
    if config is not None and not isinstance(config, PlannerConfig):
        raise TypeError(f"config: expected a PlannerConfig, got {type(config).__name__}")
    pose = sc.start if start is None else _array("start", start, 3)
    target = sc.goal if goal is None else _array("goal", goal, 2)
    return _plan(safe_map.areas, pose, target, sc.robot, config or planner_config(sc.robot))


def _array(name: str, value: Any, n: int) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected {n} finite numbers, got {value!r}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected {n} finite numbers, got {value!r}")
    return a


def _mismatch(mismatch: Mismatch | Mapping[str, float] | None) -> Mismatch:
    if mismatch is None:
        return Mismatch()
    if isinstance(mismatch, Mismatch):
        return mismatch
    if isinstance(mismatch, Mapping):
        keys = mismatch_keys()
        for key in mismatch:
            if key not in keys:
                raise MismatchError(f"mismatch: unknown key {key!r}; expected one of {', '.join(keys)}")
        return Mismatch(**dict(mismatch))
    raise TypeError(f"mismatch: expected a Mismatch or a dict of KEY: VALUE, got {type(mismatch).__name__}")


@dataclass(frozen=True)
class RunResult:
    """One finished closed-loop run.

    Attributes:
        document: the ``run --json`` document (plain Python types; see :meth:`to_dict`).
        episode: the episode with its per-step trace (:class:`~sanav_mj.sim.runner.Episode`:
            ``trace.poses()`` (S, 3) [m, m, rad], ``trace.cmd`` [(v [m/s], w [rad/s])], ...).
        prepared: the scenario, its map and the plan the run used.
        start: (3,) [m, m, rad] the start pose (yaw drawn from the seed unless given).
        sensed: with ``sensing="lidar"``, the controller that drove
            (:class:`~sanav_mj.control.sensing.SensingSAMPC`: its final ``map``, per-step
            ``records``, ``replans``); None in map mode.
        sensing_log: with ``sensing="lidar"`` and ``record_sensing=True``, the scans, map
            frames and safe areas of the run (:class:`~sanav_mj.eval.outcome.SensingLog`, what
            a recording shows); else None.
    """

    document: dict[str, Any] = field(repr=False)
    episode: Episode = field(repr=False)
    prepared: Prepared = field(repr=False)
    start: np.ndarray
    sensed: Any = field(default=None, repr=False)
    sensing_log: Any = field(default=None, repr=False)

    @property
    def controller(self) -> str:
        """The controller's name (``"sa-mpc"``, ``"mpc"``, ``"dwa"``, ``"dqn"``)."""
        return str(self.document["controller"])

    @property
    def success(self) -> bool:
        """The goal was reached with no robot-obstacle contact before it."""
        return bool(self.document["success"])

    @property
    def reason(self) -> str:
        """How the run ended: goal, collision, timeout, stuck, solver_failure, no_path, bad_measurement."""
        return str(self.document["reason"])

    def to_dict(self) -> dict[str, Any]:
        """The ``run --json`` document (a deep copy): the same keys and values ``sanav-mj run
        --json`` writes for the same arguments (wall-clock fields aside)."""
        return copy.deepcopy(self.document)


def run_scenario(
    scenario: ScenarioLike,
    controller: str | ControllerSpec = "sa-mpc",
    seed: int = 0,
    mismatch: Mismatch | Mapping[str, float] | None = None,
    yaw: float | None = None,
    resolution: float = 0.05,
    time_limit_s: float = 60.0,
    rrd: str | Path | None = None,
    sensing: str = "map",
    record_sensing: bool = False,
) -> RunResult:
    """Map, plan and drive one closed-loop episode in MuJoCo, like ``sanav-mj run``.

    Args:
        scenario: a :class:`~sanav_mj.scene.Scenario`, an MJCF path or a built-in name.
        controller: ``"sa-mpc"`` (the paper's method), ``"mpc"`` (obstacle-penalty MPC),
            ``"dwa"`` (dynamic window) or ``"dqn"`` (the shipped DQN policy) with their default
            settings, or a :class:`ControllerSpec` (a name and its configurations, e.g.
            ``ControllerSpec("sa-mpc", sa_mpc=replace(MPCConfig(), horizon=30))``), which the
            planner, the controller and the plots all read.
        seed: integer >= 0; draws the start yaw (unless ``yaw`` is given), the measurement
            noise and the control-period jitter.
        mismatch: plant-vs-model differences, a :class:`Mismatch` or a dict such as
            ``{"wheel_radius": 1.1, "delay": 1}`` (the keys of ``--mismatch``).
        yaw: [rad] start yaw instead of the seeded one.
        resolution: [m] grid cell edge (0.005 to 1.0).
        time_limit_s: [s] simulated time after which the run ends with ``timeout`` (> 0).
        rrd: write a rerun recording of the run to this path.
        sensing: ``"map"`` (the grid from the scenario's true geoms) or ``"lidar"`` (the
            robot knows only what its lidar has seen; SA-MPC only; docs/sensing.md). A lidar
            run's document gains ``"sensing"``, ``"map_update_ms"`` and ``"replans"``.
        record_sensing: (lidar) keep what the run saw in ``RunResult.sensing_log``, for a
            recording made afterwards with ``sanav_mj.record.record_episode``.

    Returns:
        A :class:`RunResult`; ``to_dict()`` is the ``run --json`` document.
    """
    if isinstance(controller, ControllerSpec):
        spec = controller
    elif isinstance(controller, str) and controller in CONTROLLER_NAMES:
        spec = ControllerSpec(controller)
    else:
        raise ValueError(f"controller: expected one of {', '.join(CONTROLLER_NAMES)} or a ControllerSpec, "
                         f"got {controller!r}")
    if sensing not in ("map", "lidar"):
        raise ValueError(f"sensing: expected 'map' or 'lidar', got {sensing!r}")
    if sensing == "lidar" and spec.name != "sa-mpc":
        raise ValueError(f"sensing: 'lidar' is supported for controller 'sa-mpc' only, got controller {spec.name!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= 2**31 - 1:
        raise ValueError(f"seed: expected an integer 0 <= seed < 2**31, got {seed!r}")
    if yaw is not None and (isinstance(yaw, bool) or not isinstance(yaw, (int, float)) or not math.isfinite(yaw)):
        raise ValueError(f"yaw: expected a finite number [rad] or None, got {yaw!r}")
    if isinstance(time_limit_s, bool) or not isinstance(time_limit_s, (int, float)) or not (
        math.isfinite(time_limit_s) and time_limit_s > 0
    ):
        raise ValueError(f"time_limit_s: expected a finite number > 0 [s], got {time_limit_s!r}")
    out = _episode.run_scenario(  # looked up at call time (tests replace it)
        _scenario(scenario),
        controller=spec.name,
        controller_spec=spec,
        seed=int(seed),
        yaw=None if yaw is None else float(yaw),
        resolution=_resolution(resolution),
        mismatch=_mismatch(mismatch),
        time_limit_s=float(time_limit_s),
        rrd=None if rrd is None else Path(rrd),
        sensing=sensing,
        record_sensing=bool(record_sensing),
    )
    return RunResult(document=out.document, episode=out.episode, prepared=out.prepared, start=out.start,
                     sensed=out.sensed, sensing_log=out.sensing_log)
