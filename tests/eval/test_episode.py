"""The whole pipeline in MuJoCo: closed-loop success, faults, determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sanav_mj.control.factory import make_controller
from sanav_mj.eval.episode import prepare, run_scenario
from sanav_mj.sim.mismatch import parse_mismatch

TIMING_KEYS = ("solve_ms", "pipeline_ms")


@pytest.fixture(scope="module")
def u_shape():
    return prepare("u_shape")


def _assert_contract(doc):
    assert set(doc) >= {
        "scenario", "controller", "seed", "start", "goal", "success", "reason", "steps", "sim_time_s",
        "path_length_m", "min_clearance_m", "collisions", "safe_area_violations", "solve_ms",
        "pipeline_ms", "mismatch", "trace",
    }
    assert set(doc["solve_ms"]) == {"mean", "max", "std", "p50", "p99"}
    assert set(doc["pipeline_ms"]) == {"mean", "max", "std"}
    assert set(doc["trace"]) == {"t", "x", "y", "yaw", "v", "w"}
    assert all(len(doc["trace"][k]) == doc["steps"] for k in doc["trace"])
    json.dumps(doc, allow_nan=False)


def test_u_shape_closed_loop_success(u_shape):
    out = run_scenario(u_shape, seed=1)
    doc = out.document
    _assert_contract(doc)
    assert doc["success"] and doc["reason"] == "goal"
    assert doc["collisions"] == 0 and doc["safe_area_violations"] == 0
    assert doc["min_clearance_m"] > 0.0
    # it went round the U: the straight line to the goal is blocked, so the path is longer
    straight = float(np.hypot(*(np.array(doc["goal"]) - np.array(doc["start"][:2]))))
    assert doc["path_length_m"] > 1.1 * straight
    end = np.array([doc["trace"]["x"][-1], doc["trace"]["y"][-1]])
    assert np.hypot(*(end - u_shape.scenario.goal)) < 0.3


def test_same_seed_same_json_except_wall_clock(u_shape):
    a = run_scenario(u_shape, seed=4, mismatch=parse_mismatch(["pos_noise=0.02", "jitter=0.1"])).document
    b = run_scenario(u_shape, seed=4, mismatch=parse_mismatch(["pos_noise=0.02", "jitter=0.1"])).document
    for key in TIMING_KEYS:
        a.pop(key), b.pop(key)
    assert a == b
    c = run_scenario(u_shape, seed=5, mismatch=parse_mismatch(["pos_noise=0.02", "jitter=0.1"])).document
    assert c["trace"]["x"] != a["trace"]["x"]


def test_nan_measurements_stop_the_robot_with_a_reason(u_shape):
    from sanav_mj.sim.plant import Plant
    from sanav_mj.sim.runner import run_episode

    scenario = u_shape.scenario
    ctrl = make_controller("sa-mpc", scenario, u_shape.grid, u_shape.areas, u_shape.plan)

    def fault(step, pose):
        return np.full(3, np.nan) if step >= 20 else pose

    ep = run_episode(Plant(scenario), ctrl, scenario.start, scenario.goal, measurement_fault=fault)
    assert ep.reason == "bad_measurement" and not ep.success
    assert ep.collisions == 0
    assert np.isfinite(np.asarray(ep.trace.cmd)).all()
    # the last commands sent are a stop
    assert ep.trace.applied[-1] == (0.0, 0.0)


def test_isolated_pose_jumps_are_rejected(u_shape):
    from sanav_mj.sim.plant import Plant
    from sanav_mj.sim.runner import run_episode

    scenario = u_shape.scenario
    ctrl = make_controller("sa-mpc", scenario, u_shape.grid, u_shape.areas, u_shape.plan)

    def fault(step, pose):
        return pose + np.array([3.0, -2.0, 0.0]) if step % 15 == 7 else pose

    ep = run_episode(Plant(scenario), ctrl, scenario.start, scenario.goal, measurement_fault=fault)
    assert ep.success and ep.collisions == 0
    jumped = [np.asarray(m) for k, m in enumerate(ep.trace.measured) if k % 15 == 7]
    true = [np.asarray(p) for k, p in enumerate(ep.trace.pose) if k % 15 == 7]
    assert all(np.hypot(*(m[:2] - p[:2])) < 0.5 for m, p in zip(jumped, true))


def test_injected_solver_failures_fall_back_without_collision(u_shape):
    from sanav_mj.control.sa_mpc import SAMPC

    scenario = u_shape.scenario
    ctrl = SAMPC(scenario.robot, u_shape.areas, u_shape.plan, failure_injector=lambda k: 25 <= k < 35)
    out = run_scenario(u_shape, seed=0, controller_obj=ctrl)
    doc = out.document
    assert doc["collisions"] == 0
    assert doc["solver_failures"] >= 10
    statuses = out.episode.trace.status[25:35]
    assert all(s.startswith("fallback") for s in statuses), statuses
    assert doc["success"]  # it recovers once the solver works again


def test_walled_off_goal_is_no_path(tmp_path):
    from sanav_mj.resources import robot_model_path

    xml = f"""<mujoco model="walled">
  <include file="{robot_model_path()}"/>
  <custom><numeric name="start" data="0 0 0"/><numeric name="goal" data="4 0"/></custom>
  <worldbody>
    <geom name="floor" type="plane" pos="2 0 0" size="3.5 2 0.1"/>
    <geom name="wall" type="box" pos="2.5 0 0.25" size="0.1 2.5 0.25"/>
  </worldbody>
