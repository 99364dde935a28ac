"""Episode-termination rules shared by the runner and the training environment.

One set of rules, one configuration (:class:`TerminationConfig`), used by
:func:`sanav_mj.sim.runner.run_episode` (evaluation) and :class:`sanav_mj.sim.nav_env.NavEnv`
(DQN training), checked after every control step in this order:

1. ``collision``: any robot-obstacle contact during or at the end of the step.
2. ``goal``: the robot centre is within ``goal_tolerance_m`` of the goal.
3. (the caller's own reasons: the runner's ``bad_measurement`` and ``solver_failure``,
   the environment's ``out_of_bounds``.)
4. ``stuck``: the progress made over the last ``stuck_window_s`` is below
   ``stuck_progress_m``.
5. ``timeout``: ``ceil(time_limit_s / dt)`` control steps have run.

**Progress** (:class:`Progress`) is measured along the planned route when the episode has
one: the arc length [m] of the robot's projection onto the route polyline
(:class:`RouteProgress`). A route may have to lead away from the goal (a serpentine maze),
so the straight-line distance to the goal is the wrong measure there. Without a route
(a controller that does not track the plan: the penalty MPC, whose reference runs straight
to the goal, DWA and the DQN; or the training environment, which has no planner) the
progress is the reduction of the straight-line distance to the goal
(:class:`GoalDistanceProgress`). Which controllers get the route is decided where the
episode is composed (:data:`sanav_mj.eval.episode.ROUTE_FOLLOWERS`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Protocol

import numpy as np

#: Reasons decided by :class:`Termination`.
RULES = ("collision", "goal", "stuck", "timeout")


@dataclass(frozen=True)
class TerminationConfig:
    """When an episode ends (see the module docstring for the order of the rules).

    Attributes:
        time_limit_s: [s] simulated time after which the episode ends with ``timeout``.
        goal_tolerance_m: [m] the goal is reached when the robot centre is this close to it.
        stuck_window_s: [s] window over which progress is measured.
        stuck_progress_m: [m] the episode ends with ``stuck`` when the progress (along the
            route, or towards the goal without one) over the last ``stuck_window_s`` is
            below this (and the goal is not reached).
    """

    time_limit_s: float = 60.0
    goal_tolerance_m: float = 0.15
    stuck_window_s: float = 8.0
    stuck_progress_m: float = 0.05

    def __post_init__(self) -> None:
        for name in ("time_limit_s", "goal_tolerance_m", "stuck_window_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{type(self).__name__}.{name}: expected a finite number > 0, got {value!r}")
        value = self.stuck_progress_m
        if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{type(self).__name__}.stuck_progress_m: expected a finite number >= 0, got {value!r}")

    def max_steps(self, dt: float) -> int:
        """Control steps of period ``dt`` [s] after which the episode times out: ``ceil(time_limit_s / dt)``."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: expected a finite number > 0 [s], got {dt!r}")
        return int(math.ceil(self.time_limit_s / dt))

    def stuck_window_steps(self, dt: float) -> int:
        """The stuck window in control steps of period ``dt`` [s] (at least 1)."""
        return max(1, int(round(self.stuck_window_s / dt)))


class Progress(Protocol):
    """A progress measure: larger is further along; differences are in metres."""

    def __call__(self, xy: np.ndarray) -> float: ...


class GoalDistanceProgress:
    """Progress towards a goal without a route: minus the straight-line distance [m] to it.

    Args:
        goal: (2,) [m] goal position.
    """

    def __init__(self, goal: np.ndarray) -> None:
        self.goal = _points("goal", goal).reshape(2)

    def __call__(self, xy: np.ndarray) -> float:
        """Minus the distance [m] from ``xy`` (2,) [m] to the goal."""
        return -float(np.hypot(*(np.asarray(xy, dtype=float)[:2] - self.goal)))


class RouteProgress:
    """Progress along a route: the arc length [m] of the nearest point of the route polyline.

    The projection is the closest point over all segments (the first one on a tie), so a
    robot driving along the route advances even where the route leads away from the goal,
    and a robot driving around in circles off the route does not.

    Args:
        route: (P, 2) [m] route vertices, P >= 1 (e.g. the plan's smoothed path followed by
            the goal). Consecutive duplicates are allowed (zero-length segments).
    """

    def __init__(self, route: np.ndarray) -> None:
        pts = _points("route", route)
        if pts.shape[0] < 1:
            raise ValueError("route: expected at least one (x, y) vertex, got none")
        self.route = pts
        if pts.shape[0] == 1:
            pts = np.vstack([pts, pts])
        self._a = pts[:-1]
        self._d = np.diff(pts, axis=0)
        self._len = np.hypot(self._d[:, 0], self._d[:, 1])
        self._s0 = np.concatenate([[0.0], np.cumsum(self._len)[:-1]])
        self._len2 = self._len**2
        self.length = float(self._len.sum())

    def __call__(self, xy: np.ndarray) -> float:
        """Arc length [m] along the route of the projection of ``xy`` (2,) [m]."""
        p = np.asarray(xy, dtype=float)[:2]
        rel = p - self._a
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(self._len2 > 0, (rel * self._d).sum(axis=1) / self._len2, 0.0)
        t = np.clip(t, 0.0, 1.0)
        foot = self._a + t[:, None] * self._d
        k = int(np.argmin(np.hypot(*(p - foot).T)))
        return float(self._s0[k] + t[k] * self._len[k])


