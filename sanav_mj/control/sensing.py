"""SA-MPC on the map its own lidar builds: map update, replanning and solve in one step.

:class:`SensingSAMPC` wraps :class:`~sanav_mj.control.sa_mpc.SAMPC`. Each control step that
brings a scan (``Observation.scan``):

1. **Map update.** The scan is added to a :class:`~sanav_mj.mapping.sensed_map.SensedMap`
   at the pose the controller *measures* (pose noise acts on the map); before the first
   plan, and whenever the robot's own cell (``MPCConfig.footprint="discs"``: the cell of
   any disc centre) is not safe, the robot's body is first observed free
   (:meth:`SensedMap.clear_box`: the lidar ahead of the axle never sees the cells under
   the robot). The map is inflated by what the footprint mode needs (the caller's
   ``inflation``); :class:`~sanav_mj.control.sensed_footprint.SensedFootprint` holds the
   mode's own points, SA-MPC footprint and corridor-search areas. The safe areas (observed free space,
   no occupied or unknown cell within the inflation radius) and the route areas (unknown
   counts as passable) are updated incrementally.
2. **Replan check.** Corridor and reference are recomputed from the measured pose when

   - ``blocked``: a rectangle of the corridor being followed is no longer entirely safe
     (:meth:`SensedMap.rects_still_safe`); the MPC's stage boxes and J_SA slots are all
     built from corridor rectangles, so after this check every rectangle the MPC uses in
     this step is observed free space in the current map;
   - ``route``: the route towards the goal crosses a cell that is no longer route-safe
     (a scan saw an obstacle on it);
   - ``extend``: the local goal is short of the goal and the safe areas grew since the
     last plan, at most every ``replan_interval`` steps.

3. **Plan.** A *route* from the measured pose to the goal is planned on the route areas;
   the local goal is the last sample of the route's leading stretch that lies in safe
   cells, and the corridor and reference the MPC follows are planned on the safe areas
   from the measured pose to that local goal (the goal itself when the whole route is in
   safe cells). The MPC's hard constraints and J_SA therefore use observed free space only.
   With ``SensingConfig.keep_rects`` (opt-in) the corridor in motion starts with the
   rectangles of the corridor being followed that hold the robot's predicted positions,
   each re-verified safe (:mod:`sanav_mj.control.replan`), so the shifted plan still fits
   the new stage boxes.
4. **Solve.** The SA-MPC step with the (possibly new) corridor. Its horizon ends at rest
   (terminal stop ``v_{N-1} = 0``, and the speed bounds it implies) with every predicted
   position inside a stage box within the safe areas: each accepted plan is a way to stop
   inside known free space, and the shifted plan stays feasible as long as its rectangles
   stay safe; when a scan removes one, the replan happens before the solve.

With ``SensingConfig.background_replan`` the ``extend`` and ``route`` replans (the corridor
being followed is still safe) are computed on a worker thread from the map and pose of step
k and handed over at step k+1 (checked against that step's map first), so they cost the
control thread only the hand-over; the run stays deterministic (the hand-over step is fixed).

Before a first plan exists (at the start the cells around the robot behind the sensor are
unknown, so the robot's own position is not yet safe) the robot turns on the spot, which
keeps its body inside the disc it already occupies, until its position is safe; with
``SensingConfig.scan_turn_stop`` (opt-in) it brakes so as to come to rest where the lidar's
field of view will have swept the unknown cells near its own points
(:mod:`~sanav_mj.control.scan_turn`), so the SA-MPC does not have to brake the turn.

The controller keeps per-step records for the run JSON, the recording and tests: the map
update time of each scan, the replans (step, reason) and the corridor rectangles in use.
"""

from __future__ import annotations

import math
import queue
import threading
import time
import weakref
from dataclasses import dataclass, replace

import numpy as np

