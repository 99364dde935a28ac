"""The known map and plan before the loop (:mod:`sanav_mj.eval.prepare`): the planner matched
to the MPC, the footprint mode's map settings and the areas its controller gets."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.eval.prepare import prepare


# --------------------------------------------------------------------------- planner_config


def _robot(**kw):
    from sanav_mj.scene import RobotParams

    values = {"wheel_radius": 0.1, "track": 0.4, "footprint_radius": 0.3, "wheel_speed_max": 20.0, "v_max": 2.0,
              "w_max": 10.0, "a_max": 1.0, "alpha_max": 3.0}
    values.update(kw)
    return RobotParams(**values)


def test_planner_config_known_answers_by_hand():
    from sanav_mj.eval.prepare import planner_config

    # rim speed 20 rad/s * 0.1 m = 2 m/s, half track 0.2 m: the MPC's w_max = min(10, 0.4 * 2 / 0.2)
    # = 4 rad/s, v_max = min(2, 2 - 4 * 0.2) = 1.2 m/s, a_max = the robot's 1 m/s^2
    cfg = planner_config(_robot())
    assert cfg.dt == 0.1
    assert cfg.speed_fraction == pytest.approx(0.8 * 1.2 / 2.0, abs=1e-12)  # 0.48: 0.96 m/s
    assert cfg.yaw_rate_fraction == pytest.approx(0.8 * 4.0 / 10.0, abs=1e-12)  # 0.32: 3.2 rad/s
    assert cfg.accel_fraction == pytest.approx(0.8, abs=1e-12)


def test_planner_config_of_the_mujoco_robot():
    from sanav_mj.eval.prepare import planner_config
    from sanav_mj.planning import PlannerConfig
    from sanav_mj.scene import load_scenario

    robot = load_scenario("single_rect").robot  # r 0.1 m, track 0.38 m, 20 rad/s, v_max 2 m/s, w_max 3 rad/s
    cfg = planner_config(robot)
    # the MPC drives at most 2 - 3 * 0.19 = 1.43 m/s: the reference tops out at 0.8 * 1.43 m/s, not 1.6 m/s
    assert cfg.speed_fraction * robot.v_max == pytest.approx(0.8 * 1.43, abs=1e-12)
    assert cfg.yaw_rate_fraction == pytest.approx(0.8, abs=1e-12)  # w_max 3 rad/s is the robot's own
    assert cfg.accel_fraction == pytest.approx(0.8, abs=1e-12)
    # everything else is the planner's default
    base = PlannerConfig()
    changed = {"dt", "speed_fraction", "yaw_rate_fraction", "accel_fraction"}
    for name in set(vars(base)) - changed:
        assert getattr(cfg, name) == getattr(base, name), name


def test_planner_config_fractions_are_capped_at_one():
    from sanav_mj.control.config import MPCConfig
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.prepare import planner_config

    # an MPC allowed 10 m/s^2 on a 1 m/s^2 robot: 0.8 * 10 / 1 = 8 -> the robot's whole a_max
    cfg = planner_config(_robot(), ControllerSpec(sa_mpc=MPCConfig(a_max=10.0, dt=0.05)))
    assert cfg.accel_fraction == 1.0
    assert cfg.dt == 0.05


def test_planner_config_open_speed_in_discs_mode_only():
    from dataclasses import replace

    from sanav_mj.control.config import MPCConfig
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.lidar import lidar_spec
    from sanav_mj.eval.prepare import planner_config

    robot = _robot()  # the MPC's v_max 1.2 m/s (test above)
    mpc = MPCConfig(footprint="discs", footprint_open_speed=0.9, footprint_open_room=0.2)
    cfg = planner_config(robot, ControllerSpec(sa_mpc=mpc))
    assert cfg.open_speed_fraction * robot.v_max == pytest.approx(0.9 * 1.2, abs=1e-12)
    assert cfg.open_room == 0.2
    assert cfg.speed_fraction == planner_config(robot).speed_fraction
    # the disc mode ignores it; a lidar run keeps it (its plans read the sensed safe cells)
    assert planner_config(robot, ControllerSpec(sa_mpc=replace(mpc, footprint="disc"))).open_speed_fraction is None
    lid = lidar_spec(ControllerSpec(sa_mpc=mpc))
    assert lid.sa_mpc.footprint_open_speed == 0.9
    assert planner_config(robot, lid).open_speed_fraction == cfg.open_speed_fraction
    with pytest.raises(ValueError, match="footprint_open_speed"):
        MPCConfig(footprint_open_speed=1.5)
    with pytest.raises(ValueError, match="footprint_open_room"):
        MPCConfig(footprint_open_room=-0.1)



def test_footprint_spec_and_map_config():
    from dataclasses import replace

    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.prepare import footprint_spec, map_config
    from sanav_mj.mapping import MapConfig

    assert footprint_spec() == ControllerSpec() and footprint_spec("dwa") == ControllerSpec("dwa")
    discs = footprint_spec("sa-mpc", "discs")
    assert discs == replace(ControllerSpec(), sa_mpc=replace(ControllerSpec().sa_mpc, footprint="discs"))
    assert map_config() == MapConfig() and map_config(resolution=0.1) == MapConfig(resolution=0.1)
    refined = replace(discs, sa_mpc=replace(discs.sa_mpc, footprint_refine=2, footprint_refine_width=0.3))
    assert map_config(refined, 0.05) == MapConfig(resolution=0.05, refine=2, refine_width=0.3)
    # the refinement is a discs-mode setting: the disc mode ignores it
    disc_refined = replace(ControllerSpec(), sa_mpc=replace(ControllerSpec().sa_mpc, footprint_refine=2))
    assert map_config(disc_refined, 0.05) == MapConfig(resolution=0.05)



def test_prepare_refines_the_map_in_discs_mode_only():
    from dataclasses import replace

    from sanav_mj.eval.prepare import footprint_spec

    discs = footprint_spec("sa-mpc", "discs")
    assert discs.sa_mpc.footprint_refine == 2  # the discs mode's default
    one = replace(discs, sa_mpc=replace(discs.sa_mpc, footprint_refine=1))
    a, b = prepare("double_rect", controller=one), prepare("double_rect", controller=discs)
    assert prepare("double_rect").grid.resolution == 0.05
    assert a.grid.resolution == 0.05 and b.grid.resolution == 0.025
    # the refined map frees a superset of the coarse map's space (each coarse cell = 2 x 2 fine cells)
    up = np.repeat(np.repeat(a.grid.occupied, 2, axis=0), 2, axis=1)[: b.grid.shape[0], : b.grid.shape[1]]
    assert not (~up & b.grid.occupied).any()
    assert b.plan.ok


def test_free_cells_reach_the_controller_only_in_discs_mode_with_growth():
    from dataclasses import replace

    from sanav_mj.control.factory import make_controller
    from sanav_mj.eval.prepare import footprint_spec

    discs = footprint_spec("sa-mpc", "discs")
    assert discs.sa_mpc.footprint_grow == 1.0  # the discs mode's default
    assert prepare("double_rect", controller=discs).areas.free.limit == 1.0
    grow = replace(discs, sa_mpc=replace(discs.sa_mpc, footprint_grow=0.5))
    disc_grow = replace(footprint_spec(), sa_mpc=replace(footprint_spec().sa_mpc, footprint_grow=0.5))
    off = replace(discs, sa_mpc=replace(discs.sa_mpc, footprint_grow=0.0))
    assert prepare("double_rect", controller=off).areas.free is None
    assert prepare("double_rect").areas.free is None
    assert prepare("double_rect", controller=disc_grow).areas.free is None
    p = prepare("double_rect", controller=grow)
    assert p.areas.free is not None and p.areas.free.limit == 0.5
    ctrl = make_controller(grow, p.scenario, p.grid, p.areas, p.plan)
    assert ctrl.chain.area_rects is not None
    for box in ctrl.chain.boxes:  # every member is whole free cells of the map's grid
        i0, j0, i1, j1 = p.areas.free.cells_of(box)
        assert not p.grid.occupied[i0:i1, j0:j1].any()
