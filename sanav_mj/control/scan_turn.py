"""The turn on the spot before the lidar run's first plan: how far it must go, how fast it may
go to stop there, and which way (:class:`~sanav_mj.control.sensing.SensingSAMPC`,
``SensingConfig.scan_turn_stop`` / ``scan_turn_route``).

Before the first plan the cells behind the robot lie in the lidar's blind sector, so the
robot's own points (the disc centres) are not yet safe; the robot turns on the spot until
they are. These functions return data only: the swept angle the lidar's geometry needs, the
yaw rate from which the turn still stops within a given angle, and the heading of a route.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["sweep_angle", "braking_rate", "route_heading", "route_bearing", "stopping_rate"]


def sweep_angle(points: np.ndarray, pose: np.ndarray, sensor_offset, half_fov: float, sign: float,
                step: float = 0.02, limit: float = math.pi) -> float:
    """[rad] >= 0, the least rotation of the robot on the spot, in the direction ``sign``
    (+1 counter-clockwise, -1 clockwise), after which each of ``points`` has been inside the
    lidar's field of view at some yaw of the turn (the yaw checked every ``step`` [rad]).

    Args:
        points: (P, 2) [m] world positions (e.g. the centres of the unknown cells near the
            robot's own points).
        pose: (3,) [m, m, rad] the robot's pose now (the rotation is about its position).
        sensor_offset: (2,) [m] the lidar's position in the base frame.
        half_fov: [rad] in (0, pi], half the lidar's field of view (a point is inside when
            its bearing from the lidar, relative to the lidar's heading, is at most this).
        sign: +1 or -1, the direction of the turn.
        step: [rad] > 0, the spacing of the yaws checked.
        limit: [rad] > 0, the largest rotation checked.

    Returns:
        The largest, over the points, of the first checked rotation at which the point is
        inside; points never inside within ``limit`` are ignored (e.g. at the lidar itself);
        0 without points.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(pts) == 0:
        return 0.0
    if not (0 < half_fov <= math.pi and step > 0 and limit > 0 and sign in (-1, 1, -1.0, 1.0)):
        raise ValueError(f"sweep_angle: expected half_fov in (0, pi], step > 0, limit > 0 and sign +-1, got "
                         f"{half_fov!r}, {step!r}, {limit!r}, {sign!r}")
    th = float(sign) * np.arange(0.0, limit + 0.5 * step, step)  # (J,)
    yaw = float(pose[2]) + th
    c, s = np.cos(yaw), np.sin(yaw)
    ox, oy = float(sensor_offset[0]), float(sensor_offset[1])
    lx = float(pose[0]) + c * ox - s * oy  # (J,) the lidar's position at each yaw
    ly = float(pose[1]) + s * ox + c * oy
    bearing = np.arctan2(pts[None, :, 1] - ly[:, None], pts[None, :, 0] - lx[:, None]) - yaw[:, None]
    inside = np.abs(np.remainder(bearing + math.pi, 2 * math.pi) - math.pi) <= half_fov  # (J, P)
    seen = inside.any(axis=0)
    if not seen.any():
        return 0.0
    first = np.argmax(inside[:, seen], axis=0)
    return float(np.abs(th[int(first.max())]))


def braking_rate(angle: float, alpha: float, dt: float) -> float:
    """[rad/s] >= 0, the largest yaw rate ``w`` from which a turn whose rate falls by
    ``alpha * dt`` [rad/s] each control step of ``dt`` [s] (each rate held over its step, the
    last one the remainder below ``alpha * dt``) turns at most ``angle`` [rad] before it
    stops: with ``A = angle / (alpha dt^2)`` and ``m`` the largest integer with
    ``m (m + 1) / 2 <= A``, ``w = (m / 2 + A / (m + 1)) alpha dt`` (the steps' rates
    ``w, w - alpha dt, ...`` sum to ``(m + 1) (m / 2 + f)``, ``f`` the fraction of ``w`` over
    ``m alpha dt``). 0 for ``angle <= 0``."""
    if not (alpha > 0 and dt > 0):
        raise ValueError(f"braking_rate: expected alpha > 0 [rad/s^2] and dt > 0 [s], got {alpha!r}, {dt!r}")
    if not angle > 0:
        return 0.0
    a = angle / (alpha * dt * dt)
    m = math.floor(math.sqrt(0.25 + 2.0 * a) - 0.5)
    while (m + 1) * (m + 2) / 2 <= a:  # rounding of the square root
        m += 1
    while m > 0 and m * (m + 1) / 2 > a:
        m -= 1
    return (m / 2 + a / (m + 1)) * alpha * dt


def route_heading(route: np.ndarray, position, distance: float = 1.0) -> float | None:
    """[rad] the bearing from ``position`` (2,) [m] to the first point of ``route`` (P, 2) [m]
    at least ``distance`` [m] from it (the last point when none is), or None when every point
    lies within 1e-9 m of ``position``."""
    pts = np.asarray(route, dtype=float).reshape(-1, 2)
    p = np.asarray(position, dtype=float).reshape(2)
    if len(pts) == 0:
        return None
    d = np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1])
    far = np.nonzero(d >= distance)[0]
    k = int(far[0]) if len(far) else int(np.argmax(d))
    if d[k] <= 1e-9:
        return None
    return math.atan2(pts[k, 1] - p[1], pts[k, 0] - p[0])


