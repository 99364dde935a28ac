"""Scenario loading: built-ins, files written from scratch, robot parameters, every error path."""

from __future__ import annotations

import math
import shutil
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest
from scipy import ndimage

from sanav_mj.resources import builtin_scenarios, robot_model_path, scenarios_dir
from sanav_mj.scene import (
    ScenarioError,
    initial_qpos,
    load_scenario,
    robot_params,
    scenario_spec,
)

BUILTINS = ["complex", "double_rect", "single_rect", "u_shape", "v_shape"]
MARGIN = 0.05  # [m] the loader's default margin


@pytest.fixture(scope="module")
def builtins():
    return {name: load_scenario(name) for name in BUILTINS}


# ----------------------------------------------------------------------------- built-ins


def test_builtin_names():
    assert builtin_scenarios() == BUILTINS


@pytest.mark.parametrize(
    "name, kinds",
    [
        ("single_rect", ["box"]),
        ("double_rect", ["box", "box"]),
        ("u_shape", ["box", "box", "box"]),
        ("v_shape", ["box", "box"]),
    ],
)
def test_builtin_obstacles(builtins, name, kinds):
    sc = builtins[name]
    assert [o.kind for o in sc.obstacles] == kinds
    assert sc.name == name and sc.path == scenarios_dir() / f"{name}.xml"
    span = sc.bounds[2:] - sc.bounds[:2]
    assert 8.0 <= span[0] <= 12.0


def test_complex_is_mixed(builtins):
    obs = builtins["complex"].obstacles
    kinds = [o.kind for o in obs]
    assert len(obs) >= 8
    assert {"box", "cylinder", "capsule"} <= set(kinds)
    box_yaws = {round(o.yaw, 3) for o in obs if o.kind == "box"}
    assert len(box_yaws) >= 4
    assert len({tuple(o.half_size) for o in obs}) >= 6


def test_v_shape_boxes_are_rotated(builtins):
    upper, lower = builtins["v_shape"].obstacles
    assert math.degrees(upper.yaw) == pytest.approx(-35.0, abs=1e-6)
    assert math.degrees(lower.yaw) == pytest.approx(35.0, abs=1e-6)


def test_static_body_obstacles_are_in_world_frame(builtins):
    # complex.xml groups box_e and box_f in body "south_group" at (7.5, -3.2)
    obs = {o.name: o for o in builtins["complex"].obstacles}
    assert obs["box_e"].center == pytest.approx([9.0, -2.7])
    assert obs["box_f"].center == pytest.approx([5.5, -3.2])
    assert math.degrees(obs["box_f"].yaw) == pytest.approx(60.0)


def _straight_line_hits(sc) -> bool:
    s = np.linspace(0.0, 1.0, 400)[:, None]
    pts = sc.start[:2] * (1 - s) + sc.goal * s
    return any(np.any(o.signed_distance(pts) < 0) for o in sc.obstacles)


@pytest.mark.parametrize("name", ["single_rect", "double_rect", "u_shape", "v_shape", "complex"])
def test_straight_line_to_goal_is_blocked(builtins, name):
    assert _straight_line_hits(builtins[name])


# ------------------------------------------------------- solvability (independent raster)


def _occupied_centres(sc, res: float):
    """Cells whose centre lies in an obstacle footprint: a raster independent of scene.py."""
    xmin, ymin, xmax, ymax = sc.bounds
    xs = np.arange(xmin + res / 2, xmax, res)
    ys = np.arange(ymin + res / 2, ymax, res)
    X, Y = np.meshgrid(xs, ys)
    occ = np.zeros(X.shape, dtype=bool)
    for o in sc.obstacles:
        dx, dy = X - o.center[0], Y - o.center[1]
        if o.kind == "box":
            c, s = math.cos(o.yaw), math.sin(o.yaw)
            u, v = c * dx + s * dy, -s * dx + c * dy
            occ |= (np.abs(u) <= o.half_size[0]) & (np.abs(v) <= o.half_size[1])
        else:
            occ |= dx**2 + dy**2 <= o.half_size[0] ** 2
    return X, Y, occ


