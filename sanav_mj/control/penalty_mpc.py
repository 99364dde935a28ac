"""The paper's MPC baseline: obstacles as convex polygons in the cost, reference straight to the goal.

Same model, horizon, weights, bounds and solver as SA-MPC (:class:`~sanav_mj.control.sa_mpc.MPCConfig`
and the shared NLP of :mod:`sanav_mj.control.problem`), but no safe areas and no position
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
- *Opening turn.* As SA-MPC, a robot facing more than ``MPCConfig.turn_in_place`` away
  from the goal first turns on the spot; with the lookahead's pull and cheap yaw error it
  otherwise reversed all the way to the block.
- *Penetration depth.* The penalty is the squared penetration depth of the inflated
  polygon (``form="depth"``), equally strong along the whole boundary; the product form
  (the mirror image of J_SA) vanishes to higher order near the vertices, where the plans
  cut into the polygon (0.11-0.13 m at a corner in the kinematic test, against 0.05 m).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import casadi as cs
import numpy as np

from sanav_mj.control.base import Command, Observation
from sanav_mj.control.backends import get_backend
from sanav_mj.control.problem import build_tracking_ocp, shift_bound_multipliers, shift_inputs, shift_multipliers
from sanav_mj.control.sa_mpc import MPCConfig
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


@dataclass(frozen=True)
class PenaltyConfig:
    """Settings of the obstacle-penalty baseline beyond the shared :class:`MPCConfig`.

    Attributes:
        q_obs: weight of each polygon's penalty (see :class:`ObstaclePenalty`): [1/m^2] for
            the ``"depth"`` form; [-] for ``"product"``, whose rows are normalised by the
            polygon's inradius.
        form: ``"depth"`` or ``"product"``, see :class:`ObstaclePenalty`.
        n_slots: obstacles considered per step (nearest polygon centres first).
        n_edges: edges per polygon slot: cylinders and capsules are ``n_edges``-gons, boxes
            octagons (4 edges and 4 corner cuts, see :func:`obstacle_polygon`) when
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
            ``MPCConfig.solve_budget_ms`` (the ``solve_budget_ms`` mismatch); an escape
            solve is cut at the smaller of the two. A step that tries the escape starts
            makes ``1 + len(escape_yaw_rates)`` solves, so its wall time can reach that many
            budgets. The escape starts are cold starts far from their solution: with the
            ZeroFPR back-end they took 25-33 ms on ``single_rect`` (10 runs, load about 1);
            with an earlier back-end 50-300 ms on a loaded 2-core machine, where a 50 ms cut
            made their iterates lose to the braking plan and the baseline stopped in front
            of the block in 2 of 10 ``single_rect`` runs.
        min_outer_iter: lower bound of the ALM outer-iteration limit of the baseline's solver
            (``max(MPCConfig.max_outer_iter, min_outer_iter)``). Its costs are about ten
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