def route_bearing(route_areas, pose: np.ndarray, goal: np.ndarray, robot, planner, default: float) -> float:
    """[rad] the heading of the route from ``pose`` (3,) [m, m, rad] to ``goal`` (2,) [m] on
    ``route_areas`` (the :class:`~sanav_mj.mapping.safe_areas.SafeAreas` where unknown space
    counts as passable; ``robot``, ``planner``: the plan's settings), taken at 1 m
    (:func:`route_heading`); ``default`` without areas or without a route."""
    from sanav_mj.planning import plan as make_plan

    if route_areas is None:
        return default
    rp = make_plan(route_areas, pose, goal, robot, planner)
    if not rp.ok or rp.reference is None:
        return default
    h = route_heading(rp.reference.states[:, :2], np.asarray(pose, dtype=float)[:2])
    return default if h is None else h


def stopping_rate(grid, unknown: np.ndarray, pose: np.ndarray, sensor_offset, angles: np.ndarray, sign: float,
                  heading: float, robot, dt: float, config) -> float:
    """[rad/s] >= ``config.scan_turn_creep``: the yaw rate of the turn on the spot (its size;
    the direction is ``sign``) from which it still stops where the lidar will have swept the
    ``unknown`` cells (flat indices of ``grid``: the unknown cells near the own points,
    :meth:`~sanav_mj.mapping.live_grid.LiveGrid.unknown_near`; :func:`sweep_angle` with the
    field of view of the scan's beam ``angles`` [rad]), or where ``heading`` [rad] is reached
    when that lies further in the turn's direction; at most ``config.scan_turn_rate`` and
    ``robot.w_max``, braking at ``robot.alpha_max`` over steps of ``dt`` [s]
    (:func:`braking_rate`). ``pose`` (3,) [m, m, rad], ``sensor_offset`` (2,) [m]."""
    i, j = np.divmod(np.asarray(unknown, dtype=np.int64), grid.shape[1])
    h = grid.resolution
    centres = np.column_stack((grid.origin[0] + (j + 0.5) * h, grid.origin[1] + (i + 0.5) * h))
    half = min(float(np.max(np.abs(angles))), math.pi) if len(angles) else math.pi
    need = sweep_angle(centres, pose, sensor_offset, half, sign) if half > 0 else 0.0
    ahead = sign * math.remainder(heading - float(pose[2]), math.tau)
    top = min(config.scan_turn_rate, robot.w_max)
    return max(config.scan_turn_creep, min(top, braking_rate(max(need, ahead), robot.alpha_max, dt)))
