"""The ``"discs"`` SA-MPC step's vectorised stage assignment and relaxation against their
per-disc references (:meth:`DiscCover.assign`, :meth:`DiscCover.relax`): bit-identical."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.control.disc_stages import DiscCover
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig, _assign_shared, _disc_margins, _plan_centres, _relax_all
from sanav_mj.control.stages import _outside_sq, assign_feasible, first_candidates
from sanav_mj.control.unicycle import rollout_np
from sanav_mj.footprint import Footprint

from mpc_cases import ROBOT, U_RECTS, U_WAYPOINTS, make_areas, make_plan

FP = Footprint(-0.25, 0.25, -0.215, 0.215)


@pytest.fixture(scope="module")
def ctl() -> SAMPC:
    areas = make_areas(U_RECTS)
    plan = make_plan(areas, [0, 1, 2], U_WAYPOINTS)
    return SAMPC(ROBOT, areas, plan, MPCConfig(footprint="discs", footprint_box_margin=0.0), footprint=FP)


def _states(rng, ctl, n1):
    """A random walk of n1 states (n1, 3) near the chain's boxes (some far outside)."""
    box = ctl.chain.stay[rng.integers(len(ctl.chain))]
    start = rng.uniform(box[:2] - 0.3, box[2:] + 0.3)
    steps = rng.normal(0.0, rng.choice([0.02, 0.1, 0.4]), (n1, 2))
    xy = start + np.cumsum(steps, axis=0)
    yaw = rng.uniform(-np.pi, np.pi) + np.cumsum(rng.normal(0, 0.2, n1))
    return np.column_stack((xy, yaw))


def test_assignment_matches_the_per_disc_reference(ctl):
    rng = np.random.default_rng(0)
    n1, n_m = ctl.N + 1, len(ctl.chain)
    fits = 0
    for trial in range(400):
        xs = _states(rng, ctl, n1)
        s_prev = None if trial % 4 == 0 else np.sort(rng.integers(0, n_m, (3, n1)), axis=1)
        tol = ctl._check_tol
        ss_ref, plain_ref, pts_ref = ctl.discs.assign(ctl.chain, xs, s_prev, tol)
        pts = ctl.discs.centres(xs)
        ss, plain = _assign_shared(ctl.chain, ctl._both, pts, s_prev, tol)
        assert np.array_equal(pts, pts_ref)
        assert np.array_equal(ss, ss_ref)
        assert plain.dtype == plain_ref.dtype and np.array_equal(plain, plain_ref)
        assert np.all(np.isin(np.diff(ss, axis=1), (0, 1)))
        for d in range(3):  # which of assign_stages' two paths decided
            d2 = _outside_sq(pts[:, d], ctl._both)
            d2[d2 < tol * tol] = 0.0
            cand = first_candidates(n_m, None if s_prev is None else s_prev[d])
            fits += assign_feasible(d2, n_m, cand, 0.3) is not None
    assert 0.1 * 1200 < fits < 0.9 * 1200  # both the bit sets and the dynamic programme


def test_assignment_covers_guesses_no_assignment_fits(ctl):
    # far outside every box: assign_feasible finds nothing, the dynamic programme decides
    xs = np.column_stack((np.linspace(-5, 5, ctl.N + 1), np.full(ctl.N + 1, 7.0), np.zeros(ctl.N + 1)))
    ss_ref, plain_ref, _ = ctl.discs.assign(ctl.chain, xs, None, ctl._check_tol)
    ss, plain = _assign_shared(ctl.chain, ctl._both, ctl.discs.centres(xs), None, ctl._check_tol)
    assert np.array_equal(ss, ss_ref) and np.array_equal(plain, plain_ref)


@pytest.mark.parametrize("tighten", [None, (0.0, False), (0.0, True), (0.012, False), (0.03, True), (0.05, False)])
def test_relaxation_matches_the_per_disc_reference(ctl, tighten):
    rng = np.random.default_rng(1)
    n1, n_m = ctl.N + 1, len(ctl.chain)
    moved = 0
    for _ in range(300):
        s = np.sort(rng.integers(0, n_m, (3, n1)), axis=1)
        plain = np.array([ctl.chain.stay[si] for si in s])
        box0 = plain[:, 0]
        # stage-0 centres inside, on the edge of, or beyond their boxes
        pts0 = rng.uniform(box0[:, :2] - 0.05, box0[:, 2:] + 0.05)
        on_edge = rng.random(3) < 0.2
        pts0[on_edge] = box0[on_edge, :2]
        plain_copy = plain.copy()
        bs_ref, e_ref = DiscCover.relax(plain, pts0, tighten)
        bs, e = _relax_all(plain, pts0, tighten)
        assert np.array_equal(plain, plain_copy)  # the input is not modified
        assert np.array_equal(bs, bs_ref) and e == e_ref
        assert np.array_equal(np.signbit(bs), np.signbit(bs_ref))
        moved += e > 0
    assert 0 < moved < 300  # both branches taken


def test_margins_match_the_per_disc_reference(ctl):
    rng = np.random.default_rng(2)
    n1, n_m = ctl.N + 1, len(ctl.chain)
    for _ in range(200):
        xs = _states(rng, ctl, n1)
        s = np.sort(rng.integers(0, n_m, (3, n1)), axis=1)
        bs = np.array([ctl.chain.stay[si] for si in s])
        ref = ctl.discs.margins(xs, bs)
        assert np.array_equal(_disc_margins(ctl.discs.centres(xs), bs), ref)


def test_describe_reuses_the_acceptance_centres_only_for_the_same_rollout(ctl):
    rng = np.random.default_rng(4)
    x0 = np.array([0.5, 0.5, 0.3])
    xs = rollout_np(x0, rng.uniform(-0.5, 0.5, (ctl.N, 2)), ctl.dt)
    ctl.position_rows(xs)  # what the acceptance test computes
    ref = ctl.discs.centres(np.vstack((x0[None], xs[1:])))
    assert _plan_centres(ctl, xs, x0) is ctl._centres_of[1]
    assert np.array_equal(_plan_centres(ctl, xs, x0), ref)
    # another rollout, or another first state: computed afresh, never the kept centres
    other = xs.copy()
    assert _plan_centres(ctl, other, x0) is not ctl._centres_of[1]
    x1 = x0 + np.array([0.01, 0.0, 0.0])
    got = _plan_centres(ctl, xs, x1)
    assert np.array_equal(got, ctl.discs.centres(np.vstack((x1[None], xs[1:]))))
