"""Interpolation (eq. 5-6), B-spline smoothing (eq. 7) and the safety adaptation
(sanav_mj/planning/smoothing.py)."""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import run_without_kernels
from planning_maps import in_union
from scipy.interpolate import BSpline

from sanav_mj.planning.smoothing import (
    Blend,
    SmoothingProblem,
    collocation,
    corridor_assignment,
    cumulative_length,
    interpolate_uniform,
    knot_vector,
    safe_curve,
    second_derivative_gram,
    uniform_basis,
)


def test_interpolate_uniform_known_answer():
    wp = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.0]])  # length 4
    u, p = interpolate_uniform(wp, 0.5)
    np.testing.assert_allclose(u, np.arange(9) * 0.5)
    np.testing.assert_allclose(p[6], [3.0, 0.0])
    np.testing.assert_allclose(p[7], [3.0, 0.5])
    np.testing.assert_allclose(p[[0, -1]], wp[[0, -1]])
    # non-divisible length: spacing shrinks so both ends are samples
    u, p = interpolate_uniform(np.array([[0.0, 0.0], [1.0, 0.0]]), 0.3)
    assert len(u) == 5 and np.allclose(np.diff(u), 0.25)


def test_interpolation_handles_repeated_waypoints():
    wp = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    np.testing.assert_allclose(cumulative_length(wp), [0, 1, 1, 3])
    u, p = interpolate_uniform(wp, 0.5)
    np.testing.assert_allclose(p[2], [1.0, 0.0])
    np.testing.assert_allclose(p[4], [1.0, 1.0])


def test_uniform_basis_matches_scipy():
    rng = np.random.default_rng(1)
    L, n = 3.7, 9
    c = rng.normal(size=(n + 3, 2))
    u = np.r_[0.0, rng.uniform(0, L, 200), L]
    first, vals = collocation(L, n, u)
    np.testing.assert_allclose(vals.sum(axis=1), 1.0)
    ours = np.einsum("kj,kjd->kd", vals, c[first[:, None] + np.arange(4)])
    ref = BSpline(knot_vector(L, n), c, 3)(u)
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    np.testing.assert_allclose(uniform_basis(np.array([0.0]))[0], [1 / 6, 4 / 6, 1 / 6, 0])


@pytest.mark.parametrize("n_int", [1, 2, 7])
def test_second_derivative_gram_is_exact(n_int):
    L = 2.5
    t = knot_vector(L, n_int)
    n = n_int + 3
    # reference: Gauss-Legendre on every knot interval (exact for these piecewise quadratics)
    g, w = np.polynomial.legendre.leggauss(3)
    edges = np.linspace(0, L, n_int + 1)
    x = (0.5 * (edges[1:, None] - edges[:-1, None]) * g + 0.5 * (edges[1:, None] + edges[:-1, None])).ravel()
    wx = (0.5 * (edges[1:, None] - edges[:-1, None]) * w).ravel()
    d2 = np.stack([BSpline(t, np.eye(n)[i], 3).derivative(2)(x) for i in range(n)])
    ref = (d2 * wx) @ d2.T
    ab = second_derivative_gram(L, n_int)
    dense = np.zeros((n, n))
    for d in range(4):
        for j in range(d, n):
            dense[j - d, j] = dense[j, j - d] = ab[3 - d, j]
    np.testing.assert_allclose(dense, ref, atol=1e-9 * np.abs(ref).max())


def _reference_fit(u, p, lam, knot_spacing):
    """Dense KKT solve of the same constrained least squares (reference for the banded one)."""
    L = u[-1]
    n_int = max(1, int(round(L / knot_spacing)))
    n = n_int + 3
    t = knot_vector(L, n_int)
    B = BSpline.design_matrix(u, t, 3, extrapolate=True).toarray()
    h = L / (len(u) - 1)
    ab = second_derivative_gram(L, n_int)
    G = np.zeros((n, n))
    for d in range(4):
        for j in range(d, n):
            G[j - d, j] = G[j, j - d] = ab[3 - d, j]
    H = BSpline.design_matrix(np.array([0.0, L]), t, 3, extrapolate=True).toarray()
    K = np.block([[h * B.T @ B + lam * G, H.T], [H, np.zeros((2, 2))]])
    rhs = np.vstack([h * B.T @ p, p[[0, -1]]])
    return np.linalg.solve(K, rhs)[:n], np.linalg.cond(K)


