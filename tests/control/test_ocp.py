"""The shared tracking NLP: cost and constraints against a NumPy reference, caching, back-ends."""

import numpy as np
import pytest

from sanav_mj.control.backend_alpaqa import PanocBackend, ZeroFprBackend
from sanav_mj.control.backend_ipopt import IpoptBackend
from sanav_mj.control.backends import make_backend
from sanav_mj.control.codegen import CACHE_ENV, compile_alpaqa_problem, default_cache_dir
from sanav_mj.control.problem import build_tracking_ocp, shift_bound_multipliers, shift_inputs, shift_multipliers
from sanav_mj.control.solver import SolverSettings
from sanav_mj.control.sa_mpc import SafeAreaPenalty
from sanav_mj.control.unicycle import rollout_np


def _random_problem(rng, n, n_extra=0):
    x0 = np.array([0.2, -0.1, 0.4])
    u_prev = np.array([0.3, -0.2])
    x_ref = np.column_stack((np.linspace(0, 2, n + 1), np.zeros(n + 1), np.zeros(n + 1)))
    u_ref = np.tile([1.0, 0.0], (n, 1))
    w = dict(q_x=np.array([3.0, 4.0, 0.5]), q_u=np.array([1.0, 0.2]), q_a=np.array([2.0, 0.3]), q_n=np.array([9.0, 8.0, 1.0]))
    z = rng.uniform(-1, 1, 2 * n)
    return x0, u_prev, x_ref, u_ref, w, z


def _numpy_cost(x0, u_prev, x_ref, u_ref, w, z, dt):
    u = z.reshape(-1, 2)
    xs = rollout_np(x0, u, dt)
    n = len(u)
    c = 0.0
    last = u_prev
    for k in range(n):
        c += w["q_x"] @ (xs[k] - x_ref[k]) ** 2 + w["q_u"] @ (u[k] - u_ref[k]) ** 2 + w["q_a"] @ (u[k] - last) ** 2
        last = u[k]
    return c + w["q_n"] @ (xs[n] - x_ref[n]) ** 2, xs


def test_objective_and_constraints_match_numpy_reference():
    rng = np.random.default_rng(0)
    n, dt = 6, 0.1
    ocp = build_tracking_ocp(n, dt)
    x0, u_prev, x_ref, u_ref, w, z = _random_problem(rng, n)
    p = ocp.layout.pack(x0, u_prev, x_ref, u_ref, w["q_x"], w["q_u"], w["q_a"], w["q_n"])
    f, g = ocp.functions()
    want, xs = _numpy_cost(x0, u_prev, x_ref, u_ref, w, z, dt)
    assert float(f(z, p)) == pytest.approx(want, rel=1e-12)
    u = z.reshape(-1, 2)
    g_want = np.concatenate((xs[1:, :2].ravel(), np.diff(u, axis=0).ravel()))
    np.testing.assert_allclose(np.array(g(z, p)).ravel(), g_want, atol=1e-12)
    assert ocp.n_g == 2 * n + 2 * (n - 1)


def test_position_cost_is_added_for_stages_one_to_n():
    rng = np.random.default_rng(1)
    n, dt = 5, 0.1
    pen = SafeAreaPenalty(2)
    ocp = build_tracking_ocp(n, dt, pen, position_constraints=False)
    x0, u_prev, x_ref, u_ref, w, z = _random_problem(rng, n, pen.n_params)
    theta = np.array([0.0, -0.05, 0.3, 0.05, 4.0, 1.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0])  # slot 2 inactive
    p = ocp.layout.pack(x0, u_prev, x_ref, u_ref, w["q_x"], w["q_u"], w["q_a"], w["q_n"], theta)
    f, g = ocp.functions()
    base, xs = _numpy_cost(x0, u_prev, x_ref, u_ref, w, z, dt)
    jsa = sum(SafeAreaPenalty.value_np(xs[k, :2], theta[None, :4], theta[4:5]) for k in range(1, n + 1))
    assert jsa > 0
    assert float(f(z, p)) == pytest.approx(base + jsa, rel=1e-12)
    assert ocp.n_g == 2 * (n - 1)  # rates only