</mujoco>"""
    path = tmp_path / "walled.xml"
    path.write_text(xml)
    out = run_scenario(str(path), seed=0)
    assert out.document["reason"] == "no_path" and not out.document["success"]
    assert out.document["steps"] == 0 and out.document["collisions"] == 0
    json.dumps(out.document, allow_nan=False)


# --------------------------------------------------------------------------- planner_config


def _robot(**kw):
    from sanav_mj.scene import RobotParams

    values = {"wheel_radius": 0.1, "track": 0.4, "footprint_radius": 0.3, "wheel_speed_max": 20.0, "v_max": 2.0,
              "w_max": 10.0, "a_max": 1.0, "alpha_max": 3.0}
    values.update(kw)
    return RobotParams(**values)


def test_planner_config_known_answers_by_hand():
    from sanav_mj.eval.episode import planner_config

    # rim speed 20 rad/s * 0.1 m = 2 m/s, half track 0.2 m: the MPC's w_max = min(10, 0.4 * 2 / 0.2)
    # = 4 rad/s, v_max = min(2, 2 - 4 * 0.2) = 1.2 m/s, a_max = the robot's 1 m/s^2
    cfg = planner_config(_robot())
    assert cfg.dt == 0.1
    assert cfg.speed_fraction == pytest.approx(0.8 * 1.2 / 2.0, abs=1e-12)  # 0.48: 0.96 m/s
    assert cfg.yaw_rate_fraction == pytest.approx(0.8 * 4.0 / 10.0, abs=1e-12)  # 0.32: 3.2 rad/s
    assert cfg.accel_fraction == pytest.approx(0.8, abs=1e-12)


def test_planner_config_of_the_mujoco_robot():
    from sanav_mj.eval.episode import planner_config
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
    from sanav_mj.eval.episode import planner_config

    # an MPC allowed 10 m/s^2 on a 1 m/s^2 robot: 0.8 * 10 / 1 = 8 -> the robot's whole a_max
    cfg = planner_config(_robot(), ControllerSpec(sa_mpc=MPCConfig(a_max=10.0, dt=0.05)))
    assert cfg.accel_fraction == 1.0
    assert cfg.dt == 0.05


def test_planner_config_open_speed_in_discs_mode_only():
    from dataclasses import replace

    from sanav_mj.control.config import MPCConfig
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.episode import lidar_spec, planner_config

    robot = _robot()  # the MPC's v_max 1.2 m/s (test above)
    mpc = MPCConfig(footprint="discs", footprint_open_speed=0.9, footprint_open_room=0.2)
    cfg = planner_config(robot, ControllerSpec(sa_mpc=mpc))
    assert cfg.open_speed_fraction * robot.v_max == pytest.approx(0.9 * 1.2, abs=1e-12)
    assert cfg.open_room == 0.2
    assert cfg.speed_fraction == planner_config(robot).speed_fraction
    # the disc mode ignores it; a lidar run drops it (not measured with the lidar)
    assert planner_config(robot, ControllerSpec(sa_mpc=replace(mpc, footprint="disc"))).open_speed_fraction is None
    lid = lidar_spec(ControllerSpec(sa_mpc=mpc))
    assert lid.sa_mpc.footprint_open_speed is None
    assert planner_config(robot, lid).open_speed_fraction is None
    with pytest.raises(ValueError, match="footprint_open_speed"):
        MPCConfig(footprint_open_speed=1.5)
    with pytest.raises(ValueError, match="footprint_open_room"):
        MPCConfig(footprint_open_room=-0.1)


def test_planned_reference_respects_the_mpc_bounds(u_shape):
    from sanav_mj.control.sa_mpc import MPCConfig

    lim = MPCConfig().limits(u_shape.scenario.robot)
    ref = u_shape.plan.reference
    assert ref.dt == MPCConfig().dt
    v = np.asarray(ref.inputs, dtype=float)[:, 0]
    assert v.max() == pytest.approx(0.8 * lim.v_max, rel=1e-3)  # reaches the cap on the long legs
    assert np.abs(np.asarray(ref.inputs)[:, 1]).max() <= 0.8 * lim.w_max + 1e-9


def test_the_controller_spec_reaches_the_controller_and_the_planner():
    from sanav_mj.control.config import MPCConfig
    from sanav_mj.control.spec import ControllerSpec

    spec = ControllerSpec(sa_mpc=MPCConfig(v_max=0.5))
    out = run_scenario("single_rect", seed=0, controller_spec=spec)
    assert out.spec is spec and out.document["reason"] == "goal"
    assert max(out.document["trace"]["v"]) <= 0.5 + 1e-12  # the controller's speed bound
    v_ref = np.asarray(out.prepared.plan.reference.inputs)[:, 0]
    assert v_ref.max() == pytest.approx(0.8 * 0.5, rel=1e-3)  # the planner's cap: 0.8 of that bound
    with pytest.raises(ValueError, match="controller_spec: names controller 'sa-mpc' but controller='dwa'"):
        run_scenario("single_rect", controller="dwa", controller_spec=spec)


def test_footprint_spec_and_map_config():
    from dataclasses import replace

    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.episode import footprint_spec, map_config
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


def test_a_discs_mode_document_names_its_footprint_settings_and_a_disc_one_is_unchanged():
    from dataclasses import replace

    from sanav_mj.eval.episode import footprint_fields, footprint_spec

    assert footprint_fields(footprint_spec()) == {} and footprint_fields(footprint_spec("dwa")) == {}
    discs = footprint_spec("sa-mpc", "discs")
    mine = replace(discs, sa_mpc=replace(discs.sa_mpc, footprint_discs=4, footprint_margin=0.03,
                                         footprint_refine=1, footprint_grow=0.5, footprint_route="pose",
                                         footprint_open_speed=0.9))
    assert footprint_fields(mine) == {"footprint": {"mode": "discs", "discs": 4, "margin_m": 0.03, "route": "pose",
                                                    "refine": 1, "grow_m": 0.5, "open_speed": 0.9}}
    assert "footprint" not in run_scenario("single_rect", seed=0, time_limit_s=0.1).document
    doc = run_scenario("single_rect", seed=0, controller_spec=discs, time_limit_s=0.1).document
    assert doc["reason"] == "timeout"
    assert doc["footprint"] == footprint_fields(discs)["footprint"] and doc["footprint"]["mode"] == "discs"


def test_prepare_refines_the_map_in_discs_mode_only():
    from dataclasses import replace

    from sanav_mj.eval.episode import footprint_spec

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
    from sanav_mj.eval.episode import footprint_spec

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
