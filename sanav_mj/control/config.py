"""Configuration of the tracking MPCs: the shared core's settings and SA-MPC's.

:class:`TrackingConfig` holds what every tracking MPC of :mod:`sanav_mj.control.tracking`
uses (horizon, weights, input bounds, solver, acceptance, fallback, opening turn);
:class:`MPCConfig` is SA-MPC's: the core's fields plus the safe-area ones and the plant
adaptation (:class:`~sanav_mj.control.adaptation.AdaptationConfig`). The penalty MPC takes a
:class:`TrackingConfig` and its own :class:`~sanav_mj.control.penalty_mpc.PenaltyConfig`.
Importing this module does not load CasADi.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sanav_mj.control.adaptation import AdaptationConfig
from sanav_mj.control.prediction import PredictionDerating
from sanav_mj.planning.manoeuvre import ManoeuvreConfig
from sanav_mj.control.backends import BACKENDS
from sanav_mj.control.solver import SolverSettings
from sanav_mj.scene import RobotParams


def _metres(name: str, v, lo: float, hi: float = math.inf, closed: bool = False) -> None:
    """Raise ValueError naming ``MPCConfig.<name>`` unless ``v`` is a finite number (not a
    bool) of metres in ``[lo, hi)`` (``[lo, hi]`` when ``closed``)."""
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and lo <= v \
            and (v <= hi if closed else v < hi):
        return
    span = f">= {lo:g}" if math.isinf(hi) else f"in [{lo:g}, {hi:g}{']' if closed else ')'}"
    raise ValueError(f"MPCConfig.{name} must be a finite number {span} m, got {v!r}")


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of the tracking-MPC core, shared by SA-MPC and the penalty MPC.

    Attributes:
        horizon: N, number of prediction steps (default 20: 2 s at dt = 0.1 s).
        dt: [s] prediction and control period (default 0.1 s, the reference's period).
        q_x: diagonal of Qx, weights of the state error (x [1/m^2], y [1/m^2], yaw [1/rad^2]).
        q_u: diagonal of Qu, weights of the input error against the reference input
            (v [s^2/m^2], w [s^2/rad^2]).
        q_a: diagonal of Qa, weights of the input increment ``u_k - u_{k-1}`` (same units).
        q_n: diagonal of QN, terminal state error weights (as q_x).
        v_min: [m/s] lowest forward speed (negative: reversing allowed); None -> -0.25 * v_max.
        v_max: [m/s] top forward speed; None -> min(robot.v_max, r_w - w_max b / 2) with
            r_w = wheel_speed_max * wheel_radius the top rim speed and b the track.
        w_max: [rad/s] top yaw rate magnitude; None -> min(robot.w_max, 0.4 r_w / (b / 2)).
            With the two defaults a wheel never needs more than its top speed at any corner
            of the input box (|v| + |w| b / 2 <= r_w), and turning gets at most 40 % of it.
        a_max: [m/s^2] rate bound of v; None -> robot.a_max.
        alpha_max: [rad/s^2] rate bound of w; None -> robot.alpha_max.
        terminal_stop: constrain the last planned speed to zero (gives recursive feasibility
            of the nominal problem, see :class:`SAMPC`).
        solver: ``"zerofpr"`` (default: alpaqa ALM + ZeroFPR with L-BFGS, compiled; PANOC's
            sibling from the same authors), ``"panoc"`` (alpaqa ALM + PANOC with L-BFGS,
            compiled: the paper's solver), ``"pantr"`` (alpaqa ALM + PANTR, PANOC's
            trust-region Newton variant, compiled) or ``"ipopt"`` (through CasADi, the
            reference), see :mod:`sanav_mj.control.problem`. ZeroFPR is the default because it
            was measured fastest with the same success and tracking: in MuJoCo (five
            scenarios x 10 seeds, CPU) step mean 0.91 ms against 1.03 (PANOC) and 1.10
            (PANTR), 99th percentile 3.8-4.0 ms against 4.5 and 3.5-3.7; on the recorded
            sequence 16 % faster than PANOC; see docs/benchmarks.md.
        tol: optimality tolerance of the solver (PANOC: stationarity of the scaled problem;
            1e-3 moves the first input by < 2e-3 m/s against a 1e-9 IPOPT solution and
            saves about a quarter of PANOC's iterations against 1e-4, see docs/benchmarks.md).
        constraint_tol: [m] allowed constraint violation reported by the solver; a solution
            violating a constraint by more than 10x this is rejected.
        max_iter: solver iteration limit per ALM pass (PANOC/ZeroFPR/PANTR inner
            iterations). 100 by default (300 before): with 20 ALM passes it bounds the work
            of one solve deterministically; measured on this machine the longest solve of the
            robustness campaign (2 700 runs) fell from 342 ms to 48 ms; nominal results
            unchanged (five scenarios x 10 seeds: same 5 191 steps, no fallback; 100
            generated clutter maps: 100 % success, longest solve 19 ms; docs/robustness.md).
        max_outer_iter: ALM outer iteration limit (PANOC/PANTR). Warm-started problems
            converge in 2-6 (99.7 % within 12); the rest are (nearly) infeasible problems in
            passages a few cm wide, where the last iterate is often still feasible within
            ``constraint_tol`` (``"inexact"``); a limit of 8 or 12 turned those into
            fallbacks (6x more on the generated clutter maps) for a lower maximum time,
            so the inner cap ``max_iter`` bounds the time instead.
        solve_budget_ms: [ms] wall-clock limit of one solve; the solver stops and its last
            iterate is used if it is feasible, else the fallback. Default None: the solve is
            limited by the iteration caps ``max_iter`` and ``max_outer_iter`` only, so the
            same inputs give the same command on any machine at any load (a wall-clock cut
            made the outcome of a seed depend on the load; docs/robustness.md). Set it (e.g.
            ``--mismatch solve_budget_ms=B``) to study a real-time budget.
        accept_inexact: use a non-converged iterate when it is finite and satisfies every
            constraint (status ``"inexact"``); when False such a step takes the fallback.
        fallback_brake: on a rejected solve, apply the previous plan only if it still meets
            every constraint of the current problem (rolled out from the current state),
            else brake at the rate bounds steering inside the corridor (see "Fallback");
            False: the paper-style fallback that replays the previous plan open loop.
        turn_in_place: [rad] when the heading error to the reference at the first step of an
            episode exceeds this, the robot first turns on the spot (status ``"turn"``, see
            "Opening turn" in :class:`SAMPC`); None: the MPC handles every start.
        turn_exit: [rad] the opening turn hands over to the MPC once the heading error is
            at most this (must be below ``turn_in_place``).
        cache_dir: folder of compiled solver code; None -> ``$SANAV_MJ_CACHE`` or
            ``~/.cache/sanav-mj``.
        reach_check: before each solve, bound the positions reachable within the input
            bounds (:func:`~sanav_mj.control.reach.unreachable_stage`); when a stage box
            cannot be reached the problem is proved infeasible and the step takes the
            fallback without a solve (the solve would have been rejected: same command,
            without the 10-40 ms of a full ALM budget). Only for position rows that are
            the positions (not disc centres). Default False (known-map runs unchanged);
            the lidar mode turns it on (``SensingConfig.reach_check``).
    """

    horizon: int = 20
    dt: float = 0.1
    q_x: tuple[float, float, float] = (10.0, 10.0, 1.0)
    q_u: tuple[float, float] = (1.0, 0.1)
    q_a: tuple[float, float] = (2.0, 0.5)
    q_n: tuple[float, float, float] = (40.0, 40.0, 2.0)
    v_min: float | None = None
    v_max: float | None = None
    w_max: float | None = None
    a_max: float | None = None
    alpha_max: float | None = None
    terminal_stop: bool = True
    solver: str = "zerofpr"
    tol: float = 1e-3
    constraint_tol: float = 1e-4
    max_iter: int = 100
    max_outer_iter: int = 20
    solve_budget_ms: float | None = None
    accept_inexact: bool = True
    fallback_brake: bool = True
    turn_in_place: float | None = 1.0
    turn_exit: float = 0.3
    cache_dir: str | None = None
    reach_check: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.reach_check, bool):
            raise ValueError(f"{self._name}.reach_check must be True or False, got {self.reach_check!r}")
        if not (isinstance(self.horizon, int) and 2 <= self.horizon <= 200):
            raise ValueError(f"{self._name}.horizon must be an integer in [2, 200], got {self.horizon!r}")
        self._positive("dt", self.dt)
        self._weights("q_x", self.q_x, 3)
        self._weights("q_u", self.q_u, 2)
        self._weights("q_a", self.q_a, 2)
        self._weights("q_n", self.q_n, 3)
        for name in ("v_max", "w_max", "a_max", "alpha_max", "tol", "constraint_tol", "solve_budget_ms"):
            self._positive(name, getattr(self, name), allow_none=True)
        if self.v_min is not None and not (math.isfinite(self.v_min) and self.v_min <= 0):
            raise ValueError(f"{self._name}.v_min must be a finite number <= 0 m/s, got {self.v_min!r}")
        if self.solver not in BACKENDS:
            raise ValueError(f"{self._name}.solver must be one of {sorted(BACKENDS)}, got {self.solver!r}")
        for name in ("max_iter", "max_outer_iter"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"{self._name}.{name} must be an integer >= 1, got {v!r}")
        self._positive("turn_in_place", self.turn_in_place, allow_none=True)
        if not (isinstance(self.turn_exit, (int, float)) and 0 <= self.turn_exit < math.pi):
            raise ValueError(f"{self._name}.turn_exit must be in [0, pi) rad, got {self.turn_exit!r}")
        if self.turn_in_place is not None and self.turn_exit >= self.turn_in_place:
            raise ValueError(
                f"{self._name}.turn_exit must be below turn_in_place ({self.turn_in_place!r} rad), got {self.turn_exit!r}"
            )

    @property
    def _name(self) -> str:
        return type(self).__name__

    def _positive(self, name: str, value, allow_none: bool = False) -> None:
        if value is None and allow_none:
            return
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{self._name}.{name} must be a positive finite number, got {value!r}")

    def _weights(self, name: str, value, n: int) -> None:
        ok = isinstance(value, tuple) and len(value) == n
        ok = ok and all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in value)
        if not ok:
            raise ValueError(f"{self._name}.{name} must be a tuple of {n} finite numbers >= 0, got {value!r}")

    def limits(self, robot: RobotParams) -> InputLimits:
        """Resolve the input and rate bounds against the robot's parameters."""
        rim = robot.wheel_speed_max * robot.wheel_radius  # [m/s] top wheel rim speed
        half_track = 0.5 * robot.track
        w_max = self.w_max if self.w_max is not None else min(robot.w_max, 0.4 * rim / half_track)
        v_max = self.v_max if self.v_max is not None else min(robot.v_max, rim - w_max * half_track)
        v_min = self.v_min if self.v_min is not None else -0.25 * v_max
        a_max = self.a_max if self.a_max is not None else robot.a_max
        alpha_max = self.alpha_max if self.alpha_max is not None else robot.alpha_max
        from sanav_mj.control.unicycle import SINC_HALF_ANGLE_MAX

        if w_max * self.dt / 2 > SINC_HALF_ANGLE_MAX:
            raise ValueError(
                f"w_max * dt / 2 must be <= {SINC_HALF_ANGLE_MAX} rad for the model, got {w_max * self.dt / 2!r}"
            )
        for name, v in (("v_max", v_max), ("w_max", w_max), ("a_max", a_max), ("alpha_max", alpha_max)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"resolved {name} must be positive and finite, got {v!r}")
        return InputLimits(v_min, v_max, w_max, a_max, alpha_max)

    def solver_settings(self) -> SolverSettings:
        """The back-end settings of this configuration (tolerances, iteration caps, budget)."""
        return SolverSettings(
            tol=self.tol,
            constraint_tol=self.constraint_tol,
            max_iter=self.max_iter,
            max_outer_iter=self.max_outer_iter,
            budget_ms=self.solve_budget_ms,
        )


