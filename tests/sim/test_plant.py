"""The MuJoCo plant: wheel kinematics against the physics, contacts, clearance, ray casts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sanav_mj.scene import load_scenario, scenario_spec
from sanav_mj.sim.plant import Plant

#: relative tolerance of the measured steady-state speed / yaw rate against the command
#: (measured here: below 0.4 % for all commands inside the wheel limits)
TOL = 0.02

BLOCK = '<geom name="block" type="box" pos="3.5 0 0.25" size="0.5 0.5 0.25"/>'  # face at x = 3.0


@pytest.fixture(scope="module")
def empty(tmp_path_factory, make_scenario_xml):
    path = tmp_path_factory.mktemp("plant") / "empty.xml"
    path.write_text(make_scenario_xml(floor='<geom name="floor" type="plane" size="20 20 0.1"/>'))
    return load_scenario(path)


@pytest.fixture(scope="module")
def block(tmp_path_factory, make_scenario_xml):
    path = tmp_path_factory.mktemp("plant") / "block.xml"
    path.write_text(make_scenario_xml(BLOCK, goal="8 2"))
    return load_scenario(path)


def _drive(plant: Plant, v: float, w: float, seconds: float, settle: float, dt: float = 0.05):
    """Command (v, w) for ``seconds``; return the measured (v, w), wheel speeds and poses after ``settle``."""
    plant.set_wheel_command(v, w)
    vel, wheels, poses = [], [], []
    while plant.time < seconds - 1e-9:
        plant.advance(dt)
        if plant.time > settle:
            vel.append(plant.body_velocity())
            wheels.append(plant.wheel_speeds())
            poses.append(plant.pose())
    return np.array(vel), np.array(wheels), np.array(poses)


def test_straight(empty):
    plant = Plant(empty)
    r = empty.robot.wheel_radius
    vel, wheels, poses = _drive(plant, 1.0, 0.0, seconds=3.0, settle=1.0)
    assert vel[:, 0] == pytest.approx(1.0, rel=TOL)
    assert np.abs(vel[:, 1]).max() < 1e-3
    assert wheels == pytest.approx(1.0 / r, rel=TOL)
    assert np.abs(poses[:, 1]).max() < 1e-3 and np.abs(poses[:, 2]).max() < 1e-3
    assert poses[-1, 0] == pytest.approx(3.0, abs=0.15)  # minus the ~0.15 s acceleration transient


def test_circle(empty):
    plant = Plant(empty)
    vel, _, poses = _drive(plant, 0.5, 0.5, seconds=6.0, settle=1.5)
    assert vel[:, 0] == pytest.approx(0.5, rel=TOL)
    assert vel[:, 1] == pytest.approx(0.5, rel=TOL)
    # the path is a circle of radius v / w = 1 m: fit its centre and radius
    x, y = poses[:, 0], poses[:, 1]
    a = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    cx, cy, c = np.linalg.lstsq(a, x**2 + y**2, rcond=None)[0]
    assert math.sqrt(c + cx**2 + cy**2) == pytest.approx(1.0, rel=TOL)


def test_top_speed_without_tipping(empty):
    plant = Plant(empty)
    plant.set_wheel_command(empty.robot.v_max, 0.0)
    tilt = 0.0
    for _ in range(40):  # 2 s
        plant.advance(0.05)
        z_axis = plant.data.xmat[plant.model.body("base").id].reshape(3, 3)[:, 2]
        tilt = max(tilt, math.acos(min(1.0, z_axis[2])))
    assert plant.body_velocity()[0] == pytest.approx(empty.robot.v_max, rel=TOL)
    assert tilt < 0.02  # [rad]


def test_at_rest_no_drift(empty):
    plant = Plant(empty)
    plant.reset(np.array([1.0, -2.0, 0.7]))
    p0 = plant.pose()
    plant.set_wheel_command(0.0, 0.0)
    plant.advance(2.0)
    assert plant.pose() == pytest.approx(p0, abs=1e-4)
    assert np.abs(plant.body_velocity()).max() < 1e-3


def test_wheel_radius_mismatch_shows_as_speed_error(empty):
    spec = scenario_spec(empty)
    for name in ("left_wheel", "right_wheel"):
        spec.geom(name).size = [0.11, 0.11, 0.025]  # 10 % larger than nominal
    plant = Plant(empty, model=spec.compile())
    vel, _, _ = _drive(plant, 1.0, 0.0, seconds=2.0, settle=1.0)
    assert vel[:, 0] == pytest.approx(1.1, rel=TOL)


def test_saturated_command_keeps_curvature(empty):
    plant = Plant(empty)
    p = empty.robot
    cmd = plant.set_wheel_command(3.0, 2.0)
    assert plant.last_command_scaled
    assert np.abs(cmd).max() == pytest.approx(p.wheel_speed_max)
    half = 0.5 * p.track * 2.0
    assert cmd[1] / cmd[0] == pytest.approx((3.0 + half) / (3.0 - half))
    cmd = plant.set_wheel_command(0.5, 0.5)
    assert not plant.last_command_scaled
    assert cmd == pytest.approx([(0.5 - 0.5 * p.track / 2) / p.wheel_radius, (0.5 + 0.5 * p.track / 2) / p.wheel_radius])


@pytest.mark.parametrize("v, w", [(math.nan, 0.0), (1.0, math.inf)])
def test_nonfinite_command_stops(empty, v, w):
    plant = Plant(empty)
    plant.set_wheel_command(1.0, 0.0)
    cmd = plant.set_wheel_command(v, w)
    assert cmd == pytest.approx([0.0, 0.0])
    assert plant.last_command_nonfinite and plant.nonfinite_commands == 1
    assert np.all(plant.data.ctrl == 0.0)


def test_advance_rounds_to_physics_steps(empty):
    plant = Plant(empty)
    ts = plant.timestep
    plant.advance(0.05)
    assert plant.time == pytest.approx(0.05)
    plant.advance(0.4 * ts)  # at least one step
    assert plant.time == pytest.approx(0.05 + ts)
    with pytest.raises(ValueError, match="duration_s"):
        plant.advance(0.0)


def test_reset(block):
    plant = Plant(block)
    assert plant.pose() == pytest.approx(block.start)
    plant.set_wheel_command(1.0, 0.3)
    plant.advance(1.0)
    plant.reset(np.array([1.0, 2.0, -0.5]))
    assert plant.time == 0.0
    assert plant.pose() == pytest.approx([1.0, 2.0, -0.5])
    assert plant.body_velocity() == pytest.approx([0.0, 0.0])


def test_contact_clearance_and_footprint_clearance_driving_into_a_box(block):
    plant = Plant(block)
    front = block.model.geom("chassis").size[0]  # chassis half length: its front face
    face = 3.0
    plant.set_wheel_command(0.8, 0.0)
    clear_hist, hit_at = [], None
    for _ in range(200):
        contacts = plant.advance(0.05)
        x = plant.pose()[0]
        if contacts:
            hit_at = x
            break
        assert plant.robot_obstacle_contacts() == 0
        clear = plant.clearance()
        clear_hist.append(clear)
        if clear < 1.9:  # within distmax: exact distance from the chassis front face
            assert clear == pytest.approx(face - (x + front), abs=2e-3)
        fp = plant.footprint_clearance()
        assert fp == pytest.approx(face - x - block.robot.footprint_radius, abs=1e-6)
        assert min(fp, 2.0) <= clear + 1e-9  # the footprint circle is conservative (clearance caps at 2 m)
    assert hit_at is not None and plant.robot_obstacle_contacts() > 0
    assert hit_at + front == pytest.approx(face, abs=0.01)
    near = np.array([c for c in clear_hist if c < 2.0])
    assert len(near) > 20 and np.all(np.diff(near) < 0)  # strictly decreasing while approaching
    assert plant.clearance() <= 0.0


def test_brief_touch_between_control_steps_is_counted(block):
    """A contact at an inner physics step is reported even if the robot has left by the end."""
    plant = Plant(block)
    front = block.model.geom("chassis").size[0]
    plant.reset(np.array([3.0 - front + 0.001, 0.0, 0.0]))  # chassis 1 mm into the face
    plant.set_wheel_command(-1.0, 0.0)  # back away
    n = plant.advance(0.2)
    assert n > 0
    assert plant._count_contacts() == 0 and plant.clearance() > 0.05  # gone by the end...
    assert plant.robot_obstacle_contacts() == n  # ...but the touch is reported
    plant.advance(0.05)
    assert plant.robot_obstacle_contacts() == 0


@pytest.mark.parametrize("yaw", [0.0, 0.6])
def test_rays_known_distances(block, yaw):
    plant = Plant(block)
    plant.reset(np.array([0.0, 0.0, yaw]))
    n = 8
    rays = plant.ray_ranges(n, 10.0, walls=False)
    angles = yaw + 2 * math.pi * np.arange(n) / n
    for k, a in enumerate(angles):
        c, s = math.cos(a), math.sin(a)
        # the block spans x [3, 4], y [-0.5, 0.5]; a ray at angle a hits the face x = 3 if |3 tan a| <= 0.5
        if c > 0 and abs(3.0 * s / c) <= 0.5:
            assert rays[k] == pytest.approx(3.0 / c, abs=1e-9)
        else:
            assert rays[k] == 10.0
    walls = plant.ray_ranges(4, 10.0)  # workspace x [-2, 10], y [-4, 4] from (0, 0)
    if yaw == 0.0:
        assert walls == pytest.approx([3.0, 4.0, 2.0, 4.0])
    assert plant.ray_ranges(4, 1.0) == pytest.approx(np.ones(4))


def test_rays_when_obstacles_share_the_robot_group(tmp_path, make_scenario_xml):
    """Obstacles in the robot's geom group: rays hitting the wheels (same group) are recast exactly."""
    path = tmp_path / "g.xml"
    path.write_text(make_scenario_xml(BLOCK.replace("/>", ' group="1"/>'), goal="8 2"))
    plant = Plant(load_scenario(path))
    rays = plant.ray_ranges(8, 10.0, walls=False)
    assert rays[0] == pytest.approx(3.0)
    assert rays[1:] == pytest.approx(np.full(7, 10.0))


def test_plant_rejects_a_foreign_model(block, empty):
    with pytest.raises(ValueError, match="geoms"):
        Plant(block, model=empty.model)
