"""Dynamic Window Approach (DWA) baseline, after Fox, Burgard and Thrun (1997).

At every control step the controller

1. builds the *dynamic window*: the (v, w) pairs reachable within one control period ``dt``
   from the current velocity under the acceleration limits ``a_max`` / ``alpha_max``,
   intersected with the speed limits ``[v_min, v_max] x [-w_max, w_max]`` and (optionally)
   with the wheel-speed limit ``|v| + |w| track / 2 <= wheel_radius * wheel_speed_max``;
2. samples it on an ``n_v x n_w`` lattice; each sample (v, w) held constant moves the
   unicycle along a circular arc of curvature ``w / v`` (a turn on the spot when v = 0);
3. traces all arcs at once (closed form, NumPy) through a signed Euclidean distance field of
   the inflated occupancy grid, computed once at construction, and keeps the *admissible*
   samples: those whose arc is free for the distance the robot needs to stop;
4. scores the admissible ones with Fox et al.'s objective
   ``heading_weight * heading + clearance_weight * clearance + velocity_weight * velocity``,
   each term normalised to [0, 1] over the admissible set (min-max), and commands the best.

Terms. ``heading = pi - |bearing error|`` at the end of the ``horizon_s`` rollout (the angle
between the robot's yaw there and the direction to the goal). ``clearance`` is, by default
(``clearance_mode="arc"``), Fox et al.'s *dist*: the path length along the arc to its first
collision, capped at ``clearance_cap_m`` (an arc that turns away from an obstacle scores
high even when it passes close to it, an arc heading into it scores low: that is what makes
DWA steer around obstacles early); a turn on the spot goes nowhere, so its clearance is the
distance field's value where the robot stands (else standing still would always score the
best clearance); ``"min"`` uses the smallest distance-field clearance along
the rollout instead. ``velocity = v``.

Velocity the window is centred on: by default the *measured* body velocity
(``Observation.velocity``), as in Fox et al. (the window is what the robot can really reach,
so it stays honest when the plant lags the command or slips); ``window_from="command"``
centres it on the previous command instead (insensitive to velocity noise). A non-finite
measurement falls back to the previous command.

Collision model. The grid is already inflated by the footprint radius plus a margin, so the
robot is a point. The distance field is signed, in metres: for a free cell the distance from
its centre to the nearest occupied cell centre (>= one cell), for an occupied cell minus the
distance to the nearest free cell centre (<= minus one cell). A position's clearance is the
value of the cell containing it (outside the grid counts as occupied); below half a cell is a
collision, i.e. exactly the occupied cells. Each arc is sampled by path length; the piece of
arc between two consecutive samples lies within the sagitta ``delta = min(s^2 |kappa| / 8,
s / 2)`` of its chord (s the spacing, kappa the curvature), so it lies in the chord's bounding
box grown by ``delta``. The spacing is chosen per arc so that this box is narrower than a
cell (``s (1 + s |kappa| / 4) <= check_step_cells`` cells), hence it meets at most 2 x 2 cells
and :meth:`DWA.path_clearance` checks them all. The check is therefore conservative for the
continuous arc, not only at the samples: no corner of an occupied cell can be cut.
Admissible arcs also keep ``safety_margin_m + speed_margin_s * |v|`` of distance-field
clearance beyond the collision threshold (the plant lags and slips, more so at speed; slow
arcs may still use the narrowest passages). If the robot already stands inside that zone or
in an occupied cell (noise, slip), an arc is admissible when it never goes deeper (its
clearance never drops below the current one), so DWA can back out.

Admissibility (Fox et al.: the robot must be able to stop before it hits anything). A sample
is admissible when its arc is free over the path length the robot covers if it holds (v, w)
for one period and then brakes at ``a_max`` along the same arc,
``stop(v) = |v| dt + v^2 / (2 a_max)``. This is recursively feasible in the nominal model: one
period after an admissible (v, w), braking along the same arc,
``(v - a_max dt, w (v - a_max dt) / v)``, needs ``stop(v) - |v| dt - a_max dt^2 / 2`` of free
path, less than what is left. That sample is added to the lattice explicitly. The free length
is measured on a path-length lattice (conservatively, to one spacing), so the re-anchored
check can miss it by up to one spacing; when nothing passes the check but the previous
command was admissible (or such a braking step), the controller brakes along that certified
arc (``status="brake"``, ``ok=True``): held piecewise constant per period, that braking
covers no more path than ``stop(v)`` and stays on the certified arc, provided the yaw
acceleration limit allows scaling w with v (``|w / v| a_max <= alpha_max``). Assumptions: the
robot follows (v, w) exactly (unicycle, no slip, window centred on the velocity it really
has) and the map is static. Collisions beyond the stopping distance do not make a sample
inadmissible; ``Command.predicted`` shows the constant-(v, w) rollout over ``horizon_s``,
which may run into obstacles beyond that distance.

When no sample is admissible and there is no certificate (off-nominal: slip, noise, a robot
already in an occupied cell, or a turn too tight to brake along) the command still brakes as
hard as the limits allow but is reported as a fallback (``status="fallback_stop"``,
``ok=False``). Rotation on the spot is part of the lattice whenever v = 0 is in the window,
so a stopped robot turns in place through the ordinary scoring.

Two small departures from the 1997 paper, both about the goal: rollouts that pass within
``goal_radius_m`` of the goal get the best heading score (the heading at the end of a
rollout that overshoots the goal is meaningless), and ``v`` is capped at
``sqrt(2 a_max d_goal)`` so the robot can stop at the goal (``goal_slowdown``). The objective
is not Gaussian-smoothed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt

from sanav_mj.control.base import Command, Observation
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.scene import RobotParams


@dataclass(frozen=True)
class DWAConfig:
    """Settings of the Dynamic Window Approach.

    The default weights and cap were picked on 30 generated clutter maps
    (:mod:`sanav_mj.generate`, seeds 100-129, kinematic unicycle plant), not on the paper's
    scenarios.

    Attributes:
        dt: [s] control period; also the time over which the window is reachable.
        horizon_s: [s] rollout at constant (v, w) for the heading term (and for the
            ``"min"`` clearance term and ``Command.predicted``).
        n_v: number of forward-speed samples across the window (>= 1).
        n_w: number of yaw-rate samples across the window (>= 1).
        v_min: [m/s] lowest forward speed commanded, <= 0 (0: forward only, as in Fox et al.).
        heading_weight: [-] weight of the normalised heading term (>= 0).
        clearance_weight: [-] weight of the normalised clearance term (>= 0).
        velocity_weight: [-] weight of the normalised forward-speed term (>= 0).
        clearance_cap_m: [m] clearances above this count as this (> 0); in ``"arc"`` mode it
            is also how far each arc is traced.
        goal_radius_m: [m] a rollout passing this close to the goal gets the best heading.
        goal_slowdown: cap the forward speed at ``sqrt(2 a_max d_goal)``.
        window_from: ``"measured"`` (centre the window on ``Observation.velocity``) or
            ``"command"`` (on the previous command).
        wheel_limits: drop samples beyond the wheel-speed limit
            ``|v| + |w| track / 2 <= wheel_radius * wheel_speed_max``.
        check_step_cells: [cells] width bound, in (0, 1), of the box around each traced
            piece of arc (the path-length spacing on a straight arc).
        clearance_mode: ``"arc"`` (Fox et al.'s dist: path length along the arc to its
            first collision) or ``"min"`` (smallest distance-field clearance within the
            horizon); both capped at ``clearance_cap_m``.
        safety_margin_m: [m] extra distance from the occupied cells that admissible arcs
            keep, on top of the grid's inflation (>= 0).
        speed_margin_s: [s] admissible arcs also keep ``speed_margin_s * |v|`` from the
            occupied cells (>= 0): it absorbs the plant's deviation from the exact unicycle
            arcs (actuator lag, slip), which grows with speed, while slow arcs may still use
            the narrowest passages.
    """

    dt: float = 0.1
    horizon_s: float = 2.0
    n_v: int = 11
    n_w: int = 21
    v_min: float = 0.0
    heading_weight: float = 0.35
    clearance_weight: float = 0.3
    velocity_weight: float = 0.35
    clearance_cap_m: float = 3.0
    goal_radius_m: float = 0.1
    goal_slowdown: bool = True
    window_from: str = "measured"
    wheel_limits: bool = True
    check_step_cells: float = 0.9
    clearance_mode: str = "arc"
    safety_margin_m: float = 0.0
    speed_margin_s: float = 0.05

    def __post_init__(self) -> None:
        for name in ("dt", "horizon_s", "clearance_cap_m"):
            _require(name, getattr(self, name), "finite and > 0", lambda x: math.isfinite(x) and x > 0)
        for name in ("heading_weight", "clearance_weight", "velocity_weight", "goal_radius_m", "safety_margin_m",
                     "speed_margin_s"):
            _require(name, getattr(self, name), "finite and >= 0", lambda x: math.isfinite(x) and x >= 0)
        _require("v_min", self.v_min, "finite and <= 0 [m/s]", lambda x: math.isfinite(x) and x <= 0)
        _require("check_step_cells", self.check_step_cells, "in (0, 1) [cells]", lambda x: 0 < x < 1)
        for name in ("n_v", "n_w"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"DWAConfig.{name}: expected an integer >= 1, got {value!r}")
        if self.horizon_s < self.dt:
            raise ValueError(f"DWAConfig.horizon_s: expected >= dt ({self.dt} s), got {self.horizon_s!r}")
        if self.heading_weight + self.clearance_weight + self.velocity_weight <= 0:
            raise ValueError("DWAConfig weights: expected at least one weight > 0, got all zero")
        if self.window_from not in ("measured", "command"):
            raise ValueError(f"DWAConfig.window_from: expected 'measured' or 'command', got {self.window_from!r}")
        if self.clearance_mode not in ("arc", "min"):
            raise ValueError(f"DWAConfig.clearance_mode: expected 'arc' or 'min', got {self.clearance_mode!r}")
        for name in ("goal_slowdown", "wheel_limits"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"DWAConfig.{name}: expected a bool, got {getattr(self, name)!r}")


def _require(name: str, value, rule: str, ok) -> None:
    try:
        good = bool(ok(float(value)))
    except (TypeError, ValueError):
        good = False
    if not good:
        raise ValueError(f"DWAConfig.{name}: expected {rule}, got {value!r}")


def signed_distance_field(grid: OccupancyGrid) -> np.ndarray:
    """Signed Euclidean distance field of an occupancy grid, cell centre to cell centre.

    Args:
        grid: the (inflated) occupancy grid.

    Returns:
        (ny, nx) [m]: for a free cell the distance from its centre to the nearest occupied
        cell's centre (>= ``resolution``; ``inf`` when no cell is occupied); for an occupied
        cell minus the distance to the nearest free cell's centre (``-inf`` when none is free).
    """
    occ = np.asarray(grid.occupied, dtype=bool)
    res = float(grid.resolution)
    if not occ.any():
        return np.full(occ.shape, np.inf)
    if occ.all():
        return np.full(occ.shape, -np.inf)
    free_dist = distance_transform_edt(~occ) * res
    occ_dist = distance_transform_edt(occ) * res
    return np.where(occ, -occ_dist, free_dist)


def unicycle_arcs(pose, v, w, t) -> np.ndarray:
    """Exact unicycle poses under constant (v, w), for many (v, w) pairs at once.

    Args:
        pose: (3,) [m, m, rad] initial x, y, yaw.
        v: (S,) [m/s] forward speeds.
        w: (S,) [rad/s] yaw rates.
        t: (T,) [s] times since the start.

    Returns:
        (S, T, 3) [m, m, rad] poses; yaw is not wrapped.
    """
    x0, y0, th0 = (float(c) for c in np.asarray(pose, dtype=float).reshape(3))
    v = np.asarray(v, dtype=float).reshape(-1, 1)
    w = np.asarray(w, dtype=float).reshape(-1, 1)
    t = np.asarray(t, dtype=float).reshape(1, -1)
    phi = w * t
    # chord of the arc: length v t sinc(phi / 2), direction th0 + phi / 2 (exact, also w = 0)
    chord = v * t * np.sinc(phi * (0.5 / np.pi))
    mid = th0 + 0.5 * phi
    out = np.empty((v.shape[0], t.shape[1], 3))
    out[..., 0] = x0 + chord * np.cos(mid)
    out[..., 1] = y0 + chord * np.sin(mid)
    out[..., 2] = th0 + phi
    return out


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _normalise(x: np.ndarray) -> np.ndarray:
    lo, hi = float(x.min()), float(x.max())
    if not hi - lo > 1e-12:
        return np.zeros_like(x)
    return (x - lo) / (hi - lo)


class DWA:
    """Dynamic Window Approach controller (the method is in the module docstring).

    Satisfies :class:`sanav_mj.control.base.Controller` (``name = "dwa"``, ``dt`` from the
    config, no range rays).

    Args:
        robot: nominal robot limits (v_max, w_max, a_max, alpha_max, wheel radius, track,
            wheel speed limit).
        grid: occupancy grid inflated by the footprint radius plus a margin.
        goal: (2,) [m] goal position.
        config: DWA settings.

    Raises:
        ValueError: the goal is not 2 finite numbers, or a robot limit is not positive.
    """

    name = "dwa"
    needs_ranges = False

    def __init__(self, robot: RobotParams, grid: OccupancyGrid, goal, config: DWAConfig = DWAConfig()):
        goal = np.asarray(goal, dtype=float).reshape(-1)
        if goal.shape != (2,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"DWA goal: expected 2 finite numbers x, y [m], got {goal.tolist()!r}")
        for field in ("v_max", "w_max", "a_max", "alpha_max"):
            value = getattr(robot, field)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"DWA robot.{field}: expected finite and > 0, got {value!r}")
        self.robot = robot
        self.grid = grid
        self.goal = goal
        self.config = config
        self.dt = float(config.dt)
        self.sdf = signed_distance_field(grid)
        self._res = float(grid.resolution)
        self._inv_res = 1.0 / self._res
        self._origin = np.asarray(grid.origin, dtype=float).reshape(2)
        self._threshold = 0.5 * self._res
        padded = np.pad(self.sdf, 1, constant_values=-np.inf)  # outside the grid is occupied
        self._stride = padded.shape[1]
        self._padded_flat = padded.ravel()
        self._wheel_v_max = float(robot.wheel_radius * robot.wheel_speed_max)
        n_ctrl = max(1, round(config.horizon_s / config.dt))
        self._t_pred = np.linspace(0.0, config.horizon_s, n_ctrl + 1)
        self._t_goal = np.linspace(0.0, config.horizon_s, 2 * n_ctrl + 1)
        self._last = np.zeros(2)
        self._certified = False

    # ------------------------------------------------------------------ distance field

    def _cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Row and column indices into the padded field of the cells holding ``xy`` (..., 2).

        Positions outside the grid map to the padding ring, whose value is ``-inf``.
        """
        xy = np.asarray(xy, dtype=float)
        ny, nx = self.sdf.shape
        j = np.floor((xy[..., 0] - self._origin[0]) * self._inv_res)
        i = np.floor((xy[..., 1] - self._origin[1]) * self._inv_res)
        j = np.clip(j, -1, nx).astype(np.intp) + 1
        i = np.clip(i, -1, ny).astype(np.intp) + 1
        return i, j

    def _lookup(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return self._padded_flat[i * self._stride + j]

    def clearance(self, xy) -> np.ndarray:
        """Signed clearance of positions: the distance field's value at the containing cell.

        Args:
            xy: (..., 2) [m] world positions.

        Returns:
            (...) [m]; ``-inf`` outside the grid. Below ``resolution / 2`` is a collision.
        """
        return self._lookup(*self._cells(xy))

    def collides(self, xy) -> np.ndarray:
        """(...) bool: True where the positions ``(..., 2)`` [m] lie in occupied (or outside) cells."""
        return self.clearance(xy) < self._threshold

    def path_clearance(self, xy, delta=0.0) -> np.ndarray:
        """Conservative clearance of the pieces of path between consecutive points.

        The piece between points k and k+1 is assumed to lie within ``delta`` of the straight
        segment joining them (``delta = 0``: the segment itself). Its clearance is the
        minimum over every cell meeting the segment's bounding box grown by ``delta``; the
        box must be narrower than one cell along x and y, so it meets at most 2 x 2 cells.

        Args:
            xy: (..., K, 2) [m] polylines of K >= 2 points.
            delta: [m] scalar or (...,) per polyline, >= 0.

        Returns:
            (..., K-1) [m] clearance of each piece; below ``resolution / 2`` is a collision.
        """
        xy = np.asarray(xy, dtype=float)
        d = np.asarray(delta, dtype=float)[..., None, None]
        a, b = xy[..., :-1, :], xy[..., 1:, :]
        i_lo, j_lo = self._cells(np.minimum(a, b) - d)
        i_hi, j_hi = self._cells(np.maximum(a, b) + d)
        return np.minimum(
            np.minimum(self._lookup(i_lo, j_lo), self._lookup(i_hi, j_hi)),
            np.minimum(self._lookup(i_lo, j_hi), self._lookup(i_hi, j_lo)),
        )

    # ------------------------------------------------------------------ the method

    def stop_distance(self, v) -> np.ndarray:
        """[m] path length to hold ``v`` [m/s] for one period then brake at ``a_max``: ``|v| dt + v^2 / (2 a_max)``."""
        v = np.asarray(v, dtype=float)
        return np.abs(v) * self.config.dt + v * v / (2.0 * self.robot.a_max)

    def window(self, velocity, pose=None) -> tuple[float, float, float, float]:
        """The dynamic window around ``velocity``.

        Args:
            velocity: (2,) [m/s, rad/s] the velocity the window is centred on.
            pose: (3,) [m, m, rad] current pose, for the goal slowdown (None: no slowdown).

        Returns:
            ``(v_lo, v_hi, w_lo, w_hi)`` [m/s, m/s, rad/s, rad/s] with lo <= hi.
        """
        r, c = self.robot, self.config
        v0, w0 = float(velocity[0]), float(velocity[1])
        dv, dw = r.a_max * c.dt, r.alpha_max * c.dt
        v_lo = min(max(v0 - dv, c.v_min), r.v_max)
        v_hi = min(max(v0 + dv, c.v_min), r.v_max)
        w_lo = min(max(w0 - dw, -r.w_max), r.w_max)
        w_hi = min(max(w0 + dw, -r.w_max), r.w_max)
        if c.goal_slowdown and pose is not None:
            d_goal = float(np.hypot(*(self.goal - np.asarray(pose, dtype=float)[:2])))
            v_cap = math.sqrt(2.0 * r.a_max * d_goal)
            v_hi = max(v_lo, min(v_hi, v_cap))
        return v_lo, v_hi, w_lo, w_hi

    def _brake(self, velocity) -> tuple[float, float]:
        """(v, w) after one period of braking at ``a_max`` along the current arc."""
        r, c = self.robot, self.config
        v0 = min(max(float(velocity[0]), c.v_min), r.v_max)
        w0 = min(max(float(velocity[1]), -r.w_max), r.w_max)
        if v0 == 0.0:
            return 0.0, w0 - math.copysign(min(abs(w0), r.alpha_max * c.dt), w0)
        v = v0 - math.copysign(min(abs(v0), r.a_max * c.dt), v0)
        return v, w0 * (v / v0)

    def evaluate(self, pose, v, w) -> dict[str, np.ndarray]:
        """Trace, check and score (v, w) samples from ``pose``: the core of :meth:`step`.

        Each sample's arc is traced by path length far enough for its stopping distance and
        the clearance term (the cap in ``"arc"`` mode, the horizon in ``"min"`` mode; at most
        one full turn for a closed circle), at the spacing of the module docstring.

        Args:
            pose: (3,) [m, m, rad] current pose.
            v: (S,) [m/s] forward speeds.
            w: (S,) [rad/s] yaw rates.

        Returns:
            Dict of (S,) arrays: ``admissible`` (bool: the arc keeps its safety margin over
            ``stop_m``), ``stop_m`` [m] the stopping distance, ``hit_m`` [m] path length to
            the piece of arc that first enters the margin zone (``inf`` if none within the
            traced length),
            ``clearance_m`` [m] the clearance term before normalisation, ``heading`` [rad]
            ``pi - |bearing error|`` at the end of the horizon (``pi`` when the rollout,
            sampled at half the control period, passes within ``goal_radius_m`` of the
            goal), ``score`` (``-inf`` where not admissible).
        """
        c = self.config
        pose = np.asarray(pose, dtype=float).reshape(3)
        v = np.asarray(v, dtype=float).reshape(-1)
        w = np.asarray(w, dtype=float).reshape(-1)
        stop = self.stop_distance(v)
        reach = np.abs(v) * c.horizon_s
        need = np.maximum(stop, c.clearance_cap_m if c.clearance_mode == "arc" else reach)
        moving = v != 0
        kappa = np.where(moving, w / np.where(moving, v, 1.0), 0.0)
        akappa = np.abs(kappa)
        s0 = c.check_step_cells * self._res
        step = s0 / (1.0 + s0 * akappa / 4.0)  # per-arc spacing: chord box + 2 sagitta <= s0
        sagitta = np.minimum(step * step * akappa / 8.0, step / 2.0)
        loop = np.where(akappa > 0, 2.0 * np.pi / np.where(akappa > 0, akappa, 1.0), np.inf)
        length = np.where(moving, np.minimum(need, loop), 0.0)
        n = int(np.ceil((length / step).max(initial=0.0))) + 1
        k = np.arange(1, n + 1)
        sigma = (np.sign(v) * step)[:, None] * k[None, :]  # signed path length (0 on the spot)
        phi = kappa[:, None] * sigma
        chord = sigma * np.sinc(phi * (0.5 / np.pi))
        mid = pose[2] + 0.5 * phi
        pts = np.empty((v.size, n + 1, 2))
        pts[:, 0, :] = pose[:2]
        pts[:, 1:, 0] = pose[0] + chord * np.cos(mid)
        pts[:, 1:, 1] = pose[1] + chord * np.sin(mid)
        clear = self.path_clearance(pts, sagitta)  # (S, n): piece k covers path (k-1, k] * step
        start_clear = float(self.clearance(pose[:2]))
        # keep the safety margin from occupied cells; inside that zone: never go deeper
        limit = np.minimum(self._threshold + c.safety_margin_m + c.speed_margin_s * np.abs(v), start_clear)
        bad = clear < limit[:, None]
        hit = np.where(bad.any(axis=1), step * (np.argmax(bad, axis=1) + 1), np.inf)
        # a collision in piece k leaves the arc free up to (k - 1) * step
        admissible = hit - step >= stop
        if c.clearance_mode == "arc":
            # a turn on the spot goes nowhere: its clearance is the one where the robot stands
            clearance = np.where(moving, hit - step, start_clear)
        else:
            in_horizon = (k[None, :] - 1) * step[:, None] <= reach[:, None]
            clearance = np.minimum(np.where(in_horizon, clear, np.inf).min(axis=1), start_clear)
        # capped above; bounded below too (an arc that starts inside an obstacle may see -inf)
        clearance = np.clip(clearance, -c.clearance_cap_m, c.clearance_cap_m)
        roll = unicycle_arcs(pose, v, w, self._t_goal)  # (S, T, 3) at half the control period
        end = roll[:, -1, :]
        bearing = np.arctan2(self.goal[1] - end[:, 1], self.goal[0] - end[:, 0])
        heading = np.pi - np.abs(_wrap(bearing - end[:, 2]))
        d_goal = np.hypot(roll[..., 0] - self.goal[0], roll[..., 1] - self.goal[1]).min(axis=1)
        heading = np.where(d_goal <= c.goal_radius_m, np.pi, heading)
        score = np.full(v.shape, -np.inf)
        if admissible.any():
            a = admissible
            score[a] = (
                c.heading_weight * _normalise(heading[a])
                + c.clearance_weight * _normalise(clearance[a])
                + c.velocity_weight * _normalise(v[a])
            )
        return {
            "admissible": admissible,
            "stop_m": stop,
            "hit_m": hit,
            "clearance_m": clearance,
            "heading": heading,
            "score": score,
        }

    def samples(self, velocity, pose) -> tuple[np.ndarray, np.ndarray]:
        """The (v, w) samples of the window around ``velocity`` (2,) at ``pose`` (3,).

        The ``n_v x n_w`` lattice over :meth:`window`, plus braking along the current arc,
        minus the samples beyond the wheel-speed limit (when ``wheel_limits``).

        Returns:
            v: (S,) [m/s], w: (S,) [rad/s].
        """
        c, r = self.config, self.robot
        v_lo, v_hi, w_lo, w_hi = self.window(velocity, pose)
        V, W = (a.ravel() for a in np.meshgrid(np.linspace(v_lo, v_hi, c.n_v), np.linspace(w_lo, w_hi, c.n_w), indexing="ij"))
        v_b, w_b = self._brake(velocity)
        if v_lo - 1e-12 <= v_b <= v_hi + 1e-12 and w_lo - 1e-12 <= w_b <= w_hi + 1e-12:
            V = np.append(V, min(max(v_b, v_lo), v_hi))
            W = np.append(W, min(max(w_b, w_lo), w_hi))
        if c.wheel_limits:
            keep = np.abs(V) + np.abs(W) * (0.5 * r.track) <= self._wheel_v_max + 1e-9
            V, W = V[keep], W[keep]
        return V, W

    def reset(self, pose) -> None:
        """Start a new episode at ``pose`` (3,) [m, m, rad], at rest."""
        self._last = np.zeros(2)
        self._certified = False

    def step(self, obs: Observation) -> Command:
        """Choose (v, w) for the next control period.

        Returns:
            A :class:`Command`; ``predicted`` is the constant-(v, w) rollout at the control
            period, ``(H+1, 3)`` [m, m, rad] with ``H = round(horizon_s / dt)``; ``margins``
            its clearances minus the collision threshold, ``(H+1,)`` [m]; ``solve_ms`` the
            wall time of the whole decision; ``status`` ``"ok"``, ``"brake"`` (certified
            braking) or ``"fallback_stop"`` (``ok=False``).
        """
        t0 = time.perf_counter()
        c, r = self.config, self.robot
        pose = np.asarray(obs.pose, dtype=float).reshape(3)
        vel = self._last
        if c.window_from == "measured":
            meas = np.asarray(obs.velocity, dtype=float).reshape(2)
            if np.all(np.isfinite(meas)):
                vel = meas
        V, W = self.samples(vel, pose)
        chosen = None
        if V.size:
            ev = self.evaluate(pose, V, W)
            if ev["admissible"].any():
                chosen = int(np.argmax(ev["score"]))
        if chosen is not None:
            v, w = float(V[chosen]), float(W[chosen])
            status, ok, certified = "ok", True, True
        else:
            v, w = self._brake(vel)
            w0, dw = float(vel[1]), r.alpha_max * c.dt
            w_clipped = min(max(w, w0 - dw, -r.w_max), w0 + dw, r.w_max)
            # braking along the previous certified arc is safe (see the module docstring)
            certified = self._certified and abs(w_clipped - w) <= 1e-12
            w = w_clipped
            status, ok = ("brake", True) if certified else ("fallback_stop", False)
        self._certified = certified
        self._last = np.array([v, w])
        predicted = unicycle_arcs(pose, [v], [w], self._t_pred)[0]
        margins = self.clearance(predicted[:, :2]) - self._threshold
        solve_ms = (time.perf_counter() - t0) * 1e3
        return Command(v=v, w=w, solve_ms=solve_ms, status=status, ok=ok, predicted=predicted, margins=margins)