#: values of :attr:`MPCConfig.footprint`.
FOOTPRINT_MODES = ("disc", "discs")
#: values of :attr:`MPCConfig.footprint_route`.
FOOTPRINT_ROUTES = ("pose", "corridor")


@dataclass(frozen=True)
class MPCConfig(TrackingConfig):
    """Settings of the SA-MPC: the core's (:class:`TrackingConfig`) plus the following.

    Attributes:
        q_sa: J_SA priority q_SA(n) [1/m] of each safe-area slot; its length is the number of
            slots: the first safe areas along the corridor that the horizon visits (unused
            slots are neutral). Two by default, the robot's area and the next: J_SA can only
            be non-zero where the hard boxes are relaxed, which is near the robot, and each
            slot costs about 20 % of the objective's evaluation time.
        box_margin: [m] each stage box is shrunk by this much per side (at most a quarter of
            its width), a margin for model mismatch between samples and the real robot.
        reference_window: samples ahead of the last progress index searched for the
            reference sample nearest to the robot; None -> horizon.
        adaptation: the adaptation to the plant (actuation monitor, pose filter, latency and
            gain compensation, speed / yaw-rate derating, traction limit), see
            :class:`~sanav_mj.control.adaptation.AdaptationConfig`.
        footprint: how the robot's body enters the map and the constraints. ``"disc"``
            (default, the paper's): the map is inflated by the circumscribed radius plus
            ``sanav_mj.eval.prepare.DEFAULT_MARGIN_M`` and the predicted position (base
            origin) must lie in the stage box. ``"discs"``: the footprint rectangle of the
            collision geoms (:func:`sanav_mj.footprint.robot_footprint`) is covered by
            ``footprint_discs`` discs of radius r_d along its long axis; the map is inflated
            by ``r_d + footprint_margin`` and the two extreme disc centres of every
            predicted state must lie in the stage box (so every centre does: they are
            collinear); J_SA is charged at every disc centre; the opening turn on the spot is
            taken only where the circle the disc centres sweep fits in a stage box (else the
            MPC turns, under the disc rows). See :mod:`sanav_mj.control.footprint`.
        footprint_discs: number of discs of the ``"discs"`` cover (>= 2).
        footprint_margin: [m] inflation margin beyond the disc radius in ``"discs"`` mode. Its
            job is the true disc centres' excursion outside the safe areas under model
            mismatch; with the stage boxes tightened online by the measured prediction error
            (``footprint_prediction``) that excursion is at most one period's error after every
            accepted or shifted plan (:mod:`sanav_mj.control.prediction`), measured at the
            robustness envelope's corner on 100 BARN-like worlds at margin 0.02: <= 1.7 cm on
            such steps, <= 3.6 cm after braking steps (which the argument does not cover;
            docs/results.md, "Sizing the margin from the measured error"). Default 0.04: covers
            both measured values (0 collisions in 100 nominal and 100 corner runs; smallest
            true footprint clearance at the corner 3.9 cm, 2.1 cm at 0.02). With the boxes
            unshrunk (``footprint_box_margin`` 0, the default since h14safe0) the largest
            excursion measured is 2.8 cm nominal and 3.9 cm at the corner (below 0.04).
        footprint_narrow_penalty: [m] ``"discs"`` mode: added to the corridor search's weight
            of every edge through a place where the circumscribed-disc map has no room
            (:func:`sanav_mj.eval.prepare.planning_areas`), so the corridor keeps to passages
            where the robot can turn when they are not much longer; 0: shortest corridor.
        footprint_route: ``"discs"`` mode: where corridor and reference come from.
            ``"pose"``: a search over poses (x, y, yaw) whose disc centres stay in the safe
            areas, turning on the spot only where the centres' sweep fits
            (:mod:`sanav_mj.planning.pose_search`); the reference's yaw is the found
            path's, the corridor the areas it passes. ``"corridor"`` (default): the paper's
            corridor and B-spline reference (heading = path tangent). Measured on the 100
            BARN-like worlds (nominal): "pose" with one 5 cm grid 73 / 100 (24 no_path, 3
            stuck), with ``footprint_refine`` 2 65 / 100 (28 no_path, 7 stuck); "corridor"
            with refine 2 76 / 100 (8 no_path, 15 stuck); 0 collisions each.
        footprint_refine: ``"discs"`` mode: the map's cells are refined by this integer
            factor where the free space is narrow (:class:`sanav_mj.mapping.MapConfig`
            ``refine``, :func:`sanav_mj.mapping.refine.refine_narrow`); 1: one grid.
            Default 2 (0.05 m cells become 0.025 m where narrow).
        footprint_refine_width: [m] ``"discs"`` mode with ``footprint_refine > 1``: a fine
            cell is used where its free run along x or y is at most this long.
        footprint_grow: [m] ``"discs"`` mode: > 0 grows every box of the corridor chain to a
            maximal free rectangle of the map's grid, each side by at most this much
            (:meth:`sanav_mj.control.stages.CorridorChain.build`); 0: the safe areas as
            they are. Default 1.0: with the prediction derating and the tightening by the
            measured error, 0 collisions in 100 BARN-like runs nominal and at the envelope's
            corner (before them 2 corner runs collided, docs/results.md "Tight spaces").
        footprint_grow_tighten: [m] with ``footprint_grow > 0``: the room growth adds to a
            stage box is tightened by this much more than ``box_margin`` (the plain box's
            room is kept), for the tracking error under model mismatch.
        footprint_box_margin: [m] ``"discs"`` mode: what ``box_margin`` is in the disc mode,
            used instead of it wherever the discs mode shrinks a stage box (the corridor chain,
            the pose route's per-disc chains and pose search, the J_SA slots) and grows it back
            (the fallback's shift check, :attr:`~sanav_mj.control.tracking.TrackingMPC.position_slack`);
            in [0, 1). See :attr:`stage_box_margin`. Default 0: the stage boxes are the
            chain members; what a fixed shrink covered is covered by the online tightening
            (``footprint_prediction``: the measured prediction error plus the pose
            estimate's offset from the measurement). Measured on the 100 BARN-like worlds
            (seed 0; docs/results.md "Tight spaces"): nominal 95 / 100 (BARN 0.435; 87 at
            0.02, 92 at 0.01), 0 collisions, largest true excursion of a disc centre outside
            every safe area 2.8 cm; at the envelope corner 89 / 100, 0 collisions, largest
            excursion 3.9 cm, smallest true clearance 4.3 cm: within ``footprint_margin``
            both, by measurement (:mod:`sanav_mj.control.prediction` says which steps its
            argument covers). Lidar runs use ``box_margin`` (:func:`sanav_mj.eval.lidar.lidar_spec`).
        footprint_prediction: ``"discs"`` mode: derate the speed and yaw-rate bounds by the
            one-step prediction error of the disc centres measured online, and (its
            ``tighten``, on) shrink the disc rows' stage boxes by that error with a relaxation
            capped at the untightened boxes
            (:class:`sanav_mj.control.prediction.PredictionDerating`, whose module docstring
            gives why this bounds the excursion and what it assumes); None: off. Unused in
            ``"disc"`` mode.
        footprint_open_speed: ``"discs"`` mode with a known map: None (one reference speed
            everywhere, 0.8 of ``v_max``) or the reference's top speed in open space as a
            fraction of the resolved ``v_max`` (:func:`sanav_mj.eval.prepare.planner_config`,
            :attr:`sanav_mj.planning.PlannerConfig.open_speed_fraction`): at path nodes whose
            centre has ``footprint_open_room`` of free inflated cells on every side; 0.8 of
            ``v_max`` elsewhere, slowing down before narrow places. Unused in ``"disc"`` mode
            and with the lidar (not measured there). Default 1.0 at room 0.15 m, measured on
            the 100 BARN-like worlds with ``footprint_box_margin`` 0 (docs/results.md, "Tight
            spaces"): 94 / 100, mean BARN 0.453 (95 / 100, 0.435 without it; the successful
            runs 10.1 s instead of 11.3 s); at the envelope corner 89 / 100, 0 collisions.
            On the first 25 worlds (box margin 0.02) room 0.25 m: 20 / 25, 0.375; 0.15 m:
            21 / 25, 0.398; 0.10 m: 20 / 25, 0.386; one speed of 0.95 ``v_max`` everywhere:
            19 / 25, 0.366; none: 20 / 25, 0.359.
        footprint_open_room: [m] that room (the half-side of a free square of cells around
            the node, in the map inflated by the disc radius and margin).
        footprint_manoeuvre: ``"discs"`` mode with a known map: None (off) or the settings of
            the manoeuvres that replace each stretch of the corridor reference whose disc
            centres leave the safe areas, on a map built with ``footprint_refine_fallback``
            (:func:`sanav_mj.eval.prepare.manoeuvre_plan`, :mod:`sanav_mj.planning.manoeuvre`;
            the plan is then followed as a pose route). Unused in ``"disc"`` mode.
        footprint_refine_fallback: ``"discs"`` mode with a known map: 0 (off) or a
            ``footprint_refine`` the map is built again with when the plan at
            ``footprint_refine`` finds no path (:func:`sanav_mj.eval.prepare.prepare`).
    """

    q_sa: tuple[float, ...] = (5.0, 5.0)
    box_margin: float = 0.02
    reference_window: int | None = None
    adaptation: AdaptationConfig = AdaptationConfig()
    footprint: str = "disc"
    footprint_discs: int = 3
    footprint_margin: float = 0.04
    footprint_narrow_penalty: float = 2.0
    footprint_route: str = "corridor"
    footprint_refine: int = 2
    footprint_refine_width: float = 0.25
    footprint_grow: float = 1.0
    footprint_grow_tighten: float = 0.0
    footprint_box_margin: float = 0.0
    footprint_prediction: PredictionDerating | None = PredictionDerating()
    footprint_open_speed: float | None = 1.0
    footprint_open_room: float = 0.15
    footprint_manoeuvre: ManoeuvreConfig | None = ManoeuvreConfig()
    footprint_refine_fallback: int = 4

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.q_sa, tuple) and 1 <= len(self.q_sa) <= 8):
            raise ValueError(f"MPCConfig.q_sa must be a tuple of 1 to 8 priorities, got {self.q_sa!r}")
        self._weights("q_sa", self.q_sa, len(self.q_sa))
        if not (isinstance(self.box_margin, (int, float)) and 0 <= self.box_margin < 1):
            raise ValueError(f"MPCConfig.box_margin must be in [0, 1) m, got {self.box_margin!r}")
        if self.reference_window is not None and not (
            isinstance(self.reference_window, int) and self.reference_window >= 1
        ):
            raise ValueError(f"MPCConfig.reference_window must be an integer >= 1 or None, got {self.reference_window!r}")
        if not isinstance(self.adaptation, AdaptationConfig):
            raise ValueError(f"MPCConfig.adaptation must be an AdaptationConfig, got {self.adaptation!r}")
        if self.footprint not in FOOTPRINT_MODES:
            raise ValueError(f"MPCConfig.footprint must be one of {FOOTPRINT_MODES}, got {self.footprint!r}")
        if isinstance(self.footprint_discs, bool) or not (isinstance(self.footprint_discs, int) and 2 <= self.footprint_discs <= 8):
            raise ValueError(f"MPCConfig.footprint_discs must be an integer in [2, 8], got {self.footprint_discs!r}")
        _metres("footprint_margin", self.footprint_margin, 0.0, 1.0)
        _metres("footprint_narrow_penalty", self.footprint_narrow_penalty, 0.0)
        if self.footprint_route not in FOOTPRINT_ROUTES:
            raise ValueError(f"MPCConfig.footprint_route must be one of {FOOTPRINT_ROUTES}, got {self.footprint_route!r}")
        fr = self.footprint_refine
        if isinstance(fr, bool) or not (isinstance(fr, int) and 1 <= fr <= 16):
            raise ValueError(f"MPCConfig.footprint_refine must be an integer in [1, 16], got {fr!r}")
        _metres("footprint_refine_width", self.footprint_refine_width, 0.0)
        _metres("footprint_grow_tighten", self.footprint_grow_tighten, 0.0, 1.0)
        if self.footprint_prediction is not None and not isinstance(self.footprint_prediction, PredictionDerating):
            raise ValueError(f"MPCConfig.footprint_prediction must be a PredictionDerating or None, "
                             f"got {self.footprint_prediction!r}")
        _metres("footprint_box_margin", self.footprint_box_margin, 0.0, 1.0)
        fo = self.footprint_open_speed
        if fo is not None and (isinstance(fo, bool) or not (isinstance(fo, (int, float)) and 0 < fo <= 1)):
            raise ValueError(f"MPCConfig.footprint_open_speed must be None or a fraction in (0, 1], got {fo!r}")
        _metres("footprint_open_room", self.footprint_open_room, 0.0, 5.0)
        _metres("footprint_grow", self.footprint_grow, 0.0, 10.0, closed=True)
        if self.footprint_manoeuvre is not None and not isinstance(self.footprint_manoeuvre, ManoeuvreConfig):
            raise ValueError(f"MPCConfig.footprint_manoeuvre must be a ManoeuvreConfig or None, "
                             f"got {self.footprint_manoeuvre!r}")
        fb = self.footprint_refine_fallback
        if isinstance(fb, bool) or not (isinstance(fb, int) and 0 <= fb <= 16):
            raise ValueError(f"MPCConfig.footprint_refine_fallback must be an integer in [0, 16], got {fb!r}")

    @property
    def stage_box_margin(self) -> float:
        """[m] the margin the stage boxes are shrunk by: ``footprint_box_margin`` in
        ``"discs"`` mode, else ``box_margin``."""
        return float(self.footprint_box_margin) if self.footprint == "discs" else self.box_margin

    def tracking(self) -> TrackingConfig:
        """The core's part of this configuration (the same values)."""
        from dataclasses import fields

        return TrackingConfig(**{f.name: getattr(self, f.name) for f in fields(TrackingConfig)})