def resolved_reference_speed(robot: RobotParams, config: MPCConfig = MPCConfig(),
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


class PenaltyMPC:
    """Obstacle-penalty MPC (the paper's baseline), implementing the Controller protocol.

    Each step the ``n_slots`` obstacles nearest the robot (polygon centre distance) fill the
    penalty slots; the reference runs along the straight line from the measured position to
    the goal, from ``lookahead`` ahead of the robot at ``reference_speed`` (stopping at the
    goal), with the goal's bearing as yaw (shifted to the measured branch) and zero inputs
    once the reference has reached the goal. The problem is solved from the shifted previous
    plan; when that plan is blocked, also from the escape guesses, keeping the cheapest
    acceptable plan (:class:`PenaltyConfig`). Every solve, escape solves included, stops at
    ``MPCConfig.solve_budget_ms`` of wall time. The opening turn on the spot (``MPCConfig.
    turn_in_place`` / ``turn_exit``), rate bounds, failure handling and fallbacks (shift the
    previous plan, then brake) are those of SA-MPC.

    Attributes:
        name: ``"mpc"``. dt: [s]. needs_ranges: False.
        stats_counts: per-episode status counts (``ok``, ``inexact``, ``turn``, ``fallback_*``) plus
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
        config: MPCConfig = MPCConfig(),
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
            config: shared MPC settings (horizon, weights, bounds, solver).
            penalty: the baseline's own settings.
            failure_injector: test hook called with the step index; True fails that solve.
        """
        if not (isinstance(inflation, (int, float)) and math.isfinite(inflation) and inflation >= 0):
            raise ValueError(f"inflation must be a finite number >= 0 m, got {inflation!r}")
        goal = np.asarray(goal, dtype=float).reshape(-1)[:2]
        if goal.shape != (2,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal must be 2 finite numbers [m], got {goal!r}")
        if config.max_outer_iter < penalty.min_outer_iter:
            config = replace(config, max_outer_iter=penalty.min_outer_iter)
        self.config = config
        self.settings = penalty
        self.robot = robot
        self.dt = float(config.dt)
        self.N = config.horizon
        limits = config.limits(robot)
        self.limits = replace(limits, v_min=0.0) if penalty.forward_only else limits
        self.goal = goal
        self.failure_injector = failure_injector
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
        key = (self.N, self.dt, self.penalty)
        if key not in _OCPS:  # building the symbolic problem takes about 0.4 s
            ocp = build_tracking_ocp(self.N, self.dt, self.penalty, position_constraints=False)
            _OCPS[key] = (ocp, ocp.functions()[0])
        self.ocp, self._objective = _OCPS[key]
        cache = Path(config.cache_dir) if config.cache_dir else None
        self.backend = get_backend(self.ocp, config.solver, config.solver_settings(), cache)
        escape_settings = replace(
            config.solver_settings(), budget_ms=_tighter(config.solve_budget_ms, penalty.escape_budget_ms)
        )
        self.escape_backend = get_backend(self.ocp, config.solver, escape_settings, cache)
        n = self.N
        self._z_lb = np.tile(self.limits.lower(), n)
        self._z_ub = np.tile(self.limits.upper(), n)
        if config.terminal_stop:
            self._z_lb[-2] = self._z_ub[-2] = 0.0
        self._rate_step = self.limits.rate() * self.dt
        self._g_lb = np.tile(-self._rate_step, n - 1)
        self._g_ub = np.tile(self._rate_step, n - 1)
        sl = self.ocp.layout.slices()
        self._p_buf = np.zeros(self.ocp.layout.size)
        for name, w in zip(("q_x", "q_u", "q_a", "q_n"), (config.q_x, config.q_u, config.q_a, config.q_n)):
            self._p_buf[sl[name]] = w
        self._sl = sl
        self.reset(np.zeros(3))

    def reset(self, pose: np.ndarray) -> None:
        """Start a new episode (robot at rest)."""
        self._u_prev = np.zeros(2)
        self._plan: np.ndarray | None = None
        self._next = 0
        self._y = self._y_z = None
        self._step_index = 0
        self._turning = self.config.turn_in_place is not None
        self.stats_counts: dict[str, int] = {}
        self.last_failure_reason: str | None = None

    @property
    def failures(self) -> int:
        return sum(v for k, v in self.stats_counts.items() if k.startswith("fallback"))

    def reference(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Straight reference to the goal from ``pose`` (3,): states (N+1, 3) and inputs (N, 2).

        Sample k lies ``min(lookahead + k * reference_speed * dt, distance to goal)`` along
        the line from the robot to the goal; its input is ``(reference_speed, 0)`` until the
        samples reach the goal, then zero. Within 0.1 m of the goal the yaw reference is the
        measured yaw (no spinning at the goal).
        """
        return straight_reference(pose, self.goal, self.settings.lookahead, self.reference_speed, self.N, self.dt)

    def _obstacle_params(self, pos: np.ndarray) -> np.ndarray:
        k = self.penalty.n_slots
        out = np.tile(self._empty_slot, (k, 1))
        if len(self._slots):
            order = np.argsort(np.hypot(*(self._centres - pos).T))[:k]
            out[: len(order)] = self._slots[order]
        return out.ravel()

    def _accept(self, res, z_lb: np.ndarray, z_ub: np.ndarray) -> str | None:
        """Status (``"ok"``/``"inexact"``) of an acceptable solution, or None (with the reason stored)."""
        z = res.z
        if not np.all(np.isfinite(z)):
            self._reject_reason = f"nonfinite:{res.status}"
            return None
        u = z.reshape(self.N, 2)
        tol = 10 * self.config.constraint_tol + 1e-9
        viol = max(
            float(np.max(z_lb - z, initial=0.0)),
            float(np.max(z - z_ub, initial=0.0)),
            float(np.max(np.abs(np.diff(u, axis=0)) - self._rate_step, initial=0.0)),
        )
        if viol <= tol and (res.converged or self.config.accept_inexact):
            return "ok" if res.converged else "inexact"
        self._reject_reason = f"rejected:{res.status}:viol={viol:.2e}"
        return None

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

    def step(self, obs: Observation) -> Command:
        """Command for the next period (wall time of the whole step, every solve, in ``solve_ms``)."""
        t0 = time.perf_counter()
        n = self.N
        k_step = self._step_index
        self._step_index += 1
        x0 = np.asarray(obs.pose, dtype=float).reshape(3)
        if not np.all(np.isfinite(x0)):
            return self._fallback(x0, t0, "bad_measurement")
        xr, ur = self.reference(x0)
        if self._turning:
            err = float(xr[0, 2] - x0[2])  # the reference yaw is on the measured branch
            if abs(err) > (self.config.turn_in_place if k_step == 0 else self.config.turn_exit):
                return self._turn_step(x0, t0, err)
            self._turning = False
        if self._plan is None:
            u_guess = np.zeros((n, 2))
        else:
            u_guess = shift_inputs(self._plan, self._next, n, self._rate_step, self._u_prev)
        z_lb = self._z_lb.copy()
        z_ub = self._z_ub.copy()
        z_lb[:2] = np.maximum(z_lb[:2], self._u_prev - self._rate_step)
        z_ub[:2] = np.minimum(z_ub[:2], self._u_prev + self._rate_step)
        p = self._p_buf.copy()
        sl = self._sl
        p[sl["x0"]] = x0
        p[sl["u_prev"]] = self._u_prev
        p[sl["x_ref"]] = xr.ravel()
        p[sl["u_ref"]] = ur.ravel()
        theta = self._obstacle_params(x0[:2])
        p[sl["extra"]] = theta
        z0 = np.clip(u_guess.ravel(), z_lb, z_ub)
        y0 = y_z0 = None
        if self._plan is not None and self._next == 1 and self._y is not None:
            y0 = shift_multipliers(self.ocp, self._y)
            y_z0 = shift_bound_multipliers(self._y_z)
        if self.failure_injector is not None and self.failure_injector(k_step):
            return self._fallback(x0, t0, "injected")
        res = self.backend.solve(p, z_lb, z_ub, self._g_lb, self._g_ub, z0, y0, y_z0)
        status = self._accept(res, z_lb, z_ub)
        if self.settings.escape_yaw_rates and (status is None or self.blocked(x0, res.z.reshape(n, 2), theta)):
            self._count("escape_tried")
            best = float(self._objective(res.z, p)) if status is not None else math.inf
            taken = False
            for guess in self.escape_guesses():
                alt = self.escape_backend.solve(
                    p, z_lb, z_ub, self._g_lb, self._g_ub, np.clip(guess.ravel(), z_lb, z_ub)
                )
                alt_status = self._accept(alt, z_lb, z_ub)
                if alt_status is None:
                    continue
                cost = float(self._objective(alt.z, p))
                if cost < best:
                    res, status, best, taken = alt, alt_status, cost, True
            if taken:
                self._count("escape_taken")
        if status is None:
            return self._fallback(x0, t0, self._reject_reason)
        u = res.z.reshape(n, 2)
        self._plan, self._next = u.copy(), 1
        self._y, self._y_z = np.asarray(res.y, float), res.y_z
        self._u_prev = u[0].copy()
        self._count(status)
        return Command(
            v=float(u[0, 0]),
            w=float(u[0, 1]),
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status=status,
            ok=True,
            predicted=rollout_np(x0, u, self.dt),
        )

    def turn_plan(self, err: float) -> np.ndarray:
        """(N, 2) inputs turning on the spot by ``err`` [rad] about as fast as the bounds allow.

        ``v = 0``; stage by stage the yaw rate takes the largest value within the rate and
        input bounds from which braking at the rate bound ``a`` (per step) turns at most the
        remaining angle ``r``: a step at ``w`` then braking turns ``dt (w^2 / (2 a) + w / 2)``,
        so ``w <= sqrt(a^2 / 4 + 2 a r / dt) - a / 2``; it brakes at the rate bound when even
        that is exceeded (and stops within one step's turn of the target).
        """
        a = float(self._rate_step[1])
        sgn = 1.0 if err >= 0 else -1.0
        rem = abs(err)
        w = sgn * float(self._u_prev[1])
        out = np.zeros((self.N, 2))
        for k in range(self.N):
            reach = math.sqrt(a * a / 4 + 2 * a * max(rem, 0.0) / self.dt) - a / 2
            w = max(min(w + a, self.limits.w_max, reach), w - a, 0.0)
            out[k, 1] = sgn * w
            rem -= w * self.dt
        return out

    def _turn_step(self, x0: np.ndarray, t0: float, err: float) -> Command:
        """The opening turn on the spot, as SA-MPC's: when the goal's bearing is more than
        ``MPCConfig.turn_in_place`` off the measured yaw at the first step, turn (status
        ``"turn"``) until it is at most ``turn_exit``; the MPC then starts from the rest of
        the turn."""
        u = self.turn_plan(err)
        self._plan, self._next = u, 1
        self._y = self._y_z = None
        self._u_prev = u[0].copy()
        self._count("turn")
        return Command(
            v=0.0,
            w=float(u[0, 1]),
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status="turn",
            ok=True,
            predicted=rollout_np(x0, u, self.dt),
        )

    def _count(self, key: str) -> None:
        self.stats_counts[key] = self.stats_counts.get(key, 0) + 1

    def _fallback(self, x0: np.ndarray, t0: float, reason: str) -> Command:
        if self._plan is not None and self._next < len(self._plan):
            u = self._plan[self._next].copy()
            rest = self._plan[self._next :]
            self._next += 1
            status = "fallback_shift"
        else:
            u = np.sign(self._u_prev) * np.maximum(np.abs(self._u_prev) - self._rate_step, 0.0)
            rest = u[None, :]
            self._plan = None
            status = "fallback_stop"
        self._y = self._y_z = None
        u = np.clip(np.nan_to_num(u), self.limits.lower(), self.limits.upper())
        self._u_prev = u
        self.stats_counts[status] = self.stats_counts.get(status, 0) + 1
        self.last_failure_reason = reason
        predicted = rollout_np(x0, rest, self.dt) if np.all(np.isfinite(x0)) else None
        return Command(
            v=float(u[0]),
            w=float(u[1]),
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status=status,
            ok=False,
            predicted=predicted,
        )
