"""The 2-D lidar: exact ranges against analytic distances, never the floor or the robot, seeded noise."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from sanav_mj.resources import robot_model_path
from sanav_mj.scene import load_scenario, robot_qpos
from sanav_mj.sim.lidar import Lidar, LidarConfig, lidar_config

# Axis-aligned box [2.5, 3.5] x [-1, 1] and a cylinder of radius 0.4 at (-1, 2); robot at (0, 0).
BOX = (2.5, -1.0, 3.5, 1.0)
CYL = (-1.0, 2.0, 0.4)
WORLD = ('<geom name="box" type="box" pos="3 0 0.3" size="0.5 1 0.3" group="{g}"/>\n'
         '<geom name="cyl" type="cylinder" pos="-1 2 0.3" size="0.4 0.3" group="{g}"/>')


def _slab(o, d, box):
    """Analytic distance along the unit ray o + t d to an axis-aligned box (inf if missed)."""
    t0, t1 = -np.inf, np.inf
    for k, (lo, hi) in enumerate(((box[0], box[2]), (box[1], box[3]))):
        if abs(d[k]) < 1e-15:
            if not lo <= o[k] <= hi:
                return np.inf
            continue
        a, b = (lo - o[k]) / d[k], (hi - o[k]) / d[k]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return t0 if t1 >= t0 >= 0 else np.inf


def _circle(o, d, cyl):
    c = np.array(cyl[:2])
    f = o - c
    b = f @ d
    disc = b * b - (f @ f - cyl[2] ** 2)
    if disc < 0:
        return np.inf
    t = -b - math.sqrt(disc)
    return t if t >= 0 else np.inf


def _analytic(origin, heading, angles, max_range):
    out = np.full(len(angles), np.inf)
    for k, a in enumerate(heading + angles):
        d = np.array([math.cos(a), math.sin(a)])
        t = min(_slab(origin, d, BOX), _circle(origin, d, CYL))
        out[k] = t if t <= max_range else np.inf
    return out


def _setup(write_scenario, group=0, pose=(0.0, 0.0, 0.3), tilt=0.0, world=None):
    sc = load_scenario(write_scenario(WORLD.format(g=group) if world is None else world,
                                      start="0 0 0", goal="1.5 -2"))
    model = sc.model
    data = mujoco.MjData(model)
    data.qpos[:] = robot_qpos(model, np.array(pose))
    if tilt:  # pitch the base about its y axis
        q = np.empty(4)
        mujoco.mju_axisAngle2Quat(q, np.array([0.0, 1.0, 0.0]), tilt)
        adr = model.jnt_qposadr[model.body("base").jntadr[0]]
        yaw = np.empty(4)
        mujoco.mju_axisAngle2Quat(yaw, np.array([0.0, 0.0, 1.0]), pose[2])
        out = np.empty(4)
        mujoco.mju_mulQuat(out, yaw, q)
        data.qpos[adr + 3: adr + 7] = out
    mujoco.mj_forward(model, data)
    return sc, model, data


def test_config_read_from_robot_model(write_scenario):
    sc, model, _ = _setup(write_scenario)
    cfg = lidar_config(model)
    assert cfg.beams == 541
    assert cfg.fov == pytest.approx(math.radians(270.0), abs=1e-15)
    assert (cfg.max_range, cfg.rate, cfg.noise_std) == (10.0, 20.0, 0.02)
    assert cfg.offset == (0.12, 0.0)
    ang = cfg.angles
    assert ang[0] == pytest.approx(-0.75 * math.pi, abs=1e-15)
    assert ang[-1] == pytest.approx(0.75 * math.pi, abs=1e-12)
    assert np.allclose(np.diff(ang), math.radians(0.5), atol=1e-14)


DECOR = '<geom name="decor" type="box" pos="1.5 0 0.3" size="0.05 3 0.3" contype="0" conaffinity="0"/>'


@pytest.mark.parametrize("group,decor", [(0, False), (1, False), (0, True)])
def test_exact_ranges_box_and_cylinder(write_scenario, group, decor):
    """Noise-free returns equal the analytic distances; group 1 = the robot's own group; a
    decoration (not an obstacle) in front of the box is seen by mj_multiRay and must be
    looked through (the recast path)."""
    world = WORLD.format(g=group) + ("\n" + DECOR if decor else "")
    sc, model, data = _setup(write_scenario, group=group, world=world)
    cfg = LidarConfig(fov=2 * math.pi, beams=720, max_range=10.0, rate=20.0, noise_std=0.0)
    lidar = Lidar(model, sc.obstacles, cfg)
    ranges, origin, heading = lidar.true_ranges(data)
    assert heading == pytest.approx(0.3, abs=1e-12)
    expect = _analytic(origin[:2], heading, cfg.angles, cfg.max_range)
    hit = np.isfinite(expect)
    assert 100 < hit.sum() < 720  # both obstacles are seen, most beams are not blocked
    if decor:
        assert "decor" not in {o.name for o in sc.obstacles}
        gid = np.full(720, -1, dtype=np.int32)
        mujoco.mj_multiRay(model, data, origin, lidar._vec.ravel(), lidar._groups, 1,
                           model.body("base").id, gid, np.zeros(720), None, 720, 10.0)
        assert np.count_nonzero(gid == model.geom("decor").id) > 20
    assert np.array_equal(np.isfinite(ranges), hit)
    # mj_ray works in double precision on coordinates of order 10 m
    assert np.max(np.abs(ranges[hit] - expect[hit])) < 1e-9
    scan = lidar.scan(data, np.random.default_rng(0))
    assert np.array_equal(scan.hit, hit)
    assert np.all(scan.ranges[~hit] == cfg.max_range)
    assert np.max(np.abs(scan.ranges[hit] - expect[hit])) < 1e-9


def test_floor_and_robot_never_hit(write_scenario):
    """Empty world, robot tilted by 0.2 rad: every beam misses (the fan stays horizontal,
    the wheels/chassis at the site's height are not returned)."""
    sc, model, data = _setup(write_scenario, world="", tilt=0.2)
    # make the robot's geoms visible to the ray group used for (absent) obstacles: group 0 and 1
    lidar = Lidar(model, sc.obstacles, LidarConfig(fov=2 * math.pi, beams=360, noise_std=0.0))
    ranges, _, _ = lidar.true_ranges(data)
    assert np.all(np.isinf(ranges))
    # With obstacles in the robot's group (so mj_multiRay sees the robot's own geoms and the
    # tilted fan starts inside the chassis): still exactly the analytic obstacle distances.
    sc, model, data = _setup(write_scenario, group=1, tilt=0.2)
    cfg = LidarConfig(fov=2 * math.pi, beams=360, noise_std=0.0)
    lidar = Lidar(model, sc.obstacles, cfg)
    ranges, origin, heading = lidar.true_ranges(data)
    expect = _analytic(origin[:2], heading, cfg.angles, cfg.max_range)
    assert np.array_equal(np.isfinite(ranges), np.isfinite(expect))
    ok = np.isfinite(expect)
    assert np.max(np.abs(ranges[ok] - expect[ok])) < 1e-9


def test_floor_in_obstacle_group_is_not_returned(write_scenario):
    """A floor sharing the obstacles' group, sensor tilted down: rays aimed below horizontal
    would meet the floor within 1 m; the horizontal fan never does."""
    sc, model, data = _setup(write_scenario, tilt=0.3)
    assert model.geom_group[model.geom("floor").id] == model.geom_group[model.geom("box").id]
    lidar = Lidar(model, sc.obstacles, LidarConfig(fov=2 * math.pi, beams=360, noise_std=0.0))
    ranges, origin, heading = lidar.true_ranges(data)
    expect = _analytic(origin[:2], heading, lidar.config.angles, 10.0)
    assert np.array_equal(np.isfinite(ranges), np.isfinite(expect))


def test_max_range_cuts_returns(write_scenario):
    sc, model, data = _setup(write_scenario, pose=(0.0, 0.0, 0.0))
    cfg = LidarConfig(fov=math.radians(10), beams=11, max_range=2.0, noise_std=0.0)
    scan = Lidar(model, sc.obstacles, cfg).scan(data, np.random.default_rng(0))
    assert not scan.hit.any()  # the box face is 2.38 m ahead of the sensor
    cfg = LidarConfig(fov=math.radians(10), beams=11, max_range=3.0, noise_std=0.0)
    scan = Lidar(model, sc.obstacles, cfg).scan(data, np.random.default_rng(0))
    assert scan.hit[5] and scan.ranges[5] == pytest.approx(2.5 - 0.12, abs=1e-9)  # sensor 0.12 m ahead


def test_noise_is_seeded_and_has_the_declared_std(write_scenario):
    sc, model, data = _setup(write_scenario)
    cfg = LidarConfig(fov=2 * math.pi, beams=2000, noise_std=0.05)
    lidar = Lidar(model, sc.obstacles, cfg)
    a = lidar.scan(data, np.random.default_rng(7))
    b = lidar.scan(data, np.random.default_rng(7))
    c = lidar.scan(data, np.random.default_rng(8))
    assert np.array_equal(a.ranges, b.ranges)
    assert not np.array_equal(a.ranges, c.ranges)
    true, _, _ = lidar.true_ranges(data)
    err = (a.ranges - true)[a.hit]
    n = err.size
    assert n > 300
    # mean within 5 standard errors of 0, sample std within 5 standard errors of 0.05
    assert abs(err.mean()) < 5 * 0.05 / math.sqrt(n)
    assert abs(err.std() - 0.05) < 5 * 0.05 / math.sqrt(2 * n)


def test_missing_field_is_named(tmp_path):
    text = robot_model_path().read_text()
    assert '<numeric name="lidar_beams"' in text
    lines = [ln for ln in text.splitlines() if 'name="lidar_beams"' not in ln]
    robot = tmp_path / "robot.xml"
    robot.write_text("\n".join(lines))
    model = mujoco.MjModel.from_xml_path(str(robot))
    with pytest.raises(ValueError, match="lidar_beams"):
        lidar_config(model)


def test_config_validation():
    with pytest.raises(ValueError, match="beams"):
        LidarConfig(beams=1)
    with pytest.raises(ValueError, match="fov"):
        LidarConfig(fov=7.0)
    with pytest.raises(ValueError, match="noise_std"):
        LidarConfig(noise_std=-0.1)


def _cross_section_distance(model, ob, z, p):
    """Signed 2-D distance from point p to obstacle ob's cross-section at height z."""
    g = ob.geom_id
    if ob.kind == "box":
        c, s = math.cos(ob.yaw), math.sin(ob.yaw)
        d = p - ob.center
        q = np.abs([c * d[0] + s * d[1], -s * d[0] + c * d[1]]) - ob.half_size
        return float(np.linalg.norm(np.maximum(q, 0)) + min(q.max(), 0.0))
    r = float(model.geom_size[g][0])
    if ob.kind == "capsule":  # rounded ends: narrower below / above the straight part
        zc, half = float(model.geom_pos[g][2]), float(model.geom_size[g][1])
        dz = max(abs(z - zc) - half, 0.0)
        r = math.sqrt(max(r * r - dz * dz, 0.0))
    return float(np.linalg.norm(p - ob.center) - r)


@pytest.mark.parametrize("name", ["single_rect", "double_rect", "u_shape", "v_shape", "complex"])
def test_builtin_scenarios_returns_lie_on_obstacle_sections(name):
    """From the start pose of each built-in scenario, every return lies on the cross-section
    of an obstacle at the scan height (boxes at any yaw, cylinders, capsules: a capsule's
    rounded end is narrower where it crosses the plane)."""
    sc = load_scenario(name)
    model = sc.model
    data = mujoco.MjData(model)
    data.qpos[:] = robot_qpos(model, sc.start)
    mujoco.mj_forward(model, data)
    cfg = lidar_config(model)
    lidar = Lidar(model, sc.obstacles, LidarConfig(cfg.fov, cfg.beams, cfg.max_range, cfg.rate, 0.0, cfg.offset))
    ranges, origin, heading = lidar.true_ranges(data)
    assert origin[2] == pytest.approx(0.28, abs=1e-3)  # the scan plane, from the robot file
    hit = np.isfinite(ranges)
    assert hit.any()
    a = heading + cfg.angles[hit]
    pts = origin[:2] + ranges[hit, None] * np.stack([np.cos(a), np.sin(a)], axis=1)
    for p in pts:
        d = min(_cross_section_distance(model, ob, origin[2], p) for ob in sc.obstacles)
        assert abs(d) < 1e-9
