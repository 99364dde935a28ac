"""The paper's MPC baseline: obstacles as convex polygons in the cost, reference straight to the goal.

Same model, horizon, weights, bounds and solver as SA-MPC (:class:`~sanav_mj.control.sa_mpc.MPCConfig`
and the shared NLP of :mod:`sanav_mj.control.ocp`), but no safe areas and no position
constraints: collision avoidance is the cost term :class:`ObstaclePenalty`, and the
reference runs from the robot straight to the goal. This is the formulation the paper
compares against (obstacles "incorporated into the MPC formulation through terms in the
cost function rather than as hard feasibility constraints"); it is expected to get trapped
in non-convex scenes (U, V). Measured on a kinematic plant: it passes a box whose inflated
polygon overlaps the straight line by 0.25 m, but stops in front of one it would have to
leave the line by 0.5 m to pass (the plan that stops at the polygon is a local minimum of
the tracking cost, and a gradient method started from it never explores going around).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import casadi as cs
import numpy as np

from sanav_mj.control.base import Command, Observation
from sanav_mj.control.ocp import (
    build_tracking_ocp,
    shift_bound_multipliers,
    shift_inputs,
    shift_multipliers,
)
from sanav_mj.control.sa_mpc import MPCConfig, get_backend
from sanav_mj.control.unicycle import rollout_np
from sanav_mj.scene import Obstacle, RobotParams

#: Half-space padding a polygon slot: 0 x + 0 y <= 1 always holds with slack 1.
_PAD_EDGE = (0.0, 0.0, 1.0)


def obstacle_polygon(obstacle: Obstacle, inflation: float, circle_sides: int = 8) -> np.ndarray:
    """Half-spaces ``a^T p <= b`` (M, 3) rows ``(ax, ay, b)`` of a convex polygon covering the inflated obstacle.

    Boxes: the four edges pushed out by ``inflation`` [m] (contains the box grown by a disc
    of that radius). Cylinders and capsules (upright): the regular ``circle_sides``-gon
    circumscribing the circle of radius ``radius + inflation``. Normals have unit length,
    so ``b - a^T p`` is the distance [m] to each edge line.
    """
    c = np.asarray(obstacle.center, dtype=float)
    if obstacle.kind == "box":
        corners = obstacle.corners()
        rows = []
        for i in range(4):
            p, q = corners[i], corners[(i + 1) % 4]
            edge = q - p
            n = np.array([edge[1], -edge[0]]) / np.hypot(*edge)  # outward for counter-clockwise corners
            rows.append((n[0], n[1], n @ p + inflation))
        return np.array(rows)
    r = float(obstacle.half_size[0]) + inflation
    ang = 2 * np.pi * np.arange(circle_sides) / circle_sides
    n = np.column_stack((np.cos(ang), np.sin(ang)))
    return np.column_stack((n, n @ c + r))


@dataclass(frozen=True)
class ObstaclePenalty:
    """Cost of entering convex polygons, a :class:`~sanav_mj.control.ocp.PositionCost`.

    ``J_obs(p) = sum_j w_j prod_i [h_ji(p)]_+^2`` with ``h_ji = b_ji - a_ji^T p`` the edge
    "depths" of polygon j, positive inside (the mirror image of the paper's J_SA): zero
    outside every polygon, and inside its gradient has a component along every edge, so
    it pushes towards the nearest way out rather than only straight back. The rows are
    normalised by the polygon's inradius so each factor is O(1). Parameters per slot:
    ``n_edges`` rows ``(ax, ay, b)`` then the weight ``w`` (0 for an unused slot); unused
    edges are ``(0, 0, 1)`` (a neutral factor 1).
    """

    n_slots: int
    n_edges: int

    @property
    def key(self) -> str:
        return f"obsprod{self.n_slots}x{self.n_edges}"

    @property
    def slot_size(self) -> int:
        return 3 * self.n_edges + 1

    @property
    def n_params(self) -> int:
        return self.n_slots * self.slot_size

    def expr(self, p, theta):
        total = 0
        for j in range(self.n_slots):
            s = theta[j * self.slot_size : (j + 1) * self.slot_size]
            prod = 1
            for i in range(self.n_edges):
                h = s[3 * i + 2] - s[3 * i] * p[0] - s[3 * i + 1] * p[1]
                prod = prod * cs.fmax(0, h) ** 2
            total = total + s[-1] * prod
        return total

    def value_np(self, p: np.ndarray, theta: np.ndarray) -> float:
        """NumPy value at ``p`` (2,) for parameters ``theta`` (n_params,)."""
        total = 0.0
        for s in np.asarray(theta, float).reshape(self.n_slots, self.slot_size):
            e = s[:-1].reshape(self.n_edges, 3)
            h = e[:, 2] - e[:, :2] @ p
            total += s[-1] * float(np.prod(np.maximum(h, 0.0) ** 2))
        return total


def normalised_rows(poly: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Polygon rows (M, 3) divided by the depth [m] of ``centre`` (2,) inside it (its inradius for boxes and circles)."""
    depth = float(np.min(poly[:, 2] - poly[:, :2] @ np.asarray(centre, dtype=float)))
    return poly / depth if depth > 1e-6 else poly


class PenaltyMPC:
    """Obstacle-penalty MPC (the paper's baseline), implementing the Controller protocol.

    Each step the ``n_slots`` obstacles nearest the robot (polygon centroid distance) fill
    the penalty slots; the reference is the straight segment from the measured position to
    the goal at ``reference_speed``, with the goal's bearing as yaw (shifted to the measured
    branch) and zero inputs once at the goal. Warm start, rate bounds, failure handling and
    fallbacks (shift the previous plan, then brake) are those of SA-MPC.

    Attributes:
        name: ``"mpc"``. dt: [s]. needs_ranges: False.
        stats_counts: per-episode status counts; ``failures`` the fallback steps.
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
        *,
        q_obs: float = 300.0,
        n_slots: int = 8,
        n_edges: int = 8,
        reference_speed: float | None = None,
        failure_injector: Callable[[int], bool] | None = None,
    ):
        """Build the controller.

        Args:
            robot: nominal robot parameters.
            obstacles: the scenario's obstacles (world frame).
            inflation: [m] how much each obstacle is grown (footprint radius + margin).
            goal: (2,) [m] goal position.
            config: shared MPC settings (horizon, weights, bounds, solver).
            q_obs: weight of each polygon's penalty (see :class:`ObstaclePenalty`).
            n_slots: obstacles considered per step (nearest first).
            n_edges: edges per polygon slot (boxes use 4, circles ``n_edges``-gons).
            reference_speed: [m/s] speed along the straight reference; None -> 0.8 v_max.
            failure_injector: test hook called with the step index; True fails that solve.
        """
        if not (math.isfinite(inflation) and inflation >= 0):
            raise ValueError(f"inflation must be a finite number >= 0 m, got {inflation!r}")
        if not (math.isfinite(q_obs) and q_obs > 0):
            raise ValueError(f"q_obs must be a positive finite number, got {q_obs!r}")
        if not (isinstance(n_slots, int) and n_slots >= 1 and isinstance(n_edges, int) and n_edges >= 4):
            raise ValueError(f"n_slots must be >= 1 and n_edges >= 4, got {n_slots!r}, {n_edges!r}")
        goal = np.asarray(goal, dtype=float).reshape(-1)[:2]
        if goal.shape != (2,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal must be 2 finite numbers [m], got {goal!r}")
        self.config = config
        self.robot = robot
        self.dt = float(config.dt)
        self.N = config.horizon
        self.limits = config.limits(robot)
        self.goal = goal
        self.failure_injector = failure_injector
        self.reference_speed = 0.8 * self.limits.v_max if reference_speed is None else float(reference_speed)
        if not (self.reference_speed > 0):
            raise ValueError(f"reference_speed must be > 0 m/s, got {reference_speed!r}")
        self.penalty = ObstaclePenalty(n_slots, n_edges)
        polys = [obstacle_polygon(o, inflation, n_edges) for o in obstacles]
        self._slots = np.zeros((len(polys), self.penalty.slot_size))
        self._centres = np.zeros((len(polys), 2))
        for i, (o, poly) in enumerate(zip(obstacles, polys)):
            rows = np.tile(_PAD_EDGE, (n_edges, 1))
            rows[: len(poly)] = normalised_rows(poly[:n_edges], o.center)
            self._slots[i, :-1] = rows.ravel()
            self._slots[i, -1] = q_obs
            self._centres[i] = o.center
        self._empty_slot = np.concatenate((np.tile(_PAD_EDGE, n_edges), [0.0]))
        self.ocp = build_tracking_ocp(self.N, self.dt, self.penalty, position_constraints=False)
        cache = Path(config.cache_dir) if config.cache_dir else None
        self.backend = get_backend(self.ocp, config.solver, config.solver_settings(), cache)
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
        self.stats_counts: dict[str, int] = {}
        self.last_failure_reason: str | None = None

    @property
    def failures(self) -> int:
        return sum(v for k, v in self.stats_counts.items() if k.startswith("fallback"))

    def reference(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Straight reference to the goal: states (N+1, 3) and inputs (N, 2)."""
        d = self.goal - pose[:2]
        dist = float(np.hypot(*d))
        n = self.N
        heading = math.atan2(d[1], d[0]) if dist > 0.1 else float(pose[2])  # no spinning at the goal
        heading = pose[2] + (heading - pose[2] + math.pi) % (2 * math.pi) - math.pi
        s = np.minimum(np.arange(n + 1) * self.reference_speed * self.dt, dist)
        unit = d / dist if dist > 1e-6 else np.zeros(2)
        xr = np.column_stack((pose[0] + s * unit[0], pose[1] + s * unit[1], np.full(n + 1, heading)))
        ur = np.zeros((n, 2))
        ur[:, 0] = np.where(s[1:] < dist, self.reference_speed, 0.0)
        return xr, ur

    def _obstacle_params(self, pos: np.ndarray) -> np.ndarray:
        k = self.penalty.n_slots
        out = np.tile(self._empty_slot, (k, 1))
        if len(self._slots):
            order = np.argsort(np.hypot(*(self._centres - pos).T))[:k]
            out[: len(order)] = self._slots[order]
        return out.ravel()

    def step(self, obs: Observation) -> Command:
        """Command for the next period (wall time of the whole step in ``solve_ms``)."""
        t0 = time.perf_counter()
        n = self.N
        k_step = self._step_index
        self._step_index += 1
        x0 = np.asarray(obs.pose, dtype=float).reshape(3)
        if not np.all(np.isfinite(x0)):
            return self._fallback(x0, t0, "bad_measurement")
        xr, ur = self.reference(x0)
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
        p[sl["extra"]] = self._obstacle_params(x0[:2])
        z0 = np.clip(u_guess.ravel(), z_lb, z_ub)
        y0 = y_z0 = None
        if self._plan is not None and self._next == 1 and self._y is not None:
            y0 = shift_multipliers(self.ocp, self._y)
            y_z0 = shift_bound_multipliers(self._y_z)
        if self.failure_injector is not None and self.failure_injector(k_step):
            return self._fallback(x0, t0, "injected")
        res = self.backend.solve(p, z_lb, z_ub, self._g_lb, self._g_ub, z0, y0, y_z0)
        z = res.z
        if not np.all(np.isfinite(z)):
            return self._fallback(x0, t0, f"nonfinite:{res.status}")
        u = z.reshape(n, 2)
        tol = 10 * self.config.constraint_tol + 1e-9
        viol = max(
            float(np.max(z_lb - z, initial=0.0)),
            float(np.max(z - z_ub, initial=0.0)),
            float(np.max(np.abs(np.diff(u, axis=0)) - self._rate_step, initial=0.0)),
        )
        if res.converged and viol <= tol:
            status = "ok"
        elif self.config.accept_inexact and viol <= tol:
            status = "inexact"
        else:
            return self._fallback(x0, t0, f"rejected:{res.status}:viol={viol:.2e}")
        self._plan, self._next = u.copy(), 1
        self._y, self._y_z = np.asarray(res.y, float), res.y_z
        self._u_prev = u[0].copy()
        self.stats_counts[status] = self.stats_counts.get(status, 0) + 1
        return Command(
            v=float(u[0, 0]),
            w=float(u[0, 1]),
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status=status,
            ok=True,
            predicted=rollout_np(x0, u, self.dt),
        )

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
