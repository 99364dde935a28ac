"""SA-MPC: corridor chain, stage assignment, constraints of the solved problem, closed loops, fallbacks."""

from __future__ import annotations

from dataclasses import replace

import casadi as cs
import numpy as np
import pytest

from sanav_mj.control.base import Observation
from sanav_mj.control import sa_mpc
from sanav_mj.control.adaptation import AdaptationConfig
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig, SafeAreaPenalty
from sanav_mj.control.tracking import Problem
from sanav_mj.control.stages import (
    CorridorChain,
    assign_stages,
    box_intersection,
    box_slack,
    bridge_box,
    stage_boxes,
)
from sanav_mj.control.unicycle import rollout_np, step_np
from sanav_mj.scene import RobotParams

from mpc_cases import L_RECTS, ROBOT, inside_union, make_areas, make_plan, plan_from_samples

# ------------------------------------------------------------------ config


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(horizon=1), "horizon"),
        (dict(dt=0.0), "dt"),
        (dict(q_x=(1.0, 2.0)), "q_x"),
        (dict(q_u=(1.0, -1.0)), "q_u"),
        (dict(q_sa=()), "q_sa"),
        (dict(v_min=0.5), "v_min"),
        (dict(box_margin=-0.1), "box_margin"),
        (dict(solver="cvx"), "solver"),
        (dict(solve_budget_ms=0.0), "solve_budget_ms"),
        (dict(turn_in_place=-1.0), "turn_in_place"),
        (dict(turn_in_place=0.5, turn_exit=0.5), "turn_exit"),
    ],
)
def test_config_rejects_bad_values_naming_the_field(kw, match):
    with pytest.raises(ValueError, match=f"MPCConfig.{match}"):
        MPCConfig(**kw)


def test_config_limits_default_from_robot_and_respect_wheel_speed():
    lim = MPCConfig().limits(ROBOT)  # ROBOT: rim speed 2 m/s, track 0.38 m, w_max 10.5 rad/s
    assert lim.w_max == pytest.approx(0.4 * 2.0 / 0.19) and lim.v_max == pytest.approx(2.0 - lim.w_max * 0.19)
    slow_turner = RobotParams(**{**ROBOT.__dict__, "w_max": 3.0})
    lim3 = MPCConfig().limits(slow_turner)
    assert lim3.w_max == 3.0 and lim3.v_max == pytest.approx(2.0 - 3.0 * 0.19)
    assert lim.a_max == ROBOT.a_max and lim.alpha_max == ROBOT.alpha_max and lim.v_min < 0
    # wheel rim speed at the corners of the input box stays within the wheel's top speed
    rim = lim.v_max + lim.w_max * ROBOT.track / 2
    assert rim <= ROBOT.wheel_speed_max * ROBOT.wheel_radius + 1e-9
    assert MPCConfig(v_max=0.5, a_max=0.7).limits(ROBOT).v_max == 0.5


# ------------------------------------------------------------------ geometry


def test_bridge_box_known_answers():
    a = np.array([0.0, 0.0, 4.0, 1.0])
    b = np.array([3.0, 1.0, 4.0, 4.0])  # above a, horizontal portal y = 1, x in [3, 4]
    np.testing.assert_allclose(bridge_box(a, b), [3, 0, 4, 4])
    c = np.array([4.0, -1.0, 6.0, 0.5])  # right of a, vertical portal x = 4, y in [0, 0.5]
    np.testing.assert_allclose(bridge_box(a, c), [0, 0, 6, 0.5])
    d = np.array([1.0, 0.5, 2.0, 3.0])  # overlapping: the intersection
    np.testing.assert_allclose(bridge_box(a, d), [1, 0.5, 2, 1])
    with pytest.raises(ValueError, match="share no boundary"):
        bridge_box(a, np.array([5.0, 5.0, 6.0, 6.0]))
    with pytest.raises(ValueError, match="share no boundary"):
        bridge_box(a, np.array([4.0, 1.0, 5.0, 2.0]))  # corner contact only


def test_chain_members_overlap_and_stay_inside_the_union(u_case):
    areas, plan = u_case
    chain = CorridorChain.build(areas, plan.corridor, 0.0)
    assert len(chain) == 2 * len(plan.corridor) - 1
    inter = box_intersection(chain.boxes[:-1], chain.boxes[1:])
    assert np.all(inter[:, 2:] - inter[:, :2] > 0.1)  # positive-area overlaps
    rng = np.random.default_rng(0)
    for box in chain.boxes:
        pts = rng.uniform(box[:2], box[2:], size=(500, 2))
        assert inside_union(pts, areas.rects).all()


def test_chain_rejects_a_corridor_of_non_adjacent_areas():
    areas = make_areas(L_RECTS)
    with pytest.raises(ValueError, match="share no boundary"):
        CorridorChain.build(areas, np.array([1, 2]))
    with pytest.raises(ValueError, match="corridor"):
        CorridorChain.build(areas, np.array([0, 7]))


def test_assignment_known_answers(l_case):
    areas, plan = l_case
    chain = CorridorChain.build(areas, plan.corridor, 0.0)  # R0=[0,0,4,1], B=[3,0,4,4], R1=[3,1,4,4]
    still = np.tile([0.5, 0.5], (6, 1))
    np.testing.assert_array_equal(assign_stages(chain, still), [0] * 6)
    # moving up the right end of R0 into R1: advance as early as the guess allows
    path = np.array([[3.5, 0.2], [3.5, 0.5], [3.5, 0.9], [3.5, 1.3], [3.5, 1.8], [3.5, 2.5]])
    s = assign_stages(chain, path)
    # (3.5, 0.2) already lies in the bridge B01 and (3.5, 1.3) in B01 ∩ R1
    np.testing.assert_array_equal(s, [1, 1, 1, 2, 2, 2])
    from_left = np.vstack(([[2.0, 0.5]], path))
    np.testing.assert_array_equal(assign_stages(chain, from_left), [0, 1, 1, 1, 2, 2, 2])
    boxes = stage_boxes(chain, s)
    assert np.all(box_slack(path, boxes) >= 0)
    # consecutive positions share the member s(k)
    for k in range(len(s) - 1):
        member = chain.boxes[s[k]][None]
        assert box_slack(path[k : k + 2], np.repeat(member, 2, 0)).min() >= 0
    # a guess that cannot be made feasible is assigned with the least violation
    # (2, 2) is 1 m from R0 and sqrt(2) m from R0 ∩ B01: staying violates less than advancing
    jump = np.array([[1.0, 0.5], [2.0, 2.0]])
    np.testing.assert_array_equal(assign_stages(chain, jump, np.array([True, False, False])), [0, 0])


