"""Safe-area MPC (SA-MPC, paper Sec. III-D/E): track the reference inside the safe rectangles.

The optimisation problem is the shared tracking NLP of :mod:`sanav_mj.control.problem` with

- hard stage boxes ``A_k p_k <= b_k`` (k = 1..N) built from the safe areas of the corridor
  (see "Stage boxes" in :class:`SAMPC`), passed as bounds of the position rows of ``g``;
- the paper's soft penalty ``J_SA(p) = prod_n sum_m [q_SA(n) h_nm(p)]_-^2`` over the safe areas
  around the horizon (:class:`SafeAreaPenalty`), added for k = 1..N;
- input bounds, input-rate bounds against the previously applied input, and (by default) a
  terminal stop ``v_{N-1} = 0``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Callable

import casadi as cs
import numpy as np

from sanav_mj.control.base import Command, Observation
from sanav_mj.control.monitor import ActuationMonitor, MonitorConfig, PoseFilter, PoseFilterConfig
from sanav_mj.control.backends import BACKENDS, get_backend
from sanav_mj.control.problem import build_tracking_ocp, shift_bound_multipliers, shift_inputs, shift_multipliers
from sanav_mj.control.solver import SolverSettings
from sanav_mj.control.unicycle import SINC_HALF_ANGLE_MAX, rollout_np
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.scene import RobotParams


def _positive(name: str, value, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"MPCConfig.{name} must be a positive finite number, got {value!r}")


def _weights(name: str, value, n: int) -> None:
    ok = isinstance(value, tuple) and len(value) == n
    ok = ok and all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in value)
    if not ok:
        raise ValueError(f"MPCConfig.{name} must be a tuple of {n} finite numbers >= 0, got {value!r}")


@dataclass(frozen=True)
class MPCConfig:
    """Settings of the SA-MPC (and of the MPC baselines that share its problem).

    Attributes:
        horizon: N, number of prediction steps (default 20: 2 s at dt = 0.1 s).
        dt: [s] prediction and control period (default 0.1 s, the reference's period).
        q_x: diagonal of Qx, weights of the state error (x [1/m^2], y [1/m^2], yaw [1/rad^2]).
        q_u: diagonal of Qu, weights of the input error against the reference input
            (v [s^2/m^2], w [s^2/rad^2]).
        q_a: diagonal of Qa, weights of the input increment ``u_k - u_{k-1}`` (same units).
        q_n: diagonal of QN, terminal state error weights (as q_x).
        q_sa: J_SA priority q_SA(n) [1/m] of each safe-area slot; its length is the number of
            slots: the first safe areas along the corridor that the horizon visits (unused
            slots are neutral). Two by default, the robot's area and the next: J_SA can only
            be non-zero where the hard boxes are relaxed, which is near the robot, and each
            slot costs about 20 % of the objective's evaluation time.
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
        box_margin: [m] each stage box is shrunk by this much per side (at most a quarter of
            its width), a margin for model mismatch between samples and the real robot.
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
        latency_compensation: predict the state at the instant the new command takes effect
            through the commands already sent but not yet applied, using the delay and gains
            identified online by the :class:`~sanav_mj.control.monitor.ActuationMonitor`
            (see "Latency compensation" in :class:`SAMPC`).
        gain_compensation: divide each sent command by the identified gains, so that the
            plant realises the planned velocity (off by default: not needed in the measured
            envelope, see docs/robustness.md).
        monitor: settings of the actuation monitor (delay range, forgetting, gain clamp).
        excursion_stop: [m] speed derating when the position (at the instant the command
            takes effect) lies outside its stage box by ``e``: the speed bound becomes
            ``v_max max(derate_floor, 1 - e / excursion_stop)``, reached at the rate bound
            (see "Measured position outside its box"). None: no derating.
        derate_floor: fraction of ``v_max`` the excursion derating never goes below (so
            that a robot slightly outside its box still makes progress back in).
        residual_free, residual_stop: [m/s] speed derating by the actuation monitor's
            velocity-tracking residual ``r`` (RMS over about 2 s of the measured minus the
            identified response, the yaw rate counted as rim speed): none up to
            ``residual_free``, then linear down to ``residual_floor v_max`` at
            ``residual_stop`` and beyond (see "Derating by tracking residual"). Measured
            residuals: below 0.006 m/s nominal, median 0.01-0.04 m/s in the envelope's
            worst corner, 0.07-1 m/s at friction 0.05-0.1 or a torque limit of 10 %
            (docs/robustness.md). None: no residual derating.
        residual_floor: fraction of ``v_max`` the residual derating never goes below.
        residual_yaw_floor: the residual derating lowers the yaw-rate bound by the same
            fraction as the speed bound, but never below this fraction of ``w_max`` (so the
            robot can still turn towards its corridor); the lateral acceleration ``v w`` a
            plant that does not follow is asked for falls with the square of the fraction.
            None: the yaw rate is not derated.
        traction_probe: speed rate bound from the monitor's traction evidence (see
            "Traction limit" in :class:`SAMPC`): while the monitor sees the plant slip, the
            rate bound of the speed (and with it the speed bounds implied by the terminal
            stop and the braking fallback) is this factor times the largest speed change
            per period the body achieved this episode, over ``dt`` (above 1: room for the
            plant to show more grip). None: the model's ``a_max`` throughout.
        traction_floor: fraction of ``a_max`` the traction bound never goes below.
        traction_recovery: per-step relative growth of the traction bound back towards
            ``a_max`` while no slip is seen (0.05: from the floor to ``a_max`` in about
            5 s).
        fallback_derated: on a rejected solve, check the shifted previous plan against the
            *derated* input bounds as well: a plan that keeps a speed (or yaw rate) above the
            current derating is not followed, the robot brakes (it used to follow its old
            plan at 1.06 m/s on a floor where the derating asked for 0.65, docs/robustness.md).
        pose_filter: settings of the :class:`~sanav_mj.control.monitor.PoseFilter` that
            fuses the measured pose with the measured body velocity before each step (it
            returns a noise-free measurement exactly; see "Pose filter" in :class:`SAMPC`).
            None: the measured pose is used as it is.
        fallback_brake: on a rejected solve, apply the previous plan only if it still meets
            every constraint of the current problem (rolled out from the current state),
            else brake at the rate bounds steering inside the corridor (see "Fallback");
            False: the paper-style fallback that replays the previous plan open loop.
        turn_in_place: [rad] when the heading error to the reference at the first step of an
            episode exceeds this, the robot first turns on the spot (status ``"turn"``, see
            "Opening turn" in :class:`SAMPC`); None: the MPC handles every start.
        turn_exit: [rad] the opening turn hands over to the MPC once the heading error is
            at most this (must be below ``turn_in_place``).
        reference_window: samples ahead of the last progress index searched for the
            reference sample nearest to the robot; None -> horizon.
        cache_dir: folder of compiled solver code; None -> ``$SANAV_MJ_CACHE`` or
            ``~/.cache/sanav-mj``.
    """

    horizon: int = 20
    dt: float = 0.1
    q_x: tuple[float, float, float] = (10.0, 10.0, 1.0)
    q_u: tuple[float, float] = (1.0, 0.1)
    q_a: tuple[float, float] = (2.0, 0.5)
    q_n: tuple[float, float, float] = (40.0, 40.0, 2.0)
    q_sa: tuple[float, ...] = (5.0, 5.0)
    v_min: float | None = None
    v_max: float | None = None
    w_max: float | None = None
    a_max: float | None = None
    alpha_max: float | None = None
    terminal_stop: bool = True
    box_margin: float = 0.02
    solver: str = "zerofpr"
    tol: float = 1e-3
    constraint_tol: float = 1e-4
    max_iter: int = 100
    max_outer_iter: int = 20
    solve_budget_ms: float | None = None
    accept_inexact: bool = True
    latency_compensation: bool = True
    gain_compensation: bool = False
    monitor: MonitorConfig = MonitorConfig()
    pose_filter: PoseFilterConfig | None = PoseFilterConfig()
    excursion_stop: float | None = 0.15
    derate_floor: float = 0.25
    residual_free: float = 0.03
    residual_stop: float | None = 0.2
    residual_floor: float = 0.1
    residual_yaw_floor: float | None = 0.3
    traction_probe: float | None = 1.25
    traction_floor: float = 0.1
    traction_recovery: float = 0.05
    fallback_derated: bool = True
    fallback_brake: bool = True
    turn_in_place: float | None = 1.0
    turn_exit: float = 0.3
    reference_window: int | None = None
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.horizon, int) and 2 <= self.horizon <= 200):
            raise ValueError(f"MPCConfig.horizon must be an integer in [2, 200], got {self.horizon!r}")
        _positive("dt", self.dt)
        _weights("q_x", self.q_x, 3)
        _weights("q_u", self.q_u, 2)
        _weights("q_a", self.q_a, 2)
        _weights("q_n", self.q_n, 3)
        if not (isinstance(self.q_sa, tuple) and 1 <= len(self.q_sa) <= 8):
            raise ValueError(f"MPCConfig.q_sa must be a tuple of 1 to 8 priorities, got {self.q_sa!r}")
        _weights("q_sa", self.q_sa, len(self.q_sa))
        for name in ("v_max", "w_max", "a_max", "alpha_max", "tol", "constraint_tol", "solve_budget_ms"):
            _positive(name, getattr(self, name), allow_none=True)
        if self.v_min is not None and not (math.isfinite(self.v_min) and self.v_min <= 0):
            raise ValueError(f"MPCConfig.v_min must be a finite number <= 0 m/s, got {self.v_min!r}")
        if not (isinstance(self.box_margin, (int, float)) and 0 <= self.box_margin < 1):
            raise ValueError(f"MPCConfig.box_margin must be in [0, 1) m, got {self.box_margin!r}")
        if self.solver not in BACKENDS:
            raise ValueError(f"MPCConfig.solver must be one of {sorted(BACKENDS)}, got {self.solver!r}")
        for name in ("max_iter", "max_outer_iter"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"MPCConfig.{name} must be an integer >= 1, got {v!r}")
        _positive("turn_in_place", self.turn_in_place, allow_none=True)
        if not (isinstance(self.turn_exit, (int, float)) and 0 <= self.turn_exit < math.pi):
            raise ValueError(f"MPCConfig.turn_exit must be in [0, pi) rad, got {self.turn_exit!r}")
        if self.turn_in_place is not None and self.turn_exit >= self.turn_in_place:
            raise ValueError(
                f"MPCConfig.turn_exit must be below turn_in_place ({self.turn_in_place!r} rad), got {self.turn_exit!r}"
            )
        if self.pose_filter is not None and not isinstance(self.pose_filter, PoseFilterConfig):
            raise ValueError(f"MPCConfig.pose_filter must be a PoseFilterConfig or None, got {self.pose_filter!r}")
        if not isinstance(self.monitor, MonitorConfig):
            raise ValueError(f"MPCConfig.monitor must be a MonitorConfig, got {self.monitor!r}")
        _positive("excursion_stop", self.excursion_stop, allow_none=True)
        _positive("traction_probe", self.traction_probe, allow_none=True)
        if not (isinstance(self.traction_floor, (int, float)) and 0 < self.traction_floor <= 1):
            raise ValueError(f"MPCConfig.traction_floor must be in (0, 1], got {self.traction_floor!r}")
        if not (isinstance(self.traction_recovery, (int, float)) and math.isfinite(self.traction_recovery)
                and self.traction_recovery >= 0):
            raise ValueError(f"MPCConfig.traction_recovery must be a finite number >= 0, got {self.traction_recovery!r}")
        for name in ("derate_floor", "residual_floor", "residual_yaw_floor"):
            v = getattr(self, name)
            if v is None and name == "residual_yaw_floor":
                continue
            if not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise ValueError(f"MPCConfig.{name} must be in [0, 1], got {v!r}")
        if not (isinstance(self.residual_free, (int, float)) and math.isfinite(self.residual_free)
                and self.residual_free >= 0):
            raise ValueError(f"MPCConfig.residual_free must be a finite number >= 0 m/s, got {self.residual_free!r}")
        if self.residual_stop is not None and not (
            isinstance(self.residual_stop, (int, float)) and math.isfinite(self.residual_stop)
            and self.residual_stop > self.residual_free
        ):
            raise ValueError(
                f"MPCConfig.residual_stop must be None or a finite number above residual_free "
                f"({self.residual_free!r} m/s), got {self.residual_stop!r}"
            )
        if self.reference_window is not None and not (
            isinstance(self.reference_window, int) and self.reference_window >= 1
        ):
            raise ValueError(f"MPCConfig.reference_window must be an integer >= 1 or None, got {self.reference_window!r}")

    def replace(self, **changes) -> MPCConfig:
        """A copy with some fields changed (validated again)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update(changes)
        return MPCConfig(**values)

    def limits(self, robot: RobotParams) -> InputLimits:
        """Resolve the input and rate bounds against the robot's parameters."""
        rim = robot.wheel_speed_max * robot.wheel_radius  # [m/s] top wheel rim speed
        half_track = 0.5 * robot.track
        w_max = self.w_max if self.w_max is not None else min(robot.w_max, 0.4 * rim / half_track)
        v_max = self.v_max if self.v_max is not None else min(robot.v_max, rim - w_max * half_track)
        v_min = self.v_min if self.v_min is not None else -0.25 * v_max
        a_max = self.a_max if self.a_max is not None else robot.a_max
        alpha_max = self.alpha_max if self.alpha_max is not None else robot.alpha_max
        if w_max * self.dt / 2 > SINC_HALF_ANGLE_MAX:
            raise ValueError(
                f"w_max * dt / 2 must be <= {SINC_HALF_ANGLE_MAX} rad for the model, got {w_max * self.dt / 2!r}"
            )
        for name, v in (("v_max", v_max), ("w_max", w_max), ("a_max", a_max), ("alpha_max", alpha_max)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"resolved {name} must be positive and finite, got {v!r}")
        return InputLimits(v_min, v_max, w_max, a_max, alpha_max)

    def solver_settings(self) -> SolverSettings:
        return SolverSettings(
            tol=self.tol,
            constraint_tol=self.constraint_tol,
            max_iter=self.max_iter,
            max_outer_iter=self.max_outer_iter,
            budget_ms=self.solve_budget_ms,
        )


