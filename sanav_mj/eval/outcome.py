"""What a finished run hands back: :class:`RunOutcome` (with the lidar run's
:class:`SensingLog`), and the small pieces both the known-map and the lidar run use to make
one (chaining the runner's step hooks, the episode of a run that found no path)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from sanav_mj.control.spec import ControllerSpec
from sanav_mj.eval.prepare import Prepared
from sanav_mj.sim.runner import Episode


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


def chain(first, second):
    """One ``on_step`` hook calling ``first`` then ``second`` (either may be None)."""
    if first is None or second is None:
        return first if second is None else second

    def both(step, trace):
        first(step, trace)
        second(step, trace)

    return both


def no_path_episode(plant, start: np.ndarray) -> Episode:
    """The episode of a run that found no path: the robot at ``start`` (3,) [m, m, rad], 0 steps,
    reason ``no_path``."""
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