def test_assignment_respects_first_candidates(l_case):
    areas, plan = l_case
    chain = CorridorChain.build(areas, plan.corridor, 0.0)
    p = np.tile([3.5, 0.5], (3, 1))  # inside R0 and B01
    assert assign_stages(chain, p)[0] == 1
    assert assign_stages(chain, p, np.array([True, False, False]))[0] == 0


def test_fast_assignment_equals_the_dynamic_programme(u_case, monkeypatch):
    import sanav_mj.control.stages as sa

    areas, plan = u_case
    chain = CorridorChain.build(areas, plan.corridor, 0.02)
    ref = plan.reference.states[:, :2]
    rng = np.random.default_rng(1)
    cases = []
    for _ in range(400):
        idx = np.minimum(rng.integers(0, len(ref)) + np.cumsum(rng.integers(0, 4, 21)), len(ref) - 1)
        guess = ref[idx] + rng.normal(0.0, rng.choice([0.0, 0.02, 0.1]), (21, 2))
        first = None
        if rng.random() < 0.7:
            first = np.zeros(len(chain), bool)
            a = rng.integers(0, len(chain))
            first[max(0, a - 2) : a + 3] = True
        cases.append((guess, first))
    hits = []
    real = sa.assign_feasible
    monkeypatch.setattr(sa, "assign_feasible", lambda *a: hits.append(real(*a)) or hits[-1])
    fast = [assign_stages(chain, g, f, tol=1e-3) for g, f in cases]
    assert sum(h is not None for h in hits) > 150  # the fast path answered most of them
    monkeypatch.setattr(sa, "assign_feasible", lambda *a: None)  # always the dynamic programme
    slow = [assign_stages(chain, g, f, tol=1e-3) for g, f in cases]
    for a, b in zip(fast, slow):
        np.testing.assert_array_equal(a, b)
    assert len({tuple(a) for a in fast}) > 50  # varied assignments, not one answer repeated


def test_safe_area_penalty_matches_numpy_and_is_zero_inside():
    pen = SafeAreaPenalty(3)
    p = cs.SX.sym("p", 2)
    th = cs.SX.sym("th", pen.n_params)
    f = cs.Function("j", [p, th], [pen.expr(p, th)])
    rects = np.array([[0.0, 0.0, 1.0, 1.0], [1.0, 0.0, 2.0, 3.0]])
    q = np.array([2.0, 5.0])
    theta = np.zeros((3, 6))
    theta[:2, :4], theta[:2, 4], theta[:2, 5] = rects, q, 1.0
    theta[2, :4] = [10, 10, 11, 11]  # inactive slot: neutral whatever its rectangle
    rng = np.random.default_rng(0)
    for pt in rng.uniform(-1, 4, size=(200, 2)):
        want = SafeAreaPenalty.value_np(pt, rects, q)
        assert float(f(pt, theta.ravel())) == pytest.approx(want, rel=1e-12, abs=1e-15)
        assert (want == 0) == bool(inside_union(pt[None], rects)[0])
    # the paper's formula at a known point: outside rect 0 by (0.5 in y), rect 1 by (0.5 in x, 0.5 in y)
    pt = np.array([0.5, -0.5])
    assert SafeAreaPenalty.value_np(pt, rects, q) == pytest.approx((2 * 0.5) ** 2 * ((5 * 0.5) ** 2 + (5 * 0.5) ** 2))


# ------------------------------------------------------------------ one solved problem


@pytest.fixture(scope="module")
def l_controller(l_case):
    areas, plan = l_case
    return SAMPC(ROBOT, areas, plan, MPCConfig())


def _check_prediction_constraints(ctl: SAMPC, cmd, tol=1e-3):
    info = ctl.last
    n = ctl.N
    xs = cmd.predicted
    assert xs.shape == (n + 1, 3) and np.all(np.isfinite(xs))
    # the inputs are the plan stored in the controller
    u = ctl.plan_inputs
    np.testing.assert_allclose(rollout_np(xs[0], u, ctl.dt), xs, atol=1e-9)
    lim = ctl.limits
    assert np.all(u[:, 0] >= lim.v_min - tol) and np.all(u[:, 0] <= lim.v_max + tol)
    assert np.all(np.abs(u[:, 1]) <= lim.w_max + tol)
    du = np.diff(np.vstack((info.u_prev, u)), axis=0)
    assert np.all(np.abs(du) <= ctl.rate_step + tol)
    if ctl.config.terminal_stop:
        assert abs(u[-1, 0]) <= tol
    assert np.all(box_slack(xs[1:, :2], info.boxes[1:]) >= -tol)
    assert np.all(cmd.margins[1:] >= -tol)
    # consecutive predicted positions share the convex member s(k) (chord safety)
    s = info.assignment
    for k in range(n):
        member = np.repeat(ctl.chain.boxes[s[k]][None], 2, 0)
        assert box_slack(xs[k : k + 2, :2], member).min() >= -tol
    # every stage's reported safe area contains the predicted position
    rects = np.asarray(ctl.areas.rects)
    assert np.all(box_slack(xs[:, :2], rects[cmd.rect_ids]) >= -tol)


def test_solved_prediction_respects_every_constraint(l_controller):
    ctl = l_controller
    x = np.array([3.3, 0.6, 0.4])
    ctl.reset(x, progress=40)  # mid-way: the horizon crosses the portal
    cmd = None
    for k in range(3):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=measured_velocity(cmd)))
        assert cmd.ok and cmd.status in ("ok", "inexact")
        _check_prediction_constraints(ctl, cmd)
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
    assert ctl.last.assignment[-1] > 0  # the horizon reaches past the first area


def test_ipopt_and_panoc_agree_on_the_sa_mpc_problem(l_case):
    areas, plan = l_case
    cfg = MPCConfig(tol=1e-6, constraint_tol=1e-6)
    x = np.array([0.6, 0.4, 0.3])
    cmds = {}
    for solver in ("panoc", "ipopt"):
        ctl = SAMPC(ROBOT, areas, plan, replace(cfg, solver=solver))
        ctl.reset(x)
        pose = x.copy()
        for k in range(15):  # same measured states: each controller sees the same sequence
            cmd = ctl.step(Observation(t=0.1 * k, pose=pose, velocity=np.zeros(2)))
            pose = step_np(pose, [0.5, 0.1], ctl.dt)
        cmds[solver] = (cmd, ctl.plan_inputs.copy())
    (ca, ua), (cb, ub) = cmds["panoc"], cmds["ipopt"]
    assert ca.status == "ok" and cb.status == "ok"
    np.testing.assert_allclose(ua, ub, atol=2e-3)
    np.testing.assert_allclose(ca.predicted, cb.predicted, atol=2e-3)


# ------------------------------------------------------------------ closed loops


def measured_velocity(cmd) -> np.ndarray:
    """(2,) body velocity a kinematic plant measures after applying ``cmd`` (zero before the first)."""
    return np.zeros(2) if cmd is None else np.array([cmd.v, cmd.w])