def _free_for_disc(sc, radius: float, res: float = 0.04, extra=None):
    """Cells where a disc of ``radius`` fits (conservative by one cell), and the cell lookup."""
    X, Y, occ = _occupied_centres(sc, res)
    if extra is not None:
        occ |= extra(X, Y)
    dist = ndimage.distance_transform_edt(~occ) * res
    xmin, ymin, xmax, ymax = sc.bounds
    to_edge = np.minimum.reduce([X - xmin, xmax - X, Y - ymin, ymax - Y])
    free = (dist > radius + res) & (to_edge > radius + res / 2)

    def cell(p):
        return int((p[1] - ymin) // res), int((p[0] - xmin) // res)

    return free, cell


def _connected(free, a, b) -> bool:
    labels, _ = ndimage.label(free)
    return bool(free[a] and free[b] and labels[a] == labels[b])


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_is_solvable(builtins, name):
    sc = builtins[name]
    free, cell = _free_for_disc(sc, sc.robot.footprint_radius + MARGIN)
    assert _connected(free, cell(sc.start), cell(sc.goal))


def test_double_rect_gap_is_the_only_passage(builtins):
    sc = builtins["double_rect"]
    low, high = sc.obstacles
    gap_lo = low.center[1] + low.half_size[1]
    gap_hi = high.center[1] - high.half_size[1]
    width = gap_hi - gap_lo
    inflated = 2 * (sc.robot.footprint_radius + MARGIN)
    assert inflated < width < inflated + 0.5  # passable, but narrow

    def plug(X, Y):
        return (np.abs(X - low.center[0]) <= low.half_size[0]) & (Y >= gap_lo) & (Y <= gap_hi)

    free, cell = _free_for_disc(sc, sc.robot.footprint_radius + MARGIN, extra=plug)
    assert not _connected(free, cell(sc.start), cell(sc.goal))


def test_u_shape_opens_towards_robot(builtins):
    sc = builtins["u_shape"]
    back = max(sc.obstacles, key=lambda o: o.center[0])
    arms = [o for o in sc.obstacles if o is not back]
    assert all(a.center[0] < back.center[0] for a in arms)  # arms reach back towards the start
    assert sc.start[0] < min(a.center[0] - a.half_size[0] for a in arms)
    assert sc.goal[0] > back.center[0] + back.half_size[0]  # goal behind the U
    # the straight line from start enters the cavity first: the local-minimum trap
    ys = sorted(a.center[1] for a in arms)
    assert ys[0] < sc.start[1] < ys[1]


# ----------------------------------------------------------------------------- robot


def test_robot_params_match_the_xml(builtins):
    """Cross-check against values parsed from the XML text independently of MuJoCo."""
    root = ET.parse(robot_model_path()).getroot()
    cls = root.find(".//default[@class='diff_drive_wheel']/geom")
    r = float(cls.get("size").split()[0])
    wheel_y = [float(b.get("pos").split()[1]) for b in root.iter("body") if b.get("name") in ("left_wheel", "right_wheel")]
    ctrl = float(root.find(".//velocity[@name='left_wheel']").get("ctrlrange").split()[1])
    deck = [float(v) for v in root.find(".//geom[@name='deck']").get("size").split()]
    limits = [float(v) for v in root.find(".//numeric[@name='robot_limits']").get("data").split()]
    p = builtins["u_shape"].robot
    assert p.wheel_radius == pytest.approx(r)
    assert p.track == pytest.approx(abs(wheel_y[0] - wheel_y[1]))
    assert p.wheel_speed_max == pytest.approx(ctrl)
    assert p.v_max == pytest.approx(ctrl * r)
    assert p.footprint_radius == pytest.approx(math.hypot(deck[0], deck[1]))  # the deck is widest
    assert p.w_max == pytest.approx(min(limits[2], 2 * p.v_max / p.track))
    assert (p.a_max, p.alpha_max) == pytest.approx(limits[:2])


def test_robot_is_jackal_like(builtins):
    m = builtins["u_shape"].model
    p = builtins["u_shape"].robot
    assert 15.0 <= m.body_subtreemass[m.body("base").id] <= 19.0
    assert 0.09 <= p.wheel_radius <= 0.11 and 0.35 <= p.track <= 0.42
    assert 1.9 <= p.v_max <= 2.1
    assert m.opt.timestep == pytest.approx(0.002)


def test_robot_params_follow_the_model(builtins):
    spec = scenario_spec(builtins["single_rect"])
    spec.geom("left_wheel").size = [0.12, 0.12, 0.025]
    spec.geom("right_wheel").size = [0.12, 0.12, 0.025]
    spec.body("left_wheel").pos = [0, 0.25, 0]
    spec.actuator("left_wheel").ctrlrange = [-10, 10]
    p = robot_params(spec.compile())
    assert p.wheel_radius == pytest.approx(0.12)
    assert p.track == pytest.approx(0.44)
    assert p.wheel_speed_max == pytest.approx(10.0)
    assert p.v_max == pytest.approx(1.2)


@pytest.mark.parametrize("yaw", [None, 1.0])
def test_initial_qpos_rests_wheels_on_the_floor(builtins, yaw):
    sc = builtins["complex"]
    m = sc.model
    d = mujoco.MjData(m)
    d.qpos[:] = initial_qpos(sc, yaw=yaw)
    mujoco.mj_forward(m, d)
    r = sc.robot.wheel_radius
    for name in ("left_wheel", "right_wheel"):
        assert d.geom_xpos[m.geom(name).id][2] - r == pytest.approx(0.0, abs=1e-9)
    assert d.xpos[m.body("base").id][:2] == pytest.approx(sc.start[:2])
    heading = d.xmat[m.body("base").id].reshape(3, 3)[:, 0]
    want = sc.start[2] if yaw is None else yaw
    assert math.atan2(heading[1], heading[0]) == pytest.approx(want)


# ------------------------------------------------------------- files written from scratch


def test_file_from_scratch_loads(write_scenario):
    path = write_scenario(
        '<geom name="wall" type="box" pos="2 0 0.25" size="0.1 1 0.25" euler="0 0 30"/>'
        '<geom name="post" type="cylinder" pos="2 2.5 0.3" size="0.2 0.3"/>'
        '<geom name="pill" type="capsule" pos="3 -2.5 0.5" size="0.25 0.25"/>'
        '<geom name="lying" type="box" pos="6 2 0.1" size="0.5 0.1 0.3" euler="90 0 0"/>'
        '<geom type="box" pos="6 -2 0.2" size="0.2 0.2 0.2"/>'
        '<geom name="decor" type="sphere" pos="8 3 0" size="0.1" contype="0" conaffinity="0"/>'
        '<geom name="mat" type="plane" pos="1 1 0.001" size="1 1 0.1" contype="0" conaffinity="0"/>'
        '<body name="group" pos="0 -3 0" euler="0 0 90"><geom name="in_body" type="box" pos="1 0 0.2" size="0.3 0.1 0.2"/></body>',
        start="0 0 0.5", goal="8 0",
    )
    sc = load_scenario(path)
    obs = {o.name: o for o in sc.obstacles}
    unnamed = [o for o in sc.obstacles if o.name.startswith("geom_")]
    assert len(unnamed) == 1 and unnamed[0].name == f"geom_{unnamed[0].geom_id}"
    assert sorted(obs) == sorted(["wall", "post", "pill", "lying", unnamed[0].name, "in_body"])  # not "decor", "mat"
    for o in sc.obstacles:
        assert sc.model.geom(o.geom_id).name in (o.name, "")
    assert obs["wall"].yaw == pytest.approx(math.radians(30))
    assert obs["wall"].half_size == pytest.approx([0.1, 1.0])
    assert obs["post"].kind == "cylinder" and obs["post"].half_size == pytest.approx([0.2, 0.2])
    assert obs["pill"].kind == "capsule" and obs["pill"].height == pytest.approx(1.0)
    # rotated 90 deg about x: the box's y axis is vertical, footprint is x by z
    assert obs["lying"].half_size == pytest.approx([0.5, 0.3])
    assert obs["lying"].yaw == pytest.approx(0.0, abs=1e-12)
    assert obs["lying"].height == pytest.approx(0.2)
    # body at (0, -3) rotated 90 deg about z: local (1, 0) lands at (0, -2), yaw 90 deg
    assert obs["in_body"].center == pytest.approx([0.0, -2.0])
    assert obs["in_body"].yaw == pytest.approx(math.pi / 2)
    assert sc.bounds == pytest.approx([-2, -4, 10, 4])
    assert sc.start == pytest.approx([0, 0, 0.5]) and sc.goal == pytest.approx([8, 0])


def test_short_include_resolves_to_packaged_robot(write_scenario):
    sc = load_scenario(write_scenario(include="diff_drive.xml"))
    assert sc.robot == load_scenario("single_rect").robot
    assert scenario_spec(sc).compile().ngeom == sc.model.ngeom


def test_local_robot_file_wins_over_packaged(write_scenario, tmp_path):
    text = robot_model_path().read_text().replace('ctrlrange="-20 20"', 'ctrlrange="-10 10"')
    (tmp_path / "diff_drive.xml").write_text(text)
    sc = load_scenario(write_scenario(include="diff_drive.xml"))
    assert sc.robot.wheel_speed_max == pytest.approx(10.0)


def test_copied_builtin_with_relative_include_still_loads(tmp_path):
    dst = tmp_path / "elsewhere" / "u_copy.xml"
    dst.parent.mkdir()
    shutil.copy(scenarios_dir() / "u_shape.xml", dst)  # its ../models/diff_drive.xml is missing here
    assert len(load_scenario(dst).obstacles) == 3


# ----------------------------------------------------------------------------- errors


def _error(spec, **kw) -> str:
    with pytest.raises(ScenarioError) as err:
        load_scenario(spec, **kw)
    msg = str(err.value)
    assert "\n" not in msg
    return msg


def test_missing_file(tmp_path):
    path = tmp_path / "nope.xml"
    msg = _error(path)
    assert str(path) in msg and "no such file" in msg


def test_unknown_builtin_name():
    msg = _error("no_such_scenario")
    assert "no_such_scenario" in msg and "u_shape" in msg


def test_directory_is_not_a_file(tmp_path):
    assert "not a file" in _error(tmp_path)


def test_not_xml(tmp_path):
    path = tmp_path / "junk.xml"
    path.write_text("this is not xml <<<")
    msg = _error(path)
    assert str(path) in msg and "not a valid MJCF model" in msg


def test_malformed_mjcf(write_scenario):
    msg = _error(write_scenario('<geom name="w" type="box" size="0.1 0.1"/><bogus/>'))
    assert "not a valid MJCF model" in msg and "bogus" in msg


def test_missing_include_says_how_to_include(write_scenario, tmp_path):
    path = write_scenario(include=str(tmp_path / "robots" / "other_robot.xml"))
    msg = _error(path)
    assert str(path) in msg and "cannot open included file" in msg
    assert str(robot_model_path()) in msg


def test_no_robot(tmp_path):
    path = tmp_path / "norobot.xml"
    path.write_text('<mujoco><custom><numeric name="start" data="0 0 0"/><numeric name="goal" data="1 0"/></custom>'
                    '<worldbody><geom name="floor" type="plane" size="5 5 0.1"/></worldbody></mujoco>')
    msg = _error(path)
    assert "robot model" in msg and "'left_wheel'" in msg


def test_no_floor(write_scenario):
    assert "no floor plane" in _error(write_scenario(floor=""))


def test_infinite_floor(write_scenario):
    msg = _error(write_scenario(floor='<geom name="floor" type="plane" size="0 0 0.1"/>'))
    assert "infinite size" in msg


def test_two_planes(write_scenario):
    msg = _error(write_scenario('<geom name="floor2" type="plane" pos="0 0 1" size="1 1 0.1"/>'))
    assert "more than one plane" in msg and "floor2" in msg


def test_rotated_floor(write_scenario):
    msg = _error(write_scenario(floor='<geom name="floor" type="plane" size="6 4 0.1" euler="0 0 30"/>'))
    assert "axis-aligned" in msg


@pytest.mark.parametrize("which, kw, fragment", [
    ("start", {"start": None}, 'missing start: add <custom><numeric name="start"'),
    ("goal", {"goal": None}, 'missing goal: add <custom><numeric name="goal"'),
    ("start", {"start": "0 0"}, "start must have 3 values (x y yaw), got 2"),
    ("goal", {"goal": "4 0 0"}, "goal must have 2 values (x y), got 3"),
    ("goal", {"goal": "nan 0"}, "goal must be finite"),
])
def test_bad_start_goal(write_scenario, which, kw, fragment):
    assert fragment in _error(write_scenario(**kw))


@pytest.mark.parametrize("kw, fragment", [
    ({"start": "20 0 0"}, "start (20.000, 0.000) is outside the workspace"),
    ({"goal": "9.8 0"}, "goal (9.800, 0.000) is outside the workspace"),  # within inflation of the edge
])
def test_start_goal_outside_workspace(write_scenario, kw, fragment):
    msg = _error(write_scenario(**kw))
    assert fragment in msg and "inflation radius" in msg


def test_goal_inside_inflated_obstacle(write_scenario):
    # box face at x = 3.7; the goal 0.3 m from it is inside the 0.38 m inflation
    msg = _error(write_scenario('<geom name="block" type="box" pos="3.5 0 0.25" size="0.2 0.5 0.25"/>', goal="4 0"))
    assert "goal (4.000, 0.000) is inside obstacle 'block' inflated by" in msg
    assert "distance 0.300 m" in msg


def test_start_inside_inflated_cylinder_respects_margin(write_scenario):
    world = '<geom name="post" type="cylinder" pos="0.76 0 0.3" size="0.4 0.3"/>'  # 0.36 m from start
    assert "start (0.000, 0.000) is inside obstacle 'post'" in _error(write_scenario(world))
    assert load_scenario(write_scenario(world), margin=0.0).obstacles[0].name == "post"


@pytest.mark.parametrize("geom, fragment", [
    ('<geom name="ball" type="sphere" pos="2 2 0.2" size="0.2"/>', "unsupported obstacle geom 'ball' of type sphere"),
    ('<geom name="egg" type="ellipsoid" pos="2 2 0.2" size="0.2 0.3 0.2"/>', "'egg' of type ellipsoid"),
    ('<geom name="rock" type="mesh" mesh="tet" pos="2 2 0"/>', "'rock' of type mesh"),
    ('<geom name="ramp" type="box" pos="2 2 0.2" size="0.5 0.5 0.2" euler="10 0 0"/>', "box 'ramp' is tilted"),
    ('<geom name="log" type="cylinder" pos="2 2 0.2" size="0.2 0.5" euler="0 90 0"/>', "cylinder 'log' is tilted"),
    ('<geom name="pill" type="capsule" pos="2 2 0.2" size="0.2 0.5" euler="45 0 0"/>', "capsule 'pill' is tilted"),
])
def test_unsupported_obstacles(write_scenario, geom, fragment):
    extra = '<asset><mesh name="tet" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset>'
    assert fragment in _error(write_scenario(geom, extra=extra))


def test_moving_obstacle_is_an_error(write_scenario):
    world = '<body name="crate" pos="2 2 0.3"><freejoint/><geom name="crate" type="box" size="0.2 0.2 0.2"/></body>'
    msg = _error(write_scenario(world))
    assert "geom 'crate' is on moving body 'crate'" in msg


def test_bad_margin(write_scenario):
    with pytest.raises(ValueError, match="margin must be a finite number >= 0"):
        load_scenario(write_scenario(), margin=-0.1)


# ------------------------------------------------ non-finite numbers, empty argument, limits (issue 12)

BLOCK = '<geom name="block" type="box" pos="2 2 0.25" size="0.2 0.3 0.25" {}/>'


@pytest.mark.parametrize("attrs, fragment", [
    ('pos="nan 2 0.25"', "geom 'block': pos must be finite"),
    ('pos="2 inf 0.25"', "geom 'block': pos must be finite"),
    ('size="inf 0.3 0.25"', "geom 'block': size must be finite"),
    ('euler="0 0 nan"', "geom 'block': orientation"),
    ('quat="nan 0 0 1"', "geom 'block': orientation"),
    ('axisangle="0 0 1 nan"', "geom 'block': orientation"),
    ('zaxis="0 nan 1"', "geom 'block': orientation"),
    ('xyaxes="1 0 0 0 inf 0"', "geom 'block': orientation"),
])
def test_non_finite_geom_is_named(write_scenario, attrs, fragment):
    geom = BLOCK.format(attrs)
    if 'pos="' in attrs:
        geom = geom.replace('pos="2 2 0.25" ', "")
    if 'size="' in attrs:
        geom = geom.replace('size="0.2 0.3 0.25" ', "")
    path = write_scenario(geom)
    msg = _error(path)
    assert str(path) in msg and fragment in msg and "NaN or inf" in msg


def test_non_finite_body_position_is_named(write_scenario):
    path = write_scenario('<body name="grp" pos="0 nan 0"><geom name="b" type="box" pos="2 2 0.2" size="0.2 0.2 0.2"/></body>')
    msg = _error(path)
    assert str(path) in msg and "body 'grp': pos must be finite" in msg


@pytest.mark.parametrize("size, fragment", [
    ("inf 4 0.1", "geom 'floor': size must be finite"),
    ("-6 4 0.1", "has a negative size [-6.0, 4.0]"),
    ("nan 4 0.1", "'floor'"),  # MuJoCo refuses a NaN plane size itself; the message still names the geom
])
def test_bad_floor_size_is_named(write_scenario, size, fragment):
    msg = _error(write_scenario(floor=f'<geom name="floor" type="plane" pos="4 0 0" size="{size}"/>'))
    assert fragment in msg and "infinite size" not in msg


def test_empty_argument_says_it_is_empty():
    msg = _error("")
    assert "scenario argument is empty" in msg and "not a file" not in msg


@pytest.mark.parametrize("old, new, fragment", [
    ('ctrlrange="-20 20"', 'ctrlrange="-1e12 1e12"', "wheel_speed_max = 1e+12 rad/s is outside the physical range"),
    ('ctrlrange="-20 20"', 'ctrlrange="-500 500"', "v_max = 50 m/s is outside"),  # 500 rad/s x 0.1 m
    ('size="0.1 0.1 0.025"', 'size="1e-9 0.1 0.025"', "wheel_radius = 1e-09 m is outside"),
    ('data="1.5 4.0 3.0"', 'data="1e9 4.0 3.0"', "a_max = 1e+09 m/s^2 is outside"),
    ('data="1.5 4.0 3.0"', 'data="1.5 4.0 1e6"', "w_cap = 1e+06 rad/s is outside"),
    ('mass="12.5"', 'mass="1e9"', "mass = 1e+09 kg is outside"),
])
def test_absurd_robot_limits_are_refused(write_scenario, tmp_path, old, new, fragment):
    text = robot_model_path().read_text()
    assert old in text
    (tmp_path / "diff_drive.xml").write_text(text.replace(old, new))
    path = write_scenario(include="diff_drive.xml")
    msg = _error(path)
    assert str(path) in msg and fragment in msg and "robot model" in msg


def test_builtin_robot_is_inside_the_ranges(builtins):
    from sanav_mj.scene import ROBOT_RANGES

    r = builtins["u_shape"].robot
    for key in ("wheel_radius", "track", "footprint_radius", "wheel_speed_max", "v_max", "a_max", "alpha_max"):
        low, high, _, _ = ROBOT_RANGES[key]
        assert low <= getattr(r, key) <= high


# ------------------------------------------------------------------------- <option timestep>


@pytest.mark.parametrize("value", ["0", "nan", "-0.002", "inf"])
def test_timestep_must_be_positive_and_finite(write_scenario, value):
    path = write_scenario(extra=f'<option timestep="{value}"/>')
    msg = _error(path)
    assert str(path) in msg and "<option timestep>" in msg and "> 0" in msg


@pytest.mark.parametrize("value, ok", [("1e-7", False), ("5e-5", False), ("1e-4", True), ("0.002", True),
                                       ("0.01", True), ("0.011", False), ("0.05", False), ("0.2", False)])
def test_timestep_against_the_control_period(write_scenario, value, ok):
    from sanav_mj.scene import check_timestep

    sc = load_scenario(write_scenario(extra=f'<option timestep="{value}"/>'))
    if ok:
        assert check_timestep(sc, 0.1) == round(0.1 / float(value))
    else:
        with pytest.raises(ScenarioError, match=r"<option timestep>: expected a finite number in \[0.0001, 0.01\] s"):
            check_timestep(sc, 0.1)


def test_run_refuses_a_tiny_timestep_before_running(write_scenario, tmp_path):
    from sanav_mj.eval.episode import run_scenario

    out = tmp_path / "r.rrd"
    path = write_scenario(extra='<option timestep="1e-7"/>')
    with pytest.raises(ScenarioError, match="1e-07 s"):
        run_scenario(path, rrd=out)
    assert not out.exists()


# ------------------------------------------------------------------ MuJoCo's own warnings


def test_mujoco_warnings_stay_off_stderr_and_leave_no_log_file(write_scenario, tmp_path):
    """The CLI in a subprocess: exactly one line on stderr, exit 2, no MUJOCO_LOG.TXT in the folder."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    path = write_scenario(floor='<geom name="floor" type="plane" pos="4 0 0" size="nan 4 0.1"/>')
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.run([sys.executable, "-m", "sanav_mj.cli", "areas", str(path)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "WARNING" not in proc.stderr, proc.stderr
    assert proc.stdout == ""
    assert list(cwd.iterdir()) == []


def test_mujoco_warnings_are_captured(write_scenario):
    from sanav_mj.scene import mujoco_warnings

    _error(write_scenario(floor='<geom name="floor" type="plane" pos="4 0 0" size="nan 4 0.1"/>'))
    assert any("NaN" in w for w in mujoco_warnings())
