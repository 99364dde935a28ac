"""DQN controller: shared observation builder, NumPy Q-network, policy file, shipped policy.

NumPy only, except the comparison with the stable-baselines3 / torch network, which is
skipped without the ``rl`` extra.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sanav_mj.control.base import Observation
from sanav_mj.control.dqn import (
    ActionSpec,
    DQNController,
    DQNPolicy,
    ObservationSpec,
    QNetwork,
    build_observation,
    default_policy_path,
)
from sanav_mj.scene import RobotParams, load_scenario

ROBOT = RobotParams(wheel_radius=0.1, track=0.38, footprint_radius=0.33, wheel_speed_max=20.0,
                    v_max=2.0, w_max=3.0, a_max=1.5, alpha_max=4.0)
SPEC = ObservationSpec()


def random_net(rng, sizes=((41, 16), (16, 8), (8, 15))) -> QNetwork:
    return QNetwork(tuple(rng.normal(size=s).astype(np.float32) for s in sizes),
                    tuple(rng.normal(size=s[1]).astype(np.float32) for s in sizes))


def bias_only_policy(best: int, actions: ActionSpec = ActionSpec()) -> DQNPolicy:
    """A policy whose Q-values ignore the input and peak at action ``best``."""
    b = np.zeros(actions.n, dtype=np.float32)
    b[best] = 1.0
    return DQNPolicy(QNetwork((np.zeros((SPEC.size, actions.n), np.float32),), (b,)), SPEC, actions, 0.1)


# ---------------------------------------------------------------- observation


def test_observation_known_answer():
    ranges = np.full(36, 5.0)
    ranges[:4] = [0.0, 2.5, 5.0, 7.0]
    obs = build_observation(SPEC, ranges, pose=np.array([1.0, 1.0, 0.0]), velocity=np.array([0.5, -3.0]),
                            goal=np.array([4.0, 5.0]))
    assert obs.dtype == np.float32 and obs.shape == (41,)
    np.testing.assert_allclose(obs[:4], [0.0, 0.5, 1.0, 1.0])
    np.testing.assert_allclose(obs[36:], [0.5, 0.6, 0.8, 0.5, -1.0], atol=1e-7)  # d = 5 of 10, (3, 4)/5, v, clipped w


def test_observation_bearing_is_in_the_robot_frame():
    ranges = np.full(36, 5.0)
    obs = build_observation(SPEC, ranges, np.array([0.0, 0.0, math.pi / 2]), np.zeros(2), np.array([3.0, 4.0]))
    # goal at world angle atan2(4, 3); robot facing +y: bearing = atan2(4, 3) - pi/2
    np.testing.assert_allclose(obs[37:39], [0.8, -0.6], atol=1e-7)
    far = build_observation(SPEC, ranges, np.zeros(3), np.zeros(2), np.array([30.0, 0.0]))
    assert far[36] == 1.0  # clipped at goal_range_m


def test_observation_rejects_wrong_ray_count_and_sanitises_nonfinite():
    with pytest.raises(ValueError, match="36 rays"):
        build_observation(SPEC, np.ones(10), np.zeros(3), np.zeros(2), np.ones(2))
    r = np.full(36, np.inf)
    r[0] = np.nan
    obs = build_observation(SPEC, r, np.zeros(3), np.zeros(2), np.ones(2))
    assert np.all(np.isfinite(obs)) and np.all(obs[:36] == 1.0)


def test_specs_validate_their_arguments():
    with pytest.raises(ValueError, match="ObservationSpec.n_rays"):
        ObservationSpec(n_rays=0)
    with pytest.raises(ValueError, match="ObservationSpec.ray_range_m"):
        ObservationSpec(ray_range_m=-1.0)
    with pytest.raises(ValueError, match="ActionSpec.w_levels"):
        ActionSpec(w_levels=(0.0, 0.0))
    with pytest.raises(ValueError, match="v_max"):
        ActionSpec(v_levels=(0.0, 2.5)).check_within(ROBOT)
    with pytest.raises(ValueError, match="w_max"):
        ActionSpec(w_levels=(-3.5, 0.0)).check_within(ROBOT)


def test_action_table_is_v_major_and_includes_rotation_and_stop():
    spec = ActionSpec(v_levels=(0.0, 0.5), w_levels=(-1.0, 0.0, 1.0))
    np.testing.assert_array_equal(spec.table(), [[0, -1], [0, 0], [0, 1], [0.5, -1], [0.5, 0], [0.5, 1]])
    default = ActionSpec().table()
    assert default.shape == (15, 2)
    assert any((default[:, 0] == 0) & (default[:, 1] != 0))  # rotate in place
    assert any((default[:, 0] == 0) & (default[:, 1] == 0))  # stop


# ---------------------------------------------------------------- network and file


def float32_error_bound(net: QNetwork, x: np.ndarray) -> np.ndarray:
    """Bound on |float32 forward pass - exact| for each Q-value, whatever the summation order.

    A layer ``h W + b`` with ``n`` inputs computed in float32 (any order, blocking or FMA, as
    BLAS kernels differ per CPU) is within ``gamma_(n+1) (|h| |W| + |b|)`` of the exact value,
    ``gamma_k = k u / (1 - k u)``, ``u = 2^-24`` (Higham, Accuracy and Stability, Sec. 3.1).
    ReLU does not enlarge errors, and a later layer carries an earlier layer's error through
    ``|W|``; so the total is at most ``sum_l gamma_(n_l+1)`` times the forward pass of the
    absolute values ``a_(l+1) = a_l |W_l| + |b_l|`` (computed in float64), plus the rounding
    of the float32 inputs and outputs (included by adding 2 u).
    """
    u = 2.0**-24
    gamma = sum((n + 1) * u / (1 - (n + 1) * u) for n in (w.shape[0] for w in net.weights))
    a = np.abs(np.asarray(x, dtype=np.float64))
    for w, b in zip(net.weights, net.biases):
        a = a @ np.abs(w.astype(np.float64)) + np.abs(b.astype(np.float64))
    return (gamma + 2 * u) * a


def test_qnetwork_equals_an_explicit_forward_pass():
    rng = np.random.default_rng(0)
    net = random_net(rng)
    x = rng.uniform(-1, 1, size=(7, 41)).astype(np.float32)
    h = x.astype(np.float64)
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        h = h @ w.astype(np.float64) + b
        if i < 2:
            h = np.where(h > 0, h, 0.0)
    bound = float32_error_bound(net, x)
    q = net.q_values(x)
    # float32 vs the (float64, effectively exact) forward pass: within the rounding bound
    assert np.all(np.abs(q - h) <= bound)
    # one row (a gemv kernel) vs the batch (a gemm kernel): both within the bound of the exact
    # value, so within twice the bound of each other. Not a relative tolerance: a Q-value near
    # zero after cancellation differs by 2.6e-4 relative between OpenBLAS's Haswell and
    # SkylakeX kernels (OPENBLAS_CORETYPE), although both are correctly rounded sums.
    for k in range(len(x)):
        assert np.all(np.abs(net.q_values(x[k]) - q[k]) <= 2 * bound[k])


def test_qnetwork_rejects_mismatched_layers():
    with pytest.raises(ValueError, match="layer 1"):
        QNetwork((np.zeros((4, 3)), np.zeros((2, 5))), (np.zeros(3), np.zeros(5)))


def test_policy_checks_its_network_against_the_specs():
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="outputs"):
        DQNPolicy(random_net(rng, ((41, 8), (8, 9))), SPEC, ActionSpec(), 0.1)
    with pytest.raises(ValueError, match="inputs"):
        DQNPolicy(random_net(rng, ((40, 8), (8, 15))), SPEC, ActionSpec(), 0.1)


def test_policy_file_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    pol = DQNPolicy(random_net(rng), ObservationSpec(goal_range_m=12.0), ActionSpec(), 0.1, info={"seed": 7})
    path = tmp_path / "p.npz"
    pol.save(path)
    back = DQNPolicy.load(path)
    assert back.obs_spec == pol.obs_spec and back.actions == pol.actions and back.dt == pol.dt
    assert back.info == {"seed": 7}
    x = rng.uniform(-1, 1, size=(5, 41)).astype(np.float32)
    np.testing.assert_array_equal(back.network.q_values(x), pol.network.q_values(x))


def test_policy_file_without_meta_is_rejected(tmp_path):
    path = tmp_path / "x.npz"
    np.savez(path, W0=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="not a DQN policy"):
        DQNPolicy.load(path)


# ---------------------------------------------------------------- controller


def test_controller_applies_the_greedy_action():
    table = ActionSpec().table()
    for best in (0, 7, 14):
        ctrl = DQNController(bias_only_policy(best), ROBOT, np.array([3.0, 0.0]))
        ctrl.reset(np.zeros(3))
        cmd = ctrl.step(Observation(t=0.0, pose=np.zeros(3), velocity=np.zeros(2), ranges=np.full(36, 5.0)))
        assert (cmd.v, cmd.w) == tuple(table[best])
        assert cmd.ok and cmd.status == "ok" and cmd.solve_ms >= 0.0
        assert ctrl.last_action == best
    assert (ctrl.name, ctrl.dt, ctrl.needs_ranges) == ("dqn", 0.1, True)


def test_controller_needs_ranges_and_a_finite_goal():
    ctrl = DQNController(bias_only_policy(0), ROBOT, np.array([3.0, 0.0]))
    with pytest.raises(ValueError, match="ranges"):
        ctrl.step(Observation(t=0.0, pose=np.zeros(3), velocity=np.zeros(2)))
    with pytest.raises(ValueError, match="goal"):
        DQNController(bias_only_policy(0), ROBOT, np.array([np.nan, 0.0]))
    slow = RobotParams(**{**ROBOT.__dict__, "v_max": 0.5})
    with pytest.raises(ValueError, match="v_max"):
        DQNController(bias_only_policy(0), slow, np.zeros(2))


# ---------------------------------------------------------------- the shipped policy


def test_shipped_policy_loads():
    sc = load_scenario("single_rect")
    ctrl = DQNController.load_default(sc.robot, sc.goal)
    pol = ctrl.policy
    assert default_policy_path().is_file()
    assert pol.network.n_in == pol.obs_spec.size and pol.network.n_out == pol.actions.n
    assert pol.dt == 0.1
    assert {"seed", "total_steps", "hyperparameters", "final_metrics"} <= set(pol.info)


def test_shipped_policy_drives():
    """From the start of a built-in scenario the shipped policy moves the MuJoCo robot with
    finite commands from its action table (no claim about reaching the goal here)."""
    from sanav_mj.sim.plant import Plant
    from sanav_mj.sim.runner import RunConfig, run_episode

    sc = load_scenario("single_rect")
    ctrl = DQNController.load_default(sc.robot, sc.goal)
    ep = run_episode(Plant(sc), ctrl, sc.start, sc.goal, RunConfig(time_limit_s=4.0))
    cmds = np.asarray(ep.trace.cmd)
    assert len(cmds) >= 10 and np.all(np.isfinite(cmds))
    table = {tuple(r) for r in ctrl.policy.actions.table()}
    assert all(tuple(c) in table for c in cmds)
    moved = np.hypot(*(ep.final_pose[:2] - sc.start[:2]))
    assert moved > 0.5, moved
    assert max(np.asarray(ep.trace.solve_ms)) > 0.0


def test_shipped_numpy_network_equals_the_sb3_network():
    pytest.importorskip("torch")
    sb3 = pytest.importorskip("stable_baselines3")
    import torch

    zip_path = default_policy_path().with_name("dqn_sb3.zip")
    if not zip_path.is_file():
        pytest.skip("the SB3 zip was not shipped (over the size limit)")
    model = sb3.DQN.load(zip_path, device="cpu")
    pol = DQNPolicy.load(default_policy_path())
    x = np.random.default_rng(0).uniform(-1, 1, size=(200, pol.obs_spec.size)).astype(np.float32)
    with torch.no_grad():
        q_torch = model.q_net(torch.as_tensor(x)).numpy()
    q = pol.network.q_values(x)
    # two float32 evaluations (NumPy/OpenBLAS vs torch/MKL or oneDNN kernels): each within the
    # rounding bound of the exact value (float32_error_bound), so within twice it of each other
    bound = 2 * float32_error_bound(pol.network, x)
    assert np.all(np.abs(q - q_torch) <= bound)
    # the greedy action agrees wherever the best two Q-values are further apart than the bound
    top2 = np.sort(q, axis=1)[:, -2:]
    clear = top2[:, 1] - top2[:, 0] > 2 * bound.max(axis=1)
    assert clear.mean() > 0.5  # 0.845 of these 200 inputs (the bound is a worst case)
    np.testing.assert_array_equal(q.argmax(axis=1)[clear], q_torch.argmax(axis=1)[clear])