def run_closed_loop(
    ctl: SAMPC, start, goal, rects, steps=400, gains=(0.95, 1.05), substeps=10, noise=0.0, seed=0, delay=0
):
    """Kinematic plant with gain mismatch and a command delay of ``delay`` periods; the
    measured velocity is the applied one. Returns (reached, executed positions, commands)."""
    rng = np.random.default_rng(seed)
    x = np.asarray(start, float).copy()
    ctl.reset(x)
    path = [x[:2].copy()]
    cmds = []
    in_flight = [np.zeros(2)] * delay
    vel = np.zeros(2)
    for k in range(steps):
        meas = x + rng.normal(0, noise, 3) * np.array([1, 1, 0.2]) if noise else x
        cmd = ctl.step(Observation(t=k * ctl.dt, pose=meas, velocity=vel))
        cmds.append(cmd)
        assert np.isfinite(cmd.v) and np.isfinite(cmd.w)
        in_flight.append(np.array([cmd.v * gains[0], cmd.w * gains[1]]))
        u = in_flight.pop(0)
        vel = u
        for _ in range(substeps):
            x = step_np(x, u, ctl.dt / substeps)
            path.append(x[:2].copy())
        if np.hypot(*(x[:2] - goal)) < 0.05 and abs(cmd.v) < 0.05:
            return True, np.array(path), cmds
    return False, np.array(path), cmds


def reaches_the_goal_inside_the_corridor(case, yaw: float) -> np.ndarray:
    """SA-MPC from (0.5, 0.5, ``yaw``) of a (areas, plan) ``case``, in closed loop with model
    mismatch (:func:`run_closed_loop`), reaches the goal inside the corridor with no solver
    failure; returns the path (T, 2) [m]."""
    areas, plan = case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    ok, path, _ = run_closed_loop(ctl, [0.5, 0.5, yaw], plan.goal, areas.rects[plan.corridor])
    assert ok
    assert inside_union(path, areas.rects[plan.corridor]).all()
    assert ctl.stats.failures == 0
    return path


@pytest.mark.parametrize("yaw", [0.0, 2.5])
def test_closed_loop_l_corridor_with_mismatch(l_case, yaw):
    reaches_the_goal_inside_the_corridor(l_case, yaw)


@pytest.mark.parametrize("yaw", [1.57, -2.0])
def test_closed_loop_u_corridor_with_mismatch(u_case, yaw):
    path = reaches_the_goal_inside_the_corridor(u_case, yaw)
    # it went around: the path visited the top area
    assert path[:, 1].max() > 3.0


def test_narrow_passage_is_traversed_thanks_to_exit_targets(monkeypatch):
    # an 8 cm sliver between two large areas (what a quadtree leaves along a diagonal wall);
    # the reference cuts into it at speed, so the robot arrives above the sliver's portal
    rects = [[0.0, 0.0, 2.0, 1.0], [2.0, 0.0, 2.4, 0.08], [2.4, 0.0, 4.0, 1.0]]
    areas = make_areas(rects)
    wps = [[0.5, 0.6], [1.6, 0.6], [2.0, 0.04], [2.4, 0.04], [2.8, 0.6], [3.5, 0.6]]
    plan = make_plan(areas, [0, 1, 2], wps, speed=1.0)
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    ok, path, _ = run_closed_loop(ctl, [0.5, 0.6, 0.0], plan.goal, areas.rects)
    assert ok and inside_union(path, areas.rects).all()
    # without the exit targets the far reference pins the plan to the wall above the portal
    stuck = SAMPC(ROBOT, areas, plan, MPCConfig())
    monkeypatch.setattr(sa_mpc, "exit_targets", lambda chain, ref_member, xr, ur, s, p0, yaw0: (xr, ur))
    ok, path, _ = run_closed_loop(stuck, [0.5, 0.6, 0.0], plan.goal, areas.rects, steps=150)
    assert not ok and path[-1, 0] < 2.0


# rectangles and reference samples (x, y, yaw, v, w every 0.1 s) of generated map clutter_0085
# where the robot, coming up a column of slivers, must turn right into a 10 cm high portal
# (R5 -> R6); at 1.144 m/s, the planner's top speed under the MPC's bounds
PORTAL_RECTS = [
    [0.8, -1.4, 1.6, -1.0], [0.8, -1.0, 1.2, -0.6], [1.0, -0.6, 1.1, -0.45], [1.0, -0.45, 1.05, 0.0],
    [1.0, 0.0, 1.1, 0.2], [0.8, 0.2, 1.2, 0.6], [1.2, 0.3, 1.4, 0.4], [1.4, 0.35, 1.8, 0.4],
    [1.8, 0.3, 2.0, 0.4], [2.0, 0.2, 2.4, 0.6], [2.4, 0.2, 4.0, 1.0],
]  # fmt: skip
PORTAL_SAMPLES = [
    [1.0, -1.367, 1.5342, 0.0, -0.0], [1.0002, -1.361, 1.5342, 0.12, -0.0], [1.0009, -1.343, 1.5342, 0.24, -0.0],
    [1.002, -1.313, 1.5342, 0.36, 0.0001], [1.0035, -1.2711, 1.5342, 0.48, 0.0003], [1.0055, -1.2171, 1.5343, 0.6, 0.0007],
    [1.0079, -1.1511, 1.5344, 0.72, 0.0033], [1.0107, -1.0732, 1.5353, 0.84, 0.0149], [1.0138, -0.9832, 1.5376, 0.96, 0.0319],
    [1.017, -0.8813, 1.5425, 1.08, 0.0707], [1.0197, -0.7687, 1.552, 1.144, 0.1171], [1.0211, -0.6543, 1.565, 1.144, 0.1424],
    [1.0209, -0.5399, 1.5799, 1.144, 0.1379], [1.0192, -0.4255, 1.5898, 1.144, 0.0606], [1.0169, -0.3111, 1.5896, 1.144, -0.111],
    [1.0159, -0.1976, 1.5652, 1.0988, -0.367], [1.0187, -0.0938, 1.5138, 0.9788, -0.6867], [1.0275, -0.0024, 1.4285, 0.8588, -1.0148],
    [1.043, 0.076, 1.3139, 0.7394, -1.2524], [1.0647, 0.1412, 1.1791, 0.6423, -1.4478], [1.092, 0.1955, 1.024, 0.5832, -1.6534],
    [1.1261, 0.2422, 0.8533, 0.5794, -1.7258], [1.1679, 0.2825, 0.6816, 0.5821, -1.7023], [1.2164, 0.3154, 0.5138, 0.5944, -1.6469],
    [1.272, 0.3411, 0.3593, 0.6456, -1.4325], [1.3386, 0.3609, 0.2269, 0.7526, -1.2159], [1.4187, 0.3745, 0.1175, 0.8726, -0.963],
    [1.5117, 0.3813, 0.0361, 0.9926, -0.658], [1.617, 0.3822, -0.0126, 1.1126, -0.3194], [1.7309, 0.3794, -0.0305, 1.144, -0.0341],
    [1.8452, 0.3762, -0.0202, 1.144, 0.2078], [1.9596, 0.3754, 0.0074, 1.144, 0.3453], [2.074, 0.3784, 0.0464, 1.144, 0.4019],
    [2.1881, 0.386, 0.0861, 1.144, 0.391], [2.3019, 0.398, 0.124, 1.144, 0.3651], [2.4151, 0.4142, 0.159, 1.144, 0.3313],
    [2.5278, 0.434, 0.1891, 1.144, 0.2702], [2.6399, 0.457, 0.2131, 1.144, 0.2102], [2.7514, 0.4822, 0.2313, 1.144, 0.1536],
    [2.8626, 0.5092, 0.2441, 1.144, 0.1073], [2.9735, 0.5374, 0.2529, 1.144, 0.0676], [3.0842, 0.5663, 0.2582, 1.144, 0.041],
    [3.1947, 0.5957, 0.2611, 1.144, 0.0176], [3.3052, 0.6253, 0.262, 1.144, 0.0013], [3.4157, 0.6549, 0.2613, 1.144, -0.0152],
    [3.5263, 0.6844, 0.259, 1.144, -0.0321],
]  # fmt: skip


