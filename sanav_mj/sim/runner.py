"""The closed-loop episode: a controller commanding the MuJoCo robot at its period ``dt``.

Physics steps at the model's timestep (about 2 ms); the controller runs every ``dt`` with a
zero-order hold on (v, w), which the plant turns into wheel velocity commands using the
*nominal* wheel radius and track. Contact, friction and slip are MuJoCo's.

The runner records everything per step into an :class:`EpisodeTrace`; it never prints,
plots or writes files (that is the job of ``eval``, ``record`` and ``cli``).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from sanav_mj.control.base import Command, Controller, Observation
from sanav_mj.sim.mismatch import Mismatch
from sanav_mj.sim.plant import Plant
from sanav_mj.sim.termination import Progress, RouteProgress, Termination, TerminationConfig

REASONS = ("goal", "collision", "timeout", "stuck", "solver_failure", "no_path", "bad_measurement")


@dataclass(frozen=True)
class RunConfig(TerminationConfig):
    """Episode settings: the shared termination rules plus the runner's own.

    The termination fields (``time_limit_s``, ``goal_tolerance_m``, ``stuck_window_s``,
    ``stuck_progress_m``) are those of :class:`~sanav_mj.sim.termination.TerminationConfig`
    (the same rules :class:`~sanav_mj.sim.nav_env.NavEnv` trains under).

    Attributes:
        max_solver_failures: consecutive solver failures after which the run ends with
            ``solver_failure`` (the robot has been brought to a stop by the fallback).
        n_rays: number of range rays given to controllers that ask for them.
        ray_range_m: [m] maximum ray range.
    """

    max_solver_failures: int = 20
    n_rays: int = 36
    ray_range_m: float = 5.0

    def __post_init__(self) -> None:
        super().__post_init__()
        value = self.ray_range_m
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"RunConfig.ray_range_m: expected a finite number > 0, got {value!r}")
        if self.max_solver_failures < 1 or self.n_rays < 1:
            raise ValueError("RunConfig.max_solver_failures and n_rays: expected >= 1")


@dataclass
class EpisodeTrace:
    """Per-control-step record of an episode (S steps). Lists are filled by the runner.

    Attributes:
        t: [s] simulation time at the start of each step.
        pose: true base pose x, y, yaw [m, m, rad] from MuJoCo.
        measured: the pose the controller saw (noise, faults) [m, m, rad].
        cmd: commanded (v, w) [m/s, rad/s] output by the controller.
        applied: (v, w) that reached the wheels this step (after the delay line).
        velocity: measured base (v, w) [m/s, rad/s] from MuJoCo.
        wheel_cmd: commanded (left, right) wheel speeds [rad/s].
        wheel_speed: measured (left, right) wheel speeds [rad/s].
        solve_ms: [ms] controller decision wall time.
        pipeline_ms: [ms] whole per-step controller work (solve plus preparation).
        status: controller status string.
        ok: controller succeeded (False when a fallback was used).
        clearance: [m] distance between the robot and the nearest obstacle.
        contacts: number of robot-obstacle contacts after the step.
        predicted: (N+1, 3) predicted states or None.
        rect_ids: (N+1,) safe-area ids assigned to the horizon or None.
        margins: (N+1,) [m] constraint slack of the horizon or None.
    """

    t: list[float] = field(default_factory=list)
    pose: list[np.ndarray] = field(default_factory=list)
    measured: list[np.ndarray] = field(default_factory=list)
    cmd: list[tuple[float, float]] = field(default_factory=list)
    applied: list[tuple[float, float]] = field(default_factory=list)
    velocity: list[np.ndarray] = field(default_factory=list)
    wheel_cmd: list[np.ndarray] = field(default_factory=list)
    wheel_speed: list[np.ndarray] = field(default_factory=list)
    solve_ms: list[float] = field(default_factory=list)
    pipeline_ms: list[float] = field(default_factory=list)
    status: list[str] = field(default_factory=list)
    ok: list[bool] = field(default_factory=list)
    clearance: list[float] = field(default_factory=list)
    contacts: list[int] = field(default_factory=list)
    predicted: list[np.ndarray | None] = field(default_factory=list)
    rect_ids: list[np.ndarray | None] = field(default_factory=list)
    margins: list[np.ndarray | None] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t)

    def poses(self) -> np.ndarray:
        """(S, 3) true poses [m, m, rad]."""
        return np.asarray(self.pose, dtype=float).reshape(-1, 3)


@dataclass
class Episode:
    """Outcome of :func:`run_episode`.

    Attributes:
        success: the goal was reached with no robot-obstacle contact before it.
        reason: one of :data:`REASONS`.
        steps: control steps executed.
        sim_time_s: [s] simulated time.
        collisions: control steps that ended with at least one robot-obstacle contact.
        solver_failures: control steps whose command came from a fallback.
        final_pose: (3,) [m, m, rad].
        trace: the per-step record.
        wall_time_s: [s] wall time of the loop.
    """

    success: bool
    reason: str
    steps: int
    sim_time_s: float
    collisions: int
    solver_failures: int
    final_pose: np.ndarray
    trace: EpisodeTrace
    wall_time_s: float


def _finite_pose(pose: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(pose)))


def run_episode(
    plant: Plant,
    controller: Controller,
    start: np.ndarray,
    goal: np.ndarray,
    config: RunConfig = RunConfig(),
    mismatch: Mismatch = Mismatch(),
    rng: np.random.Generator | None = None,
    measurement_fault: Callable[[int, np.ndarray], np.ndarray] | None = None,
    on_step: Callable[[int, EpisodeTrace], None] | None = None,
    route: np.ndarray | None = None,
    scan: Callable[[], object] | None = None,
    scan_period_s: float | None = None,
    progress: Progress | None = None,
) -> Episode:
    """Run one closed-loop episode.

    Args:
        plant: the MuJoCo robot (possibly built from a mismatched model copy).
        controller: any :class:`~sanav_mj.control.base.Controller`; called every ``controller.dt``.
        start: (3,) [m, m, rad] initial pose.
        goal: (2,) [m] goal position.
        config: episode settings.
        mismatch: the signal part of the mismatch is applied here (delay, pose noise, jitter).
        rng: source of the noise and jitter (seeded by the caller).
        measurement_fault: optional ``f(step, pose) -> pose`` that corrupts the measurement
            (fault injection: NaN, jumps). A non-finite or implausible measurement is
            rejected: the previous valid one is held, and after 5 consecutive rejections the
            run stops the robot and ends with ``bad_measurement``.
        on_step: optional ``f(step, trace)`` called after each step is recorded (the edge
            hook for live recording; algorithms never log themselves).
        route: optional (P, 2) [m] planned route the controller follows; ``stuck`` then
            measures progress along it (:class:`~sanav_mj.sim.termination.RouteProgress`),
            else as the reduction of the straight-line distance to the goal (see
            :mod:`sanav_mj.sim.termination`).
        scan: optional ``f() -> scan`` that casts the robot's lidar in the current physics
            state (``sanav_mj.sim.lidar.Lidar.scan`` bound to the plant's data and a seeded
            generator); the scan is passed to the controller in ``Observation.scan``, at most
            once per control step, at the sensor's rate ``1 / scan_period_s`` (with the
            default ``None`` period: every step). Its wall time is part of ``pipeline_ms``.
        scan_period_s: [s] time between scans.
        progress: the ``stuck`` rule's progress measure, instead of the one ``route``
            implies (e.g. :class:`~sanav_mj.sim.termination.ReplannedRouteProgress` for a
            controller that replans).

    Returns:
        The :class:`Episode` with its trace.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    goal = np.asarray(goal, dtype=float).reshape(2)
    dt = float(controller.dt)
    plant.reset(np.asarray(start, dtype=float))
    controller.reset(plant.pose())
    trace = EpisodeTrace()
    delay_line: deque[tuple[float, float]] = deque([(0.0, 0.0)] * mismatch.delay)
    if progress is None and route is not None:
        progress = RouteProgress(route)
    rules = Termination(config, dt, goal, progress)
    last_valid = plant.pose()
    bad_streak = 0
    consecutive_failures = 0
    collisions = 0
    failures = 0
    reason = "timeout"
    success = False
    wall0 = time.perf_counter()
    step = 0
    next_scan = -math.inf
    for step in range(rules.max_steps):
        t = plant.time
        true_pose = plant.pose()
        meas = true_pose.copy()
        if mismatch.pos_noise > 0:
            meas[:2] += rng.normal(0.0, mismatch.pos_noise, size=2)
        if mismatch.yaw_noise > 0:
            meas[2] += rng.normal(0.0, mismatch.yaw_noise)
        if measurement_fault is not None:
            meas = np.asarray(measurement_fault(step, meas), dtype=float)
        # Reject non-finite or physically impossible jumps (more than 3x top speed over dt + 0.2 m).
        jump = np.hypot(*(meas[:2] - last_valid[:2])) if _finite_pose(meas) else np.inf
        if not _finite_pose(meas) or jump > 3.0 * plant.robot.v_max * dt + 0.2:
            bad_streak += 1
            meas = last_valid.copy()
        else:
            bad_streak = 0
            last_valid = meas.copy()
        scan_ms = 0.0
        sensed = None
        if scan is not None and t >= next_scan - 1e-9:
            t_scan = time.perf_counter()
            sensed = scan()
            scan_ms = (time.perf_counter() - t_scan) * 1e3
            next_scan = t + (scan_period_s or 0.0) if next_scan == -math.inf else max(
                next_scan + (scan_period_s or 0.0), t)
        obs = Observation(
            t=t,
            pose=meas,
            velocity=plant.body_velocity(),
            ranges=plant.ray_ranges(config.n_rays, config.ray_range_m) if controller.needs_ranges else None,
            scan=sensed,
        )
        t0 = time.perf_counter()
        cmd: Command = controller.step(obs)
        pipeline_ms = (time.perf_counter() - t0) * 1e3 + scan_ms
        v, w = float(cmd.v), float(cmd.w)
        if not (math.isfinite(v) and math.isfinite(w)):
            v, w = 0.0, 0.0
            cmd = Command(v=0.0, w=0.0, solve_ms=cmd.solve_ms, status="nonfinite_command", ok=False)
        if bad_streak >= 5:
            v, w = 0.0, 0.0
        delay_line.append((v, w))
        applied = delay_line.popleft()
        wheel_cmd = plant.set_wheel_command(*applied)
        period = dt
        if mismatch.jitter > 0:
            period = dt * (1.0 + rng.uniform(-mismatch.jitter, mismatch.jitter))
        plant.advance(period)

        contacts = plant.robot_obstacle_contacts()
        trace.t.append(t)
        trace.pose.append(true_pose)
        trace.measured.append(meas)
        trace.cmd.append((v, w))
        trace.applied.append(applied)
        trace.velocity.append(obs.velocity)
        trace.wheel_cmd.append(np.asarray(wheel_cmd, dtype=float))
        trace.wheel_speed.append(plant.wheel_speeds())
        trace.solve_ms.append(float(cmd.solve_ms))
        trace.pipeline_ms.append(pipeline_ms)
        trace.status.append(cmd.status)
        trace.ok.append(bool(cmd.ok))
        trace.clearance.append(plant.clearance())
        trace.contacts.append(contacts)
        trace.predicted.append(cmd.predicted)
        trace.rect_ids.append(cmd.rect_ids)
        trace.margins.append(cmd.margins)
        if on_step is not None:
            on_step(step, trace)

        failures += not cmd.ok
        consecutive_failures = consecutive_failures + 1 if not cmd.ok else 0
        collisions += contacts > 0
        pose_now = plant.pose()
        ended = rules.arrival(pose_now[:2], contacts)
        if ended is None and bad_streak >= 5:
            ended = "bad_measurement"
        if ended is None and consecutive_failures >= config.max_solver_failures:
            ended = "solver_failure"
        if ended is None:
            ended = rules.stalled(pose_now[:2], step + 1)
        if ended is not None:
            reason, success = ended, ended == "goal"
            break
    plant.set_wheel_command(0.0, 0.0)
    return Episode(
        success=success,
        reason=reason,
        steps=len(trace),
        sim_time_s=plant.time,
        collisions=collisions,
        solver_failures=failures,
        final_pose=plant.pose(),
        trace=trace,
        wall_time_s=time.perf_counter() - wall0,
    )
