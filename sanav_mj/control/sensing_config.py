"""Settings of the lidar sensing loop (:class:`~sanav_mj.control.sensing.SensingSAMPC`):
replanning, the turn on the spot, localisation, the sensed map and the footprint."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sanav_mj.footprint import Footprint
from sanav_mj.mapping.sensed_map import SensedMapConfig

__all__ = ["SensingConfig"]


@dataclass(frozen=True)
class SensingConfig:
    """Settings of the sensing loop.

    Attributes:
        replan_interval: [steps] smallest number of control steps between two ``extend``
            replans (a growing map alone does not replan every step), >= 1.
        beam_stride: [beams] add every ``beam_stride``-th beam of a scan to the map (1: all);
            fewer beams halve the map update's work, at the price of gaps between far beams
            that later scans fill (safety is unaffected: fewer observations mean less known
            free space, never more), integer >= 1.
        scan_turn_rate: [rad/s] yaw rate of the turn on the spot before the first plan, > 0;
            the turn goes towards the goal's bearing (the plan that follows starts closer to
            its heading). 2 rad/s (was 1): with the turn towards the goal, the 13 runs that
            reached the goal among the five paper scenarios and barn_0000-0009 (seed 0,
            discs) took 159 s in all against 185 s (2026-11-25).
        max_scan_turn_s: [s] give up turning after this long (the run then ends as stuck
            or timed out without a plan), > 0.
        background_replan: ``extend`` and ``route`` replans (the corridor being followed is
            still safe) are computed off the control thread: requested at step k from the
            map and pose of step k, started after step k's solve, and handed over at step
            k+1, where the control thread waits for it if it is not done, checks its
            corridor against step k+1's map and adopts it (or drops it when a rectangle is
            no longer safe). The hand-over step is fixed, so the run is the same whatever the
            thread's timing. ``initial`` and ``blocked`` replans (the current corridor is no
            longer usable) stay synchronous. Default False (every replan in the step that
            needs it): deferring changes the runs (one step of plan latency), measured in
            docs/benchmarks.md, "Lidar closed loop per step".
        map: the sensed map's resolution, quadtree, log-odds and scan-matcher settings.
        localise: estimate the pose from odometry and the scans (see "Localisation" in the
            class docstring) and place each scan at that estimate; False: place each scan at
            the measured pose (noise included), as before.
        controller_pose: the pose of the SA-MPC's state feedback: ``"estimate"`` (default)
            or ``"measured"``. Map, own-cell checks and replanning use the estimate either
            way. Measured on the envelope's four all-at-once corners with lidar (160 runs,
            commit f77bb07): ``"estimate"`` 153 / 160 to the goal and 0 collisions,
            ``"measured"`` 156 / 160 with 3 collisions (complex 2, u_shape 1: feedback from a
            pose 2 deg off the one the corridor was planned from); an earlier version of the
            localiser gave 152 / 160 and 159 / 160, both 0 collisions.
        skip_unmatched: with ``localise``, a scan whose match failed (``poor``: residuals
            too large, or ``few_points``) is not added to the map (static worlds: a skipped
            scan removes no observed free space and adds none). An ``ambiguous`` match is
            used: the directions the scan does not constrain keep the odometry prediction.
        footprint: the robot's body rectangle in the base frame; the cells it covers are
            observed free (shrunk by the pose bound, :meth:`SensedMap.clear_box`). None: the
            circumscribed disc of ``robot.footprint_radius`` is cleared instead (not provably
            free: it reaches beyond the body).
        pose_bound: ([m], [rad]) bound on the error of the pose the map is built at, used to
            shrink the body rectangle: ``shrink = pose_bound[0] + rho * pose_bound[1]`` with
            ``rho`` the rectangle's circumradius.
        meas_sigma0: ([m], [rad]) initial standard deviation assumed for the measured pose
            (localising: it anchors the estimate to the world frame, see the class docstring).
        meas_floor: ([m], [rad]) smallest standard deviation ever assumed for it.
        meas_forget: weight of each new sample in the measurement noise's running variance,
            in [0, 1] (0: ``meas_sigma0`` throughout).
        consistent_chi2: the measured pose is kept as the estimate when the match is ``ok``
            (every direction constrained) and the measured pose's scan cost exceeds the
            match's by at most this (:attr:`MatchResult.check_delta`; 11.34: the 99 % point
            of chi-square with 3 degrees of freedom). On an ``ambiguous`` match only while
            the learnt measurement noise is below ``precise_meas``: a weakly constrained
            direction lets a pose 2 deg off pass (measured: complex, seed 0).
        precise_meas: ([m], [rad]) learnt measurement noise below which the measured pose
            may be kept on an ambiguous match (an exact measurement in a sparse world).
        odometry_sigma: ([m], [rad]) standard deviation of the odometry prediction's error
            per control step (measured 0.007 rad rms on complex, seed 0), weighing prediction
            against measurement when a scan gives no match.
        reach_check: turn on the SA-MPC's ``reach_check`` (``MPCConfig.reach_check``):
            a step whose stage boxes the robot provably cannot stay in (after a ``blocked``
            replan the new boxes can be shorter than the distance it needs to stop) goes to
            the braking fallback without running the solver, which would spend its whole
            ALM budget (10-40 ms) before being rejected. The command is the same as without
            it (the skipped solve could not have been accepted); only the step time
            changes (docs/benchmarks.md, "Lidar closed loop per step").
        narrow_width: [m] ``MPCConfig.footprint="discs"``: the corridor search adds
            ``footprint_narrow_penalty`` per edge through a place narrower than this (where
            the circumscribed disc does not fit: ``2 (R + margin - inflation)`` counted in
            whole cells, :func:`sanav_mj.eval.lidar.sensed_narrow_width`;
            :class:`~sanav_mj.control.sensed_footprint.SensedFootprint`); unused in
            ``"disc"`` mode. >= 0.
        refresh: ``extend`` replans also once the corridor reaches the goal (the safe areas
            grew since the last plan, at most every ``replan_interval`` steps), so the
            corridor is made of the current map's areas, not of the slivers the goal's
            surroundings were when first seen. False (default): not after the corridor
            reaches the goal. The ``"discs"`` mode needs it (each disc centre must fit the
            corridor's boxes: a 5 cm sliver at the goal stalled it, e.g. barn_0004).
        straight_brake: the SA-MPC's braking fallback keeps the heading
            (:class:`~sanav_mj.control.sensed_footprint.StraightBrakeSAMPC`) instead of
            steering to the side deepest in the corridor; set in ``"discs"`` mode (see there).
        keep_rects: a replan in motion keeps the rectangles of the corridor being followed
            that hold the robot's predicted positions (each re-verified safe in the current
            map, a partly unsafe one cut to a safe part holding them;
            :mod:`sanav_mj.control.replan`), so the corridor starts with the boxes the
            shifted plan lies in; False (default): the corridor is planned on the current
            areas alone. Off by default: on the paper scenarios it cuts fallback steps (94 ->
            12 over seeds 0-4), but on the BARN-like worlds (disc mode) it lost 7 worlds and
            won none (58 -> 51 of 100), and no narrower rule tried kept both
            (docs/sensing.md, "Keeping the rectangles in use").
        route_polyline: the route to the goal (on the route areas, only checked against the
            map and used to place the local goal, never followed) is the planner's portal
            waypoint polyline sampled every ``PlannerConfig.spacing``
            (:func:`~sanav_mj.planning.pipeline.route_points`), without the smoothing and
            time parametrisation a followed reference needs (about 1 ms less per replan);
            False (default): a full :func:`plan` whose reference samples are the route. Off by
            default: it changes the runs, and in tests/eval/test_sensing_loop.py's hidden-box
            world the changed path left a box corner unseen, so one safe cell of the sensed
            map lay 1.6 cm inside the true inflated obstacle (a limit of the map, see
            docs/sensing.md, not of the route).
        grow: [m] > 0: every box of the SA-MPC's corridor chain is grown to a maximal
            rectangle of cells *safe in the map the plan is adopted on*, at most this far per
            side (the known map's ``MPCConfig.footprint_grow``, applied to the sensed safe
            grid: :class:`~sanav_mj.mapping.grow.FreeCells` of :meth:`LiveGrid.safe_grid`,
            tightened by ``MPCConfig.footprint_grow_tighten``).
            The grown boxes join the corridor rectangles of the ``blocked`` check, so every
            box the MPC uses in a step is observed-safe in that step's map. The incremental
            safe areas cut the sensed free space into staircases of one-cell slivers; a disc
            centre's stage boxes in them stalled the robot (e.g. barn_0007: three boxes
            0.05 m high at the top edge, the solver failing at rest). 0 (default): the
            chain's boxes are the corridor's rectangles and bridges.
        unseen_route: dimensionless >= 0: the route to the goal (never followed; it places
            the local goal) weighs each edge of the route areas by ``1 + unseen_route * u``,
            ``u`` the mean share of the two joined areas' cells not yet safe in the sensed
            map (:func:`sanav_mj.planning.unseen.penalise_unseen`), so a route through seen
            free space is preferred to a straight guess through unknown space. 0 (default):
            unknown space weighs as free space. Off by default: at 0.6 on the 100 BARN-like
            worlds (discs) the mean BARN metric rose 0.335 -> 0.343 (85 / 100 both, 0
            collisions) but one run (barn_0013) stalled 85 steps outside the step's safe
            areas (docs/results.md, "Where the lidar run's time goes").
        scan_turn_stop: the turn on the spot before the first plan brakes so as to stop
            where the lidar's field of view will have swept every unknown cell within the
            inflation radius of the own points' cells (predicted from the lidar's offset and
            field of view, :func:`~sanav_mj.control.scan_turn.sweep_angle`), turning at up to
            ``scan_turn_rate`` (capped by ``RobotParams.w_max``) and at least
            ``scan_turn_creep`` until the own points are safe. Off by default: the first
            motion comes 0.27 s sooner on 20 BARN-like worlds (seed 0, discs; 2.42 -> 2.15 s)
            and the paper scenarios with the lidar stay 50 / 50 with 0 collisions, but on the
            100 BARN-like worlds (discs, lidar, with the safe braking fallback) seeds 0-4 gave
            426 / 500 at the goal against 441 / 500 with it off, mean BARN 0.331 against
            0.338 (docs/results.md, "Lidar tempo"). False: at ``scan_turn_rate`` until
            they are (the SA-MPC then brakes the turn, overshooting by about
            ``rate^2 / (2 alpha_max)``, 0.5 rad at 2 rad/s). Only the turn's speed changes:
            the robot turns on the spot either way and the first plan still waits for the own
            points to be safe.
        scan_turn_route: the turn on the spot goes towards the heading of the route (planned
            on the route areas of the first scan: unknown space counts as passable) at 1 m
            from the robot, instead of towards the goal's bearing; the goal's bearing when no
            route exists.
        scan_turn_creep: [rad/s] > 0, the least yaw rate of the ``scan_turn_stop`` turn
            while the own points are not yet safe (a cell the prediction calls swept but no
            beam has crossed yet).
    """

    replan_interval: int = 5
    beam_stride: int = 1
    scan_turn_rate: float = 2.0
    max_scan_turn_s: float = 8.0
    background_replan: bool = False
    map: SensedMapConfig = field(default_factory=SensedMapConfig)
    localise: bool = True
    controller_pose: str = "estimate"
    skip_unmatched: bool = True
    footprint: Footprint | None = None
    pose_bound: tuple[float, float] = (0.03, 0.02)
    meas_sigma0: tuple[float, float] = (0.05, 0.05)
    meas_floor: tuple[float, float] = (0.003, 0.003)
    meas_forget: float = 0.05
    consistent_chi2: float = 11.34
    odometry_sigma: tuple[float, float] = (0.005, 0.007)
    precise_meas: tuple[float, float] = (0.01, 0.01)
    reach_check: bool = True
    narrow_width: float = 0.0
    refresh: bool = False
    straight_brake: bool = False
    keep_rects: bool = False
    route_polyline: bool = False
    grow: float = 0.0
    unseen_route: float = 0.0
    scan_turn_stop: bool = False
    scan_turn_route: bool = False
    scan_turn_creep: float = 0.5

    def __post_init__(self) -> None:
        if isinstance(self.replan_interval, bool) or not isinstance(self.replan_interval, int) \
                or self.replan_interval < 1:
            raise ValueError(f"SensingConfig.replan_interval: expected an integer >= 1, got {self.replan_interval!r}")
        if self.controller_pose not in ("estimate", "measured"):
            raise ValueError(f"SensingConfig.controller_pose: expected 'estimate' or 'measured', "
                             f"got {self.controller_pose!r}")
        if not (len(self.pose_bound) == 2 and all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
                                                  for v in self.pose_bound)):
            raise ValueError(f"SensingConfig.pose_bound: expected two finite numbers >= 0 [m, rad], "
                             f"got {self.pose_bound!r}")
        for name in ("meas_sigma0", "meas_floor", "odometry_sigma", "precise_meas"):
            v = getattr(self, name)
            if not (len(v) == 2 and all(isinstance(x, (int, float)) and math.isfinite(x) and x > 0 for x in v)):
                raise ValueError(f"SensingConfig.{name}: expected two finite numbers > 0 [m, rad], got {v!r}")
        if not (isinstance(self.meas_forget, (int, float)) and 0 <= self.meas_forget <= 1):
            raise ValueError(f"SensingConfig.meas_forget: expected a number in [0, 1], got {self.meas_forget!r}")
        if not isinstance(self.consistent_chi2, (int, float)) or math.isnan(self.consistent_chi2):
            raise ValueError(f"SensingConfig.consistent_chi2: expected a number (-inf: never keep the measured "
                             f"pose), got {self.consistent_chi2!r}")
        if self.footprint is not None and not isinstance(self.footprint, Footprint):
            raise ValueError(f"SensingConfig.footprint: expected a sanav_mj.footprint.Footprint or None, "
                             f"got {type(self.footprint).__name__}")
        if isinstance(self.beam_stride, bool) or not isinstance(self.beam_stride, int) or self.beam_stride < 1:
            raise ValueError(f"SensingConfig.beam_stride: expected an integer >= 1, got {self.beam_stride!r}")
        for name in ("scan_turn_stop", "scan_turn_route"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"SensingConfig.{name}: expected True or False, got {getattr(self, name)!r}")
        for name in ("scan_turn_rate", "max_scan_turn_s", "scan_turn_creep"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"SensingConfig.{name}: expected a finite number > 0, got {v!r}")
        if not (isinstance(self.narrow_width, (int, float)) and math.isfinite(self.narrow_width)
                and self.narrow_width >= 0):
            raise ValueError(f"SensingConfig.narrow_width: expected a finite number >= 0 [m], got {self.narrow_width!r}")
        for name in ("refresh", "straight_brake"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"SensingConfig.{name}: expected True or False, got {getattr(self, name)!r}")
        if not isinstance(self.route_polyline, bool):
            raise ValueError(f"SensingConfig.route_polyline: expected True or False, got {self.route_polyline!r}")
        if not isinstance(self.keep_rects, bool):
            raise ValueError(f"SensingConfig.keep_rects: expected True or False, got {self.keep_rects!r}")
        if not (isinstance(self.grow, (int, float)) and not isinstance(self.grow, bool)
                and math.isfinite(self.grow) and 0 <= self.grow <= 10):
            raise ValueError(f"SensingConfig.grow: expected a number in [0, 10] [m], got {self.grow!r}")
        if not (isinstance(self.unseen_route, (int, float)) and not isinstance(self.unseen_route, bool)
                and math.isfinite(self.unseen_route) and self.unseen_route >= 0):
            raise ValueError(f"SensingConfig.unseen_route: expected a finite number >= 0, got {self.unseen_route!r}")
        if not isinstance(self.background_replan, bool):
            raise ValueError(f"SensingConfig.background_replan: expected True or False, got {self.background_replan!r}")