def test_thin_portal_at_right_angles_does_not_stall(monkeypatch):
    # The exit target of the stages whose reference lies beyond R5 is a point of the thin
    # R5 ∩ bridge(R5, R6). With the reference's speed kept as those stages' input target the
    # optimal plan drove through that point and out of the 10 cm strip, so the guess never
    # fitted the bridge, the assignment never advanced and the plan kept postponing its
    # motion: the robot stopped for good below the portal. A standing target (zero input
    # reference) lets it settle in the strip, advance and turn through.
    areas = make_areas(PORTAL_RECTS)
    plan = plan_from_samples(areas, list(range(len(PORTAL_RECTS))), PORTAL_SAMPLES)
    robot = RobotParams(**{**ROBOT.__dict__, "w_max": 3.0, "alpha_max": 4.0})  # the MuJoCo robot's rates
    start = [1.0, -1.367, 0.86]
    ctl = SAMPC(robot, areas, plan, MPCConfig())
    ok, path, _ = run_closed_loop(ctl, start, plan.goal, areas.rects, steps=150)
    assert ok and inside_union(path, areas.rects).all()
    stall = SAMPC(robot, areas, plan, MPCConfig())
    real = sa_mpc.exit_targets  # the targets without their zero inputs
    monkeypatch.setattr(sa_mpc, "exit_targets", lambda *args: (real(*args)[0], args[3]))
    ok, path, _ = run_closed_loop(stall, start, plan.goal, areas.rects, steps=150)
    assert not ok and path[-1, 0] < 1.2  # stopped for good in R5, below the portal


def test_closed_loop_with_measurement_noise_stays_inside(u_case):
    areas, plan = u_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(box_margin=0.04))
    ok, path, cmds = run_closed_loop(ctl, [0.5, 0.5, 1.57], plan.goal, areas.rects[plan.corridor], noise=0.01, seed=3)
    assert ok
    assert inside_union(path, areas.rects[plan.corridor]).all()
    assert ctl.stats.failures <= 2


def test_measured_position_outside_its_box_is_recovered(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    x = np.array([1.0, -0.03, 0.0])  # at rest, 3 cm below R0 (5 cm below its shrunk box)
    ctl.reset(x, progress=5)
    first = None
    cmd = None
    for k in range(25):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=measured_velocity(cmd)))
        assert cmd.ok
        first = cmd if first is None else first
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
        assert x[1] >= -0.03 - 1e-3  # never further out than it was
    assert first.margins[0] == pytest.approx(-0.05, abs=1e-9)  # the measured position is outside ...
    assert np.all(first.margins[1:] >= -0.05 - 1e-3)  # ... the plan may not go further out
    assert cmd.margins[0] >= 0  # and the robot is back inside its box


# ------------------------------------------------------------------ failures


def test_injected_failures_shift_then_stop_then_recover(l_case):
    areas, plan = l_case
    fail = set(range(15, 15 + 25))  # more failures than the horizon: the plan runs out
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(), failure_injector=lambda k: k in fail)
    x = np.array([0.5, 0.5, 0.0])
    ctl.reset(x)
    statuses, speeds, path = [], [], []
    cmd = None
    for k in range(60):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=measured_velocity(cmd)))
        assert np.isfinite(cmd.v) and np.isfinite(cmd.w)
        statuses.append(cmd.status)
        speeds.append(cmd.v)
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
        path.append(x[:2].copy())
    n = ctl.N
    assert all(s == "ok" for s in statuses[:15])
    assert statuses[15 : 15 + n - 1] == ["fallback_shift"] * (n - 1)  # the rest of the last plan
    assert all(s == "fallback_stop" for s in statuses[15 + n - 1 : 40])
    assert all(not c for c in [statuses[k] == "ok" for k in fail])
    assert abs(speeds[39]) < 1e-9  # stopped (terminal_stop: the shifted plan ends at rest)
    assert statuses[40] == "ok" and statuses[-1] == "ok"  # recovers
    assert ctl.stats.failures == 25
    assert inside_union(np.array(path), areas.rects[plan.corridor]).all()


def test_rejected_solution_takes_the_fallback(l_case, monkeypatch):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    x = np.array([0.5, 0.5, 0.0])
    ctl.reset(x)
    assert ctl.step(Observation(t=0.0, pose=x, velocity=np.zeros(2))).ok
    real = ctl.backend.solve

    def broken(*a, **k):
        r = real(*a, **k)
        r.z = r.z * np.nan
        return r

    monkeypatch.setattr(ctl.backend, "solve", broken)
    cmd = ctl.step(Observation(t=0.1, pose=x, velocity=np.zeros(2)))
    assert not cmd.ok and cmd.status == "fallback_shift" and np.isfinite(cmd.v)
    assert ctl.last_failure_reason.startswith("nonfinite")
    monkeypatch.setattr(ctl.backend, "solve", real)
    nan_pose = np.array([np.nan, 0.5, 0.0])
    cmd = ctl.step(Observation(t=0.2, pose=nan_pose, velocity=np.zeros(2)))
    assert not cmd.ok and np.isfinite(cmd.v) and np.isfinite(cmd.w)


def test_tiny_solve_budget_never_produces_nan(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(solve_budget_ms=0.001))
    x = np.array([0.5, 0.5, 0.0])
    ctl.reset(x)
    cmd = None
    for k in range(20):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=measured_velocity(cmd)))
        assert np.isfinite(cmd.v) and np.isfinite(cmd.w)
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
    assert inside_union(x[None, :2], areas.rects).all()