@dataclass(frozen=True)
class InputLimits:
    """Resolved bounds: v in [v_min, v_max] [m/s], |w| <= w_max [rad/s], rates a_max [m/s^2], alpha_max [rad/s^2]."""

    v_min: float
    v_max: float
    w_max: float
    a_max: float
    alpha_max: float

    def lower(self) -> np.ndarray:
        return np.array([self.v_min, -self.w_max])

    def upper(self) -> np.ndarray:
        return np.array([self.v_max, self.w_max])

    def rate(self) -> np.ndarray:
        """(2,) [m/s^2, rad/s^2] rate bounds."""
        return np.array([self.a_max, self.alpha_max])


@dataclass(frozen=True)
class SafeAreaPenalty:
    """The paper's soft safe-area penalty as a :class:`~sanav_mj.control.problem.PositionCost`.

    ``J_SA(p) = prod_n (a_n sum_m [q_n h_nm(p)]_-^2 + (1 - a_n))`` over ``n_slots`` rectangle
    slots, with ``h_n = (px - xmin, py - ymin, xmax - px, ymax - py)`` [m], ``[h]_- = min(0, h)``,
    priority ``q_n`` [1/m] and activity flag ``a_n`` in {0, 1}. An active slot is the paper's
    factor; an inactive slot is the neutral factor 1 (padding: repeating a rectangle instead
    would raise its factor to a power and flatten the penalty near its boundary). Zero
    whenever ``p`` is inside any active rectangle. Parameters per slot: ``xmin, ymin, xmax,
    ymax, q, a`` (6,), slots concatenated.
    """

    n_slots: int

    @property
    def key(self) -> str:
        return f"jsa{self.n_slots}"

    @property
    def n_params(self) -> int:
        return 6 * self.n_slots

    def expr(self, p, theta):
        out = 1
        for n in range(self.n_slots):
            r = theta[6 * n : 6 * n + 6]
            h = cs.vertcat(p[0] - r[0], p[1] - r[1], r[2] - p[0], r[3] - p[1])
            neg = cs.fmin(0, r[4] * h)
            out = out * (r[5] * cs.sumsqr(neg) + (1 - r[5]))
        return out

    @staticmethod
    def value_np(p: np.ndarray, rects: np.ndarray, q: np.ndarray) -> float:
        """NumPy value of the penalty at ``p`` (2,) for active ``rects`` (n, 4) [m], priorities ``q`` (n,)."""
        h = np.stack((p[0] - rects[:, 0], p[1] - rects[:, 1], rects[:, 2] - p[0], rects[:, 3] - p[1]), axis=1)
        neg = np.minimum(0.0, q[:, None] * h)
        return float(np.prod(np.sum(neg * neg, axis=1)))


# --------------------------------------------------------------------------------------
# Corridor chain: safe areas and the bridge boxes between consecutive ones


