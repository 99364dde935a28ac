"""Hand-made safe areas, corridors and references for the control tests (imported as ``mpc_cases``)."""

from __future__ import annotations

import numpy as np

from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.scene import RobotParams

ROBOT = RobotParams(
    wheel_radius=0.1,
    track=0.38,
    footprint_radius=0.3,
    wheel_speed_max=20.0,
    v_max=2.0,
    w_max=10.5,
    a_max=1.5,
    alpha_max=6.0,
)


def make_areas(rects) -> SafeAreas:
    """SafeAreas from rectangles (R, 4); edges/portals from shared boundary segments."""
    rects = np.asarray(rects, dtype=float)
    edges, weights, portals = [], [], []
    for i in range(len(rects)):
        for j in range(i + 1, len(rects)):
            a, b = rects[i], rects[j]
            lo = np.maximum(a[:2], b[:2])
            hi = np.minimum(a[2:], b[2:])
            w = hi - lo
            if (abs(w[0]) < 1e-9 and w[1] > 1e-9) or (abs(w[1]) < 1e-9 and w[0] > 1e-9):
                edges.append((i, j))
                ca, cb = (a[:2] + a[2:]) / 2, (b[:2] + b[2:]) / 2
                weights.append(float(np.hypot(*(ca - cb))))
                portals.append([lo, hi])
    return SafeAreas(
        rects=rects,
        edges=np.array(edges, dtype=int).reshape(-1, 2),
        weights=np.array(weights, dtype=float),
        portals=np.array(portals, dtype=float).reshape(-1, 2, 2),
    )


def make_reference(waypoints, areas: SafeAreas, corridor, speed=0.5, dt=0.1, accel=0.5) -> Reference:
    """Constant-speed (with a start ramp) reference along a polyline, sampled every dt."""
    wp = np.asarray(waypoints, dtype=float)
    seg = np.diff(wp, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate(([0.0], np.cumsum(lengths)))
    total = cum[-1]
    # arc length over time: accelerate at `accel` to `speed`, cruise, decelerate to the end
    s_list, s, v = [0.0], 0.0, 0.0
    while s < total - 1e-9:
        remaining = total - s
        v_brake = np.sqrt(2 * accel * remaining)
        v = min(speed, v + accel * dt, v_brake)
        v = max(v, 0.02)
        s = min(total, s + v * dt)
        s_list.append(s)
    s_arr = np.array(s_list)
    xy = np.stack([np.interp(s_arr, cum, wp[:, i]) for i in range(2)], axis=1)
    d = np.diff(xy, axis=0)
    yaw = np.arctan2(d[:, 1], d[:, 0])
    yaw = np.concatenate((yaw, yaw[-1:]))
    yaw = np.unwrap(yaw)
    states = np.column_stack((xy, yaw))
    v_ref = np.concatenate((np.hypot(d[:, 0], d[:, 1]) / dt, [0.0]))
    w_ref = np.concatenate((np.diff(yaw) / dt, [0.0]))
    inputs = np.column_stack((v_ref, w_ref))
    inputs[-1] = 0.0
    rects = areas.rects
    area = np.empty(len(states), dtype=int)
    for k, (x, y) in enumerate(xy):
        inside = [r for r in corridor if rects[r, 0] - 1e-9 <= x <= rects[r, 2] + 1e-9 and rects[r, 1] - 1e-9 <= y <= rects[r, 3] + 1e-9]
        area[k] = inside[0]
    return Reference(dt=dt, states=states, inputs=inputs, area=area)


def make_plan(areas, corridor, waypoints, **kw) -> Plan:
    ref = make_reference(waypoints, areas, corridor, **kw)
    wp = np.asarray(waypoints, float)
    return Plan(
        ok=True,
        reason="ok",
        corridor=np.asarray(corridor, dtype=int),
        goal=wp[-1].copy(),
        waypoints=wp,
        path=wp,
        smoothed=wp,
        reference=ref,
    )


L_RECTS = [[0.0, 0.0, 4.0, 1.0], [3.0, 1.0, 4.0, 4.0], [-2.0, -1.0, 0.0, 2.0]]  # last one: not in the corridor
L_WAYPOINTS = [[0.5, 0.5], [3.5, 0.5], [3.5, 3.5]]

U_RECTS = [[0.0, 0.0, 1.0, 3.0], [0.0, 3.0, 4.0, 4.0], [3.0, 0.0, 4.0, 3.0]]
U_WAYPOINTS = [[0.5, 0.5], [0.5, 3.5], [3.5, 3.5], [3.5, 0.5]]


def inside_union(points, rects, tol=1e-9) -> np.ndarray:
    """(P,) bool: each point (P, 2) lies in at least one rectangle (R, 4)."""
    p = np.asarray(points)[:, None, :]
    r = np.asarray(rects)[None]
    ok = (p[..., 0] >= r[..., 0] - tol) & (p[..., 1] >= r[..., 1] - tol) & (p[..., 0] <= r[..., 2] + tol) & (p[..., 1] <= r[..., 3] + tol)
    return ok.any(axis=1)


def plan_from_samples(areas: SafeAreas, corridor, samples, dt=0.1) -> Plan:
    """A plan whose reference is the given samples taken every ``dt`` [s].

    Args:
        samples: (K, 5) rows ``x, y, yaw, v, w`` [m, m, rad, m/s, rad/s] (a recorded
            reference); the plan's goal is the last position.
        corridor: safe-area indices; each sample's area is the first of them containing it.
    """
    samples = np.asarray(samples, dtype=float)
    xy = samples[:, :2]
    rects = areas.rects
    area = np.array(
        [next(r for r in corridor if np.all(p >= rects[r, :2] - 1e-9) and np.all(p <= rects[r, 2:] + 1e-9)) for p in xy]
    )
    ref = Reference(dt=dt, states=samples[:, :3].copy(), inputs=samples[:, 3:5].copy(), area=area)
    return Plan(True, "ok", np.asarray(corridor, dtype=int), xy[-1].copy(), xy, xy, xy, ref)