def test_plan_without_reference_is_rejected(l_case):
    areas, plan = l_case
    bad = type(plan)(False, "no_path", plan.corridor, plan.goal, plan.waypoints, plan.path, plan.smoothed, None)
    with pytest.raises(ValueError, match="plan must be successful"):
        SAMPC(ROBOT, areas, bad)


def test_controller_protocol_attributes(l_controller):
    assert l_controller.name == "sa-mpc" and l_controller.dt == pytest.approx(0.1)
    assert l_controller.needs_ranges is False


def test_reference_yaw_is_shifted_to_the_measured_branch(l_controller):
    ctl = l_controller
    ctl.reset(np.array([0.5, 0.5, 0.0]))
    xr, ur = ctl.reference(np.array([0.5, 0.5, 4 * np.pi + 0.1]))
    assert abs(xr[0, 2] - (4 * np.pi + 0.1)) < np.pi
    assert ur.shape == (ctl.N, 2) and xr.shape == (ctl.N + 1, 3)


# ------------------------------------------------------------------ opening turn on the spot

MJ_RATES = RobotParams(**{**ROBOT.__dict__, "w_max": 3.0, "alpha_max": 4.0})  # rate step 0.4 rad/s


def test_turn_plan_is_the_time_optimal_rest_to_rest_profile(l_case):
    areas, plan = l_case
    ctl = SAMPC(MJ_RATES, areas, plan, MPCConfig())
    u = ctl.turn_plan(1.0)
    np.testing.assert_allclose(u[:, 0], 0.0)
    np.testing.assert_allclose(u[:10, 1], [0.4, 0.8, 1.2, 1.6, 2.0, 1.6, 1.2, 0.8, 0.4, 0.0], atol=1e-12)
    np.testing.assert_allclose(u[10:], 0.0)
    long = ctl.turn_plan(-3.0)  # reaches the yaw-rate bound, then brakes to rest
    assert np.all(long[:, 1] <= 1e-12) and np.min(long[:, 1]) == pytest.approx(-3.0)
    for w in (u[:, 1], long[:, 1]):
        assert np.sum(w) * 0.1 == pytest.approx(np.sign(w.sum()) * abs(w.sum()) * 0.1)
        assert np.all(np.abs(np.diff(np.concatenate(([0.0], w)))) <= 0.4 + 1e-12) and w[-1] == 0.0
    assert np.sum(long[:, 1]) * 0.1 == pytest.approx(-3.0)


def test_opening_turn_on_the_spot_then_the_mpc(l_case):
    areas, plan = l_case  # the reference starts along +x
    ctl = SAMPC(MJ_RATES, areas, plan, MPCConfig())
    x = np.array([0.5, 0.5, 3.0])
    ctl.reset(x)
    cmds, poses = [], []
    cmd = None
    for k in range(200):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x.copy(), velocity=measured_velocity(cmd)))
        cmds.append(cmd)
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
        poses.append(x.copy())
        if np.hypot(*(x[:2] - plan.goal)) < 0.05 and abs(cmd.v) < 0.05:
            break
    status = [c.status for c in cmds]
    n_turn = status.index("ok")
    assert n_turn >= 5 and set(status[:n_turn]) == {"turn"} and "turn" not in status[n_turn:]
    # on the spot: no motion, every plan inside its boxes and at rest at its end
    assert all(c.v == 0.0 and np.all(c.margins >= -1e-9) for c in cmds[:n_turn])
    np.testing.assert_allclose(np.array(poses[:n_turn])[:, :2], 0.5)
    assert abs(poses[n_turn - 1][2]) <= ctl.config.turn_exit + 1e-9  # handed over when aligned
    # input and rate bounds hold across the hand-over and after
    u = np.array([[c.v, c.w] for c in cmds])
    du = np.abs(np.diff(np.vstack(([0.0, 0.0], u)), axis=0))
    assert np.all(du <= ctl.rate_step + 1e-6)
    assert np.all(np.abs(u[:, 1]) <= ctl.limits.w_max + 1e-9)
    assert ctl.stats.failures == 0 and np.hypot(*(x[:2] - plan.goal)) < 0.05


def test_opening_turn_can_be_disabled(l_case):
    areas, plan = l_case
    ctl = SAMPC(MJ_RATES, areas, plan, MPCConfig(turn_in_place=None))
    ctl.reset(np.array([0.5, 0.5, 3.0]))
    cmd = ctl.step(Observation(t=0.0, pose=np.array([0.5, 0.5, 3.0]), velocity=np.zeros(2)))
    assert cmd.status in ("ok", "inexact")
    small = SAMPC(MJ_RATES, areas, plan, MPCConfig())  # a small heading error starts with the MPC
    small.reset(np.array([0.5, 0.5, 0.8]))
    assert small.step(Observation(t=0.0, pose=np.array([0.5, 0.5, 0.8]), velocity=np.zeros(2))).status == "ok"


def test_implied_input_bounds_known_answer_and_never_cut_a_feasible_plan(l_case):
    areas, plan = l_case
    ctl = SAMPC(MJ_RATES, areas, plan, MPCConfig())  # rate step (0.15 m/s, 0.4 rad/s), N = 20
    ctl.reset(np.array([0.5, 0.5, 0.0]), u_prev=np.array([1.0, 0.5]), opening_turn=False)  # a cruise state
    ctl.step(Observation(t=0.0, pose=np.array([0.5, 0.5, 0.0]), velocity=np.zeros(2)))
    lo, hi = ctl.last.input_lower, ctl.last.input_upper
    lim, n = ctl.limits, ctl.N
    for k in range(n):
        stop = (n - 1 - k) * 0.15
        assert hi[k, 0] == pytest.approx(min(lim.v_max, 1.0 + 0.15 * (k + 1), stop))
        assert lo[k, 0] == pytest.approx(max(lim.v_min, 1.0 - 0.15 * (k + 1), -stop))
        assert hi[k, 1] == pytest.approx(min(lim.w_max, 0.5 + 0.4 * (k + 1)))
        assert lo[k, 1] == pytest.approx(max(-lim.w_max, 0.5 - 0.4 * (k + 1)))
    # random plans within the input bounds, the rate bounds from u_prev and the terminal stop
    rng = np.random.default_rng(0)
    for _ in range(200):
        u = np.empty((n, 2))
        last = np.array([1.0, 0.5])
        for k in range(n):
            last = np.clip(last + rng.uniform(-1, 1, 2) * [0.15, 0.4], lim.lower(), lim.upper())
            u[k] = last
        # brake to the terminal stop as late as the rate bound allows
        for k in range(n - 1, -1, -1):
            u[k, 0] = np.clip(u[k, 0], -(n - 1 - k) * 0.15, (n - 1 - k) * 0.15)
        assert np.all(np.abs(np.diff(np.vstack(([1.0, 0.5], u)), axis=0)) <= [0.15 + 1e-12, 0.4 + 1e-12])
        assert np.all(u >= lo - 1e-12) and np.all(u <= hi + 1e-12)


