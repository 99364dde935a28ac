"""SensingSAMPC unit checks: the map is built at the measured pose; before its own position is
observed safe the robot only turns on the spot; configuration errors."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sanav_mj.control.base import Observation
from sanav_mj.control.sensing import SensingSAMPC, grid_cells, in_ok_cells
from sanav_mj.control.sensing_config import SensingConfig
from sanav_mj.mapping.live_grid import OCCUPIED
from sanav_mj.scene import load_scenario


def _ctrl(**kwargs):
    sc = load_scenario("single_rect")
    return sc, SensingSAMPC(sc.robot, (-2.0, -3.0, 8.0, 3.0), (6.0, 0.0), sc.robot.footprint_radius + 0.05,
                            (0.12, 0.0), config=SensingConfig(**kwargs))


def _wall_scan(dist: float):
    """A 180-beam full-circle scan whose forward beams (|angle| <= 10 deg) return at ``dist`` [m]."""
    angles = np.linspace(-np.pi, np.pi, 180, endpoint=False)
    hit = np.abs(angles) <= np.radians(10)
    ranges = np.where(hit, dist, 4.0)
    return SimpleNamespace(ranges=ranges, hit=hit, angles=angles)


@pytest.mark.parametrize("dx", [0.0, 1.0])
def test_scan_is_placed_at_the_measured_pose(dx):
    """Without localisation, the same scan at a measured pose 1 m further in x puts its
    returns exactly 20 cells (1 m at 0.05 m) further: the map follows what the controller
    measures, noise included."""
    _, ctrl = _ctrl(localise=False)
    ctrl.step(Observation(t=0.0, pose=np.array([dx, 0.0, 0.0]), velocity=np.zeros(2), scan=_wall_scan(2.0)))
    occ = np.argwhere(ctrl.map.grid.states() == OCCUPIED)
    cols = occ[:, 1]
    # returns at x = dx + 0.12 + 2.0 m; grid origin x = -2 m, cells of 0.05 m
    expected = int(np.floor((dx + 2.12 + 2.0) / 0.05))
    assert abs(np.median(cols) - expected) <= 1


def test_localising_starts_at_the_reset_pose():
    """With localisation the first scan is placed at the pose given to reset (the start),
    not at a measured pose 1 m off: with nothing to match, prediction and measurement are
    blended by their variances (odometry 5 mm against the initially assumed 5 cm)."""
    _, ctrl = _ctrl()
    ctrl.reset(np.zeros(3))
    ctrl.step(Observation(t=0.0, pose=np.array([1.0, 0.0, 0.0]), velocity=np.zeros(2), scan=_wall_scan(2.0)))
    assert ctrl.match_log[0][0] == "empty"
    assert abs(ctrl.estimate[0]) < 0.05  # the blend moved it by 1 m * 0.005^2 / (0.005^2 + 0.05^2)
    first = np.argwhere(ctrl.map.grid.states() == OCCUPIED)
    assert abs(np.median(first[:, 1]) - np.floor((ctrl.estimate[0] + 2.12 + 2.0) / 0.05)) <= 1


def test_turns_on_the_spot_until_its_own_position_is_observed_safe():
    _, ctrl = _ctrl()
    cmd = ctrl.step(Observation(t=0.0, pose=np.zeros(3), velocity=np.zeros(2), scan=_wall_scan(2.0)))
    # a full-circle scan plus the footprint disc: the robot's cell is safe at once and it plans
    assert ctrl.mpc is not None and ctrl.records[0].replan == "initial"
    _, ctrl2 = _ctrl()
    narrow = _wall_scan(2.0)
    narrow.hit[:] = False
    narrow.ranges[:] = 0.05  # sees nothing around: its surroundings stay unknown
    cmd = ctrl2.step(Observation(t=0.0, pose=np.zeros(3), velocity=np.zeros(2), scan=narrow))
    assert ctrl2.mpc is None and cmd.status == "scan_turn" and cmd.v == 0.0 and 0 < cmd.w <= 0.4 + 1e-12
    assert len(ctrl2.records[0].corridor_rects) == 0


@pytest.mark.parametrize("yaw, sign", [(0.86, -1.0), (-0.5, 1.0), (np.pi - 0.1, -1.0), (-np.pi + 0.1, 1.0)])
def test_the_turn_on_the_spot_goes_towards_the_goal(yaw, sign):
    """The scan turn before the first plan turns towards the goal's bearing (the goal is
    straight ahead along +x of the origin here), at the yaw-rate rate bound up to
    ``scan_turn_rate`` (the plain turn, ``scan_turn_stop`` off), and keeps its direction."""
    from dataclasses import replace

    sc, ctrl = _ctrl()
    ctrl.config = replace(ctrl.config, scan_turn_stop=False)
    ctrl.reset(np.array([0.0, 0.0, yaw]))
    blind = _wall_scan(2.0)
    blind.hit[:] = False
    blind.ranges[:] = 0.05  # sees nothing: keeps turning
    ws = []
    for k in range(12):
        cmd = ctrl.step(Observation(t=0.1 * k, pose=np.array([0.0, 0.0, yaw]), velocity=np.zeros(2), scan=blind))
        assert ctrl.mpc is None and cmd.status == "scan_turn"
        ws.append(cmd.w)
    ws = np.array(ws)
    assert np.all(sign * ws > 0)
    step = sc.robot.alpha_max * ctrl.dt
    assert np.allclose(np.abs(ws), np.minimum(step * np.arange(1, 13), ctrl.config.scan_turn_rate), atol=1e-12)


@pytest.mark.parametrize("kwargs", [{"replan_interval": 0}, {"beam_stride": 0}, {"scan_turn_rate": -1.0},
                                    {"max_scan_turn_s": float("inf")}, {"replan_interval": True},
                                    {"controller_pose": "true"}, {"pose_bound": (0.03, -1.0)},
                                    {"meas_sigma0": (0.0, 0.05)}, {"meas_forget": 2.0},
                                    {"consistent_chi2": float("nan")}, {"footprint": (0.1, 0.2)}])
def test_config_errors_name_the_field(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        SensingConfig(**kwargs)


def test_closed_square_cell_test_matches_the_four_shifted_points():
    """in_ok_cells (one lookup for the four points shifted by +-1e-6 cell) against the
    plain definition: a point is accepted when any of its four shifted points' cells is; on
    random points, cell edges and corners, and points outside the grid (clipped)."""
    _, ctrl = _ctrl()
    for k in range(3):
        ctrl.step(Observation(t=0.1 * k, pose=np.array([0.5 * k, 0.0, 0.3 * k]), velocity=np.zeros(2),
                              scan=_wall_scan(2.0)))
    g = ctrl.map.grid
    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.uniform((-2.5, -3.5), (8.5, 3.5), (300, 2)),
                          np.round(rng.uniform((-2, -3), (8, 3), (200, 2)) / 0.05) * 0.05,  # corners
                          np.column_stack([np.round(rng.uniform(-2, 8, 100) / 0.05) * 0.05,
                                           rng.uniform(-3, 3, 100)])])  # vertical edges
    e = 1e-6 * g.resolution
    for ok_at in (g.safe_at, g.route_safe_at):
        ref = np.zeros(len(pts), dtype=bool)
        for dx, dy in ((-e, -e), (-e, e), (e, -e), (e, e)):
            ref |= ok_at(grid_cells(g, pts + np.array([dx, dy])))
        got = in_ok_cells(g, pts, ok_at)
        assert np.array_equal(got, ref)
        assert ref.any() and not ref.all()


def test_cells_of_a_few_points_equal_the_array_path():
    """grid_cells on up to four points (the robot's own: Python floats) gives the same cells as
    its NumPy path on many points: random points, points on cell edges and just beside them,
    and points outside the grid (clamped)."""
    _, ctrl = _ctrl()
    g = ctrl.map.grid
    rng = np.random.default_rng(7)
    filler = np.zeros((5, 2))  # more than four points: the array path
    for k in range(3000):
        p = int(rng.integers(1, 5))
        pts = rng.uniform((-3.0, -4.0), (9.0, 4.0), (p, 2))
        if k % 3 == 0:  # on cell edges (origin + n h), or one rounding step beside them
            pts = g.origin + np.round((pts - g.origin) / g.resolution) * g.resolution
            pts = pts + rng.choice([0.0, 1e-15, -1e-15], (p, 2))
        fast = grid_cells(g, pts)
        ref = grid_cells(g, np.vstack([pts, filler]))[:p]
        assert fast.dtype == np.int64 and np.array_equal(fast, ref)


def test_the_braking_turn_keeps_its_rate_on_steps_without_a_scan():
    """``scan_turn_stop``: a control step that brings no scan (a lidar slower than the control
    rate) turns at the rate the last scan's field of view gives on the unchanged map, not at
    the plain ``scan_turn_rate``: the commands equal those of a run whose scans add nothing."""
    def run(every):
        sc, ctrl = _ctrl(localise=False, scan_turn_stop=True)
        blind = _wall_scan(2.0)
        blind.hit[:] = False
        blind.ranges[:] = 0.05  # sees nothing: the map stays as the first step leaves it
        ws, yaw = [], 0.86
        for k in range(10):
            scan = blind if k % every == 0 else None
            cmd = ctrl.step(Observation(t=0.1 * k, pose=np.array([0.0, 0.0, yaw]), velocity=np.zeros(2), scan=scan))
            assert ctrl.mpc is None and cmd.status == "scan_turn"
            ws.append(cmd.w)
            yaw += cmd.w * 0.1
        return np.array(ws), ctrl

    every_step, ctrl = run(1)
    assert ctrl.config.scan_turn_stop
    assert np.allclose(run(2)[0], every_step, atol=1e-12)
    assert np.abs(every_step).max() < ctrl.config.scan_turn_rate  # braking below the plain rate