class ReplannedRouteProgress:
    """Progress along a route that is replanned during the episode (a robot that maps as it
    drives): the arc length [m] advanced along the route current at each step, summed.

    When the route changes (a replan), progress restarts from the position's projection on
    the new route, so a replan neither adds nor removes progress; backing out of a dead end
    along the new route counts as progress, whereas the straight-line distance to the goal
    would count it as regress. Before the first route exists there is no progress.

    Args:
        current: ``f() -> (P, 2) [m] route or None``, the route followed now (a new array
            object after each replan).
        goal: (2,) [m] goal; appended to a route that does not end there (:func:`route_of`).
    """

    def __init__(self, current, goal: np.ndarray) -> None:
        self._current = current
        self.goal = _points("goal", goal).reshape(2)
        self._route = None
        self._measure: RouteProgress | None = None
        self._last = 0.0
        self.total = 0.0

    def __call__(self, xy: np.ndarray) -> float:
        """The summed progress [m] at ``xy`` (2,) [m]."""
        r = self._current()
        if r is None:
            return self.total
        if r is not self._route:
            self._route = r
            self._measure = RouteProgress(route_of(r, self.goal))
            self._last = self._measure(xy)
            return self.total
        s = self._measure(xy)
        self.total += s - self._last
        self._last = s
        return self.total


class Termination:
    """The termination rules of one episode (stateful: it keeps the progress window).

    Args:
        config: the rules' settings.
        dt: [s] control period.
        goal: (2,) [m] goal position.
        progress: the progress measure for ``stuck``; default :class:`GoalDistanceProgress`.
    """

    def __init__(self, config: TerminationConfig, dt: float, goal: np.ndarray, progress: Progress | None = None) -> None:
        self.config = config
        self.dt = float(dt)
        self.goal = _points("goal", goal).reshape(2)
        self.progress = progress if progress is not None else GoalDistanceProgress(self.goal)
        self.max_steps = config.max_steps(self.dt)
        self._window = config.stuck_window_steps(self.dt)
        self._hist: deque[float] = deque(maxlen=self._window + 1)

    def reset(self) -> None:
        """Forget the progress history (a new episode)."""
        self._hist.clear()

    def goal_distance(self, xy: np.ndarray) -> float:
        """[m] straight-line distance from ``xy`` (2,) [m] to the goal."""
        return float(np.hypot(*(np.asarray(xy, dtype=float)[:2] - self.goal)))

    def arrival(self, xy: np.ndarray, contacts: int) -> str | None:
        """Rules 1-2 after a step: ``"collision"`` when ``contacts`` > 0, ``"goal"`` when the
        position ``xy`` (2,) [m] is within the goal tolerance, else None."""
        if contacts > 0:
            return "collision"
        if self.goal_distance(xy) <= self.config.goal_tolerance_m:
            return "goal"
        return None

    def stalled(self, xy: np.ndarray, steps: int) -> str | None:
        """Rules 4-5 after a step: records the progress at ``xy`` (2,) [m]; ``"stuck"`` when it
        grew by less than ``stuck_progress_m`` over the window, ``"timeout"`` when ``steps``
        (control steps run so far) reached ``max_steps``, else None."""
        p = self.progress(xy)
        self._hist.append(p)
        if len(self._hist) > self._window and p - self._hist[0] < self.config.stuck_progress_m:
            return "stuck"
        if steps >= self.max_steps:
            return "timeout"
        return None


def route_of(path: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """The route a plan defines for :class:`RouteProgress`: its path (P, 2) [m], ended by
    the goal (2,) [m] when the path does not already end there (a projected goal).

    Returns:
        (P, 2) or (P + 1, 2) [m].
    """
    pts = _points("path", path)
    g = _points("goal", goal).reshape(1, 2)
    if pts.shape[0] == 0 or not np.array_equal(pts[-1], g[0]):
        pts = np.vstack([pts, g])
    return pts


def _points(name: str, value: np.ndarray) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.ndim == 1 and a.size == 2:
        a = a.reshape(1, 2)
    if a.ndim != 2 or a.shape[1] != 2 or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected finite (x, y) points [m] of shape (P, 2), got shape {np.shape(value)}")
    return a