from sanav_mj.control.base import Command, Observation
from sanav_mj.control.config import MPCConfig
from sanav_mj.control.localisation import ScanLocaliser
from sanav_mj.control.replan import kept_prefix, prefixed_areas
from sanav_mj.control.sa_mpc import SAMPC
from sanav_mj.control.scan_turn import route_bearing, stopping_rate
from sanav_mj.control.sensed_footprint import SensedFootprint, StraightBrakeSAMPC
from sanav_mj.control.sensing_config import SensingConfig
from sanav_mj.mapping.grow import FreeCells
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.mapping.sensed_map import SensedMap, SensedUpdate
from sanav_mj.planning import PlannerConfig
from sanav_mj.planning import plan as make_plan
from sanav_mj.planning.pipeline import route_points
from sanav_mj.planning.unseen import penalise_unseen
from sanav_mj.planning.reference import Plan
from sanav_mj.scene import RobotParams

__all__ = ["SensingSAMPC", "StepRecord"]


def _with_free(areas: SafeAreas, free: FreeCells | None) -> SafeAreas:
    """``areas`` carrying ``free`` (the planner's open-space speed reads it), or ``areas``
    itself when ``free`` is None."""
    return areas if free is None else replace(areas, free=free)


def _growing(areas: SafeAreas, sensed: SensedMap, grow: float, tighten: float,
             table: FreeCells | None = None) -> SafeAreas:
    """``areas`` carrying the :class:`~sanav_mj.mapping.grow.FreeCells` of the cells safe in
    ``sensed`` now (growth limit ``grow`` [m], ``tighten`` [m]), so SA-MPC's corridor chain
    grows its boxes into them (``SensingConfig.grow``); ``areas`` itself when ``grow`` is 0.
    ``table``: the table of those very cells when the caller has it (a plan made on this
    step's map), reused with ``grow`` and ``tighten`` instead of summing the grid again."""
    if grow <= 0:
        return areas
    if table is not None:
        return replace(areas, free=replace(table, limit=float(grow), tighten=float(tighten)))
    return replace(areas, free=FreeCells.of(sensed.grid.safe_grid(), grow, tighten))


@dataclass(frozen=True)
class StepRecord:
    """What the sensing loop did at one control step.

    Attributes:
        map_ms: [ms] map update time (grid, safe and route areas) of this step's scan, or
            None without a scan.
        replan: the replan reason (``"initial"``, ``"blocked"``, ``"route"``, ``"extend"``)
            or None.
        replan_ms: [ms] time the control thread spent on planning this step: a synchronous
            plan, or waiting for and adopting a background plan (0 without either).
        corridor_rects: (C, 4) [m] the corridor rectangles the MPC used this step (empty
            while turning before the first plan).
        map_changed: whether the safe areas changed this step.
        plan_ms: [ms] computing time of the plan adopted this step, wherever it ran (the
            background thread for a deferred plan; 0 without a new plan).
        deferred: the plan adopted this step was computed in the background (requested the
            step before).
        requested: the reason of a background replan requested this step (adopted, or
            dropped, at the next step), or None.
    """

    map_ms: float | None
    replan: str | None
    replan_ms: float
    corridor_rects: np.ndarray
    map_changed: bool
    plan_ms: float = 0.0
    deferred: bool = False
    requested: str | None = None


@dataclass(frozen=True)
class _Planned:
    """A computed plan, not yet followed: what :meth:`SensingSAMPC._adopt` needs.

    ``areas`` / ``boxes`` are the safe areas (and their cell boxes) it was planned on,
    ``route`` (P, 2) [m] the route to the goal (None: none even through unknown space),
    ``local_goal`` (2,) [m], ``reason`` the replan reason, ``ms`` [ms] the computing time and
    ``free`` the :class:`~sanav_mj.mapping.grow.FreeCells` of the safe cells it read for the
    open-space speed (None without it).
    """

    plan: Plan
    areas: SafeAreas
    boxes: np.ndarray
    route: np.ndarray | None
    local_goal: np.ndarray
    reason: str
    ms: float
    free: FreeCells | None = None


