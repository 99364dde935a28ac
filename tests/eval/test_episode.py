"""The whole pipeline in MuJoCo: closed-loop success, faults, determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sanav_mj.control.factory import make_controller
from sanav_mj.eval.episode import run_scenario
from sanav_mj.eval.prepare import prepare
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



def test_a_discs_mode_document_names_its_footprint_settings_and_a_disc_one_is_unchanged():
    from dataclasses import replace

    from sanav_mj.eval.prepare import footprint_fields, footprint_spec

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