def box_intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection of boxes ``xmin, ymin, xmax, ymax`` (..., 4); empty when min > max."""
    return np.concatenate((np.maximum(a[..., :2], b[..., :2]), np.minimum(a[..., 2:], b[..., 2:])), axis=-1)


def shrink_box(box: np.ndarray, margin: float) -> np.ndarray:
    """Shrink boxes (..., 4) by ``margin`` [m] per side, at most a quarter of each width."""
    box = np.asarray(box, dtype=float)
    w = box[..., 2:] - box[..., :2]
    m = np.minimum(margin, 0.25 * np.maximum(w, 0.0))
    return np.concatenate((box[..., :2] + m, box[..., 2:] - m), axis=-1)


def bridge_box(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """A convex box inside ``a ∪ b`` whose intersections with ``a`` and with ``b`` have positive area.

    If the rectangles overlap with positive area the bridge is their intersection. If they
    only share a boundary segment (a portal), e.g. the vertical segment ``x = c``,
    ``y in [y0, y1]``, the bridge is ``[min(xmin), max(xmax)] x [y0, y1]``: every point of it
    lies in ``a`` (left of c) or ``b`` (right of c) because both contain the band
    ``y in [y0, y1]`` over their whole x extent.

    Args:
        a, b: (4,) [m] rectangles ``xmin, ymin, xmax, ymax``.
        tol: [m] tolerance for touching edges.

    Raises:
        ValueError: when the rectangles do not share a boundary segment of positive length.
    """
    inter = box_intersection(a, b)
    w = inter[2:] - inter[:2]
    if np.all(w > tol):
        return inter
    if abs(w[0]) <= tol and w[1] > tol:  # vertical portal
        return np.array([min(a[0], b[0]), inter[1], max(a[2], b[2]), inter[3]])
    if abs(w[1]) <= tol and w[0] > tol:  # horizontal portal
        return np.array([inter[0], min(a[1], b[1]), inter[2], max(a[3], b[3])])
    raise ValueError(f"safe areas {a.tolist()} and {b.tolist()} share no boundary segment of positive length")


@dataclass(frozen=True)
class CorridorChain:
    """The chain ``R_0, B_01, R_1, B_12, ..., R_{C-1}`` of convex boxes along a corridor.

    Consecutive members intersect with positive area and every member lies inside the union
    of the corridor's safe areas.

    Attributes:
        boxes: (L,) x 4 [m] member boxes, L = 2C - 1.
        rect_pair: (L, 2) int safe-area indices of each member: ``(r, r)`` for a safe area,
            ``(r_i, r_{i+1})`` for a bridge.
        stay: (L, 4) [m] stage box when staying on member j: ``shrink(C_j)``.
        advance: (L, 4) [m] stage box when advancing onto member j: ``shrink(C_{j-1} ∩ C_j)``
            (row 0 unused).
    """

    boxes: np.ndarray
    rect_pair: np.ndarray
    stay: np.ndarray
    advance: np.ndarray

    def __len__(self) -> int:
        return int(self.boxes.shape[0])

    @staticmethod
    def build(areas: SafeAreas, corridor: np.ndarray, margin: float = 0.0) -> CorridorChain:
        """Chain of the corridor ``(C,)`` int indices into ``areas.rects``; boxes shrunk by ``margin`` [m]."""
        rects = np.asarray(areas.rects, dtype=float)
        corridor = np.asarray(corridor, dtype=int).ravel()
        if corridor.size == 0:
            raise ValueError("plan.corridor must hold at least one safe-area index, got an empty array")
        if corridor.min() < 0 or corridor.max() >= len(rects):
            raise ValueError(f"plan.corridor indices must be in [0, {len(rects)}), got {corridor.tolist()}")
        boxes, pairs = [rects[corridor[0]]], [(corridor[0], corridor[0])]
        for i, j in zip(corridor[:-1], corridor[1:]):
            boxes.append(bridge_box(rects[i], rects[j]))
            pairs.append((i, j))
            boxes.append(rects[j])
            pairs.append((j, j))
        boxes = np.array(boxes)
        stay = shrink_box(boxes, margin)
        adv = np.empty_like(boxes)
        adv[0] = stay[0]
        adv[1:] = shrink_box(box_intersection(boxes[:-1], boxes[1:]), margin)
        return CorridorChain(boxes, np.array(pairs, dtype=int), stay, adv)


def _outside(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Euclidean distance (P, L) [m] from points (P, 2) to boxes (L, 4) (0 inside)."""
    return np.sqrt(_outside_sq(points, boxes))


def _outside_sq(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Squared Euclidean distance (P, L) [m^2] from points (P, 2) to boxes (L, 4) (0 inside)."""
    dx = np.maximum(np.maximum(boxes[None, :, 0] - points[:, :1], points[:, :1] - boxes[None, :, 2]), 0.0)
    dy = np.maximum(np.maximum(boxes[None, :, 1] - points[:, 1:], points[:, 1:] - boxes[None, :, 3]), 0.0)
    return dx * dx + dy * dy


def assign_stages(
    chain: CorridorChain,
    guess: np.ndarray,
    first_candidates: np.ndarray | None = None,
    tol: float = 1e-6,
    reanchor_distance: float = 0.3,
) -> np.ndarray:
    """Monotone assignment of chain members to the stages 0..N of a guessed trajectory.

    Finds ``s`` (N+1,) with ``s(k) - s(k-1)`` in {0, 1} minimising the summed distance of
    each guessed position ``g_k`` outside its stage box (``stay[s(k)]`` if ``s(k) = s(k-1)``,
    else ``advance[s(k)]``; k = 0 uses ``stay[s(0)]``), distances below ``tol`` counting as
    zero; between assignments whose violations differ by less than about 1e-4 m it takes
    the larger ``sum_k s(k)`` (advance as early as the guess allows), so an assignment
    under which the guess is feasible always beats one under which it is not. Dynamic
    programming over (stage, member) restricted to the reachable band, O(N L).

    Args:
        chain: the corridor chain.
        guess: (N+1, 2) [m] guessed positions, ``guess[0]`` the measured one.
        first_candidates: (L,) bool, members allowed for ``s(0)`` (None: all). Ignored when
            ``guess[0]`` is farther than ``reanchor_distance`` [m] from all of them.
        tol: [m] distances below this count as zero.
        reanchor_distance: [m] see ``first_candidates``.

    Returns:
        (N+1,) int chain member per stage.
    """
    n1 = guess.shape[0]
    L = len(chain)
    d2 = _outside_sq(guess, np.concatenate((chain.stay, chain.advance)))
    d2[d2 < tol * tol] = 0.0
    if L <= 62:
        s = _assign_feasible(d2, L, first_candidates, reanchor_distance)
        if s is not None:
            return s
    v = np.sqrt(d2)
    big = 1e7  # [1/m]: violation weight against the progress count (<= (N+1) L)
    idx = np.arange(L, dtype=float)
    c_stay = (v[:, :L] * big - idx).tolist()
    c_adv = (v[:, L:] * big - idx).tolist()
    inf = math.inf
    key = list(c_stay[0])
    if first_candidates is not None and np.min(v[0, :L][first_candidates]) <= reanchor_distance:
        key = [c if ok else inf for c, ok in zip(key, first_candidates.tolist())]
    finite = [j for j in range(L) if key[j] < inf]
    lo, hi = finite[0], finite[-1]
    back = [[False] * L for _ in range(n1)]
    for k in range(1, n1):
        hi_new = min(L - 1, hi + 1)
        row_s, row_a, bk = c_stay[k], c_adv[k], back[k]
        new = [inf] * L
        prev = inf
        for j in range(lo, hi_new + 1):
            cur = key[j]
            st = cur + row_s[j]
            ad = prev + row_a[j]
            if ad < st:
                new[j] = ad
                bk[j] = True
            else:
                new[j] = st
            prev = cur
        key = new
        hi = hi_new
    j = min(range(lo, hi + 1), key=key.__getitem__)
    s = np.empty(n1, dtype=int)
    for k in range(n1 - 1, 0, -1):
        s[k] = j
        if back[k][j]:
            j -= 1
    s[0] = j
    return s


def _assign_feasible(v: np.ndarray, L: int, first_candidates, reanchor_distance: float) -> np.ndarray | None:
    """The assignment of :func:`assign_stages` when one with zero violation exists, else None.

    Among zero-violation assignments the one advancing as early as possible is pointwise
    the largest (if another one advanced at a stage where it did not, it could have too),
    hence the unique maximiser of ``sum_k s(k)`` that the dynamic programme returns. With
    the members as bits of an integer, stage k's feasible members ``R_k`` (a zero-violation
    completion to stage N exists) follow backwards in a few integer operations per stage,
    then the assignment forwards: 5-10x faster than the dynamic programme in Python.

    Args:
        v: (N+1, 2L) [m^2] squared distances of the guessed positions outside each
            member's stay box (first L columns) and advance box (last L), zero below the
            tolerance.
        L: number of members (<= 62).
        first_candidates, reanchor_distance: as in :func:`assign_stages`.
    """
    weights = np.left_shift(np.int64(1), np.arange(L, dtype=np.int64))
    zero = v == 0.0
    stay = (zero[:, :L] @ weights).tolist()
    adv = (zero[:, L:] @ weights).tolist()
    n1 = len(stay)
    reach = [0] * n1
    r = stay[-1]
    reach[-1] = r
    for k in range(n1 - 2, -1, -1):
        # member j at stage k continues by staying on j (stay box of k+1) or advancing to j+1
        r = (stay[k + 1] & r) | ((adv[k + 1] & r) >> 1)
        reach[k] = r
    first = stay[0] & reach[0]
    if first_candidates is not None and np.min(v[0, :L][first_candidates]) <= reanchor_distance**2:
        first &= int(first_candidates.astype(np.int64) @ weights)
    if first == 0:
        return None
    s = np.empty(n1, dtype=int)
    j = first.bit_length() - 1
    s[0] = j
    for k in range(1, n1):
        if (adv[k] >> (j + 1)) & (reach[k] >> (j + 1)) & 1:
            j += 1
        s[k] = j
    return s


def stage_boxes(chain: CorridorChain, s: np.ndarray) -> np.ndarray:
    """Stage boxes (N+1, 4) [m] of an assignment ``s`` (N+1,): ``shrink(C_{s(k-1)} ∩ C_{s(k)})``."""
    out = chain.stay[s].copy()
    adv = np.flatnonzero(np.diff(s) > 0) + 1
    out[adv] = chain.advance[s[adv]]
    return out


def box_slack(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Smallest slack ``b - a^T p`` [m] of each point (K, 2) in its box (K, 4); negative outside."""
    return np.min(np.concatenate((points - boxes[:, :2], boxes[:, 2:] - points), axis=1), axis=1)