# ------------------------------------------------------------------ model mismatch handling


@pytest.mark.parametrize("delay", [1, 3])
def test_closed_loop_with_delay_and_geometry_mismatch(u_case, delay):
    # actuator delay, wheels 10 % large, track 10 % narrow
    areas, plan = u_case
    steps = {}
    for compensate in (True, False):
        ctl = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(latency_compensation=compensate)))
        ok, path, cmds = run_closed_loop(
            ctl, [0.5, 0.5, 1.57], plan.goal, areas.rects[plan.corridor], gains=(1.1, 1.1 / 0.9), delay=delay
        )
        assert ctl.monitor.delay == delay  # identified either way
        np.testing.assert_allclose(ctl.monitor.gains, [1.1, 1.1 / 0.9], rtol=0.02)
        if compensate:
            assert ok and ctl.stats.failures == 0
            assert inside_union(path, areas.rects[plan.corridor]).all()
        steps[compensate] = len(cmds)
    if delay == 3:  # planning from the measured state with a late plant weaves: twice as long
        assert steps[True] < 0.6 * steps[False]


def test_effective_state_rolls_the_pose_through_the_commands_in_flight(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    pose = np.array([0.5, 0.5, 0.3])
    assert ctl.adaptation.effective_state(pose) is pose  # no delay identified yet
    ctl.monitor.delay = 2
    ctl.monitor.gains = np.array([1.1, 0.9])
    ctl.monitor.record([0.4, 0.5])
    ctl.monitor.record([0.6, -0.2])
    want = step_np(step_np(pose, [0.44, 0.45], ctl.dt), [0.66, -0.18], ctl.dt)
    np.testing.assert_allclose(ctl.adaptation.effective_state(pose), want, atol=1e-12)
    assert ctl.adaptation.effective_state(pose) is not pose
    off = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(latency_compensation=False)))
    off.monitor.delay = 2
    assert off.adaptation.effective_state(pose) is pose


def test_speed_cap_known_answers(l_controller):
    ctl = l_controller
    vm = ctl.limits.v_max
    assert ctl.adaptation.speed_cap(0.0) == vm
    assert ctl.adaptation.speed_cap(0.03) == pytest.approx(vm * (1 - 0.03 / 0.15))
    assert ctl.adaptation.speed_cap(1.0) == pytest.approx(vm * 0.25)
    assert SAMPC(ROBOT, ctl.areas, ctl.plan, MPCConfig(adaptation=AdaptationConfig(excursion_stop=None))).adaptation.speed_cap(1.0) == vm


def test_residual_cap_known_answers(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(residual_free=0.05, residual_stop=0.3, residual_floor=0.1)))
    vm = ctl.limits.v_max
    ctl.monitor.residual = np.array([0.04, 0.0])
    assert ctl.adaptation.residual_cap() == vm
    ctl.monitor.residual = np.array([0.0, 0.175 / 0.19])  # 0.175 m/s at the rim: half way
    assert ctl.adaptation.residual_cap() == pytest.approx(vm * (1 - 0.9 * 0.5))
    ctl.monitor.residual = np.array([0.3, 0.3])
    assert ctl.adaptation.residual_cap() == pytest.approx(0.1 * vm)
    off = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(residual_stop=None)))
    off.monitor.residual = np.array([1.0, 1.0])
    assert off.adaptation.residual_cap() == vm
    with pytest.raises(ValueError, match="AdaptationConfig.residual_stop"):
        MPCConfig(adaptation=AdaptationConfig(residual_free=0.3, residual_stop=0.2))
    with pytest.raises(ValueError, match="AdaptationConfig.residual_floor"):
        MPCConfig(adaptation=AdaptationConfig(residual_floor=1.5))
    with pytest.raises(ValueError, match="AdaptationConfig.excursion_stop"):
        MPCConfig(adaptation=AdaptationConfig(excursion_stop=0.0))


def test_outside_its_box_at_speed_the_speed_bound_brakes_to_the_cap(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(pose_filter=None)))  # a real jump, not noise
    x = np.array([1.0, 0.5, 0.0])
    ctl.reset(x, progress=5, opening_turn=False)
    vel = np.zeros(2)
    for k in range(12):  # get up to speed along R0
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=vel))
        vel = np.array([cmd.v, cmd.w])
        x = step_np(x, vel, ctl.dt)
    v0 = cmd.v
    assert v0 > 0.4
    x_out = x + np.array([0.0, -0.58, 0.0])  # measured 10 cm below the shrunk R0 box (y >= 0.02)
    cmd = ctl.step(Observation(t=1.2, pose=x_out, velocity=np.array([cmd.v, cmd.w])))
    cap = ctl.adaptation.speed_cap(0.02 - x_out[1])
    ub = ctl.last.input_upper[:, 0]
    a_dt = ctl.limits.a_max * ctl.dt
    assert cap < v0
    # each stage may go no faster than braking from v0 at the rate bound or the cap
    assert np.all(ub <= np.maximum(cap, v0 - np.arange(1, ctl.N + 1) * a_dt) + 1e-12)
    assert cmd.v <= v0 - a_dt + 1e-9 or cmd.v <= cap + 1e-9


def test_fallback_brakes_when_the_previous_plan_no_longer_fits(l_case):
    areas, plan = l_case
    fail = {12}
    cfg = MPCConfig(adaptation=AdaptationConfig(pose_filter=None))  # the jump below is real, not noise to filter out
    ctl = SAMPC(ROBOT, areas, plan, cfg, failure_injector=lambda k: k in fail)
    x = np.array([0.5, 0.5, 0.0])
    ctl.reset(x)
    cmd = None
    for k in range(12):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=measured_velocity(cmd)))
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
    v0, w0 = cmd.v, cmd.w
    assert v0 > 0.4
    # the robot turned out to be heading 40 deg to the right of where the plan thinks: the
    # rest of the plan, rolled out from there, leaves R0 through its lower side
    x_bad = x + np.array([0.0, -0.42, -0.7])
    cmd = ctl.step(Observation(t=1.2, pose=x_bad, velocity=measured_velocity(cmd)))
    assert cmd.status == "fallback_stop" and not cmd.ok
    assert cmd.v == pytest.approx(v0 - ctl.limits.a_max * ctl.dt)
    assert abs(cmd.w - w0) <= ctl.limits.alpha_max * ctl.dt + 1e-9
    assert cmd.w > w0  # it steers left, back into R0
    # the same step with the paper-style fallback replays the old plan
    old = SAMPC(ROBOT, areas, plan, replace(cfg, fallback_brake=False), failure_injector=lambda k: k in fail)
    y = np.array([0.5, 0.5, 0.0])
    old.reset(y)
    c = None
    for k in range(12):
        c = old.step(Observation(t=0.1 * k, pose=y, velocity=measured_velocity(c)))
        y = step_np(y, [c.v, c.w], old.dt)
    assert old.step(Observation(t=1.2, pose=x_bad, velocity=measured_velocity(c))).status == "fallback_shift"


