"""SA-MPC with the footprint as discs (``MPCConfig.footprint="discs"``): rows, bounds, turns."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sanav_mj.control.base import Observation
from sanav_mj.control.footprint import disc_centres
from sanav_mj.control.problem import build_tracking_ocp
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig, SafeAreaPenalty
from sanav_mj.control.stages import CorridorChain, assign_stages, box_slack, relax_boxes
from sanav_mj.control.unicycle import rollout_np
from sanav_mj.footprint import Footprint

from mpc_cases import L_RECTS, L_WAYPOINTS, ROBOT, make_areas, make_plan

FP = Footprint(-0.25, 0.25, -0.215, 0.215)  # the packaged robot's deck
DISCS = MPCConfig(footprint="discs", footprint_discs=3, footprint_box_margin=0.0)
D_OFF = 0.5 / 3  # [m] the outer disc centres of the 3-disc cover sit at +-hx + hx/3


def _corridor_controller(half_width: float, length: float = 3.0, cfg: MPCConfig = DISCS) -> SAMPC:
    """A straight corridor along x of safe-area half width ``half_width`` (the map is
    inflated by disc radius + margin, so the free passage is 2 (r_d + margin + half_width))."""
    areas = make_areas([[0.0, -half_width, length, half_width]])
    plan = make_plan(areas, [0], [[0.3, 0.0], [length - 0.3, 0.0]])
    return SAMPC(ROBOT, areas, plan, cfg, footprint=FP)


@pytest.mark.parametrize(
    "kw, match",
    [(dict(footprint="rectangle"), "footprint"), (dict(footprint_discs=1), "footprint_discs"),
     (dict(footprint_margin=-0.01), "footprint_margin"),
     (dict(footprint_narrow_penalty=-1.0), "footprint_narrow_penalty"),
     (dict(footprint_box_margin=-0.01), "footprint_box_margin"), (dict(footprint_box_margin=1.0), "footprint_box_margin"),
     (dict(footprint_box_margin=True), "footprint_box_margin"), (dict(footprint_box_margin=float("nan")), "footprint_box_margin")],
)
def test_config_rejects_bad_footprint_fields(kw, match):
    with pytest.raises(ValueError, match=match):
        MPCConfig(**kw)


def test_discs_mode_shrinks_its_boxes_by_its_own_margin_and_the_disc_mode_by_box_margin():
    assert MPCConfig(box_margin=0.03, footprint_box_margin=0.01).stage_box_margin == 0.03
    assert MPCConfig(footprint="discs", box_margin=0.03, footprint_box_margin=0.01).stage_box_margin == 0.01
    # the chain (and the shift check's slack) of the discs mode: the safe area [0, 3] x [-0.2, 0.2]
    # shrunk by footprint_box_margin, whatever box_margin is
    for fb in (0.0, 0.015):
        ctl = _corridor_controller(0.2, cfg=replace(DISCS, box_margin=0.05, footprint_box_margin=fb))
        np.testing.assert_allclose(ctl.chain.stay[0], [fb, -0.2 + fb, 3.0 - fb, 0.2 - fb], atol=1e-15)
        assert ctl.position_slack == fb
    areas = make_areas([[0.0, -0.2, 3.0, 0.2]])
    plan = make_plan(areas, [0], [[0.3, 0.0], [2.7, 0.0]])
    disc = SAMPC(ROBOT, areas, plan, MPCConfig(box_margin=0.05, footprint_box_margin=0.0))
    np.testing.assert_allclose(disc.chain.stay[0], [0.05, -0.15, 2.95, 0.15], atol=1e-15)
    assert disc.position_slack == 0.05


def test_discs_mode_needs_the_footprint():
    areas = make_areas([[0.0, -0.1, 3.0, 0.1]])
    plan = make_plan(areas, [0], [[0.3, 0.0], [2.7, 0.0]])
    with pytest.raises(ValueError, match="footprint"):
        SAMPC(ROBOT, areas, plan, DISCS)


def test_default_ocp_is_unchanged_and_disc_rows_are_keyed():
    pen = SafeAreaPenalty(2)
    base = build_tracking_ocp(20, 0.1, pen)
    assert base.key == "track-N20-dt0.1-pc1-jsa2" and base.n_pos == 40 and base.n_points == 1
    offsets, _ = FP.discs(3)
    disc = build_tracking_ocp(20, 0.1, pen, points=offsets)
    assert disc.n_pos == 120 and disc.key != base.key and disc.key.startswith(base.key)
    # the rows are the disc centres of the rollout, stage-major
    f, g = disc.functions()
    rng = np.random.default_rng(3)
    z = rng.uniform(-0.5, 0.5, 40)
    p = np.zeros(disc.layout.size)
    p[:3] = [1.0, 2.0, 0.3]
    xs = rollout_np(p[:3], z.reshape(20, 2), 0.1)
    gv = np.asarray(g(z, p)).ravel()
    np.testing.assert_allclose(gv[:120], disc_centres(xs[1:], offsets).ravel(), rtol=0, atol=1e-12)


def test_corridor_exactly_as_wide_as_the_discs_holds_and_a_tilt_is_infeasible():
    """Safe area of zero width slack: the free passage is exactly 2 (r_d + margin) + 2 mm."""
    h = 1e-3
    # the rows' geometry as such: without the tightening by the prediction error (which
    # would take a quarter of this 2 mm box; tests/control/test_prediction.py)
    from sanav_mj.control.prediction import PredictionDerating

    ctl = _corridor_controller(h, cfg=replace(DISCS, footprint_prediction=PredictionDerating(tighten=False)))
    assert ctl.discs.radius == pytest.approx(math.hypot(0.25 / 3, 0.215))
    guess = np.tile([1.0, 0.0, 0.0], (ctl.N + 1, 1))
    xr, ur = ctl.reference(guess[0])
    con = ctl.constrain(guess[0], xr, ur, guess)
    rows = ctl.position_rows(guess)
    assert rows.shape == con.pos_lb.shape == (6 * ctl.N,)
    assert np.all(rows >= con.pos_lb) and np.all(rows <= con.pos_ub)  # aligned: every row holds
    np.testing.assert_allclose(con.pos_lb[1::2], -h) and np.testing.assert_allclose(con.pos_ub[1::2], h)
    # tilted by 0.1 rad: the front disc centre is D_OFF sin(0.1) = 16.6 mm off the axis, 15.6 mm out
    tilted = guess.copy()
    tilted[1:, 2] = 0.1
    viol = np.max(np.maximum(ctl.position_rows(tilted) - con.pos_ub, con.pos_lb - ctl.position_rows(tilted)))
    assert viol == pytest.approx(D_OFF * math.sin(0.1) - h, abs=1e-12)
    # the paper's single point (disc mode) would accept the tilted state
    point = _corridor_controller(h, cfg=replace(DISCS, footprint="disc"))
    con_p = point.constrain(guess[0], *point.reference(guess[0]), guess)
    rp = point.position_rows(tilted)
    assert np.all(rp >= con_p.pos_lb) and np.all(rp <= con_p.pos_ub)


def test_solved_plan_keeps_every_disc_in_its_box_and_no_opening_turn_where_it_cannot_turn():
    ctl = _corridor_controller(0.05)  # the sweep circle (0.167 m) does not fit: no turn on the spot
    x = np.array([0.3, 0.0, 0.2])
    ctl.reset(x)
    cmd = None
    for k in range(5):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=None))
        assert cmd.status in ("ok", "inexact")
        rows = ctl.position_rows(cmd.predicted)
        d = ctl.discs.offsets.shape[0]
        lb = np.repeat(ctl.last.boxes[1:, None, :2], d, axis=1).ravel()
        assert rows.shape == lb.shape
        assert np.all(cmd.margins[1:] >= -1e-3)
        x = cmd.predicted[1]
    wide = _corridor_controller(0.5)  # here it fits (0.5 >= 0.167): the opening turn runs
    wide.reset(np.array([1.0, 0.0, 2.0]))
    assert wide.step(Observation(t=0.0, pose=np.array([1.0, 0.0, 2.0]), velocity=None)).status == "turn"
    narrow = _corridor_controller(0.05)
    narrow.reset(np.array([1.0, 0.0, 2.0]))
    assert narrow.turn_allowed(np.array([1.0, 0.0, 2.0])) is False


def test_l_corner_discs_take_their_own_areas():
    """Per-disc assignment: with the front disc past the portal and the rear one before it,
    each has the stage boxes of its own member (one convex box for both could not hold them)."""
    areas = make_areas(L_RECTS)
    plan = make_plan(areas, [0, 1], L_WAYPOINTS)
    ctl = SAMPC(ROBOT, areas, plan, DISCS, footprint=FP)
    x = np.array([3.5, 0.95, math.pi / 2])  # rear centre at y = 0.78 (area 0), front at 1.12 (area 1)
    guess = np.tile(x, (ctl.N + 1, 1))
    ss, bs, exc = ctl.discs.stages(ctl.chain, guess, None, 1e-9)
    assert exc == 0.0
    assert ss[2, 0] > ss[0, 0]  # the front disc is further along the chain than the rear one
    c = disc_centres(guess, ctl.discs.offsets)
    for d in range(3):
        assert np.all(box_slack(c[:, d], bs[d]) >= 0)


def test_assignment_and_relaxation_with_several_points():
    areas = make_areas(L_RECTS)
    plan = make_plan(areas, [0, 1], L_WAYPOINTS)
    chain = CorridorChain.build(areas, plan.corridor)
    pts = np.stack([np.tile([1.0, 0.5], (5, 1)), np.tile([3.5, 2.0], (5, 1))], axis=1)  # (5, 2, 2)
    s_multi = assign_stages(chain, pts)
    # the worst point decides: the second point lies only in member 2 (area 1)
    assert np.all(s_multi >= 0) and s_multi.shape == (5,)
    boxes = np.tile([0.0, 0.0, 1.0, 1.0], (3, 1))
    out, e = relax_boxes(boxes, np.array([[1.2, 0.5], [0.5, -0.1]]))
    np.testing.assert_allclose(out[1:], [[0.0, -0.1, 1.2, 1.0]] * 2)
    assert e == pytest.approx(0.2)
    np.testing.assert_allclose(out[0], boxes[0])


def test_map_inflation_follows_the_footprint_mode():
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.prepare import DEFAULT_MARGIN_M, map_inflation
    from sanav_mj.scene import load_scenario

    sc = load_scenario("u_shape")
    assert map_inflation(sc) == sc.robot.footprint_radius + DEFAULT_MARGIN_M
    spec = ControllerSpec("sa-mpc", replace(MPCConfig(), footprint="discs", footprint_margin=0.03))
    assert map_inflation(sc, spec) == pytest.approx(math.hypot(0.25 / 3, 0.215) + 0.03, abs=1e-9)


def test_planning_areas_penalise_only_in_discs_mode():
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.prepare import planning_areas, prepare
    from sanav_mj.scene import load_scenario

    sc = load_scenario("v_shape")
    spec = ControllerSpec("sa-mpc", replace(MPCConfig(), footprint="discs", footprint_narrow_penalty=0.7))
    areas = prepare(sc, controller=spec).areas
    assert planning_areas(areas, sc) is areas
    out = planning_areas(areas, sc, spec)
    narrow = out.weights != areas.weights
    assert narrow.any() and not narrow.all()
    np.testing.assert_array_equal(out.weights[narrow], areas.weights[narrow] + 0.7)


def test_safe_area_slots_all_or_none_when_the_discs_span_more_areas():
    """Three areas under two slots: the partial set (first two) would charge a disc in the
    third area; all-or-none switches J_SA off instead (every slot inactive: J_SA = 1, constant)."""
    from sanav_mj.control.stages import safe_area_params

    areas = make_areas(L_RECTS)
    plan = make_plan(areas, [0, 1], L_WAYPOINTS)
    chain = CorridorChain.build(areas, plan.corridor)  # members R0, B01, R1: areas 0, 1
    rects = np.asarray(areas.rects)
    q = np.array([5.0, 5.0])
    part = safe_area_params(chain, rects, (0, 2), 1, q[:1], 0.0).reshape(1, 6)
    np.testing.assert_allclose(part[0], [*rects[0], 5.0, 1.0])  # first area only
    none = safe_area_params(chain, rects, (0, 2), 1, q[:1], 0.0, all_or_none=True).reshape(1, 6)
    assert none[0, 5] == 0.0
    both = safe_area_params(chain, rects, (0, 2), 2, q, 0.0, all_or_none=True).reshape(2, 6)
    np.testing.assert_allclose(both[:, 5], [1.0, 1.0])  # they fit: unchanged
    # in the controller: a disc in area 1 is not charged when the assignment spans both
    ctl = SAMPC(ROBOT, areas, plan, replace(DISCS, q_sa=(5.0,)), footprint=FP)
    theta = ctl._sa_params(np.array([0, 2]))
    assert SafeAreaPenalty.value_np(np.array([3.5, 3.0]), theta.reshape(1, 6)[:, :4], theta.reshape(1, 6)[:, 4] * 0 + 5) > 0
    assert theta.reshape(1, 6)[0, 5] == 0.0


def test_a_stalled_discs_controller_tries_the_escape_guesses_in_turn():
    from sanav_mj.control.disc_stages import STALL_STEPS, escape_guesses
    from sanav_mj.control.tracking import ActivePlan

    ctl = _corridor_controller(0.05)
    ctl.reset(np.array([1.0, 0.0, 0.0]), progress=5)
    rest = np.zeros((ctl.N, 2))
    ctl._active = ActivePlan(rest.copy(), 1, y=np.ones(3))
    esc = escape_guesses(ctl.N)
    for _ in range(STALL_STEPS - 1):  # at rest, not yet long enough: the shifted plan
        np.testing.assert_array_equal(ctl._guess_inputs(), rest)
    np.testing.assert_array_equal(ctl._guess_inputs(), esc[0])
    assert ctl._active.y is None  # no multipliers of the abandoned plan
    np.testing.assert_array_equal(ctl._guess_inputs(), esc[1])
    ctl._u_prev = np.array([0.3, 0.0])  # moving again: back to the shifted plan
    np.testing.assert_array_equal(ctl._guess_inputs(), rest)
    # the escapes respect the terminal stop and start from rest within one ramp step
    for g in esc:
        assert g.shape == (ctl.N, 2) and np.all(g[-1] == 0) and np.all(np.abs(g[0]) <= np.array([0.2, 1.5]) / 3 + 1e-12)
    # the paper's mode never escapes
    point = _corridor_controller(0.05, cfg=replace(DISCS, footprint="disc"))
    point.reset(np.array([1.0, 0.0, 0.0]), progress=5)
    point._active = ActivePlan(rest.copy(), 1)
    for _ in range(STALL_STEPS + 2):
        np.testing.assert_array_equal(point._guess_inputs(), rest)
