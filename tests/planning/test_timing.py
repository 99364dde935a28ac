"""Speed profile and sampling at the MPC step (sanav_mj/planning/timing.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.planning.timing import discrete_geometry, profile_curve, sample_profile, speed_profile


def _loop_profile(ds, kappa, v_cap, w_cap, a_lat, a_max):
    """Reference: the textbook sequential forward-backward pass."""
    k = np.abs(kappa)
    env = np.array([k[max(i - 1, 0) : i + 2].max() for i in range(len(k))])
    lim = np.array([min(v_cap, w_cap / e if e > 0 else np.inf, np.sqrt(a_lat / e) if e > 0 else np.inf) for e in env])
    lim[0] = lim[-1] = 0.0
    v = lim.copy()
    for i in range(len(v) - 1):
        v[i + 1] = min(v[i + 1], np.sqrt(v[i] ** 2 + 2 * a_max * ds[i]))
    for i in range(len(v) - 1, 0, -1):
        v[i - 1] = min(v[i - 1], np.sqrt(v[i] ** 2 + 2 * a_max * ds[i - 1]))
    return v


@pytest.mark.parametrize("seed", range(5))
def test_vectorised_profile_matches_sequential_pass(seed):
    rng = np.random.default_rng(seed)
    n = 300
    ds = rng.uniform(0.005, 0.05, n - 1)
    kappa = rng.normal(0, 2, n) * (rng.random(n) < 0.3)
    args = (1.6, 2.4, 1.0, 1.2)
    np.testing.assert_allclose(speed_profile(ds, kappa, *args), _loop_profile(ds, kappa, *args), atol=1e-12)


def test_circle_geometry():
    R = 2.0
    th = np.linspace(0, np.pi, 400)
    pts = R * np.column_stack([np.cos(th), np.sin(th)])
    sigma, heading, kappa, _ = discrete_geometry(pts)
    np.testing.assert_allclose(kappa, 1 / R, rtol=1e-4)
    assert sigma[-1] == pytest.approx(np.pi * R, rel=1e-4)
    np.testing.assert_allclose(heading[1:-1], th[1:-1] + np.pi / 2, atol=1e-3)


def test_straight_line_trapezoid_known_duration():
    L, v, a = 8.0, 1.6, 1.2
    u = np.linspace(0, L, 401)
    pts = np.column_stack([u, np.zeros_like(u)])
    prof = profile_curve(u, pts, v, 3.0, 1.0, a)
    T = L / v + v / a  # accelerate, cruise, brake
    assert prof.duration == pytest.approx(T, rel=2e-3)
    s = sample_profile(prof, 0.1)
    assert s.t[-1] >= prof.duration and s.v[0] == 0.0 and s.v[-1] == 0.0
    assert np.max(s.v) == pytest.approx(v)
    assert np.all(np.abs(np.diff(s.v)) <= a * 0.1 + 1e-9)
    assert np.all(np.diff(s.sigma) <= v * 0.1 + 1e-9)
    assert s.sigma[-1] == pytest.approx(L)
    np.testing.assert_allclose(s.yaw, 0.0)


def test_short_path_still_moves():
    u = np.array([0.0, 0.01])
    prof = profile_curve(u, np.array([[0.0, 0.0], [0.01, 0.0]]), 1.0, 1.0, 1.0, 1.0)
    assert np.isfinite(prof.duration) and prof.duration > 0
    s = sample_profile(prof, 0.1)
    assert s.sigma[-1] == pytest.approx(0.01)


def test_tight_arc_respects_yaw_rate_and_lateral_limits():
    R = 0.3
    th = np.linspace(0, 1.5 * np.pi, 600)
    pts = R * np.column_stack([np.cos(th), np.sin(th)])
    prof = profile_curve(th * R, pts, 2.0, 1.0, 0.5, 1.0)
    s = sample_profile(prof, 0.1)
    assert np.all(np.abs(s.w) <= 1.0 + 1e-9)
    assert np.max(prof.v) == pytest.approx(min(1.0 * R, np.sqrt(0.5 * R)), rel=1e-3)
    assert np.all(np.abs(np.diff(s.v)) <= 0.1 + 1e-9)


def test_speed_profile_from_a_start_speed_exact():
    """Replanning in motion: the profile starts at ``v_start`` (capped by the first node's limit)
    and accelerates from it, ``v_1^2 = v_start^2 + 2 a ds``; 0 gives the rest-to-rest profile."""
    from sanav_mj.planning.timing import speed_profile

    ds = np.full(40, 0.05)
    kappa = np.zeros(41)
    v = speed_profile(ds, kappa, 10.0, 5.0, 1.0, 1.0, v_start=0.5)
    assert v[0] == 0.5 and v[-1] == 0.0
    assert v[1] == pytest.approx(np.sqrt(0.25 + 2 * 1.0 * 0.05), rel=1e-12)
    assert np.array_equal(speed_profile(ds, kappa, 10.0, 5.0, 1.0, 1.0, v_start=0.0),
                          speed_profile(ds, kappa, 10.0, 5.0, 1.0, 1.0))
    assert speed_profile(ds, kappa, 0.3, 5.0, 1.0, 1.0, v_start=0.5)[0] == pytest.approx(0.3, rel=1e-15)


def test_plan_rejects_a_negative_start_speed():
    from sanav_mj.planning import plan
    from sanav_mj.eval.prepare import prepare

    prep = prepare("single_rect")
    with pytest.raises(ValueError, match="start_speed"):
        plan(prep.areas, prep.scenario.start, prep.scenario.goal, prep.scenario.robot, start_speed=-1.0)