def test_brake_plan_stops_at_the_rate_bounds(l_controller):
    ctl = l_controller
    ctl.reset(np.array([1.0, 0.5, 0.0]), u_prev=np.array([1.2, 0.8]))  # a cruise state
    u = ctl.brake_plan(np.array([1.0, 0.5, 0.0]))
    a, al = ctl.limits.a_max * ctl.dt, ctl.limits.alpha_max * ctl.dt
    np.testing.assert_allclose(u[:, 0], np.maximum(1.2 - a * np.arange(1, ctl.N + 1), 0.0))
    assert np.all(np.abs(np.diff(np.concatenate(([[1.2, 0.8]], u)), axis=0)) <= [a, al] + np.array([1e-12, 1e-12]))
    np.testing.assert_allclose(u[-1], [0.0, 0.0], atol=1e-12)


def test_default_limits_are_deterministic(l_case):
    assert MPCConfig().solve_budget_ms is None
    areas, plan = l_case
    runs = []
    for _ in range(2):
        ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
        _, path, cmds = run_closed_loop(ctl, [0.5, 0.5, 0.0], plan.goal, areas.rects[plan.corridor], steps=60, delay=1)
        runs.append(np.array([[c.v, c.w] for c in cmds]))
    np.testing.assert_array_equal(runs[0], runs[1])


def _problem(g_lb, g_ub, z_lb, z_ub, u, guess):
    n = len(u)
    return Problem(np.zeros(0), z_lb, z_ub, g_lb, g_ub, np.zeros(2 * n), u, guess, z_lb, z_ub)


def test_shift_fits_up_to_the_box_margin(l_controller):
    ctl = l_controller
    n = ctl.N
    m = ctl.config.box_margin
    u = np.zeros((n, 2))
    guess = np.tile([1.0, 0.5, 0.0], (n + 1, 1))
    # every stage box [0.9, 0.4] - [1.1, 0.6]; rate rows +-0.15 / +-0.5; inputs in +-1
    g_lb = np.concatenate((np.tile([0.9, 0.4], n), np.tile([-0.15, -0.5], n - 1)))
    g_ub = np.concatenate((np.tile([1.1, 0.6], n), np.tile([0.15, 0.5], n - 1)))
    z_lb, z_ub = -np.ones(2 * n), np.ones(2 * n)
    assert ctl.shift_fits(_problem(g_lb, g_ub, z_lb, z_ub, u, guess))
    out = guess.copy()
    out[5, 1] = 0.6 + 0.5 * m  # half the margin beyond its box: still inside the member
    assert ctl.shift_fits(_problem(g_lb, g_ub, z_lb, z_ub, u, out))
    out[5, 1] = 0.6 + 1.5 * m  # beyond the member
    assert not ctl.shift_fits(_problem(g_lb, g_ub, z_lb, z_ub, u, out))
    jump = u.copy()
    jump[3, 0] = 0.2  # a rate row violated: no margin there
    assert not ctl.shift_fits(_problem(g_lb, g_ub, z_lb, z_ub, jump, guess))
    steady = np.full((n, 2), 0.2)  # no rate row violated, but above an input bound of 0.1
    assert ctl.shift_fits(_problem(g_lb, g_ub, z_lb, z_ub, steady, guess))
    assert not ctl.shift_fits(_problem(g_lb, g_ub, z_lb, np.full(2 * n, 0.1), steady, guess))


def test_residual_yaw_cap_known_answers(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(residual_free=0.05, residual_stop=0.3, residual_floor=0.1)))
    wm = ctl.limits.w_max
    ctl.monitor.residual = np.array([0.04, 0.0])
    assert ctl.adaptation.residual_yaw_cap() == wm
    ctl.monitor.residual = np.array([0.0, 0.175 / 0.19])  # half way: the speed bound is 55 %
    assert ctl.adaptation.residual_yaw_cap() == pytest.approx(wm * (1 - 0.9 * 0.5))
    ctl.monitor.residual = np.array([0.3, 0.3])  # speed bound 10 %, yaw rate floor 30 %
    assert ctl.adaptation.residual_yaw_cap() == pytest.approx(0.3 * wm)
    off = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(residual_yaw_floor=None)))
    off.monitor.residual = np.array([1.0, 1.0])
    assert off.adaptation.residual_yaw_cap() == wm
    with pytest.raises(ValueError, match="AdaptationConfig.residual_yaw_floor"):
        MPCConfig(adaptation=AdaptationConfig(residual_yaw_floor=-0.1))


def _cruise_with_residual(ctl, residual, fail_at=None, steps=12):
    """Drive along R0 for ``steps`` steps, then one more step with the monitor's residual
    forced to ``residual`` (the monitor's own update switched off). Returns (last cmd, v0, w0)."""
    x = np.array([0.5, 0.5, 0.0])
    ctl.reset(x)
    cmd = None
    for k in range(steps):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=measured_velocity(cmd)))
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
    v0, w0 = cmd.v, cmd.w
    ctl.monitor.update = lambda velocity: None
    ctl.monitor.residual = np.asarray(residual, float)
    cmd = ctl.step(Observation(t=0.1 * steps, pose=x, velocity=measured_velocity(cmd)))
    return cmd, v0, w0


def test_residual_derating_bounds_the_yaw_rate_at_the_rate_bound(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    _, _, w0 = _cruise_with_residual(ctl, [0.3, 0.3])
    wcap = ctl.adaptation.residual_yaw_cap()
    assert wcap < ctl.limits.w_max
    al = ctl.limits.alpha_max * ctl.dt
    k = np.arange(1, ctl.N + 1)
    np.testing.assert_allclose(
        ctl.last.input_upper[:, 1],
        np.minimum(np.minimum(ctl.limits.w_max, w0 + k * al), np.maximum(wcap, w0 - k * al)),
        atol=1e-12,
    )
    np.testing.assert_allclose(
        ctl.last.input_lower[:, 1],
        np.maximum(np.maximum(-ctl.limits.w_max, w0 - k * al), np.minimum(-wcap, w0 + k * al)),
        atol=1e-12,
    )
    assert np.all(ctl.last.input_upper[2:, 1] == pytest.approx(wcap))
    off = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(residual_yaw_floor=None)))
    _cruise_with_residual(off, [0.3, 0.3])
    assert off.last.input_upper[-1, 1] == off.limits.w_max