@pytest.mark.parametrize("lam", [1e-4, 1e-2, 1.0])
def test_banded_fit_matches_dense_kkt_and_clamps_the_ends(lam):
    rng = np.random.default_rng(2)
    wp = np.array([[0.0, 0.0], [2.0, 0.3], [2.5, 2.0], [4.0, 2.2]])
    u, p = interpolate_uniform(wp, 0.1)
    p = p + 0.01 * rng.normal(size=p.shape)
    spl = SmoothingProblem(u, p, 0.3).solve(lam)
    ref, cond = _reference_fit(u, p, lam, 0.3)
    # Two backward-stable solves of the same KKT system (banded vs dense LU), each with a
    # backward error of about n eps: their solutions differ by at most 2 cond(K) n eps |x|
    # (cond(K) 12 to 641 here; measured differences 2e-15 to 2e-14, bound 3e-11).
    eps = np.finfo(float).eps
    n_kkt = len(ref) + 2
    np.testing.assert_allclose(spl.coeffs, ref, atol=2 * cond * n_kkt * eps * np.abs(ref).max())
    # the end clamps are equality constraints of the same solve: the same bound on the
    # coefficients, times the (partition-of-unity) basis sum 1
    np.testing.assert_allclose(spl(np.array([0.0, u[-1]])), p[[0, -1]], atol=2 * cond * n_kkt * eps * np.abs(ref).max())


def test_straight_data_gives_the_straight_line():
    wp = np.array([[1.0, 1.0], [9.0, 3.0]])
    u, p = interpolate_uniform(wp, 0.1)
    spl = SmoothingProblem(u, p, 0.2).solve(0.5)
    x = np.linspace(0, u[-1], 301)
    np.testing.assert_allclose(spl(x), wp[0] + (wp[1] - wp[0]) * (x / u[-1])[:, None], atol=1e-9)


def test_larger_lambda_smooths_more():
    wp = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 3.0]])
    u, p = interpolate_uniform(wp, 0.1)
    prob = SmoothingProblem(u, p, 0.2)
    dev, rough = [], []
    x = np.linspace(0, u[-1], 601)
    for lam in (1e-4, 1e-2, 1.0):
        s = prob.solve(lam)
        dev.append(np.max(np.linalg.norm(s(u) - p, axis=1)))
        d2 = np.diff(s(x), 2, axis=0)
        rough.append(np.sum(d2**2))
    assert dev[0] < dev[1] < dev[2]
    assert rough[0] > rough[1] > rough[2]


def test_corridor_assignment_monotone_and_flags_outside():
    rects = np.array([[0.0, 0.0, 2.0, 1.0], [1.0, 1.0, 2.0, 3.0]])
    pts = np.array([[0.5, 0.5], [1.5, 1.0], [1.5, 0.9], [1.5, 2.0], [0.5, 2.0]])
    hint = np.array([0, 0, 1, 1, 1])
    pos, ok = corridor_assignment(rects, pts, hint)
    assert ok.tolist() == [True, True, True, True, False]
    assert pos[:4].tolist() == [0, 0, 0, 1]
    # going back along the corridor is refused
    pts2 = np.array([[1.5, 2.0], [0.5, 0.5]])
    _, ok2 = corridor_assignment(rects, pts2, np.array([1, 1]))
    assert ok2.tolist() == [True, False]


def test_blend_widening_merges_and_covers():
    b = Blend((), ramp=0.2).widened(np.array([1.0, 1.05, 3.0]), 0.1, 4.0)
    np.testing.assert_allclose(b.intervals, [(0.9, 1.15), (2.9, 3.1)])
    np.testing.assert_allclose(b(np.array([1.0, 2.9, 0.7, 0.5, 2.0])), [1.0, 1.0, 0.0, 0.0, 0.0], atol=1e-12)
    assert 0.0 < b(np.array([0.8]))[0] < 1.0
    np.testing.assert_allclose(b.widened(np.array([2.0]), 0.5, 4.0).intervals, [(0.9, 3.1)])


# An L-turn whose portal crossing sits close to the inner corner (3, 1): plain smoothing cuts it.
L_RECTS = np.array([[0.0, 0.0, 4.0, 1.0], [3.0, 1.0, 4.0, 4.0]])
L_MILD = np.array([[0.5, 0.5], [3.1, 1.0], [3.5, 3.5]])  # crossing 0.1 m from the corner
L_SHARP = np.array([[0.5, 0.5], [3.05, 1.0], [3.5, 3.5]])  # 0.05 m: a cubic on 0.2 m knots cannot follow


