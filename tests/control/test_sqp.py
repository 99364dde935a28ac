"""The SQP back-end: answers against IPOPT, constraints, warm start, infeasible problems."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest
from mpc_cases import ROBOT

from sanav_mj.control.base import Observation
from sanav_mj.control.backend_ipopt import IpoptBackend
from sanav_mj.control.backends import make_backend
from sanav_mj.control.problem import build_tracking_ocp, shift_inputs, shift_multipliers
from sanav_mj.control.solver import SolverSettings
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig, SafeAreaPenalty
from sanav_mj.control.sqp import (
    SqpBackend,
    compile_sqp_function,
    sqp_functions,
    tracking_residuals,
)
from sanav_mj.control.unicycle import rollout_np, step_np


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("sqp_cache")


def _sa_problem(ocp, y_max=0.2):
    """A small SA-MPC-like problem: J_SA active (the reference leaves the first area), the
    position bound ``y <= y_max``, input and rate bounds active at the optimum."""
    n = ocp.horizon
    x_ref = np.column_stack((np.linspace(0, 3, n + 1), np.linspace(0, 1, n + 1), np.zeros(n + 1)))
    u_ref = np.tile([1.5, 0.0], (n, 1))
    theta = np.array([-1.0, -0.5, 10.0, 0.15, 3.0, 1.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0])  # slot 2 inactive
    p = ocp.layout.pack([0, 0, 0], [0.5, 0.0], x_ref, u_ref, [10, 10, 1], [1, 0.1], [2, 0.5], [40, 40, 2], theta)
    z_lb, z_ub = np.tile([-0.3, -4.0], n), np.tile([1.2, 4.0], n)
    z_lb[:2] = np.maximum(z_lb[:2], [0.35, -0.6])
    z_ub[:2] = np.minimum(z_ub[:2], [0.65, 0.6])
    rate = np.tile([0.15, 0.6], n - 1)
    g_lb = np.concatenate((np.tile([-1.0, -0.5], n), -rate))
    g_ub = np.concatenate((np.tile([10.0, y_max], n), rate))
    return p, z_lb, z_ub, g_lb, g_ub


def _violation(ocp, z, p, z_lb, z_ub, g_lb, g_ub) -> float:
    g = np.array(cs.Function("g", [ocp.z, ocp.p], [ocp.g])(z, p)).ravel()
    return max(np.max(g_lb - g), np.max(g - g_ub), np.max(z_lb - z), np.max(z - z_ub), 0.0)


@pytest.mark.parametrize("hessian", ["exact", "objective", "gauss-newton"])
def test_sqp_equals_ipopt_on_a_constrained_safe_area_problem(cache, hessian):
    ocp = build_tracking_ocp(8, 0.1, SafeAreaPenalty(2))
    args = _sa_problem(ocp)
    settings = SolverSettings(tol=1e-7, constraint_tol=1e-8)
    sqp = SqpBackend(ocp, settings, cache, hessian=hessian)
    ref = IpoptBackend(ocp, SolverSettings(tol=1e-10, constraint_tol=1e-10)).solve(*args, np.zeros(ocp.n_z))
    res = sqp.solve(*args, np.zeros(ocp.n_z))
    assert ref.converged and res.converged and res.status == "Converged"
    np.testing.assert_allclose(res.z, ref.z, atol=1e-6)
    np.testing.assert_allclose(res.y, ref.y, atol=1e-4 * max(1.0, np.abs(ref.y).max()))
    np.testing.assert_allclose(res.y_z, ref.y_z, atol=1e-4 * max(1.0, np.abs(ref.y_z).max()))
    assert _violation(ocp, res.z, *args) <= 1e-8
    g = np.array(cs.Function("g", [ocp.z, ocp.p], [ocp.g])(res.z, args[0])).ravel()
    assert g[1 : 2 * ocp.horizon : 2].max() == pytest.approx(0.15 + 0.05, abs=1e-9)  # y <= 0.2 active
    assert np.any(res.y > 1e-3) and np.all(np.isfinite(res.y))


def test_tracking_residuals_leave_exactly_the_position_cost():
    ocp = build_tracking_ocp(6, 0.1, SafeAreaPenalty(2))
    p = _sa_problem(ocp)[0]
    r = cs.Function("r", [ocp.z, ocp.p], [ocp.f - cs.sumsqr(tracking_residuals(ocp))])
    theta = p[ocp.layout.slices()["extra"]]
    z = (np.tile([1.5, 3.0], (6, 1)) + np.random.default_rng(0).uniform(-0.2, 0.2, (6, 2))).ravel()  # leaves y <= 0.15
    xs = rollout_np(p[:3], z.reshape(6, 2), 0.1)
    want = sum(SafeAreaPenalty.value_np(xs[k, :2], theta[None, :4], theta[4:5]) for k in range(1, 7))
    assert want > 0.01
    assert float(r(z, p)) == pytest.approx(want, rel=1e-10, abs=1e-12)


def test_warm_start_from_the_solution_needs_no_iteration(cache):
    ocp = build_tracking_ocp(8, 0.1, SafeAreaPenalty(2))
    args = _sa_problem(ocp)
    sqp = SqpBackend(ocp, SolverSettings(tol=1e-6, constraint_tol=1e-6), cache)
    cold = sqp.solve(*args, np.zeros(ocp.n_z))
    warm = sqp.solve(*args, cold.z, cold.y)
    assert cold.converged and warm.converged
    assert cold.iterations >= 2 and warm.iterations == 0
    np.testing.assert_array_equal(warm.z, cold.z)  # returned as given


def test_infeasible_problem_is_reported_and_the_output_is_finite(cache):
    ocp = build_tracking_ocp(8, 0.1, SafeAreaPenalty(2))
    p, z_lb, z_ub, g_lb, g_ub = _sa_problem(ocp)
    g_lb[0] = 1.0  # x_1 >= 1 m after 0.1 s at <= 0.65 m/s: impossible
    sqp = SqpBackend(ocp, SolverSettings(), cache)
    for z0 in (np.zeros(ocp.n_z), np.full(ocp.n_z, np.nan)):
        res = sqp.solve(p, z_lb, z_ub, g_lb, g_ub, z0)
        assert not res.converged and res.status == "Infeasible"
        assert np.all(np.isfinite(res.z)) and np.all(np.isfinite(res.y)) and np.all(np.isfinite(res.y_z))
        assert np.all(res.z >= z_lb) and np.all(res.z <= z_ub)
    # the same problem made feasible again is solved by the same back-end
    g_lb[0] = -1.0
    assert sqp.solve(p, z_lb, z_ub, g_lb, g_ub, np.zeros(ocp.n_z)).converged


def test_registered_and_cached(cache):
    ocp = build_tracking_ocp(3, 0.1)
    assert isinstance(make_backend("sqp", ocp, SolverSettings(), cache), SqpBackend)
    fn = sqp_functions(ocp)
    path, compiled = compile_sqp_function(fn, cache)
    assert not compiled and path.is_file()  # built by make_backend above
    with pytest.raises(ValueError, match="hessian must be"):
        sqp_functions(ocp, "bfgs")


def test_sqp_equals_ipopt_along_an_sa_mpc_closed_loop(l_case):
    """Problems posed by SA-MPC (default horizon and weights) along a closed loop through the
    L corridor: the warm-started SQP answer (default tolerances) equals a tight IPOPT's, within
    the bounds, and the warm start cuts the iterations against cold starts."""
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig(solver="ipopt", tol=1e-9, constraint_tol=1e-9))
    problems = []
    real = ctl.backend.solve

    def recording(*args):
        res = real(*args)
        problems.append((args[:5], res))
        return res

    ctl.backend.solve = recording
    try:
        x = np.array([0.5, 0.5, 0.3])
        ctl.reset(x)
        for k in range(40):
            cmd = ctl.step(Observation(t=0.1 * k, pose=x.copy(), velocity=np.zeros(2)))
            x = step_np(x, [0.95 * cmd.v, 1.05 * cmd.w], ctl.dt)
    finally:
        ctl.backend.solve = real
    assert len(problems) >= 30
    ocp, n = ctl.ocp, ctl.ocp.horizon
    f = cs.Function("f", [ocp.z, ocp.p], [ocp.f])
    sqp = make_backend("sqp", ocp, MPCConfig(solver="sqp").solver_settings())
    rate_step = ctl.limits.rate() * ctl.dt
    prev, warm_it, cold_it = None, 0, 0
    for (p, z_lb, z_ub, g_lb, g_ub), ref in problems:
        assert ref.converged
        if prev is None:
            z0, y0 = np.zeros(2 * n), None
        else:
            z0 = shift_inputs(prev.z.reshape(n, 2), 1, n, rate_step, prev.z[:2]).ravel()
            y0 = shift_multipliers(ocp, prev.y, shift_rates=False)
        res = sqp.solve(p, z_lb, z_ub, g_lb, g_ub, np.clip(z0, z_lb, z_ub), y0)
        cold = sqp.solve(p, z_lb, z_ub, g_lb, g_ub, np.clip(np.zeros(2 * n), z_lb, z_ub))
        assert res.converged and cold.converged
        assert _violation(ocp, res.z, p, z_lb, z_ub, g_lb, g_ub) <= 1e-4
        assert float(f(res.z, p)) - float(f(ref.z, p)) <= 1e-3 * max(1.0, float(f(ref.z, p)))
        np.testing.assert_allclose(res.z[:2], ref.z[:2], atol=5e-3)
        warm_it += res.iterations
        cold_it += cold.iterations
        prev = res
    assert warm_it < cold_it
