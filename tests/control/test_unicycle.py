"""The unicycle model: CasADi and NumPy twins agree, and the step is the exact ZOH solution."""

import math

import casadi as cs
import numpy as np

from sanav_mj.control.unicycle import (
    arc_chord_deviation,
    rollout_cs,
    rollout_np,
    sinc_half,
    step_function,
    step_np,
)


def _random_states_inputs(rng, n):
    x = np.column_stack((rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-10, 10, n)))
    u = np.column_stack((rng.uniform(-2, 2, n), rng.uniform(-15, 15, n)))  # |w dt / 2| <= 0.75
    return x, u


def test_casadi_step_equals_numpy_twin():
    rng = np.random.default_rng(0)
    x, u = _random_states_inputs(rng, 500)
    f = step_function(0.1)
    got = np.array(f.map(500)(x.T, u.T)).T
    np.testing.assert_allclose(got, step_np(x, u, 0.1), rtol=0, atol=1e-12)


def test_symbolic_rollout_equals_numpy_rollout():
    rng = np.random.default_rng(1)
    x0 = np.array([0.3, -0.2, 2.5])
    us = np.column_stack((rng.uniform(-1, 2, 15), rng.uniform(-4, 4, 15)))
    sx = cs.SX.sym("x", 3)
    su = cs.SX.sym("u", 15 * 2)
    xs = rollout_cs(sx, [su[2 * k : 2 * k + 2] for k in range(15)], 0.05)
    f = cs.Function("r", [sx, su], [cs.horzcat(*xs).T])
    np.testing.assert_allclose(np.array(f(x0, us.ravel())), rollout_np(x0, us, 0.05), atol=1e-12)


def test_rollout_is_repeated_step():
    rng = np.random.default_rng(2)
    x0 = np.array([1.0, 2.0, -0.5])
    us = np.column_stack((rng.uniform(0, 1, 10), rng.uniform(-3, 3, 10)))
    xs = rollout_np(x0, us, 0.1)
    x = x0
    eps = np.finfo(float).eps
    for k in range(10):
        x = step_np(x, us[k], 0.1)
        # Same formula, but rollout_np uses math.cos/sin (libm, <= 1 ulp) and step_np NumPy's
        # (SIMD kernels chosen by CPU, <= 4 ulp): each step may differ by 5 ulp of cos/sin times
        # |ds| <= 0.1 m plus the rounding of the sums (2 ulp of |x| <= 4); the differences add up
        # over the k + 1 steps: (k + 1) (0.1 * 5 + 2 * 4) eps.
        np.testing.assert_allclose(xs[k + 1], x, rtol=0, atol=(k + 1) * (0.1 * 5 + 2 * 4) * eps)


def test_step_is_exact_solution_of_the_continuous_unicycle():
    # Integrate xdot = v cos(th), ydot = v sin(th), thdot = w with tiny Euler steps.
    rng = np.random.default_rng(3)
    x, u = _random_states_inputs(rng, 20)
    dt = 0.1
    m = 20000
    y = x.copy()
    for _ in range(m):
        y = y + (dt / m) * np.column_stack((u[:, 0] * np.cos(y[:, 2]), u[:, 0] * np.sin(y[:, 2]), u[:, 1]))
    np.testing.assert_allclose(step_np(x, u, dt), y, atol=5e-5)


def test_straight_and_turn_in_place_known_answers():
    np.testing.assert_allclose(step_np([0, 0, 0], [1.0, 0.0], 0.5), [0.5, 0, 0], atol=1e-15)
    np.testing.assert_allclose(step_np([1, 2, 0.3], [0.0, 2.0], 0.5), [1, 2, 1.3], atol=1e-15)
    # quarter circle of radius 1: v = 1, w = 1, t = pi/2 from (0,0,0) ends at (1, 1, pi/2)
    np.testing.assert_allclose(step_np([0, 0, 0], [1.0, 1.0], math.pi / 2), [1, 1, math.pi / 2], atol=1e-9)


def test_polynomial_sinc_matches_numpy_sinc():
    w = np.linspace(-20, 20, 2001)  # |w dt / 2| <= 1
    np.testing.assert_allclose(sinc_half(w, 0.1), np.sinc(w * 0.05 / np.pi), atol=1e-12)
    assert sinc_half(0.0, 0.1) == 1.0


def test_arc_chord_deviation_against_sampled_arc():
    for v, w, dt in [(1.0, 2.0, 0.1), (0.5, 8.0, 0.2), (2.0, 0.0, 0.1)]:
        t = np.linspace(0, dt, 2001)
        pts = np.array([step_np([0, 0, 0], [v, w], ti) for ti in t])[:, :2]
        a, b = pts[0], pts[-1]
        d = b - a
        dist = np.abs(d[0] * (pts[:, 1] - a[1]) - d[1] * (pts[:, 0] - a[0])) / np.hypot(*d)
        assert abs(arc_chord_deviation(v, w, dt) - dist.max()) < 1e-9
        assert arc_chord_deviation(v, w, dt) <= abs(v * w) * dt**2 / 8 + 1e-15


def _rollout_reference(x0, us, dt):
    """The per-step loop rollout_np replaced (numpy rows set one by one, _sinc_poly called)."""
    import math

    from sanav_mj.control.unicycle import _sinc_poly

    us = np.asarray(us, dtype=float).reshape(-1, 2)
    xs = np.empty((us.shape[0] + 1, 3))
    px, py, th = (float(c) for c in np.asarray(x0, dtype=float).reshape(3))
    xs[0] = px, py, th
    for k in range(us.shape[0]):
        v, w = float(us[k, 0]), float(us[k, 1])
        half = 0.5 * w * dt
        ds = v * dt * _sinc_poly(half * half)
        mid = th + half
        px += ds * math.cos(mid)
        py += ds * math.sin(mid)
        th += w * dt
        xs[k + 1] = px, py, th
    return xs


def test_rollout_np_is_bit_identical_to_the_per_step_loop():
    from sanav_mj.control.unicycle import rollout_np

    rng = np.random.default_rng(3)
    for n in (0, 1, 5, 20, 40):
        for _ in range(50):
            x0 = rng.normal(0, 3, 3)
            us = np.column_stack((rng.uniform(-1, 1, n), rng.uniform(-3, 3, n)))
            us[rng.random(n) < 0.1] = 0.0
            got, ref = rollout_np(x0, us, 0.1), _rollout_reference(x0, us, 0.1)
            assert got.shape == ref.shape == (n + 1, 3) and got.dtype == ref.dtype
            assert np.array_equal(got, ref) and np.array_equal(np.signbit(got), np.signbit(ref))