@dataclass(frozen=True)
class InputLimits:
    """Resolved bounds: v in [v_min, v_max] [m/s], |w| <= w_max [rad/s], rates a_max [m/s^2], alpha_max [rad/s^2]."""

    v_min: float
    v_max: float
    w_max: float
    a_max: float
    alpha_max: float

    def lower(self) -> np.ndarray:
        """(2,) [m/s, rad/s] lower input bounds."""
        return np.array([self.v_min, -self.w_max])

    def upper(self) -> np.ndarray:
        """(2,) [m/s, rad/s] upper input bounds."""
        return np.array([self.v_max, self.w_max])

    def rate(self) -> np.ndarray:
        """(2,) [m/s^2, rad/s^2] rate bounds."""
        return np.array([self.a_max, self.alpha_max])


@dataclass(frozen=True)
class PenaltyConfig:
    """Settings of the obstacle-penalty baseline beyond the core's :class:`~sanav_mj.control.config.TrackingConfig`.

    Attributes:
        q_obs: weight of each polygon's penalty (see :class:`~sanav_mj.control.penalty_mpc.ObstaclePenalty`): [1/m^2] for
            the ``"depth"`` form; [-] for ``"product"``, whose rows are normalised by the
            polygon's inradius.
        form: ``"depth"`` or ``"product"``, see :class:`~sanav_mj.control.penalty_mpc.ObstaclePenalty`.
        n_slots: obstacles considered per step (nearest polygon centres first).
        n_edges: edges per polygon slot: cylinders and capsules are ``n_edges``-gons, boxes
            octagons (4 edges and 4 corner cuts, see :func:`~sanav_mj.control.penalty_mpc.obstacle_polygon`) when
            ``n_edges >= 8``, else rectangles.
        reference_speed: [m/s] speed along the straight reference; None -> 0.8 v_max.
        lookahead: [m] the reference starts this far ahead of the robot on the straight
            line to the goal (0: at the robot; it never passes the goal).
        forward_only: drive forwards only (``v_min = 0``) instead of the shared ``v_min``.
            Without the opening turn, a robot facing away from the goal reversed all the way
            to the block (yaw error is cheap against the lookahead's pull); with it,
            reversing is harmless (10/10 on ``single_rect`` either way), so off by default.
        escape_yaw_rates: [rad/s] yaw rates of the extra initial guesses tried when the plan
            is blocked (each held for ``escape_steps`` steps, then 0); empty: never.
        escape_steps: steps of the horizon that turn in an escape guess.
        escape_speed: [m/s] lowest forward speed of an escape guess (it drives at
            ``max(previous speed, escape_speed)``).
        blocked_travel: the plan counts as blocked when it enters a polygon and its path is
            shorter than this fraction of the reference's ``N * reference_speed * dt``.
        escape_budget_ms: [ms] extra wall-clock limit of each escape solve (None: none).
            Every solve of the controller, escape solves included, respects the shared
            ``TrackingConfig.solve_budget_ms`` (the ``solve_budget_ms`` mismatch); an escape
            solve is cut at the smaller of the two. A step that tries the escape starts
            makes ``1 + len(escape_yaw_rates)`` solves, so its wall time can reach that many
            budgets. The escape starts are cold starts far from their solution: with the
            ZeroFPR back-end they took 25-33 ms on ``single_rect`` (10 runs, load about 1);
            with an earlier back-end 50-300 ms on a loaded 2-core machine, where a 50 ms cut
            made their iterates lose to the braking plan and the baseline stopped in front
            of the block in 2 of 10 ``single_rect`` runs.
        min_outer_iter: lower bound of the ALM outer-iteration limit of the baseline's solver
            (``max(TrackingConfig.max_outer_iter, min_outer_iter)``). Its costs are about ten
            times SA-MPC's (the reference lies ahead of the robot) and cold starts need more
            passes to meet the rate bounds: with 8 (SA-MPC's setting for a while), the first
            solve of every ``single_rect`` run failed.
    """

    q_obs: float = 3000.0
    form: str = "depth"
    n_slots: int = 8
    n_edges: int = 8
    reference_speed: float | None = None
    lookahead: float = 3.0
    forward_only: bool = False
    escape_yaw_rates: tuple[float, ...] = (1.0, -1.0)
    escape_steps: int = 10
    escape_speed: float = 0.3
    blocked_travel: float = 0.6
    escape_budget_ms: float | None = None
    min_outer_iter: int = 20

    def __post_init__(self) -> None:
        if not (isinstance(self.q_obs, (int, float)) and math.isfinite(self.q_obs) and self.q_obs > 0):
            raise ValueError(f"PenaltyConfig.q_obs must be a positive finite number, got {self.q_obs!r}")
        if self.form not in ("depth", "product"):
            raise ValueError(f"PenaltyConfig.form must be 'depth' or 'product', got {self.form!r}")
        if not (isinstance(self.n_slots, int) and self.n_slots >= 1):
            raise ValueError(f"PenaltyConfig.n_slots must be an integer >= 1, got {self.n_slots!r}")
        if not (isinstance(self.n_edges, int) and self.n_edges >= 4):
            raise ValueError(f"PenaltyConfig.n_edges must be an integer >= 4, got {self.n_edges!r}")
        rs = self.reference_speed
        if rs is not None and not (isinstance(rs, (int, float)) and math.isfinite(rs) and rs > 0):
            raise ValueError(f"PenaltyConfig.reference_speed must be None or a positive finite m/s, got {rs!r}")
        if not (isinstance(self.lookahead, (int, float)) and math.isfinite(self.lookahead) and self.lookahead >= 0):
            raise ValueError(f"PenaltyConfig.lookahead must be a finite number >= 0 m, got {self.lookahead!r}")
        rates = self.escape_yaw_rates
        if not (isinstance(rates, tuple) and all(isinstance(w, (int, float)) and math.isfinite(w) for w in rates)):
            raise ValueError(f"PenaltyConfig.escape_yaw_rates must be a tuple of finite rad/s, got {rates!r}")
        if not (isinstance(self.escape_steps, int) and self.escape_steps >= 1):
            raise ValueError(f"PenaltyConfig.escape_steps must be an integer >= 1, got {self.escape_steps!r}")
        es = self.escape_speed
        if not (isinstance(es, (int, float)) and math.isfinite(es) and es >= 0):
            raise ValueError(f"PenaltyConfig.escape_speed must be a finite number >= 0 m/s, got {es!r}")
        bt = self.blocked_travel
        if not (isinstance(bt, (int, float)) and 0 < bt <= 1):
            raise ValueError(f"PenaltyConfig.blocked_travel must be in (0, 1], got {bt!r}")
        eb = self.escape_budget_ms
        if eb is not None and not (isinstance(eb, (int, float)) and math.isfinite(eb) and eb > 0):
            raise ValueError(f"PenaltyConfig.escape_budget_ms must be None or a positive finite ms, got {eb!r}")
        mo = self.min_outer_iter
        if not (isinstance(mo, int) and mo >= 1):
            raise ValueError(f"PenaltyConfig.min_outer_iter must be an integer >= 1, got {mo!r}")