def _safe(wp, rects=L_RECTS, seg=(0, 1), **kw):
    args = dict(
        spacing=0.1, knot_spacing=0.2, lam=0.05, check_spacing=0.02, lambda_factor=0.1,
        max_lambda_steps=5, blend_margin=0.1, blend_ramp=0.3, lambda_window=0.5,
    )
    args.update(kw)
    return safe_curve(wp, np.array(seg), rects, **args)


@pytest.mark.parametrize("wp", [L_MILD, L_SHARP])
def test_plain_smoothing_cuts_the_corner(wp):
    u, p = interpolate_uniform(wp, 0.1)
    spl = SmoothingProblem(u, p, 0.2).solve(0.05)
    assert not in_union(L_RECTS, spl(np.linspace(0, u[-1], 500))).all()


@pytest.mark.parametrize("window", [0.5, np.inf])
def test_adaptation_reduces_lambda_and_stays_inside(window):
    res = _safe(L_MILD, lambda_window=window)
    assert res.safe
    assert res.curve.lambda_steps > 0 and not res.curve.blend.intervals  # refits sufficed
    x = np.linspace(0, res.curve.length, 3000)
    assert in_union(L_RECTS, res.curve(x)).all()
    assert in_union(L_RECTS, res.nodes).all()


def test_local_adaptation_keeps_the_other_corner_smooth():
    """A tight corner and a roomy one: reducing lam near the tight corner only leaves the
    roomy corner as the plain fit; reducing it everywhere sharpens that corner too."""
    rects = np.array([[0.0, 0.0, 4.0, 1.0], [3.0, 1.0, 4.0, 6.0], [3.0, 6.0, 10.0, 7.0]])
    wp = np.array([[0.5, 0.5], [3.1, 1.0], [3.5, 6.0], [9.5, 6.5]])
    u, p = interpolate_uniform(wp, 0.1)
    plain = SmoothingProblem(u, p, 0.2).solve(0.05)
    roomy = cumulative_length(wp)[2] + np.linspace(-1.0, 1.0, 101)
    dev = {}
    for window in (0.5, np.inf):
        res = _safe(wp, rects, (0, 1, 2), lambda_window=window)
        assert res.safe and res.curve.lambda_steps > 0 and not res.curve.blend.intervals
        # the dense nodes are checked exactly; between them (0.02 m) the curve may graze a
        # reflex corner by a fraction of a millimetre
        assert in_union(rects, res.nodes).all()
        assert in_union(rects, res.curve(np.linspace(0, res.curve.length, 4000)), tol=1e-3).all()
        dev[window] = np.max(np.linalg.norm(res.curve(roomy) - plain(roomy), axis=1))
    assert dev[0.5] < 0.005 < 0.05 < dev[np.inf]


@pytest.mark.parametrize("steps", [0, 2])
def test_adaptation_falls_back_locally_when_refits_do_not_suffice(steps):
    res = _safe(L_SHARP, max_lambda_steps=steps)
    assert res.safe and res.curve.lambda_steps == steps
    covered = res.curve.blend.covered
    assert 0.0 < covered < 0.5 * res.curve.length  # local, not the whole path
    assert in_union(L_RECTS, res.nodes).all()
    # away from the fallback stretch the curve is still the spline
    a, b = res.curve.blend.intervals[0]
    far = np.array([0.2 * a, b + 0.5 * (res.curve.length - b) + 0.3])
    np.testing.assert_allclose(res.curve(far), res.curve.spline(far), atol=1e-12)


def test_spline_at_collocation_is_the_call_bit_for_bit():
    # safe_curve evaluates its refits at one precomputed collocation: same bits as calling
    wp = np.array([[0.0, 0.0], [2.0, 0.3], [2.5, 1.7], [4.0, 2.0]])
    u, p = interpolate_uniform(wp, 0.1)
    prob = SmoothingProblem(u, p, 0.4)
    uc = np.linspace(0.0, u[-1], 57)
    chk = collocation(prob.length, prob.n_intervals, uc)
    for lam in (1e-3, 1e-1):
        spl = prob.solve(lam)
        assert np.array_equal(spl.at_collocation(*chk), spl(uc))


