"""The paper's MPC baseline: obstacles as convex polygons in the cost, reference straight to the goal.

Same model, horizon, weights, bounds and solver as SA-MPC (the tracking-MPC core
:class:`~sanav_mj.control.tracking.TrackingMPC` with its
:class:`~sanav_mj.control.config.TrackingConfig`, and the shared NLP of
:mod:`sanav_mj.control.problem`), but no safe areas and no position
constraints: collision avoidance is the cost term :class:`ObstaclePenalty` over the inflated
obstacle polygons, and the reference is the straight line from the robot to the goal. This
is the formulation the paper compares against (obstacles "incorporated into the MPC
formulation through terms in the cost function rather than as hard feasibility
constraints"); it is expected to get trapped in non-convex scenes (U, V).

These choices make the baseline pass a convex obstacle that blocks the straight line; the
first version (reference starting at the robot, warm start only, product penalty) stopped in
front of the block of ``single_rect`` in every run. See :class:`PenaltyConfig` and
docs/results.md for the measurements behind them:

- *Lookahead.* The reference starts ``lookahead`` metres ahead of the robot. When it starts
  at the robot, lagging behind it costs only second order, so a plan that brakes in front
  of the obstacle always beats one that swerves (checked with IPOPT from several initial
  guesses at every approach distance on ``single_rect``). With a lookahead, lagging costs
  first order and swerving becomes the better plan once the obstacle enters the horizon
  (3 m; 2 m lost a near-tie at full speed in 1 of 10 ``single_rect`` runs with an earlier
  back-end).
- *Escape starts.* A gradient method warm-started from a braking plan stays in that basin,
  so when the plan is blocked (it enters a polygon and covers less than ``blocked_travel``
  of the reference's distance) the same problem is also solved from two swerving initial
  guesses (constant yaw rates of either sign) and the plan of lowest cost is kept. The
  problem is unchanged; only the starting points differ (multi-start, no planner).
- *Opening turn.* As SA-MPC (the core's), a robot facing more than ``TrackingConfig.turn_in_place`` away
  from the goal first turns on the spot; with the lookahead's pull and cheap yaw error it
  otherwise reversed all the way to the block.
- *Penetration depth.* The penalty is the squared penetration depth of the inflated
  polygon (``form="depth"``), equally strong along the whole boundary; the product form
  (the mirror image of J_SA) vanishes to higher order near the vertices, where the plans
  cut into the polygon (0.11-0.13 m at a corner in the kinematic test, against 0.05 m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import casadi as cs
import numpy as np

from sanav_mj.control.adaptation import NO_ADAPTATION, PlantAdaptation
from sanav_mj.control.backends import get_backend
from sanav_mj.control.config import PenaltyConfig, TrackingConfig
from sanav_mj.control.problem import build_tracking_ocp
from sanav_mj.control.solver import SolveResult
from sanav_mj.control.tracking import Constraints, Problem, TrackingMPC
from sanav_mj.control.unicycle import rollout_np
from sanav_mj.scene import Obstacle, RobotParams

#: Symbolic problems and their objective functions by (horizon, dt, penalty structure),
#: shared by the controllers of a process (they hold no episode state).
_OCPS: dict[tuple, tuple] = {}

#: [m] slack of the padding rows of the "depth" penalty (never the nearest edge).
_FAR = 1e6


def obstacle_polygon(obstacle: Obstacle, inflation: float, circle_sides: int = 8, corner_cuts: bool = True) -> np.ndarray:
    """Half-spaces ``a^T p <= b`` (M, 3) rows ``(ax, ay, b)`` of a convex polygon covering the inflated obstacle.

    The inflated obstacle is the footprint grown by a disc of radius ``inflation`` [m]. Boxes:
    the octagon of its supporting lines normal to the four edges and to the four corner
    bisectors (the edges pushed out by ``inflation``, the corners cut by the tangents of
    the corner arcs), rows in the order edge, corner, edge, ...; with ``corner_cuts``
    False only the four edges (a rectangle with sharp corners, up to ``0.41 inflation``
    beyond the inflated box). Cylinders and
    capsules (upright): the regular ``circle_sides``-gon circumscribing the circle of
    radius ``radius + inflation``. Normals have unit length, so ``b - a^T p`` is the
    distance [m] to each edge line.
    """
    c = np.asarray(obstacle.center, dtype=float)
    if obstacle.kind == "box":
        corners = obstacle.corners()
        normals = []
        for i in range(4):
            edge = corners[(i + 1) % 4] - corners[i]
            normals.append(np.array([edge[1], -edge[0]]) / np.hypot(*edge))  # outward for counter-clockwise corners
        rows = []
        for i in range(4):
            n, q = normals[i], corners[(i + 1) % 4]  # edge i ends at corner i + 1 ...
            m = n + normals[(i + 1) % 4]  # ... where edge i + 1 starts: the corner's bisector
            m = m / np.hypot(*m)
            rows.append((n[0], n[1], n @ q + inflation))
            if corner_cuts:
                rows.append((m[0], m[1], m @ q + inflation))
        return np.array(rows)
    r = float(obstacle.half_size[0]) + inflation
    ang = 2 * np.pi * np.arange(circle_sides) / circle_sides
    n = np.column_stack((np.cos(ang), np.sin(ang)))
    return np.column_stack((n, n @ c + r))


@dataclass(frozen=True)
class ObstaclePenalty:
    """Cost of entering convex polygons, a :class:`~sanav_mj.control.problem.PositionCost`.

    ``h_ji = b_ji - a_ji^T p`` is the signed distance [m] of ``p`` inside edge line i of
    polygon j (unit normals; positive inside). Two forms, both zero outside every polygon
    and positive inside:

    - ``"depth"``: ``J_obs(p) = sum_j w_j [min_i h_ji(p)]_+^2``, the squared penetration
      depth (the distance to the nearest edge) [m^2], so ``w_j`` is in [1/m^2]. Its gradient
      is continuous (zero on the boundary) and pushes straight out through the nearest edge;
      it is equally strong everywhere along the boundary, corners included.
    - ``"product"``: ``J_obs(p) = sum_j w_j prod_i [h_ji(p)]_+^2`` (the mirror image of the
      paper's J_SA, the usual form with PANOC); smooth, but it vanishes to higher order
      near every vertex, where the plans cut into the polygon. Rows are best normalised
      (:func:`normalised_rows`) so each factor is O(1).

    Parameters per slot: ``n_edges`` rows ``(ax, ay, b)`` then the weight ``w`` (0 for an
    unused slot); unused edges are :meth:`pad_row` (never the binding edge, or a neutral
    factor 1).
    """

    n_slots: int
    n_edges: int
    form: str = "depth"

    def __post_init__(self) -> None:
        if self.form not in ("depth", "product"):
            raise ValueError(f"ObstaclePenalty.form must be 'depth' or 'product', got {self.form!r}")

    @property
    def key(self) -> str:
        return f"obs{self.form}{self.n_slots}x{self.n_edges}"

    @property
    def slot_size(self) -> int:
        return 3 * self.n_edges + 1

    @property
    def n_params(self) -> int:
        return self.n_slots * self.slot_size

    def pad_row(self) -> tuple[float, float, float]:
        """Row of an unused edge: ``0 x + 0 y <= b`` with ``b`` 1 (product) or 1e6 m (depth)."""
        return (0.0, 0.0, 1.0) if self.form == "product" else (0.0, 0.0, _FAR)

    def expr(self, p, theta):
        total = 0
        for j in range(self.n_slots):
            s = theta[j * self.slot_size : (j + 1) * self.slot_size]
            hs = [s[3 * i + 2] - s[3 * i] * p[0] - s[3 * i + 1] * p[1] for i in range(self.n_edges)]
            if self.form == "product":
                term = 1
                for h in hs:
                    term = term * cs.fmax(0, h) ** 2
            else:
                depth = hs[0]
                for h in hs[1:]:
                    depth = cs.fmin(depth, h)
                term = cs.fmax(0, depth) ** 2
            total = total + s[-1] * term
        return total

    def value_np(self, p: np.ndarray, theta: np.ndarray) -> float:
        """NumPy value at ``p`` (2,) for parameters ``theta`` (n_params,)."""
        return float(self.values_np(np.asarray(p, dtype=float).reshape(1, 2), theta)[0])

    def values_np(self, points: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """NumPy values (K,) at ``points`` (K, 2) [m] for parameters ``theta`` (n_params,)."""
        slots = np.asarray(theta, dtype=float).reshape(self.n_slots, self.slot_size)
        edges = slots[:, :-1].reshape(self.n_slots, self.n_edges, 3)
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        h = edges[None, :, :, 2] - np.einsum("kp,sep->kse", pts, edges[:, :, :2])
        if self.form == "product":
            terms = np.prod(np.maximum(h, 0.0) ** 2, axis=2)
        else:
            terms = np.maximum(np.min(h, axis=2), 0.0) ** 2
        return terms @ slots[:, -1]


def normalised_rows(poly: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Polygon rows (M, 3) divided by the depth [m] of ``centre`` (2,) inside it (its inradius for boxes and circles)."""
    depth = float(np.min(poly[:, 2] - poly[:, :2] @ np.asarray(centre, dtype=float)))
    return poly / depth if depth > 1e-6 else poly


def resolved_reference_speed(robot: RobotParams, config: TrackingConfig = TrackingConfig(),
                             penalty: PenaltyConfig = PenaltyConfig()) -> float:
    """[m/s] speed along the straight reference: ``penalty.reference_speed``, or 0.8 times
    the MPC's resolved ``v_max`` (``config.limits(robot)``) when that is None."""
    if penalty.reference_speed is not None:
        return float(penalty.reference_speed)
    return 0.8 * config.limits(robot).v_max


def straight_reference(pose: np.ndarray, goal: np.ndarray, lookahead: float, speed: float, horizon: int,
                       dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The baseline's reference from ``pose`` (3,) [m, m, rad] to ``goal`` (2,) [m].

    Sample k (k = 0..horizon) lies ``min(lookahead + k * speed * dt, d)`` metres along the
    line from the robot to the goal (``d`` its distance, [m]; ``lookahead`` [m], ``speed``
    [m/s], ``dt`` [s]), with the goal's bearing as yaw on the branch of ``pose[2]`` (the
    measured yaw within 0.1 m of the goal: no spinning there); its input is ``(speed, 0)``
    until the samples reach the goal, then zero.

    Returns:
        states (horizon + 1, 3) [m, m, rad] and inputs (horizon, 2) [m/s, rad/s].
    """
    pose = np.asarray(pose, dtype=float).reshape(3)
    d = np.asarray(goal, dtype=float).reshape(2) - pose[:2]
    dist = float(np.hypot(*d))
    n = int(horizon)
    heading = math.atan2(d[1], d[0]) if dist > 0.1 else float(pose[2])
    heading = pose[2] + (heading - pose[2] + math.pi) % (2 * math.pi) - math.pi
    s = np.minimum(lookahead + np.arange(n + 1) * speed * dt, dist)
    unit = d / dist if dist > 1e-6 else np.zeros(2)
    xr = np.column_stack((pose[0] + s * unit[0], pose[1] + s * unit[1], np.full(n + 1, heading)))
    ur = np.zeros((n, 2))
    ur[:, 0] = np.where(s[1:] < dist, speed, 0.0)
    return xr, ur


def _tighter(a: float | None, b: float | None) -> float | None:
    """The smaller of two optional limits (None: no limit)."""
    if a is None:
        return b
    return a if b is None else min(a, b)


class PenaltyMPC(TrackingMPC):
    """Obstacle-penalty MPC (the paper's baseline) on the tracking-MPC core; a Controller.

    Each step the ``n_slots`` obstacles nearest the robot (polygon centre distance) fill the
    penalty slots (:meth:`constrain`: the baseline's cost, no position constraints); the
    reference runs along the straight line from the measured position to the goal, from
    ``lookahead`` ahead of the robot at ``reference_speed`` (stopping at the goal), with the
    goal's bearing as yaw (shifted to the measured branch) and zero inputs once the reference
    has reached the goal. The problem is solved from the shifted previous plan; when that
    plan is blocked, also from the escape guesses, keeping the cheapest acceptable plan
    (:meth:`solve`, :class:`PenaltyConfig`). Every solve, escape solves included, stops at
    ``TrackingConfig.solve_budget_ms`` of wall time. The step, warm start, acceptance,
    opening turn on the spot (``turn_in_place`` / ``turn_exit``) and the fallback policy
    (follow the shifted previous plan only while it meets the current input and rate bounds,
    else brake straight at the rate bounds) are the core's
    (:class:`~sanav_mj.control.tracking.TrackingMPC`); the plant adaptation is off
    (:data:`~sanav_mj.control.adaptation.NO_ADAPTATION`). Its input bounds keep the
    baseline's own form (terminal stop ``v_{N-1} = 0`` and the rate bound of ``u_0`` as
    variable bounds, the other rate bounds as constraint rows).

    Attributes:
        name: ``"mpc"``. dt: [s]. needs_ranges: False.
        stats: per-episode status counts (``ok``, ``inexact``, ``turn``, ``fallback_*``) plus
            ``escape_tried`` (steps that solved from the escape guesses) and ``escape_taken``
            (steps whose plan came from one of them).
        failures: the fallback steps.
    """

    name = "mpc"
    needs_ranges = False

    def __init__(
        self,
        robot: RobotParams,
        obstacles: Sequence[Obstacle],
        inflation: float,
        goal: np.ndarray,
        config: TrackingConfig = TrackingConfig(),
        penalty: PenaltyConfig = PenaltyConfig(),
        *,
        failure_injector: Callable[[int], bool] | None = None,
    ):
        """Build the controller.

        Args:
            robot: nominal robot parameters.
            obstacles: the scenario's obstacles (world frame).
            inflation: [m] how much each obstacle is grown (footprint radius + margin).
            goal: (2,) [m] goal position.
            config: the core's settings (horizon, weights, bounds, solver, turn, fallback);
                an SA-MPC :class:`~sanav_mj.control.config.MPCConfig` gives its core part.
            penalty: the baseline's own settings.
            failure_injector: test hook called with the step index; True fails that solve.
        """
        if not (isinstance(inflation, (int, float)) and math.isfinite(inflation) and inflation >= 0):
            raise ValueError(f"inflation must be a finite number >= 0 m, got {inflation!r}")
        goal = np.asarray(goal, dtype=float).reshape(-1)[:2]
        if goal.shape != (2,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal must be 2 finite numbers [m], got {goal!r}")
        if not isinstance(config, TrackingConfig):
            raise ValueError(f"config must be a TrackingConfig, got {type(config).__name__}")
        if type(config) is not TrackingConfig:
            config = config.tracking()
        if config.max_outer_iter < penalty.min_outer_iter:
            config = replace(config, max_outer_iter=penalty.min_outer_iter)
        self.settings = penalty
        self.goal = goal
        limits = config.limits(robot)
        limits = replace(limits, v_min=0.0) if penalty.forward_only else limits
        dt = float(config.dt)
        self.reference_speed = resolved_reference_speed(robot, config, penalty)
        n_edges = penalty.n_edges
        self.penalty = ObstaclePenalty(penalty.n_slots, n_edges, penalty.form)
        polys = [obstacle_polygon(o, inflation, n_edges, corner_cuts=n_edges >= 8) for o in obstacles]
        self._slots = np.zeros((len(polys), self.penalty.slot_size))
        self._centres = np.zeros((len(polys), 2))
        for i, (o, poly) in enumerate(zip(obstacles, polys)):
            rows = np.tile(self.penalty.pad_row(), (n_edges, 1))
            rows[: len(poly)] = normalised_rows(poly, o.center) if penalty.form == "product" else poly
            self._slots[i, :-1] = rows.ravel()
            self._slots[i, -1] = penalty.q_obs
            self._centres[i] = o.center
        self._empty_slot = np.concatenate((np.tile(self.penalty.pad_row(), n_edges), [0.0]))
        key = (config.horizon, dt, self.penalty)
        if key not in _OCPS:  # building the symbolic problem takes about 0.4 s
            ocp = build_tracking_ocp(config.horizon, dt, self.penalty, position_constraints=False)
            _OCPS[key] = (ocp, ocp.functions()[0])
        ocp, self._objective = _OCPS[key]
        adaptation = PlantAdaptation(robot, dt, limits.v_max, limits.w_max, limits.a_max,
                                     limits.lower(), limits.upper(), NO_ADAPTATION)
        super().__init__(robot, config, limits, ocp, adaptation, failure_injector=failure_injector)
        cache = Path(config.cache_dir) if config.cache_dir else None
        escape_settings = replace(
            config.solver_settings(), budget_ms=_tighter(config.solve_budget_ms, penalty.escape_budget_ms)
        )
        self.escape_backend = get_backend(self.ocp, config.solver, escape_settings, cache)
        self.reset(np.zeros(3))

    def reference(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Straight reference to the goal from ``pose`` (3,): states (N+1, 3) and inputs (N, 2).

        Sample k lies ``min(lookahead + k * reference_speed * dt, distance to goal)`` along
        the line from the robot to the goal; its input is ``(reference_speed, 0)`` until the
        samples reach the goal, then zero. Within 0.1 m of the goal the yaw reference is the
        measured yaw (no spinning at the goal).
        """
        return straight_reference(pose, self.goal, self.settings.lookahead, self.reference_speed, self.N, self.dt)

    def obstacle_params(self, pos: np.ndarray) -> np.ndarray:
        """Penalty parameters (n_params,) of the ``n_slots`` obstacles nearest ``pos`` (2,) [m]
        (polygon centre distance), empty slots padded with a zero weight."""
        k = self.penalty.n_slots
        out = np.tile(self._empty_slot, (k, 1))
        if len(self._slots):
            order = np.argsort(np.hypot(*(self._centres - pos).T))[:k]
            out[: len(order)] = self._slots[order]
        return out.ravel()

    def constrain(self, x0: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray, guess: np.ndarray) -> Constraints:
        """The baseline's cost data: the nearest obstacles' polygons; no position constraints."""
        return Constraints(np.zeros(0), np.zeros(0), self.obstacle_params(x0[:2]), x_ref, u_ref)

    def input_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(2N,) input bounds: the limits, the terminal stop ``v_{N-1} = 0`` and the rate bound of
        ``u_0`` against the previous input (the other rate bounds are constraint rows)."""
        n = self.N
        z_lb = np.tile(self.limits.lower(), n)
        z_ub = np.tile(self.limits.upper(), n)
        if self.config.terminal_stop:
            z_lb[-2] = z_ub[-2] = 0.0
        z_lb[:2] = np.maximum(z_lb[:2], self._u_prev - self._rate_step)
        z_ub[:2] = np.minimum(z_ub[:2], self._u_prev + self._rate_step)
        return z_lb, z_ub

    def blocked(self, x0: np.ndarray, u: np.ndarray, theta: np.ndarray) -> bool:
        """Whether the plan ``u`` (N, 2) from ``x0`` (3,) enters a polygon (penalty parameters
        ``theta``) and covers less than ``blocked_travel`` of the reference's distance."""
        pred = rollout_np(x0, u, self.dt)
        if not np.any(self.penalty.values_np(pred[1:, :2], theta) > 0):
            return False
        travel = float(np.sum(np.hypot(*np.diff(pred[:, :2], axis=0).T)))
        return travel < self.settings.blocked_travel * self.N * self.reference_speed * self.dt

    def escape_guesses(self) -> list[np.ndarray]:
        """Extra initial guesses (N, 2) [m/s, rad/s]: turn at each escape yaw rate, then straight."""
        v = max(float(self._u_prev[0]), self.settings.escape_speed)
        out = []
        for w in self.settings.escape_yaw_rates:
            g = np.zeros((self.N, 2))
            g[:, 0] = v
            g[: self.settings.escape_steps, 1] = w
            out.append(g)
        return out

    def solve(self, prob: Problem, x0: np.ndarray) -> tuple[SolveResult, str | None, str]:
        """Solve from the warm start; when rejected or blocked, also from the escape guesses
        (cold starts), keeping the acceptable plan of lowest cost."""
        res, status, reason = super().solve(prob, x0)
        theta = prob.p[self._p_slices["extra"]]
        n = self.N
        if self.settings.escape_yaw_rates and (status is None or self.blocked(x0, res.z.reshape(n, 2), theta)):
            self.stats.count("escape_tried")
            best = float(self._objective(res.z, prob.p)) if status is not None else math.inf
            taken = False
            for guess in self.escape_guesses():
                alt = self.escape_backend.solve(
                    prob.p, prob.z_lb, prob.z_ub, prob.g_lb, prob.g_ub, np.clip(guess.ravel(), prob.z_lb, prob.z_ub)
                )
                alt_status, alt_reason = self.acceptance(alt, x0, prob)
                if alt_status is None:
                    continue
                cost = float(self._objective(alt.z, prob.p))
                if cost < best:
                    res, status, best, taken = alt, alt_status, cost, True
            if taken:
                self.stats.count("escape_taken")
        return res, status, reason