def test_layout_slices_cover_the_parameter_vector():
    ocp = build_tracking_ocp(4, 0.1, SafeAreaPenalty(3))
    sl = ocp.layout.slices()
    covered = np.zeros(ocp.layout.size, dtype=int)
    for s in sl.values():
        covered[s] += 1
    assert np.all(covered == 1)
    assert sl["x_ref"].stop - sl["x_ref"].start == 15 and sl["extra"].stop - sl["extra"].start == 18


def test_builder_rejects_bad_arguments():
    with pytest.raises(ValueError, match="horizon"):
        build_tracking_ocp(0, 0.1)
    with pytest.raises(ValueError, match="dt"):
        build_tracking_ocp(3, -0.1)
    with pytest.raises(ValueError, match="solver must be one of"):
        make_backend("nope", build_tracking_ocp(3, 0.1), SolverSettings())


def test_cache_dir_honours_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "c"))
    assert default_cache_dir() == tmp_path / "c"
    monkeypatch.delenv(CACHE_ENV)
    assert default_cache_dir().name == "sanav-mj"


def test_compiled_problem_is_cached_on_disk(tmp_path):
    ocp = build_tracking_ocp(2, 0.1)
    f, g = ocp.functions()
    path1, compiled1 = compile_alpaqa_problem(f, g, "no", tmp_path)
    path2, compiled2 = compile_alpaqa_problem(f, g, "no", tmp_path)
    assert compiled1 and not compiled2 and path1 == path2 and path1.is_file()
    other = build_tracking_ocp(3, 0.1).functions()
    path3, compiled3 = compile_alpaqa_problem(*other, "no", tmp_path)
    assert compiled3 and path3 != path1  # a different structure never reuses the library


def _box_problem(ocp):
    """A small problem whose optimum has active input, rate and position bounds."""
    n = ocp.horizon
    x0 = np.array([0.0, 0.0, 0.0])
    x_ref = np.column_stack((np.linspace(0, 3, n + 1), np.linspace(0, 1, n + 1), np.zeros(n + 1)))
    u_ref = np.tile([1.5, 0.0], (n, 1))
    p = ocp.layout.pack(x0, [0.5, 0.0], x_ref, u_ref, [10, 10, 1], [1, 0.1], [2, 0.5], [40, 40, 2])
    z_lb = np.tile([-0.3, -4.0], n)
    z_ub = np.tile([1.2, 4.0], n)
    z_lb[:2] = np.maximum(z_lb[:2], [0.5 - 0.15, -0.6])
    z_ub[:2] = np.minimum(z_ub[:2], [0.5 + 0.15, 0.6])
    pos_lb = np.tile([-1.0, -0.5], n)
    pos_ub = np.tile([10.0, 0.2], n)  # y <= 0.2 is active
    rate = np.tile([0.15, 0.6], n - 1)
    return p, z_lb, z_ub, np.concatenate((pos_lb, -rate)), np.concatenate((pos_ub, rate))


@pytest.mark.parametrize("backend", [PanocBackend, ZeroFprBackend])
def test_panoc_and_ipopt_agree_on_a_constrained_problem(tmp_path, backend):
    ocp = build_tracking_ocp(8, 0.1)
    args = _box_problem(ocp)
    z0 = np.zeros(ocp.n_z)
    panoc = backend(ocp, SolverSettings(tol=1e-7, constraint_tol=1e-7), tmp_path)
    ipopt = IpoptBackend(ocp, SolverSettings(tol=1e-9, constraint_tol=1e-9))
    a = panoc.solve(*args, np.clip(z0, args[1], args[2]))
    b = ipopt.solve(*args, z0)
    assert a.converged and b.converged
    np.testing.assert_allclose(a.z, b.z, atol=2e-4)
    f, g = ocp.functions()
    assert float(f(a.z, args[0])) == pytest.approx(float(f(b.z, args[0])), rel=1e-5)
    gb = np.array(g(b.z, args[0])).ravel()
    assert gb[1::2][: ocp.horizon].max() == pytest.approx(0.2, abs=1e-6)  # the y bound is active
    np.testing.assert_allclose(a.y, b.y, atol=5e-2 * max(1.0, np.abs(b.y).max()))