@pytest.mark.parametrize("seed", range(5))
def test_solve_through_dpbsv_equals_scipy_solveh_banded(seed):
    """SmoothingProblem.solve calls LAPACK dpbsv directly; scipy.linalg.solveh_banded (the
    reference: the same routine behind argument checks) gives the same coefficients bit for
    bit on seeded random data, weights and smoothing weights."""
    from scipy.linalg import solveh_banded

    rng = np.random.default_rng(seed)
    m = int(rng.integers(20, 200))
    u = np.linspace(0.0, rng.uniform(1.0, 12.0), m)
    p = np.cumsum(rng.normal(0.0, 0.1, (m, 2)), axis=0)
    prob = SmoothingProblem(u, p, rng.uniform(0.1, 0.5))
    for lam, w in ((rng.uniform(0.01, 2.0), None), (rng.uniform(0.01, 2.0), rng.uniform(0.5, 8.0, m))):
        spl = prob.solve(lam, w)
        btb, btp = (prob.btb, prob.btp) if w is None else prob._assemble(w)
        sol = solveh_banded(btb + lam * prob.gram, np.hstack([btp, prob.H]), check_finite=False)
        x, z = sol[:, :2], sol[:, 2:]
        mu = np.linalg.solve(prob.H.T @ z, prob.H.T @ x - prob.d)
        assert np.array_equal(spl.coeffs, x - z @ mu)


@pytest.mark.parametrize("seed", range(8))
def test_compiled_corridor_assignment_equals_the_numpy_reference(seed):
    """The compiled corridor assignment (sanav_mj.planning.assign_kernel) gives the same
    positions and flags as the NumPy reference on seeded random corridors and points: points
    inside their hint rectangle, in a neighbour within the band, only behind (assignment
    would go backwards), outside everything, on rectangle edges (within the tolerance) and
    NaN; with bands 0-3."""
    from sanav_mj.planning import assign_kernel

    if not assign_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy path exists")
    rng = np.random.default_rng(seed)
    C = int(rng.integers(1, 12))
    lo = np.cumsum(rng.uniform(0.2, 0.8, (C, 2)), axis=0) - rng.uniform(0.0, 0.5, (C, 2))
    rects = np.hstack([lo, lo + rng.uniform(0.3, 1.2, (C, 2))])
    K = int(rng.integers(1, 400))
    hint = np.sort(rng.integers(0, C, K)).astype(np.int64)
    r = rects[hint]
    pts = rng.uniform(r[:, :2] - 0.4, r[:, 2:] + 0.4)
    edge = rng.random(K) < 0.1
    pts[edge, 0] = r[edge, 2] + rng.choice([-1e-10, 1e-10, 2e-9], edge.sum())  # within / beyond the tolerance
    pts[rng.random(K) < 0.02] = np.nan
    for band in (0, 1, 2, 3):
        ref = corridor_assignment(rects, pts, hint, band, use_kernel=False)
        fast = corridor_assignment(rects, pts, hint, band)
        assert fast[0].dtype == ref[0].dtype and np.array_equal(fast[0], ref[0]) and np.array_equal(fast[1], ref[1])
    inside = (rects[hint, :2] + rects[hint, 2:]) / 2
    ref, fast = corridor_assignment(rects, inside, hint, use_kernel=False), corridor_assignment(rects, inside, hint)
    assert fast[0] is hint and ref[0] is hint and fast[1].all()


def test_smoothing_runs_without_the_compiled_kernel():
    """With SANAV_MJ_NO_CKERNEL=1 a fresh process has no compiled assignment and computes the
    same assignment (NumPy path) as this process for a seeded random case with points
    outside their hint rectangles."""
    code = (
        "import numpy as np; from sanav_mj.planning import assign_kernel;"
        "from sanav_mj.planning.smoothing import corridor_assignment;"
        "assert not assign_kernel.kernel_available();"
        "rng = np.random.default_rng(3); lo = np.cumsum(rng.uniform(0.2, 0.8, (6, 2)), axis=0);"
        "rects = np.hstack([lo, lo + 0.7]); hint = np.sort(rng.integers(0, 6, 200));"
        "pts = rng.uniform(rects[hint, :2] - 0.4, rects[hint, 2:] + 0.4);"
        "pos, ok = corridor_assignment(rects, pts, hint); print(pos.tolist(), ok.tolist())"
    )
    out = run_without_kernels(code)
    rng = np.random.default_rng(3)
    lo = np.cumsum(rng.uniform(0.2, 0.8, (6, 2)), axis=0)
    rects = np.hstack([lo, lo + 0.7])
    hint = np.sort(rng.integers(0, 6, 200))
    pts = rng.uniform(rects[hint, :2] - 0.4, rects[hint, 2:] + 0.4)
    pos, ok = corridor_assignment(rects, pts, hint)
    assert not ok.all() and out.strip() == f"{pos.tolist()} {ok.tolist()}"