def test_fallback_does_not_follow_the_old_plan_faster_than_the_derated_speed(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(), failure_injector=lambda k: k == 12)
    cmd, v0, _ = _cruise_with_residual(ctl, [0.3, 0.3])
    assert v0 > 0.4 and ctl.adaptation.residual_cap() < v0 - ctl.limits.a_max * ctl.dt
    assert cmd.status == "fallback_stop"  # the rest of the plan cruises on: brake instead
    assert cmd.v == pytest.approx(v0 - ctl.limits.a_max * ctl.dt)
    old = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(fallback_derated=False)), failure_injector=lambda k: k == 12)
    cmd, v0, _ = _cruise_with_residual(old, [0.3, 0.3])
    assert cmd.status == "fallback_shift" and cmd.v > v0 - old.limits.a_max * old.dt


def test_the_pose_filter_feeds_the_problem(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    assert ctl.adaptation.pose_filter is not None
    ctl.reset(np.array([0.5, 0.5, 0.0]), opening_turn=False)
    ctl.adaptation.pose_filter.update = lambda pose, velocity: np.array([0.6, 0.45, 0.1])
    ctl.step(Observation(t=0.0, pose=np.array([0.5, 0.5, 0.0]), velocity=np.zeros(2)))
    np.testing.assert_array_equal(ctl.last.guess_states[0], [0.6, 0.45, 0.1])
    off = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(pose_filter=None)))
    assert off.adaptation.pose_filter is None
    with pytest.raises(ValueError, match="AdaptationConfig.pose_filter"):
        MPCConfig(adaptation=AdaptationConfig(pose_filter=0.1))


def test_closed_loop_with_large_noise_the_pose_filter_calms_the_commands(u_case):
    areas, plan = u_case
    rects = areas.rects[plan.corridor]
    jerk = {}
    for name, cfg in (("filter", MPCConfig()), ("raw", MPCConfig(adaptation=AdaptationConfig(pose_filter=None)))):
        ctl = SAMPC(ROBOT, areas, plan, cfg)
        ok, _, cmds = run_closed_loop(ctl, [0.5, 0.5, 1.57], plan.goal, rects, noise=0.1, seed=3)
        assert ok
        jerk[name] = np.abs(np.diff([c.w for c in cmds])).mean()  # [rad/s] mean yaw-rate change per step
    assert jerk["filter"] < 0.5 * jerk["raw"]  # measured 0.10 against 0.31 rad/s


def test_default_iteration_caps_bound_the_solver_effort():
    cfg = MPCConfig()
    assert cfg.solve_budget_ms is None
    assert (cfg.max_iter, cfg.max_outer_iter) == (100, 20)
    s = cfg.solver_settings()
    assert (s.max_iter, s.max_outer_iter, s.budget_ms) == (100, 20, None)


# ------------------------------------------------------------------ traction limit


def test_traction_accel_known_answers(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(traction_probe=1.25, traction_floor=0.1, traction_recovery=0.05)))
    a_max = ctl.limits.a_max
    assert ctl.accel == a_max and ctl.adaptation.traction_accel(ctl.accel) == a_max  # no slip seen
    ctl.monitor.slipping = True
    ctl.monitor.peak_dv = 0.04  # [m/s per period]: 0.4 m/s^2
    assert ctl.adaptation.traction_accel(ctl.accel) == pytest.approx(1.25 * 0.4)
    ctl.monitor.peak_dv = 0.0
    assert ctl.adaptation.traction_accel(ctl.accel) == pytest.approx(0.1 * a_max)  # the floor
    ctl.monitor.peak_dv = 1.0
    assert ctl.adaptation.traction_accel(ctl.accel) == a_max  # never above the model's bound
    ctl.monitor.slipping = False
    ctl.accel = 0.5
    assert ctl.adaptation.traction_accel(ctl.accel) == pytest.approx(0.5 * 1.05)  # recovers while no slip is seen
    ctl.accel = a_max
    assert ctl.adaptation.traction_accel(ctl.accel) == a_max
    off = SAMPC(ROBOT, areas, plan, MPCConfig(adaptation=AdaptationConfig(traction_probe=None)))
    off.monitor.slipping = True
    assert off.adaptation.traction_accel(off.accel) == a_max
    for kw, match in ((dict(traction_probe=0.0), "traction_probe"), (dict(traction_floor=1.5), "traction_floor"),
                      (dict(traction_recovery=-0.1), "traction_recovery")):
        with pytest.raises(ValueError, match=f"AdaptationConfig.{match}"):
            AdaptationConfig(**kw)


def test_a_slipping_plant_is_planned_to_brake_at_the_grip_it_showed(l_case):
    # the monitor sees slip with 0.04 m/s per period of grip: the MPC's speed rate bound,
    # the speed bounds implied by the terminal stop and the braking fallback use 0.5 m/s^2
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    x = np.array([0.5, 0.5, 0.0])
    ctl.reset(x)
    cmd = None
    for k in range(8):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=measured_velocity(cmd)))
        x = step_np(x, [cmd.v, cmd.w], ctl.dt)
    assert ctl.accel == ctl.limits.a_max  # a kinematic plant with grip: no slip
    ctl.monitor.update = lambda velocity: None
    ctl.monitor.slipping = True
    ctl.monitor.peak_dv = 0.04
    v0 = cmd.v
    cmd = ctl.step(Observation(t=0.8, pose=x, velocity=measured_velocity(cmd)))
    a = 1.25 * 0.4
    assert ctl.accel == pytest.approx(a)
    np.testing.assert_allclose(ctl.last.rate_step, [a * ctl.dt, ctl.limits.alpha_max * ctl.dt])
    k = np.arange(ctl.N)
    assert np.all(ctl.last.input_upper[:, 0] <= (ctl.N - 1 - k) * a * ctl.dt + 1e-12)
    assert np.all(ctl.last.input_upper[:, 0] <= v0 + (k + 1) * a * ctl.dt + 1e-12)
    plan_v = ctl.brake_plan(x)[:, 0]
    np.testing.assert_allclose(plan_v, np.maximum(ctl.u_prev[0] - (k + 1) * a * ctl.dt, 0.0), atol=1e-12)
    ctl.reset(x)
    assert ctl.accel == ctl.limits.a_max


def test_friction_005_double_rect_seed1_no_longer_slides_out_at_the_corner():
    # the one collision of the campaign at 5e9dc79: the floor gives 0.36-0.49 m/s^2 of grip,
    # the model brakes at 1.5; the robot reached 0.93 m/s and slid 10 cm out of its corridor
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.sim.mismatch import parse_mismatch

    doc = run_scenario("double_rect", seed=1, mismatch=parse_mismatch(["friction=0.05"])).document
    assert doc["collisions"] == 0
    assert doc["success"] and doc["reason"] == "goal"