class _Worker:
    """The background planning thread of one controller: one job at a time, submitted
    without waiting for the thread to be scheduled (a thread started per job cost the
    control thread up to 3 ms on the loaded machine); :meth:`result` waits for the job's
    result (re-raising its error); :meth:`close` ends the thread."""

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._done: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._serve, daemon=True, name="sensing-replan")
        self._thread.start()

    def _serve(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            fn, args = job
            try:
                self._done.put((fn(*args), None))
            except BaseException as exc:  # handed to the control thread at the hand-over
                self._done.put((None, exc))

    def submit(self, fn, args: tuple) -> None:
        self._jobs.put((fn, args))

    def result(self):
        out, exc = self._done.get()
        if exc is not None:
            raise exc
        return out

    def close(self) -> None:
        self._jobs.put(None)
        self._thread.join()

    @staticmethod
    def stop(jobs: queue.SimpleQueue) -> None:
        """End the thread serving ``jobs`` without waiting (a controller dropped unsettled)."""
        jobs.put(None)


def grid_cells(g, pts: np.ndarray) -> np.ndarray:
    """(P,) int64 flat indices ``i * nx + j`` of the cells of the points ``pts`` (P, 2) [m]
    of the grid ``g`` (``shape``, ``origin``, ``resolution``), clamped to the grid."""
    ny, nx = g.shape
    if len(pts) <= 4:
        # a few points (the robot's own): the same arithmetic on Python floats (IEEE
        # doubles, as NumPy's), without a dozen array calls
        ox, oy = float(g.origin[0]), float(g.origin[1])
        h = float(g.resolution)
        flat = pts.ravel().tolist()
        if all(abs(v) < 1e15 for v in flat):  # finite and far inside int64 after floor
            return np.array([min(max(math.floor((y - oy) / h), 0), ny - 1) * nx
                             + min(max(math.floor((x - ox) / h), 0), nx - 1)
                             for x, y in zip(flat[0::2], flat[1::2])], dtype=np.int64)
    j = np.clip(np.floor((pts[:, 0] - g.origin[0]) / g.resolution).astype(np.int64), 0, nx - 1)
    i = np.clip(np.floor((pts[:, 1] - g.origin[1]) / g.resolution).astype(np.int64), 0, ny - 1)
    return i * nx + j


def in_ok_cells(g, pts: np.ndarray, ok_at) -> np.ndarray:
    """(P,) bool: each point (P, 2) [m] lies in a cell of the grid ``g`` that ``ok_at`` (flat
    cell indices -> bool) accepts, cells taken as closed squares (a point on a cell edge,
    where the planner's closed rectangles put samples, counts for either side)."""
    ny, nx = g.shape
    e = 1e-6 * g.resolution
    # the cells of the four points shifted by (+-e, +-e): column and row for both signs
    # at once (the same arithmetic as grid_cells on each shifted point), one lookup for all four
    shift = np.array([[-e], [e]])
    j = np.clip(np.floor((pts[:, 0] + shift - g.origin[0]) / g.resolution).astype(np.int64), 0, nx - 1)
    i = np.clip(np.floor((pts[:, 1] + shift - g.origin[1]) / g.resolution).astype(np.int64), 0, ny - 1)
    cells = i[:, None, :] * nx + j[None, :, :]  # (2, 2, P): (row sign, column sign, point)
    return ok_at(cells.ravel()).reshape(4, len(pts)).any(axis=0)


def local_goal(g, route: np.ndarray | None, goal: np.ndarray) -> np.ndarray | None:
    """(2,) [m] the last point of ``route``'s (P, 2) [m] leading stretch in safe cells of the
    grid ``g`` (a copy of ``goal`` (2,) [m] when the whole route is safe, or without a route);
    None when the route does not start in safe cells."""
    if route is None:
        return goal.copy()
    safe = in_ok_cells(g, route, g.safe_at)
    if safe.all():
        return goal.copy()
    first = int(np.argmax(safe))
    if not safe[first]:
        return None
    stop = first + int(np.argmin(safe[first:]))  # first unsafe sample after the safe stretch
    return route[stop - 1].copy()


class SensingSAMPC:
    """SA-MPC driving on the map its lidar builds (the Controller protocol).

    Args:
        robot: nominal robot parameters.
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        goal: (2,) [m] goal position.
        inflation: [m] footprint radius + margin (as the known-map grid).
        sensor_offset: (2,) [m] lidar position in the base frame.
        mpc: the SA-MPC settings.
        planner: the planner settings (matched to the MPC).
        config: sensing-loop settings.

    Localisation (``config.localise``): :class:`~sanav_mj.control.localisation.ScanLocaliser`
    (odometry prediction corrected by matching each scan against the map, see its docstring).

    Attributes:
        name: ``"sa-mpc"``; dt: [s] control period; needs_ranges: False.
        map: the :class:`SensedMap` of the episode.
        estimate: (3,) [m, m, rad] the current pose estimate.
        match_log: per step, the scan match status (``"ok"``, ``"ambiguous"``, ``"poor"``,
            ``"few_points"``, ``"empty"``, ``"measured"`` (the measured pose was consistent
            with the scan and kept); ``"none"`` without a scan or without localising)
            and the estimate (3,) after it.
        mpc: the inner :class:`SAMPC` (None before the first plan).
        records: one :class:`StepRecord` per step.
        route: (P, 2) [m] the latest route to the goal, or None.
        local_goal: (2,) [m] the goal of the corridor being followed, or None.
        plan_boxes: (R, 4) int64 cell boxes of the safe areas the current plan was made on
            (``mpc.areas``).
        last_scan: the scan of the last step (None without one).
        areas: the current safe areas (None before the first scan).
        prepare_ms: [ms] construction time: the SA-MPC (its OCP and compiled solver) is
            built here, before the control loop, so that the first plan only replaces its
            plan (paid once per controller, not in any step's ``pipeline_ms``).
    """

    name = "sa-mpc"
    needs_ranges = False

    def __init__(self, robot: RobotParams, bounds, goal, inflation: float, sensor_offset=(0.0, 0.0),
                 mpc: MPCConfig = MPCConfig(), planner: PlannerConfig | None = None,
                 config: SensingConfig = SensingConfig()) -> None:
        self.robot = robot
        self.bounds = np.asarray(bounds, dtype=float).reshape(4)
        self.goal = np.asarray(goal, dtype=float).reshape(2)
        self.inflation = float(inflation)
        self.sensor_offset = tuple(float(v) for v in sensor_offset)
        self.mpc_config = replace(mpc, reach_check=True) if config.reach_check and not mpc.reach_check else mpc
        self.planner = planner if planner is not None else PlannerConfig(dt=mpc.dt)
        self.config = config
        self.dt = float(mpc.dt)
        # the footprint mode's own points, SA-MPC footprint and corridor-search areas
        self.body = SensedFootprint.of(mpc, config.footprint, config.narrow_width)
        self._mpc_class = StraightBrakeSAMPC if config.straight_brake else SAMPC
        self.mpc: SAMPC | None = None
        t0 = time.perf_counter()
        self._spare: SAMPC | None = self._prebuilt_mpc()
        self.prepare_ms = (time.perf_counter() - t0) * 1e3
        self.reset(np.zeros(3))

    def _prebuilt_mpc(self) -> SAMPC | None:
        """An SA-MPC built (OCP, compiled solver loaded) before the control loop, on a plan
        across the whole map (one rectangle); the first plan of the episode replaces that plan
        and resets it (exactly what a later episode does with the controller it keeps).
        None when no such plan exists (a map too small for the planner): the first plan then
        builds the SA-MPC in the loop."""
        x0, y0, x1, y1 = self.bounds
        w, h = x1 - x0, y1 - y0
        rects = np.array([[x0, y0, x1, y1]], dtype=float)
        areas = SafeAreas(rects, np.zeros((0, 2), dtype=np.int64), np.zeros(0), np.zeros((0, 2, 2)))
        start = np.array([x0 + 0.25 * w, y0 + 0.5 * h, 0.0])
        plan = make_plan(areas, start, np.array([x0 + 0.75 * w, y0 + 0.5 * h]), self.robot, self.planner)
        if not plan.ok or plan.reference is None or len(plan.corridor) == 0:
            return None
        return self._mpc_class(self.robot, areas, plan, self.mpc_config, footprint=self.body.mpc_footprint)

    # ------------------------------------------------------------------ episode

    def reset(self, pose: np.ndarray) -> None:
        """Start a new episode at ``pose`` (3,) [m, m, rad] with an empty map."""
        if getattr(self, "_pending", False):
            self.settle()
        self._pending = False  # a background plan was requested and not yet collected
        if not hasattr(self, "_worker"):
            self._worker: _Worker | None = None
        if self.config.background_replan and self._worker is None:
            self._start_worker()  # here, before the loop
        self.map = SensedMap(self.bounds, self.inflation, self.sensor_offset, self.config.map)
        self.localiser = ScanLocaliser(self.config, pose)
        self._scanned = False  # a scan has been added: the map's safe areas are the current ones
        self.plan_boxes = np.zeros((0, 4), dtype=np.int64)
        self._have_route = False  # route areas exist (after the first scan, when kept)
        self._route_dirty = True  # route or route grid changed since the route was last found clear
        self._corridor_rects = np.zeros((0, 4))
        self._plain_rects = self._corridor_rects  # the corridor's rectangles (without grown boxes)
        self.route: np.ndarray | None = None
        self.local_goal: np.ndarray | None = None
        self.records: list[StepRecord] = []
        self.last_scan = None
        self._predicted: np.ndarray | None = None  # (N+1, 3) the last command's predicted states
        self._since_plan = 0
        self._grown = False
        self._turn_steps = 0
        self._turn_w = 0.0
        self._turn_sign = 1.0
        self._turn_heading = 0.0  # [rad] the heading the turn on the spot goes towards
        self._angles = None  # the beam angles of the last scan (None before the first)
        self._mpc_fresh = True
        if self.mpc is not None:
            self.mpc.reset(np.asarray(pose, dtype=float).reshape(3))
            if isinstance(self.mpc, StraightBrakeSAMPC):
                self.mpc.free_areas = self.map.areas_now  # the new episode's map

    @property
    def areas(self) -> SafeAreas | None:
        """The current safe areas (observed free space), None before the first scan. The
        map's compact snapshot of them is taken when read (the step itself reads them only
        to plan)."""
        return self.map.areas_now() if self._scanned else None

    @property
    def estimate(self) -> np.ndarray:
        """(3,) [m, m, rad] the current pose estimate (:attr:`ScanLocaliser.estimate`)."""
        return self.localiser.estimate

    @property
    def match_log(self) -> list[tuple[str, np.ndarray]]:
        """Per step, the scan match status and the estimate after it (:attr:`ScanLocaliser.match_log`)."""
        return self.localiser.match_log

    @property
    def replans(self) -> int:
        """Plans made after the first one in this episode."""
        return max(0, sum(r.replan is not None for r in self.records) - 1)

    @property
    def map_update_ms(self) -> list[float]:
        """[ms] map update time of every scan of the episode."""
        return [r.map_ms for r in self.records if r.map_ms is not None]

    # ------------------------------------------------------------------ step

    def step(self, obs: Observation) -> Command:
        """Map update, replan when needed, SA-MPC solve (see the module docstring)."""
        t_loc = time.perf_counter()
        pose, add_scan = self.localiser.localise(obs, self.map)
        loc_ms = (time.perf_counter() - t_loc) * 1e3
        if self.config.localise and self.config.controller_pose == "estimate":
            obs = replace(obs, pose=pose)
        self.last_scan = obs.scan
        if obs.scan is not None:
            self._angles = obs.scan.angles  # [rad] the beams' directions (the turn's field of view)
        # a background plan requested at the last step: wait for it before the scan changes
        # the map it reads (the hand-over step is fixed, whatever the thread's timing)
        t_wait = time.perf_counter()
        pending = self._collect()
        replan_ms = (time.perf_counter() - t_wait) * 1e3 if pending is not None else 0.0
        map_ms = None
        changed = False
        if obs.scan is not None and np.all(np.isfinite(pose)):
            t0 = time.perf_counter()
            changed = False
            if self.mpc is None or not self._own_safe(pose):
                fp = self._clear_body(pose)  # the safe snapshot too only when read (to plan)
                changed, self._route_dirty = fp.changed, self._route_dirty or fp.route_changed
            k = self.config.beam_stride
            # the route areas are needed only to plan: their snapshot is taken in _compute
            if add_scan:
                up = self.map.integrate(pose, obs.scan.ranges[::k], obs.scan.hit[::k], obs.scan.angles[::k],
                                        route_snapshot=False, snapshot=False)
                changed = up.changed or changed
                self._route_dirty = self._route_dirty or up.route_changed
            map_ms = (time.perf_counter() - t0) * 1e3 + loc_ms
            self._scanned = True
            self._have_route = self.map.route is not None
            self._grown = self._grown or changed
        self._since_plan += 1
        replanned, plan_ms, deferred = None, 0.0, False
        if pending is not None:
            t0 = time.perf_counter()
            # the plan was made on the map of the last step: adopted only when every corridor
            # rectangle is still safe after this step's scan (else dropped; the checks below
            # then decide again)
            rects = np.asarray(pending.areas.rects, dtype=float)[np.asarray(pending.plan.corridor, int)]
            if self.map.rects_still_safe(rects).all():
                self._adopt(pending, pose, since_plan=1, grown=changed)
                replanned, plan_ms, deferred = pending.reason, pending.ms, True
            replan_ms += (time.perf_counter() - t0) * 1e3
        reason = self._replan_reason(changed, pose)
        request = None
        if reason is not None and np.all(np.isfinite(pose)):
            speed = float(obs.velocity[0]) if obs.velocity is not None and np.isfinite(obs.velocity[0]) else 0.0
            args = self._plan_inputs(pose, max(0.0, speed), reason)
            if self.config.background_replan and reason in ("extend", "route") and self.mpc is not None:
                request = args  # started after the solve, adopted at the next step
            else:
                t0 = time.perf_counter()
                planned = self._compute(*args)
                if planned is not None:
                    self._adopt(planned, pose)
                    replanned, plan_ms, deferred = reason, planned.ms, False
                replan_ms += (time.perf_counter() - t0) * 1e3
        if self.mpc is None:
            cmd = self._scan_turn(obs)
        else:
            cmd = self.mpc.step(obs)
        self._predicted = cmd.predicted
        if request is not None:
            t0 = time.perf_counter()
            if self._worker is None:
                self._start_worker()
            self._worker.submit(self._compute, request)
            self._pending = True
            replan_ms += (time.perf_counter() - t0) * 1e3
        self.records.append(StepRecord(map_ms, replanned, replan_ms, self._corridor_rects.copy(), changed,
                                       plan_ms, deferred, None if request is None else reason))
        return cmd

    def _start_worker(self) -> None:
        self._worker = _Worker()
        weakref.finalize(self, _Worker.stop, self._worker._jobs)

    def _collect(self) -> _Planned | None:
        """The background plan requested at the last step (waiting for it), or None."""
        if not self._pending:
            return None
        self._pending = False
        return self._worker.result()

    def settle(self) -> None:
        """End of an episode: wait for a background plan still running, drop it, and end the
        worker thread (a later episode starts a new one)."""
        self._collect()
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def _clear_body(self, pose: np.ndarray) -> SensedUpdate:
        """Observe free the cells the robot's body covers (config ``footprint``, shrunk by the
        pose bound; else the circumscribed disc); the map's update (``changed``: the safe
        areas changed, ``route_changed``: a route cell changed)."""
        fp = self.config.footprint
        if fp is None:
            return self.map.clear_footprint(pose, self.robot.footprint_radius, route_snapshot=False, snapshot=False)
        shrink = self.config.pose_bound[0] + fp.circumradius * self.config.pose_bound[1]
        return self.map.clear_box(pose, (fp.xmin, fp.xmax, fp.ymin, fp.ymax), shrink, route_snapshot=False,
                                  snapshot=False)

    def _replan_reason(self, changed: bool, pose: np.ndarray) -> str | None:
        if not self._scanned or not np.all(np.isfinite(pose)):
            return None
        if self.mpc is None or self.local_goal is None:
            # the first plan waits until the robot's own position is observed safe (or the
            # turn on the spot has lasted its limit: the planner then projects the start)
            turned_out = self._turn_steps * self.dt >= self.config.max_scan_turn_s
            safe_here = self._own_safe(pose)
            return "initial" if safe_here or turned_out else None
        if changed and len(self._corridor_rects) and not self.map.rects_still_safe(self._corridor_rects).all():
            return "blocked"
        if self.route is not None and self._have_route and self._route_dirty:
            # the route can only stop being clear when it or a route cell changed
            if not self._route_clear():
                return "route"
            self._route_dirty = False
        far = self.config.refresh or np.hypot(*(self.local_goal - self.goal)) > 1e-9
        if far and self._grown and self._since_plan >= self.config.replan_interval:
            return "extend"
        return None

    def _own_safe(self, pose: np.ndarray) -> bool:
        """Whether the robot's own points (its position; ``"discs"``: every disc centre) at
        ``pose`` (3,) [m, m, rad] lie in safe cells."""
        return bool(self.map.grid.safe_at(grid_cells(self.map.grid, self.body.own_points(pose))).all())

    def _route_clear(self) -> bool:
        return bool(in_ok_cells(self.map.grid, self.route, self.map.grid.route_safe_at).all())

    def _plan_inputs(self, pose: np.ndarray, speed: float, reason: str) -> tuple:
        """Everything :meth:`_compute` reads that the control thread changes later (the map
        itself is read only before the next scan is integrated)."""
        kept = None
        if self.config.keep_rects and self.mpc is not None and not self._mpc_fresh and self._predicted is not None:
            g = self.map.grid
            pts = np.vstack([pose[None, :2], self._predicted[1:, :2]])
            kept = kept_prefix(self._plain_rects, pts, g.blocked, g.origin, g.resolution)
        return (pose.copy(), speed, reason, self.map.areas_now(), self.map.boxes_now(), self._have_route,
                self.mpc is not None, kept)

    def _compute(self, pose: np.ndarray, speed: float, reason: str, areas: SafeAreas, boxes: np.ndarray,
                 have_route: bool, moving: bool, kept: np.ndarray | None = None) -> _Planned | None:
        """Route (on the route areas) and local corridor (on ``areas``, after the ``kept``
        (K, 4) [m] rectangles of the corridor being followed when given) from ``pose`` (3,)
        [m, m, rad], the reference starting at the measured forward ``speed`` [m/s] (0 before
        the MPC runs, ``moving`` False); None when no local plan exists. Reads the map but
        changes nothing the control thread uses (it may run on the background thread)."""
        t0 = time.perf_counter()
        route_areas = self.map.route_areas()[1] if have_route else None
        route = None  # no route even through unknown space: head for the goal's projection
        if route_areas is not None and self.config.route_polyline:
            # the waypoint polyline, ending at the goal used (projected into the route areas
            # when the goal lies within the inflation of an obstacle), so a goal close to an
            # obstacle does not make the route look blocked at every step
            route = route_points(self.body.planning_areas(route_areas), pose, self.goal, self.planner)
        elif route_areas is not None:
            r_areas = self.body.planning_areas(route_areas)
            if self.config.unseen_route > 0:
                g = self.map.grid
                r_areas = penalise_unseen(r_areas, g.safe(), g.origin, g.resolution, self.config.unseen_route)
            route_plan = make_plan(r_areas, pose, self.goal, self.robot, self.planner)
            if route_plan.ok and route_plan.reference is not None:
                route = route_plan.reference.states[:, :2]  # the reference samples, as above
        target = self._local_goal(route)
        if target is None:
            return None
        v0 = speed if moving else 0.0
        # the open-space speed (PlannerConfig.open_speed_fraction) reads the cells safe in the
        # sensed map now: unknown cells are never open
        free = FreeCells.of(self.map.grid.safe_grid(), 0.0) if self.planner.open_speed_fraction is not None else None
        local = None
        if kept is not None and len(kept):
            g = self.map.grid
            k_areas, k_boxes = prefixed_areas(areas, boxes, kept, g.origin, g.resolution)
            local = make_plan(_with_free(self.body.planning_areas(k_areas), free), pose, target, self.robot,
                              self.planner, start_speed=v0)
            if local.ok and local.reference is not None and len(local.corridor):
                areas, boxes = k_areas, k_boxes
            else:
                local = None
        if local is None:
            local = make_plan(_with_free(self.body.planning_areas(areas), free), pose, target, self.robot,
                              self.planner, start_speed=v0)
        if not local.ok or local.reference is None or len(local.corridor) == 0:
            return None
        return _Planned(local, areas, boxes, route, np.asarray(target, dtype=float), reason,
                        (time.perf_counter() - t0) * 1e3, free)

    def _adopt(self, planned: _Planned, pose: np.ndarray, since_plan: int = 0, grown: bool = False) -> None:
        """Follow ``planned`` from now on; ``since_plan`` [steps] and ``grown`` (the safe areas
        changed since the map it was planned on) for a plan made at an earlier step. A plan
        made in this step (``since_plan`` 0) read this step's map: its table of safe cells is
        reused for the chain's growth."""
        self._follow(planned.plan, pose, planned.areas, planned.boxes, planned.free if since_plan == 0 else None)
        self.route = planned.route
        self._route_dirty = True
        self.local_goal = planned.local_goal
        self._since_plan = since_plan
        self._grown = grown

    def _local_goal(self, route: np.ndarray | None) -> np.ndarray | None:
        """:func:`local_goal` on the current map."""
        return local_goal(self.map.grid, route, self.goal)

    def _follow(self, plan: Plan, pose: np.ndarray, areas: SafeAreas, boxes: np.ndarray,
                table: FreeCells | None = None) -> None:
        areas = _growing(areas, self.map, self.config.grow, self.mpc_config.footprint_grow_tighten, table)
        u_prev = np.array([0.0, self._turn_w])
        if self.mpc is None and self._spare is None:
            self.mpc = self._mpc_class(self.robot, areas, plan, self.mpc_config, footprint=self.body.mpc_footprint)
            self.mpc.reset(pose, u_prev=u_prev)
        elif self.mpc is None:
            self.mpc, self._spare = self._spare, None
            self.mpc.replace_plan(areas, plan)
            self.mpc.reset(pose, u_prev=u_prev)
        elif self._mpc_fresh:
            self.mpc.replace_plan(areas, plan)
            self.mpc.reset(pose, u_prev=u_prev)
        else:
            self.mpc.replace_plan(areas, plan)
        self._mpc_fresh = False
        if isinstance(self.mpc, StraightBrakeSAMPC):
            self.mpc.free_areas = self.map.areas_now  # what its braking fallback stays inside
        self._plain_rects = np.asarray(areas.rects, dtype=float)[np.asarray(plan.corridor, int)]
        # with growth, the grown chain members too: checked at every scan (``blocked``)
        self._corridor_rects = self._plain_rects if areas.free is None else \
            np.vstack([self._plain_rects, np.asarray(self.mpc.chain.boxes, dtype=float)])
        self.plan_boxes = boxes

    def _scan_turn(self, obs: Observation) -> Command:
        """Turn on the spot (the body stays in the disc it occupies) to see around the robot."""
        finite = bool(np.all(np.isfinite(obs.pose)))
        if self._turn_steps == 0:  # towards the goal's bearing or the route's heading: the plan starts closer to it
            h = math.atan2(self.goal[1] - float(obs.pose[1]), self.goal[0] - float(obs.pose[0]))
            if self.config.scan_turn_route and finite:
                h = route_bearing(self.body.planning_areas(self.map.route_areas()[1]), obs.pose, self.goal,
                                  self.robot, self.planner, h)
            self._turn_sign = -1.0 if finite and math.remainder(h - float(obs.pose[2]), math.tau) < 0 else 1.0
            self._turn_heading = h
        self._turn_steps += 1
        rate = self._turn_sign * self.config.scan_turn_rate
        if self.config.scan_turn_stop and finite and self._angles is not None:
            g = self.map.grid  # a step without a scan: the same map, the last scan's field of view
            rate = self._turn_sign * stopping_rate(g, g.unknown_near(grid_cells(g, self.body.own_points(obs.pose))),
                                                   obs.pose, self.sensor_offset, self._angles, self._turn_sign,
                                                   self._turn_heading, self.robot, self.dt, self.config)
        target = 0.0 if self._turn_steps * self.dt > self.config.max_scan_turn_s else rate
        step = self.robot.alpha_max * self.dt  # within the yaw-rate rate bound of the MPC that follows
        w = float(np.clip(target, self._turn_w - step, self._turn_w + step))
        self._turn_w = w
        return Command(v=0.0, w=w, solve_ms=0.0, status="scan_turn", ok=True)