def _resample(ref: Reference, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference states (K', 3), inputs (K', 2) and areas (K',) resampled to period ``dt`` [s].

    States and inputs are interpolated linearly in time; each new sample takes the area of
    the nearest original sample.
    """
    k = len(ref)
    if abs(ref.dt - dt) <= 1e-9 * dt:
        return np.asarray(ref.states, float), np.asarray(ref.inputs, float), np.asarray(ref.area, int)
    t = np.arange(k) * ref.dt
    tn = np.arange(0.0, t[-1] + 1e-9, dt)
    states = np.stack([np.interp(tn, t, ref.states[:, i]) for i in range(3)], axis=1)
    inputs = np.stack([np.interp(tn, t, ref.inputs[:, i]) for i in range(2)], axis=1)
    area = np.asarray(ref.area, int)[np.minimum(np.rint(tn / ref.dt).astype(int), k - 1)]
    return states, inputs, area


@dataclass
class _Plan:
    """The active input plan: inputs (N, 2), the next index to apply, multipliers to reuse, braking or not."""

    u: np.ndarray
    next: int
    y: np.ndarray | None = None
    y_z: np.ndarray | None = None
    brake: bool = False


@dataclass(frozen=True)
class StepInfo:
    """The problem data of the last step (for inspection, recording and tests).

    Attributes:
        assignment: (N+1,) int chain member of each stage.
        boxes: (N+1, 4) [m] stage boxes as imposed (shrunk, relaxed); row 0 is the box of
            the measured position (not a constraint).
        guess: (N, 2) [m/s, rad/s] warm-start inputs (the shifted previous plan).
        guess_states: (N+1, 3) [m, m, rad] the warm start rolled out from the measured state.
        x_ref: (N+1, 3) [m, m, rad] reference states over the horizon.
        u_ref: (N, 2) [m/s, rad/s] reference inputs.
        u_prev: (2,) [m/s, rad/s] previously applied input.
        input_lower, input_upper: (N, 2) input bounds including the rate bound of u_0 and
            the terminal stop.
        rate_step: (2,) [m/s, rad/s] largest change of each input per step.
    """

    assignment: np.ndarray
    boxes: np.ndarray
    guess: np.ndarray
    guess_states: np.ndarray
    x_ref: np.ndarray
    u_ref: np.ndarray
    u_prev: np.ndarray
    input_lower: np.ndarray
    input_upper: np.ndarray
    rate_step: np.ndarray


@dataclass
class SAMPCStats:
    """Counters of one episode: steps per status and failures."""

    counts: dict[str, int] = field(default_factory=dict)

    @property
    def failures(self) -> int:
        """Steps whose command came from a fallback."""
        return sum(v for k, v in self.counts.items() if k.startswith("fallback"))


class SAMPC:
    """Safe-area MPC controller (the paper's Sec. III-D/E) implementing the Controller protocol.

    Each step: update the actuation monitor with the measured velocity, filter the measured
    pose with the measured velocity, predict the state
    at which the new command takes effect (latency compensation), find the progress along
    the reference, build the stage boxes, bound the speed by the excursion and the
    tracking residual, solve the NLP (:mod:`sanav_mj.control.problem`) warm-started from the
    shifted previous plan, check the result, apply the first input (or a fallback).

    **Stage boxes.** The corridor ``c_0..c_{C-1}`` gives the chain ``R_0, B_01, R_1, ...``
    (:class:`CorridorChain`) where ``B_ij`` is a bridge box inside ``R_i ∪ R_j`` crossing
    their common portal; consecutive members intersect with positive area. A monotone
    assignment ``s(k)``, ``s(k) - s(k-1) in {0, 1}``, of members to stages gives the stage sets
    ``S_k = C_{s(k-1)} ∩ C_{s(k)}`` (``S_k = C_{s(k)}`` when ``s`` stays); the constraint
    ``A_k p_k <= b_k`` is ``p_k in shrink(S_k)`` for k = 1..N, each box shrunk by
    ``box_margin`` (at most a quarter of its width). ``s`` is chosen by
    :func:`assign_stages` for the guessed trajectory (the shifted previous plan rolled out
    from the measured state): the assignment under which the guess violates the boxes
    least, advancing as early as it allows.

    **Targets beyond the assigned area.** A stage whose reference sample lies in a corridor
    area *ahead* of the stage's chain member cannot reach it; its position target is the
    reference sample projected onto the central half of the exit region of the member,
    ``shrink(C_{s(k)} ∩ C_{s(k)+1})``, and its yaw target the bearing from the robot to that
    point (when it is more than 2 cm away). Without this the far reference pulls the plan
    against the nearest wall of the current area, which in a narrow passage need not touch
    the portal to the next one: the plan stops at the wall, the assignment never advances
    and the robot stalls (seen on ``v_shape``, where the corridor threads 5-15 cm slivers).
    With it the plan heads for the portal, the guess enters the intersection and the
    assignment advances next step. The reference *inputs* of such stages are zero: the
    target stands still, and the reference's own speed there (it belongs to a sample beyond
    the portal) made the optimal plan drive through the target and out of the thin
    intersection, so the guess never fitted the next member and the assignment never
    advanced; the plan then kept postponing its motion and the robot stalled for good
    (4 of 100 generated clutter maps, e.g. a 10 cm portal entered at right angles).

    **Implied input bounds.** The rate bounds and the terminal stop imply simple bounds on
    each input: ``|u_k - u_prev| <= (k + 1) rate_step`` (reachable from the previous input)
    and ``|v_k| <= (N - 1 - k) a_max dt`` (able to stop by the last stage). They are passed
    as variable bounds together with the input bounds. They remove no feasible plan (every
    plan satisfying the rate bounds and the terminal stop satisfies them), so the problem
    and its optimum are unchanged; but PANOC/PANTR handle variable bounds by projection,
    exactly and at no cost, whereas the rate rows go through the augmented Lagrangian. In
    cruise every plan brakes to its terminal stop at the rate bound over its last stages,
    and after a standstill it accelerates at it: with the implied bounds those active rate
    rows no longer need multipliers. Measured on the MuJoCo step time (five scenarios x 10
    seeds, CPU): PANTR mean -16 %, 99th percentile -18 %; PANOC mean -37 %, 99th
    percentile -19 % (docs/benchmarks.md).

    **Safety between samples.** ``p_k in S_k ⊂ C_{s(k)}`` and ``p_{k+1} in S_{k+1} ⊂ C_{s(k)}``,
    so the chord ``[p_k, p_{k+1}]`` lies in the convex member ``C_{s(k)}``, which lies in the
    union of safe areas. The nominal robot drives an arc, not the chord; the arc stays within
    ``|v w| dt^2 / 8`` of it (:func:`~sanav_mj.control.unicycle.arc_chord_deviation`, 1.5 mm
    at 0.6 m/s and 2 rad/s with dt = 0.1 s), which the obstacle inflation margin of the
    safe-area map has to cover. For k = 0 the position is the measurement, a parameter: if
    it lies within ``S_0 = shrink(C_{s(0)})`` the argument holds from the first sample on.

    **Measured position outside its box** (noise, slip, mismatch): p_0 cannot be constrained,
    and requiring ``p_1`` inside a box that a robot at rest cannot reach in one step would
    make the problem infeasible (a unicycle needs time to move sideways). Each side of the
    boxes of stages 1..N is widened by the amount p_0 lies beyond that side of its own box
    ``S_0``: the plan may not go further out than the robot already is, staying put is
    feasible for a robot at rest, and J_SA (zero inside the corridor's areas, which are
    shrunk by the same margin) together with the tracking cost pulls the plan back in. The
    widening is re-measured every step, so it vanishes once the robot is back inside; it
    never exceeds the measured excursion, which lies inside the real safe area as long as
    it is smaller than ``box_margin``. Because an excursion is evidence that the model is
    wrong, the speed bound of every stage is lowered at the same time, to
    ``v_max max(derate_floor, 1 - e / excursion_stop)`` for an excursion ``e`` (reached at
    the rate bound from the previous input, so the bounds stay consistent): the further
    out, the slower, which shortens the stopping distance and the distance driven on a
    wrong model before the next measurement.

    **Derating by tracking residual.** Slip (low friction), a saturated actuator (small
    torque limit) or a delay beyond what the monitor identifies make the measured body
    velocity differ from the identified response to the sent commands. The monitor's RMS
    residual over its forgetting window lowers the speed bound like an excursion does
    (``MPCConfig.residual_stop``): a plant that does not do what it is told is driven
    slowly, down to ``residual_floor v_max``, so that its braking distance and the error
    it accumulates per period shrink with the speed.

    The same fraction lowers the yaw-rate bound (not below ``residual_yaw_floor w_max``):
    at low friction with an over-turning plant the loop weaves at up to +-2 rad/s while
    driving at 0.8 m/s, asking for more lateral acceleration than the floor gives; derating
    both inputs cuts the asked-for ``v w`` with the square of the fraction.

    **Traction limit.** The residual measures the tracking error, not the braking
    capability: on a floor with 0.36-0.49 m/s^2 of grip (friction 0.05) the identified
    speed gain drops to its clamp, absorbs the slow ramp, and the residual stays near
    0.04 m/s while the commanded speed runs 0.5 m/s ahead of the measured one; the robot
    reached 0.93 m/s with the model braking at 1.5 m/s^2 and slid out of its corridor at a
    corner. The monitor flags slip when the measured speed stays more than
    ``monitor.slip_gap`` from the commands of *every* candidate delay (a delayed plant with
    grip reaches the command of its delay, so it is not mistaken for a slipping one), and
    keeps the largest speed change per period the body achieved (a lower bound of the grip;
    periods of fast turning excluded). While slip is seen, the rate bound of the speed
    becomes ``traction_probe`` times that grip (not below ``traction_floor a_max``); every
    bound derived from ``a_max`` follows, per solve: the rate constraints, the speed bounds
    implied by the terminal stop (so each plan can stop inside its stage boxes at the
    grip the plant showed) and the braking fallback. Without slip the bound recovers by
    ``traction_recovery`` per step. In the envelope and the nominal runs the flag is never
    raised, so nothing changes there (every run bit-identical); a plant whose gain error
    exceeds about 15 % at speed is flagged like a slipping one (docs/robustness.md).

    **Pose filter.** Before anything else the measured pose is fused with the measured body
    velocity by a :class:`~sanav_mj.control.monitor.PoseFilter` (an EKF whose measurement
    noise is identified online from the lag-one covariance of the measurement increments
    against the odometry, so slip is not taken for noise). A noise-free pose (nominal, and
    on a slipping floor) is returned exactly, so the nominal controller is unchanged; under
    white noise of 5-20 cm the estimate's error is a third to a seventh of the
    measurement's (synthetic check). A real jump (relocalisation) is followed after the
    filter's consistency restart.

    **Latency compensation.** A plant that applies each command ``d`` control steps late
    (actuator and communication latency) makes an MPC that plans from the measured state
    weave: its first input takes effect ``d dt`` later than it assumes. The controller knows
    the commands it sent; the :class:`~sanav_mj.control.monitor.ActuationMonitor` identifies
    ``d`` (0..``monitor.max_delay``) and the gains ``(g_v, g_w)`` online from the measured body
    velocity (least squares with forgetting, per candidate delay; smallest residual wins,
    with hysteresis). Each step rolls the measured pose forward through the ``d`` commands
    already sent and not yet applied (scaled by the gains) and poses the problem from that
    predicted state, with the last sent input as ``u_prev``. The stage-0 position of every
    argument below is then that prediction; the positions between the measurement and it
    were planned by the earlier solves that sent those commands. Assumed: the delay is an
    integer number of periods and constant over the forgetting horizon (about 2 s); a wrong
    estimate shows up as tracking error like any other mismatch.

    **Recursive feasibility** (nominal model, no disturbance, converged solves, the default
    ``terminal_stop``): let ``u*`` be the previous plan with positions ``p*_0..p*_N`` and
    assignment ``s*``. The next measured state is ``x*_1``. The shifted plan
    ``(u*_1, ..., u*_{N-1}, (0, w'))``, with ``w'`` the last yaw rate brought towards 0 by one
    rate step, satisfies the input bounds, the rate bounds (same increments; ``u*_1 - u*_0``
    against the new previous input ``u*_0``) and the terminal stop (its last speed is 0). Its
    positions are ``p*_1..p*_N, p*_N`` (``v*_{N-1} = 0``, so the last step only turns), which
    satisfy the boxes of the shifted assignment ``s*(1..N), s*(N)``: that assignment has zero
    violation, so the minimiser chosen by :func:`assign_stages` also has zero violation and
    the shifted plan is feasible for the new problem. Without ``terminal_stop`` the last
    shifted position may leave the last box and feasibility is not guaranteed. With model
    mismatch, noise or an inexact solve none of this is guaranteed; the relaxation above
    and the fallback cover those cases.

    **Fallback.** A solve is rejected when the back-end does not converge (unless
    ``accept_inexact`` and the iterate satisfies every constraint), returns non-finite
    values, or the rolled-out plan violates a constraint by more than 10x
    ``constraint_tol``. With ``fallback_brake`` (default) the rest of the previous plan
    (the warm start, ending at rest) is then rolled out from the *current* state and
    checked against the current problem (:meth:`_shift_fits`): input and rate bounds as
    posed (with the speed and yaw-rate derating when ``fallback_derated``), positions
    inside their stage boxes grown back by
    ``box_margin``, i.e. inside the chain members and so inside the safe areas. If it
    passes, its first input is applied (status ``"fallback_shift"``; without mismatch this
    is the recursive-feasibility case). Accepting the shift up to the margin matters in
    slivers a few cm wide: braking there instead (a 5 % geometry error was enough to make
    the shifted plan miss a 1 cm wide stage box) left the robot stopped in a place from
    which the MPC did not restart (7 of 8 ``v_shape`` runs at wheel radius 1.05 / track
    0.9, docs/robustness.md). Otherwise the robot
    brakes (status ``"fallback_stop"``, re-planned every step from the current state): the
    speed goes to zero at the rate bound while the yaw rate ramps at its rate bound towards
    the one of five candidates (0, +-w_max/2, +-w_max) whose braking path stays deepest
    inside the corridor's chain members (:meth:`brake_plan`). It never replays an old plan
    that the current state contradicts: under mismatch that open-loop replay at speed was
    the last step before most collisions (docs/robustness.md). With ``fallback_brake=False``
    the previous plan is replayed open loop until it runs out, then the robot brakes
    straight. Commands are always finite.

    **What the mismatch handling assumes, and what it does not give.** Nothing above is a
    guarantee under mismatch: the stage boxes constrain the *model's* prediction. What the
    mechanisms give is that model error is met by going slower (excursion derating),
    planning from where the robot will be when the command acts (latency compensation) and
    stopping instead of replaying (fallback). A plant that cannot follow the braking the
    model assumes (``a_max``; e.g. at very low friction or a small torque limit) before
    the monitor has seen it slip (see "Traction limit"), or a
    position error larger than ``box_margin`` plus the map's inflation margin within one
    period can still collide; docs/robustness.md gives the measured envelope.

    **Opening turn.** With a random initial yaw the robot often starts facing away from the
    reference. Posed to the MPC, that start is the hardest problem of the episode: the
    optimal plan turns on the spot at the yaw-acceleration bound with most rate constraints
    active, and PANOC needed 1000-1900 iterations (20-57 ms) for it. As is standard practice,
    the controller instead starts the episode with a dedicated turn on the spot when the
    heading error to the reference (at the robot's progress index) exceeds
    ``turn_in_place``, until it is at most ``turn_exit``; then the MPC takes over, warm
    started with the rest of the turn. Each turn step plans ``v = 0`` and the time-optimal
    rest-to-rest yaw-rate profile within the input and rate bounds (:meth:`_turn_plan`), so
    every constraint of the MPC problem holds for that plan: the position stays where it
    is, hence inside the stage box of the measured position, the plan ends at rest
    (terminal stop), and it is a feasible shifted plan for the MPC's first problem. The
    commands have status ``"turn"`` and the same prediction, rectangle ids and margins as
    an MPC step.

    Attributes:
        name: ``"sa-mpc"``.
        dt: [s] control period.
        needs_ranges: False.
        config, robot, limits: settings and resolved input limits.
        chain: the corridor chain.
        monitor: the :class:`~sanav_mj.control.monitor.ActuationMonitor` (identified delay,
            gains and tracking residual of the current episode).
        pose_filter: the :class:`~sanav_mj.control.monitor.PoseFilter`, or None.
        stats: per-episode status counts (``stats.failures`` counts fallback steps).
        last: :class:`StepInfo` of the last step that reached the solver stage, or None.
        last_failure_reason: why the last fallback was taken, or None.
        accel: [m/s^2] the current rate bound of the speed: ``limits.a_max``, lowered while
            the monitor sees slip (see "Traction limit").
        build_s: [s] time spent building this controller (including the solver back-end).
    """

    name = "sa-mpc"
    needs_ranges = False

    def __init__(
        self,
        robot: RobotParams,
        areas: SafeAreas,
        plan: Plan,
        config: MPCConfig = MPCConfig(),
        *,
        failure_injector: Callable[[int], bool] | None = None,
    ):
        """Build the controller (and its solver, once per process).

        Args:
            robot: nominal robot parameters (input and rate bounds by default).
            areas: the safe areas.
            plan: a successful plan (corridor and reference).
            config: settings.
            failure_injector: test hook called with the step index; returning True makes
                that step's solve count as failed.

        Raises:
            ValueError: the plan failed or has no reference, or the corridor is not a chain
                of adjacent safe areas.
        """
        t0 = time.perf_counter()
        if not plan.ok or plan.reference is None:
            raise ValueError(f"plan must be successful with a reference, got ok={plan.ok} reason={plan.reason!r}")
        if len(plan.reference) < 1:
            raise ValueError("plan.reference must hold at least one sample")
        self.config = config
        self.robot = robot
        self.dt = float(config.dt)
        self.limits = config.limits(robot)
        self.areas = areas
        self._rects = np.asarray(areas.rects, dtype=float)
        self.plan = plan
        self.chain = CorridorChain.build(areas, plan.corridor, config.box_margin)
        self.ref_states, self.ref_inputs, ref_area = _resample(plan.reference, self.dt)
        # chain index (2 x corridor position) of each reference sample's area, -1 if off the corridor
        pos = {int(a): 2 * i for i, a in enumerate(np.asarray(plan.corridor, int))}
        self._ref_chain = np.array([pos.get(int(a), -1) for a in ref_area], dtype=int)
        self.failure_injector = failure_injector
        self.monitor = ActuationMonitor(config.monitor)
        self.pose_filter = PoseFilter(self.dt, config.pose_filter) if config.pose_filter is not None else None
        n = config.horizon
        self.N = n
        self.penalty = SafeAreaPenalty(len(config.q_sa))
        self.ocp = build_tracking_ocp(n, self.dt, self.penalty, position_constraints=True)
        cache = Path(config.cache_dir) if config.cache_dir else None
        self.backend = get_backend(self.ocp, config.solver, config.solver_settings(), cache)
        # Constant parts of the problem data (the speed's rate bound may be lowered per
        # episode by the traction estimate, see "Traction limit" in the class doc).
        self._set_accel(self.limits.a_max)
        self._weights = tuple(np.asarray(w, float) for w in (config.q_x, config.q_u, config.q_a, config.q_n))
        self._q_sa = np.asarray(config.q_sa, float)
        self._check_tol = 10.0 * config.constraint_tol + 1e-9
        self._sa_cache: dict[tuple[int, int], np.ndarray] = {}
        sl = self.ocp.layout.slices()
        self._p_buf = np.zeros(self.ocp.layout.size)
        for name, w in zip(("q_x", "q_u", "q_a", "q_n"), self._weights):
            self._p_buf[sl[name]] = w
        self._p_slices = sl
        self.reset(np.array([*self.ref_states[0, :2], self.ref_states[0, 2]]))
        self.build_s = time.perf_counter() - t0

    def _set_accel(self, a_max: float) -> None:
        """Set the rate bound of the speed to ``a_max`` [m/s^2] and everything derived from it
        (input bounds implied by the terminal stop, reach from the previous input, rate
        constraints); the yaw-rate bound stays ``limits.alpha_max``."""
        n = self.N
        self.accel = float(a_max)
        self._z_lb = np.tile(self.limits.lower(), n)
        self._z_ub = np.tile(self.limits.upper(), n)
        self._rate_step = np.array([self.accel, self.limits.alpha_max]) * self.dt
        if self.config.terminal_stop:
            # v_{N-1} = 0 and the rate bound imply |v_k| <= (N-1-k) a dt: implied bounds
            # (see "Implied input bounds" in the class doc)
            stop = (n - 1 - np.arange(n)) * self._rate_step[0]
            self._z_lb[0::2] = np.maximum(self._z_lb[0::2], -stop)
            self._z_ub[0::2] = np.minimum(self._z_ub[0::2], stop)
        # |u_k - u_prev| <= (k + 1) * rate step, implied by the rate bounds from u_prev
        self._reach = np.outer(np.arange(1, n + 1), self._rate_step).ravel()
        self._rate_lb = np.tile(-self._rate_step, n - 1)
        self._rate_ub = np.tile(self._rate_step, n - 1)

    def traction_accel(self) -> float:
        """[m/s^2] the next rate bound of the speed from the monitor's traction evidence.

        While the monitor sees the plant slip (``monitor.slipping``): ``traction_probe``
        times the largest speed change per period measured this episode (``peak_dv``, a
        lower bound of the grip) over ``dt``, not below ``traction_floor a_max``. Otherwise
        the current bound recovers by the factor ``1 + traction_recovery`` per step up to
        ``limits.a_max``; it is ``limits.a_max`` as long as no slip was seen (see "Traction
        limit" in the class doc).
        """
        cfg = self.config
        a_max = self.limits.a_max
        if cfg.traction_probe is None:
            return a_max
        if self.monitor.slipping:
            est = cfg.traction_probe * self.monitor.peak_dv / self.dt
            return float(min(a_max, max(est, cfg.traction_floor * a_max)))
        return float(min(a_max, self.accel * (1.0 + cfg.traction_recovery)))

    # ---------------------------------------------------------------- episode state

    def reset(self, pose: np.ndarray) -> None:
        """Start a new episode at ``pose`` (3,) [m, m, rad]; the robot is assumed at rest."""
        pose = np.asarray(pose, dtype=float).reshape(3)
        self._u_prev = np.zeros(2)
        self.monitor.reset()
        if self.accel != self.limits.a_max:
            self._set_accel(self.limits.a_max)
        if self.pose_filter is not None:
            self.pose_filter.reset()
        self._active: _Plan | None = None
        self._s_prev: np.ndarray | None = None
        self._step_index = 0
        self._turning = self.config.turn_in_place is not None
        self.stats = SAMPCStats()
        self.last_failure_reason: str | None = None
        self.last: StepInfo | None = None
        w = min(len(self.ref_states), 2 * self.N + 1)
        d = np.hypot(*(self.ref_states[:w, :2] - pose[:2]).T)
        self._ref_index = int(np.argmin(d))

    # ---------------------------------------------------------------- pieces of a step

    def _progress(self, pos: np.ndarray) -> int:
        """Index of the reference sample nearest ``pos`` in the window ahead of the last one."""
        k = len(self.ref_states)
        win = self.config.reference_window or self.N
        lo = self._ref_index
        hi = min(k, lo + win + 1)
        seg = self.ref_states[lo:hi, :2] - pos
        i = lo + int(np.argmin(np.einsum("ij,ij->i", seg, seg)))
        self._ref_index = i
        return i

    def horizon_reference(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference states (N+1, 3) and inputs (N, 2) for the horizon starting at ``pose``.

        The samples start at the progress index; past the end the last state is held with
        zero inputs. The yaw is shifted by a multiple of 2 pi so that its first sample is
        within pi of the measured yaw (the reference yaw is unwrapped, the measured one is
        not), which makes the yaw error the wrapped one.
        """
        i = self._progress(pose[:2])
        k = len(self.ref_states)
        idx = np.minimum(np.arange(i, i + self.N + 1), k - 1)
        xr = self.ref_states[idx].copy()
        ur = self.ref_inputs[idx[:-1]].copy()
        ur[idx[:-1] >= k - 1] = 0.0
        xr[:, 2] += 2 * np.pi * np.round((pose[2] - xr[0, 2]) / (2 * np.pi))
        self._horizon_idx = idx
        return xr, ur

    def _exit_targets(
        self, xr: np.ndarray, ur: np.ndarray, s: np.ndarray, p0: np.ndarray, yaw0: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reference states (N+1, 3) and inputs (N, 2) pulled into reach: see "Targets beyond
        the assigned area" in the class doc."""
        ahead = self._ref_chain[self._horizon_idx] > s
        ahead &= s + 1 < len(self.chain)
        if not ahead.any():
            return xr, ur
        ur = ur.copy()
        ur[ahead[1:]] = 0.0  # a target that stands still: no reference motion into it
        out = xr.copy()
        k = np.flatnonzero(ahead)
        box = self.chain.advance[s[k] + 1]
        inner = 0.25 * (box[:, 2:] - box[:, :2])  # aim at the central half, not the edge
        tgt = np.clip(out[k, :2], box[:, :2] + inner, box[:, 2:] - inner)
        out[k, :2] = tgt
        d = tgt - p0
        far = np.hypot(d[:, 0], d[:, 1]) > 0.02
        if far.any():
            bearing = np.arctan2(d[far, 1], d[far, 0])
            out[k[far], 2] = yaw0 + (bearing - yaw0 + np.pi) % (2 * np.pi) - np.pi
        return out, ur

    def _guess_inputs(self) -> np.ndarray:
        """(N, 2) warm start: the rest of the active plan, then braking towards (0, 0)."""
        if self._active is None:
            return np.zeros((self.N, 2))
        return shift_inputs(self._active.u, self._active.next, self.N, self._rate_step, self._u_prev)

    def _first_candidates(self) -> np.ndarray | None:
        """Members allowed for stage 0: within two of the previous anchor (None at a cold start)."""
        if self._s_prev is None:
            return None
        L = len(self.chain)
        anchor = int(self._s_prev[1])
        cand = np.zeros(L, dtype=bool)
        cand[max(0, anchor - 2) : min(L, anchor + 3)] = True
        return cand

    def _relaxed_boxes(self, boxes: np.ndarray, p0: np.ndarray) -> tuple[np.ndarray, float]:
        """Widen each side of the boxes of stages 1..N by how far p0 lies beyond that side of the stage-0 box.

        Returns the boxes (N+1, 4) [m] and the excursion [m]: the distance of ``p0`` (2,)
        outside the stage-0 box (0 inside).
        """
        below = np.maximum(boxes[0, :2] - p0, 0.0)
        above = np.maximum(p0 - boxes[0, 2:], 0.0)
        if not (below.any() or above.any()):
            return boxes, 0.0
        out = boxes.copy()
        out[1:, :2] -= below
        out[1:, 2:] += above
        return out, float(np.hypot(*(below + above)))

    def _sa_params(self, s: np.ndarray) -> np.ndarray:
        """J_SA slot parameters (6 * slots,): the distinct safe areas of members s(0)..s(N), in order."""
        key = (int(s[0]), int(s[-1]))
        theta = self._sa_cache.get(key)
        if theta is None:
            slots = self.penalty.n_slots
            ids: list[int] = []
            for pair in self.chain.rect_pair[key[0] : key[1] + 1]:
                for r in pair:
                    if int(r) not in ids:
                        ids.append(int(r))
            ids = ids[:slots]
            theta = np.zeros((slots, 6))
            theta[: len(ids), :4] = shrink_box(self._rects[ids], self.config.box_margin)
            theta[: len(ids), 4] = self._q_sa[: len(ids)]
            theta[: len(ids), 5] = 1.0
            theta[len(ids) :, 2:4] = 1.0  # inactive slots: any finite rectangle
            theta = theta.ravel()
            self._sa_cache[key] = theta
        return theta

    def _rect_ids(self, s: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """Safe-area index for each stage: of the member's area(s), the one containing the position best."""
        pair = self.chain.rect_pair[s]
        slack_a = box_slack(pos, self._rects[pair[:, 0]])
        slack_b = box_slack(pos, self._rects[pair[:, 1]])
        return np.where(slack_a >= slack_b, pair[:, 0], pair[:, 1])

    def _violation(self, z: np.ndarray, xs: np.ndarray, g_lb: np.ndarray, g_ub: np.ndarray, z_lb, z_ub) -> float:
        """Largest violation of any constraint by the plan ``z`` with rolled-out states ``xs``."""
        u = z.reshape(-1, 2)
        g = np.concatenate((xs[1:, :2].ravel(), np.diff(u, axis=0).ravel()))
        v = max(
            float(np.max(g_lb - g, initial=0.0)),
            float(np.max(g - g_ub, initial=0.0)),
            float(np.max(z_lb - z, initial=0.0)),
            float(np.max(z - z_ub, initial=0.0)),
        )
        return v

    def _shift_fits(self, g_lb, g_ub, z_lb, z_ub, u_guess: np.ndarray, guess: np.ndarray) -> bool:
        """Whether the shifted previous plan ``u_guess`` (N, 2), rolled out from the current
        state as ``guess`` (N+1, 3), may still be followed (see "Fallback" in the class doc).

        Input and rate bounds (as posed, with the derating when ``fallback_derated``) must
        hold within the solver check tolerance; the positions may leave their stage boxes by at most
        ``box_margin``, i.e. they stay inside the unshrunk chain members, which lie in the
        safe areas.
        """
        z = u_guess.ravel()
        g = np.concatenate((guess[1:, :2].ravel(), np.diff(u_guess, axis=0).ravel()))
        tol = np.full(g.shape, self._check_tol)
        tol[: 2 * self.N] += self.config.box_margin
        return bool(
            np.all(g >= g_lb - tol) and np.all(g <= g_ub + tol)
            and np.all(z >= z_lb - self._check_tol) and np.all(z <= z_ub + self._check_tol)
        )

    def _turn_plan(self, err: float) -> np.ndarray:
        """(N, 2) inputs turning on the spot by ``err`` [rad] as fast as the bounds allow.

        ``v = 0`` throughout; the yaw rate starts from the previous one and, stage by stage,
        takes the largest value within the rate and input bounds from which braking at the
        rate bound does not turn past ``err`` (time-optimal rest-to-rest profile of the
        discrete double integrator); it brakes at the rate bound when even that overshoots.
        """
        n = self.N
        dt = self.dt
        a = float(self._rate_step[1])  # [rad/s] largest yaw-rate change per step
        w_max = self.limits.w_max
        sgn = 1.0 if err >= 0 else -1.0
        rem = abs(err)
        w = sgn * float(self._u_prev[1])  # yaw rate towards the target
        out = np.zeros((n, 2))
        for k in range(n):
            # Largest w' >= 0 whose braking run turns at most rem: in units of dt the run
            # turns S(w') = (m + 1) w' - a m (m + 1) / 2 with m = floor(w' / a), continuous
            # and increasing; solve piece by piece.
            budget = rem / dt
            best = 0.0
            m = 0
            while budget > 0:
                cand = (budget + a * m * (m + 1) / 2) / (m + 1)
                if cand < (m + 1) * a:
                    best = cand
                    break
                m += 1
            w = min(max(best, w - a, -w_max), w + a, w_max)
            out[k, 1] = sgn * w
            rem -= w * dt
        return out

    def _turn_step(self, x0: np.ndarray, t0: float, err: float) -> Command:
        """One step of the opening turn on the spot (see "Opening turn" in the class doc)."""
        u = self._turn_plan(err)
        xs = rollout_np(x0, u, self.dt)
        s = assign_stages(self.chain, xs[:, :2], self._first_candidates(), tol=self._check_tol)
        boxes, _ = self._relaxed_boxes(stage_boxes(self.chain, s), x0[:2])
        return self._accept(_Plan(u, 1), xs, s, boxes, x0, t0, "turn")

    # ---------------------------------------------------------------- mismatch handling

    def effective_state(self, pose: np.ndarray) -> np.ndarray:
        """(3,) state at the instant the next command takes effect, from the measured ``pose`` (3,).

        With latency compensation and an identified delay of ``d`` steps, the measured pose is
        rolled forward through the ``d`` commands already sent and not yet applied, scaled by
        the identified gains (see "Latency compensation" in the class doc); else ``pose``.
        """
        if not self.config.latency_compensation or self.monitor.delay == 0:
            return pose
        pending = self.monitor.pending() * self.monitor.gains
        return rollout_np(pose, pending, self.dt)[-1]

    def _send(self, u: np.ndarray) -> tuple[float, float]:
        """The command (v, w) sent for the planned (true) input ``u`` (2,); recorded in the monitor."""
        cmd = np.asarray(u, dtype=float).copy()
        if self.config.gain_compensation:
            cmd = cmd / self.monitor.gains
        cmd = np.clip(np.nan_to_num(cmd), self.limits.lower(), self.limits.upper())
        self.monitor.record(cmd)
        return float(cmd[0]), float(cmd[1])

    def speed_cap(self, excursion: float) -> float:
        """[m/s] speed bound for a position ``excursion`` [m] outside its stage box.

        ``v_max max(derate_floor, 1 - excursion / excursion_stop)``: the further the robot
        has drifted out of its box, the slower it may go (see "Measured position outside its
        box" in the class doc).
        """
        stop = self.config.excursion_stop
        if stop is None or excursion <= 0:
            return self.limits.v_max
        return self.limits.v_max * max(self.config.derate_floor, 1.0 - excursion / stop)

    def residual_cap(self) -> float:
        """[m/s] speed bound from the monitor's velocity-tracking residual (see ``MPCConfig.residual_stop``)."""
        cfg = self.config
        if cfg.residual_stop is None:
            return self.limits.v_max
        r = float(np.hypot(self.monitor.residual[0], self.config.monitor.half_track * self.monitor.residual[1]))
        frac = min(max((r - cfg.residual_free) / (cfg.residual_stop - cfg.residual_free), 0.0), 1.0)
        return self.limits.v_max * (1.0 - (1.0 - cfg.residual_floor) * frac)

    def residual_yaw_cap(self) -> float:
        """[rad/s] yaw-rate bound from the monitor's velocity-tracking residual.

        The same fraction of ``w_max`` as :meth:`residual_cap` takes of ``v_max``, but never
        below ``residual_yaw_floor w_max`` (see "Derating by tracking residual" in the class
        doc); ``w_max`` when ``residual_yaw_floor`` or ``residual_stop`` is None.
        """
        cfg = self.config
        if cfg.residual_yaw_floor is None or cfg.residual_stop is None:
            return self.limits.w_max
        frac = self.residual_cap() / self.limits.v_max
        return self.limits.w_max * max(frac, cfg.residual_yaw_floor)

    def _union_slack(self, points: np.ndarray) -> np.ndarray:
        """(P,) [m] largest slack of each point (P, 2) over the corridor chain's members (negative: outside all)."""
        b = self.chain.boxes
        sl = np.minimum(
            np.minimum(points[:, None, 0] - b[None, :, 0], b[None, :, 2] - points[:, None, 0]),
            np.minimum(points[:, None, 1] - b[None, :, 1], b[None, :, 3] - points[:, None, 1]),
        )
        return sl.max(axis=1)

    def brake_plan(self, x0: np.ndarray) -> np.ndarray:
        """(N, 2) inputs braking at the rate limits, steering to stay inside the corridor.

        The speed goes to zero at the rate bound from the previous input. The yaw rate ramps
        at its rate bound from the previous one towards each of 0, +-w_max / 2 and +-w_max
        (five candidates); each candidate is rolled out from ``x0`` (3,) and scored by the
        smallest slack of its positions in the corridor chain's members (saturated at 5 cm,
        so any candidate that stays 5 cm inside counts as good); the best wins, ties going to
        the first (yaw rate towards 0).
        """
        n = self.N
        a, al = float(self._rate_step[0]), float(self._rate_step[1])
        v0, w0 = float(self._u_prev[0]), float(self._u_prev[1])
        k = np.arange(1, n + 1)
        v = np.sign(v0) * np.maximum(abs(v0) - k * a, 0.0)
        wm = self.limits.w_max
        best, best_score = None, -np.inf
        for target in (0.0, 0.5 * wm, -0.5 * wm, wm, -wm):
            w = w0 + np.clip(target - w0, -k * al, k * al)
            # once stopped, bring the yaw rate back to rest as well
            stopped = np.flatnonzero(v == 0.0)
            if stopped.size:
                j = stopped[0]
                w[j:] = np.sign(w[j - 1] if j > 0 else w0) * np.maximum(
                    abs(w[j - 1] if j > 0 else w0) - np.arange(1, n - j + 1) * al, 0.0
                )
            u = np.stack((v, w), axis=1)
            if not np.all(np.isfinite(x0)):
                return u
            xs = rollout_np(x0, u, self.dt)
            score = min(float(self._union_slack(xs[1:, :2]).min()), 0.05)
            if score > best_score + 1e-9:
                best, best_score = u, score
        return best

    # ---------------------------------------------------------------- the step

    def step(self, obs: Observation) -> Command:
        """Compute the command for the next period from the measured pose (wall time in ``solve_ms``)."""
        t0 = time.perf_counter()
        n = self.N
        k_step = self._step_index
        self._step_index += 1
        x_meas = np.asarray(obs.pose, dtype=float).reshape(3)
        if obs.velocity is not None:
            self.monitor.update(obs.velocity)
            a = self.traction_accel()
            if a != self.accel:
                self._set_accel(a)
        if not np.all(np.isfinite(x_meas)):
            return self._fallback(x_meas, t0, None, None, "bad_measurement")
        if self.pose_filter is not None:
            x_meas = self.pose_filter.update(x_meas, obs.velocity)
        x0 = self.effective_state(x_meas)

        xr, ur = self.horizon_reference(x0)
        if self._turning:
            err = float(xr[0, 2] - x0[2])  # wrapped: the reference yaw is shifted to the measured branch
            limit = self.config.turn_in_place if k_step == 0 else self.config.turn_exit
            if abs(err) > limit:
                return self._turn_step(x0, t0, err)
            self._turning = False
        u_guess = self._guess_inputs()
        guess = rollout_np(x0, u_guess, self.dt)
        s = assign_stages(self.chain, guess[:, :2], self._first_candidates(), tol=self._check_tol)
        boxes = stage_boxes(self.chain, s)
        boxes_c, excursion = self._relaxed_boxes(boxes, x0[:2])
        xr, ur = self._exit_targets(xr, ur, s, x0[:2], float(x0[2]))

        u_prev = np.tile(self._u_prev, n)
        z_ub = np.minimum(self._z_ub, u_prev + self._reach)
        z_lb = np.minimum(np.maximum(self._z_lb, u_prev - self._reach), z_ub)
        z_lb_plain, z_ub_plain = z_lb.copy(), z_ub.copy()
        cap = min(self.speed_cap(excursion), self.residual_cap())
        if cap < self.limits.v_max:
            z_lb = self._derate(z_lb, z_ub, u_prev, 0, cap)
        wcap = self.residual_yaw_cap()
        if wcap < self.limits.w_max:
            z_lb = self._derate(z_lb, z_ub, u_prev, 1, wcap)
        if self.config.fallback_derated:
            z_lb_plain, z_ub_plain = z_lb, z_ub
        g_lb = np.concatenate((boxes_c[1:, :2].ravel(), self._rate_lb))
        g_ub = np.concatenate((boxes_c[1:, 2:].ravel(), self._rate_ub))
        p = self._p_buf.copy()
        sl = self._p_slices
        p[sl["x0"]] = x0
        p[sl["u_prev"]] = self._u_prev
        p[sl["x_ref"]] = xr.ravel()
        p[sl["u_ref"]] = ur.ravel()
        p[sl["extra"]] = self._sa_params(s)
        z0 = np.clip(u_guess.ravel(), z_lb, z_ub)
        self.last = StepInfo(
            s, boxes_c, u_guess, guess, xr, ur, self._u_prev.copy(), z_lb.reshape(n, 2), z_ub.reshape(n, 2), self._rate_step
        )
        problem = (g_lb, g_ub, z_lb_plain, z_ub_plain, u_guess, guess)
        y0 = y_z0 = None
        if self._active is not None and self._active.next == 1 and self._active.y is not None:
            y0 = shift_multipliers(self.ocp, self._active.y, shift_rates=False)
            y_z0 = shift_bound_multipliers(self._active.y_z)

        if self.failure_injector is not None and self.failure_injector(k_step):
            return self._fallback(x0, t0, s, boxes_c, "injected", problem)
        res = self.backend.solve(p, z_lb, z_ub, g_lb, g_ub, z0, y0, y_z0)
        z = res.z
        if not np.all(np.isfinite(z)):
            return self._fallback(x0, t0, s, boxes_c, f"nonfinite:{res.status}", problem)
        xs = rollout_np(x0, z.reshape(n, 2), self.dt)
        viol = self._violation(z, xs, g_lb, g_ub, z_lb, z_ub)
        feasible = viol <= self._check_tol
        if res.converged and feasible:
            status = "ok"
        elif self.config.accept_inexact and feasible:
            status = "inexact"
        else:
            return self._fallback(x0, t0, s, boxes_c, f"rejected:{res.status}:viol={viol:.2e}", problem)
        plan = _Plan(z.reshape(n, 2).copy(), 1, np.asarray(res.y, float), res.y_z)
        return self._accept(plan, xs, s, boxes_c, x0, t0, status)

    def _derate(self, z_lb: np.ndarray, z_ub: np.ndarray, u_prev: np.ndarray, col: int, cap: float) -> np.ndarray:
        """Lower the bound of input ``col`` (0: v [m/s], 1: w [rad/s]) to ``|u| <= cap``, reached at
        the rate bound from ``u_prev`` (2N,) (never asks for more than the rate allows).

        Updates ``z_ub`` (2N,) in place and returns the new ``z_lb`` (2N,), kept <= ``z_ub``.
        """
        sl = slice(col, None, 2)
        z_ub[sl] = np.minimum(z_ub[sl], np.maximum(cap, u_prev[sl] - self._reach[sl]))
        z_lb[sl] = np.maximum(z_lb[sl], np.minimum(-cap, u_prev[sl] + self._reach[sl]))
        return np.minimum(z_lb, z_ub)

    def _accept(
        self, plan: _Plan, xs: np.ndarray, s: np.ndarray, boxes: np.ndarray, x0: np.ndarray, t0: float, status: str
    ) -> Command:
        """Make ``plan`` (its inputs (N, 2)) the active plan and send its first input.

        ``xs`` (N+1, 3) is its rollout from ``x0`` (3,), ``s`` (N+1,) the stage assignment and
        ``boxes`` (N+1, 4) [m] the stage boxes as imposed; ``t0`` the step's start
        (``time.perf_counter``). Returns the command with prediction, rectangle ids and margins.
        """
        self._active = plan
        self._s_prev = s
        self._u_prev = plan.u[0].copy()
        self._count(status)
        margins = np.concatenate(([box_slack(x0[None, :2], boxes[:1])[0]], box_slack(xs[1:, :2], boxes[1:])))
        v, w = self._send(plan.u[0])
        return Command(
            v=v,
            w=w,
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status=status,
            ok=True,
            predicted=xs,
            rect_ids=self._rect_ids(s, xs[:, :2]),
            margins=margins,
        )

    def _count(self, status: str) -> None:
        self.stats.counts[status] = self.stats.counts.get(status, 0) + 1

    def _fallback(self, x0, t0, s, boxes, reason: str, problem=None) -> Command:
        """Apply the next input of the active plan if it is still feasible, else brake (see "Fallback")."""
        a = self._active
        rest = None
        if a is not None and not a.brake and a.next < len(a.u):
            shift_ok = not self.config.fallback_brake
            if not shift_ok and problem is not None:
                shift_ok = self._shift_fits(*problem)
            if shift_ok:
                u = a.u[a.next].copy()
                a.next += 1
                a.y = None
                a.y_z = None
                status = "fallback_shift"
                rest = a.u[a.next - 1 :]
        if rest is None:
            if self.config.fallback_brake:
                plan = self.brake_plan(x0)
                u = plan[0].copy()
                self._active = _Plan(plan, 1, brake=True)
                rest = plan
            else:
                u = np.sign(self._u_prev) * np.maximum(np.abs(self._u_prev) - self._rate_step, 0.0)
                self._active = None
                rest = u[None, :]
            status = "fallback_stop"
        u = np.clip(np.nan_to_num(u), self.limits.lower(), self.limits.upper())
        self._u_prev = u
        if s is not None:
            self._s_prev = s
        self._count(status)
        self.last_failure_reason = reason
        predicted = None
        if np.all(np.isfinite(x0)):
            predicted = rollout_np(x0, rest, self.dt)
        v, w = self._send(u)
        return Command(
            v=v,
            w=w,
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status=status,
            ok=False,
            predicted=predicted,
            rect_ids=None,
            margins=None,
        )