def test_shift_inputs_brakes_within_the_rate_limits():
    u = np.array([[1.0, 0.5], [1.1, 0.4], [1.2, -0.3]])
    rate = np.array([0.5, 0.2])
    out = shift_inputs(u, 1, 5, rate, u[0])
    np.testing.assert_allclose(out, [[1.1, 0.4], [1.2, -0.3], [0.7, -0.1], [0.2, 0.0], [0.0, 0.0]])
    np.testing.assert_allclose(shift_inputs(u, 3, 2, rate, np.array([0.3, -0.5])), [[0.0, -0.3], [0.0, -0.1]])


def test_shift_multipliers_moves_one_stage():
    ocp = build_tracking_ocp(3, 0.1)
    y = np.arange(ocp.n_g, dtype=float)  # positions 0..5, rates 6..9
    np.testing.assert_allclose(shift_multipliers(ocp, y), [2, 3, 4, 5, 4, 5, 8, 9, 0, 0])
    # rate multipliers kept in place (the terminal braking stays at the end of the horizon)
    np.testing.assert_allclose(shift_multipliers(ocp, y, shift_rates=False), [2, 3, 4, 5, 4, 5, 6, 7, 8, 9])
    assert shift_bound_multipliers(None) is None
    np.testing.assert_allclose(shift_bound_multipliers(np.arange(6.0)), [2, 3, 4, 5, 0, 0])


def test_compiled_functions_equal_casadi_on_the_safe_area_problem(tmp_path):
    """The compiled library (common subexpressions eliminated, CasADi's fmin/fmax branch)
    evaluates f, grad f, g and the augmented Lagrangian as CasADi does, with J_SA's [.]_-
    active at some stages and not at others."""
    import alpaqa
    import casadi as cs

    rng = np.random.default_rng(3)
    n, dt = 6, 0.1
    pen = SafeAreaPenalty(2)
    ocp = build_tracking_ocp(n, dt, pen)
    x0, u_prev, x_ref, u_ref, w, z = _random_problem(rng, n, pen.n_params)
    theta = np.array([0.0, -0.05, 0.3, 0.05, 4.0, 1.0, 0.25, -0.5, 1.0, 0.5, 2.0, 1.0])
    p = ocp.layout.pack(x0, u_prev, x_ref, u_ref, w["q_x"], w["q_u"], w["q_a"], w["q_n"], theta)
    f, g = ocp.functions()
    path, _ = compile_alpaqa_problem(f, g, "no", tmp_path)
    prob = alpaqa.load_casadi_problem(str(path))
    prob.param = p
    gl, gu = np.full(ocp.n_g, -0.1), np.full(ocp.n_g, 0.1)
    prob.general_bounds.lower, prob.general_bounds.upper = gl, gu
    grad_f = cs.Function("gf", [ocp.z, ocp.p], [cs.gradient(ocp.f, ocp.z)])
    for _ in range(3):
        z = rng.uniform(-1, 1, ocp.n_z)
        y, sigma = rng.normal(size=ocp.n_g), rng.uniform(1, 100, ocp.n_g)
        assert prob.eval_objective(z) == pytest.approx(float(f(z, p)), rel=1e-12)
        np.testing.assert_allclose(prob.eval_objective_gradient(z), np.array(grad_f(z, p)).ravel(), rtol=1e-11, atol=1e-11)
        gz = np.array(g(z, p)).ravel()
        np.testing.assert_allclose(prob.eval_constraints(z), gz, rtol=1e-12, atol=1e-14)
        zeta = gz + y / sigma
        d = zeta - np.clip(zeta, gl, gu)
        psi = float(f(z, p)) + 0.5 * np.dot(sigma * d, d)
        assert prob.eval_augmented_lagrangian(z, y, sigma)[0] == pytest.approx(psi, rel=1e-12)


def test_solver_settings_reject_bad_values():
    with pytest.raises(ValueError, match="position_scale"):
        SolverSettings(position_scale=0.0)
    with pytest.raises(ValueError, match="max_iter"):
        SolverSettings(max_iter=0)
    with pytest.raises(ValueError, match="input_scale"):
        SolverSettings(input_scale=(1.0, -3.0))
    with pytest.raises(ValueError, match="budget_ms"):
        SolverSettings(budget_ms=-1.0)
