"""The turn on the spot before the lidar run's first plan (:mod:`sanav_mj.control.scan_turn`):
known answers of the swept angle, the braking rate and the route's heading."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sanav_mj.control.scan_turn import braking_rate, route_heading, sweep_angle

HALF = math.radians(135.0)


def _inside(p, pose, offset, theta):
    yaw = pose[2] + theta
    lx = pose[0] + math.cos(yaw) * offset[0] - math.sin(yaw) * offset[1]
    ly = pose[1] + math.sin(yaw) * offset[0] + math.cos(yaw) * offset[1]
    b = math.remainder(math.atan2(p[1] - ly, p[0] - lx) - yaw, math.tau)
    return abs(b) <= HALF


@pytest.mark.parametrize("point, sign, angle", [
    ((-1.0, 0.0), 1, 45.0),  # straight behind: 45 deg either way
    ((-1.0, 0.0), -1, 45.0),
    ((math.cos(math.radians(-150)), math.sin(math.radians(-150))), -1, 15.0),  # behind right, clockwise
    ((math.cos(math.radians(-150)), math.sin(math.radians(-150))), 1, 75.0),  # ... counter-clockwise
    ((1.0, 0.3), 1, 0.0),  # ahead: already inside
])
def test_sweep_angle_known_answers_with_the_lidar_on_the_axle(point, sign, angle):
    step = 0.01
    got = sweep_angle(np.array([point]), np.zeros(3), (0.0, 0.0), HALF, sign, step=step)
    # the first checked rotation at or after the exact one
    assert math.radians(angle) - 1e-9 <= got <= math.radians(angle) + step + 1e-9


def test_sweep_angle_is_the_first_rotation_inside_for_an_offset_lidar_and_the_largest_over_points():
    pose = np.array([0.3, -0.2, 0.86])
    off = (0.12, 0.0)
    rng = np.random.default_rng(0)
    pts = pose[:2] + rng.uniform(-0.5, 0.5, (40, 2))
    step = 0.02
    for sign in (1, -1):
        firsts = []
        for p in pts:
            t = sweep_angle(p[None], pose, off, HALF, sign, step=step)
            j = round(t / step)
            never = not any(_inside(p, pose, off, sign * k * step) for k in range(round(math.pi / step) + 1))
            if never:  # never inside within half a turn (close behind the lidar): ignored
                assert t == 0.0
                continue
            assert _inside(p, pose, off, sign * j * step)
            assert j == 0 or not any(_inside(p, pose, off, sign * k * step) for k in range(j))
            firsts.append(t)
        assert sweep_angle(pts, pose, off, HALF, sign, step=step) == max(firsts)
    assert sweep_angle(np.zeros((0, 2)), pose, off, HALF, 1) == 0.0
    with pytest.raises(ValueError, match="half_fov"):
        sweep_angle(pts, pose, off, 4.0, 1)


def test_braking_rate_stops_within_the_angle():
    alpha, dt = 4.0, 0.1
    # n steps of falling rate cover alpha dt^2 n (n + 1) / 2: the rate is exactly n alpha dt
    for n in (1, 3, 7):
        assert braking_rate(alpha * dt * dt * n * (n + 1) / 2, alpha, dt) == pytest.approx(n * alpha * dt, rel=1e-12)
    for angle in (0.05, 0.7, 2.2, 3.0):
        w, turned = braking_rate(angle, alpha, dt), 0.0
        while w > 1e-12:
            turned += w * dt
            w = max(0.0, w - alpha * dt)
        assert turned == pytest.approx(angle, rel=1e-12)  # the largest such rate: it uses the whole angle
    assert braking_rate(0.0, alpha, dt) == 0.0 and braking_rate(-1.0, alpha, dt) == 0.0
    with pytest.raises(ValueError, match="alpha"):
        braking_rate(1.0, 0.0, dt)


def test_route_heading_known_answers():
    route = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 1.0], [2.0, 1.0]])
    assert route_heading(route, (0.0, 0.0), 1.0) == pytest.approx(math.pi / 4)  # (1, 1) is the first >= 1 m
    assert route_heading(route, (0.0, 0.0), 0.4) == pytest.approx(0.0)
    assert route_heading(route, (0.0, 0.0), 5.0) == pytest.approx(math.atan2(1.0, 2.0))  # none far enough: the farthest
    assert route_heading(np.zeros((3, 2)), (0.0, 0.0)) is None
    assert route_heading(np.zeros((0, 2)), (0.0, 0.0)) is None
