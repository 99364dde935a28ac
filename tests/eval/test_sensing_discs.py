"""The footprint discs mode (``MPCConfig.footprint="discs"``) with the lidar.

- The sensed map is inflated by the disc cover's radius + ``footprint_margin`` (known answer
  on a hand-made scan: where the safe cells end in front of a wall).
- Every disc centre's hard rows (its stage boxes, the documented widening towards a measured
  position outside its box undone) lie in cells observed safe at that step, and in free
  cells of the true grid inflated the same way; the first plan waits until every disc centre
  stands in a safe cell.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from _helpers import cells_of_box
from sanav_mj.control.prediction import PredictionDerating
from sanav_mj.eval.episode import run_scenario
from sanav_mj.eval.lidar import lidar_cell, lidar_controller, lidar_match, lidar_spec
from sanav_mj.eval.prepare import DEFAULT_MARGIN_M, footprint_spec, prepare
from sanav_mj.footprint import robot_footprint
from sanav_mj.scene import load_scenario

DISCS = footprint_spec("sa-mpc", "discs")




def _wall_scan(x_wall: float, n: int = 721):
    """A scan from a sensor at the origin facing +x of a wall at x = ``x_wall`` [m]: beams over
    +-60 deg, each ending exactly on the wall."""
    a = np.linspace(-math.pi / 3, math.pi / 3, n)
    return x_wall / np.cos(a), np.ones(n, bool), a


@pytest.mark.parametrize("mode, inflation, last_safe", [
    # the wall's return cells are column 60 (x in [2.0, 2.05)); a cell is safe when the gap
    # between its square and the wall cells' exceeds the inflation: (60 - j - 1) 0.05 m
    ("discs", None, 53),  # 0.231 + 0.05 = 0.281 m: column 53 has a gap of 0.30 m, column 54 0.25 m
    ("disc", 0.330 + DEFAULT_MARGIN_M, 51),  # 0.38 m: column 51 has 0.40 m, column 52 0.35 m
])
def test_sensed_map_is_inflated_by_the_mode_radius(mode, inflation, last_safe):
    sc = load_scenario("single_rect")
    ctrl = lidar_controller(sc, footprint_spec("sa-mpc", mode))
    fp = robot_footprint(sc.model)
    expected = fp.discs(3)[1] + DISCS.sa_mpc.footprint_margin if mode == "discs" else sc.robot.footprint_radius + DEFAULT_MARGIN_M
    assert ctrl.map.grid.inflation == pytest.approx(expected, abs=1e-12)
    if inflation is not None:
        assert expected == pytest.approx(inflation, abs=5e-4)
    # the hand-made scan in a fresh map of the same construction, sensor at (0, 0) facing +x
    from sanav_mj.mapping.sensed_map import SensedMap, SensedMapConfig

    m = SensedMap((-1.0, -2.5, 4.0, 2.5), ctrl.map.grid.inflation, (0.0, 0.0), SensedMapConfig(resolution=0.05))
    m.integrate(np.zeros(3), *_wall_scan(2.025))
    g = m.grid
    i0 = int(math.floor((0.0 - g.origin[1]) / g.resolution))  # the row of y in [0, 0.05)
    safe_row = np.flatnonzero(g.safe()[i0])
    assert safe_row.max() == last_safe
    wall_col = int(math.floor((2.025 - g.origin[0]) / g.resolution))
    assert wall_col == 60 and g.states()[i0, wall_col] != 0  # the return's cell is known (occupied)


def _discs_checked_run(scenario: str, seed: int):
    """A discs-mode lidar run checking, at every solved step, each disc centre's stage boxes
    against the step's safe grid and the true grid (same inflation and cells)."""
    sc = load_scenario(scenario)
    ctrl = lidar_controller(sc, DISCS)
    mpc = ctrl._spare  # the SA-MPC the first plan adopts (built before the loop)
    assert mpc is not None and mpc.discs is not None
    seen = {}
    orig = mpc.constrain

    def constrain(x0, x_ref, u_ref, guess):
        con = orig(x0, x_ref, u_ref, guess)
        seen["guess0"], seen["bs"] = guess[0].copy(), con.context[3]
        return con

    mpc.constrain = constrain
    # the true grid of the sensed map's cells (0.05 / footprint_refine m), one grid as the sensed one
    from dataclasses import replace

    one = replace(DISCS, sa_mpc=replace(DISCS.sa_mpc, footprint_refine=1))
    truth = prepare(sc, resolution=ctrl.map.grid.resolution, controller=lidar_spec(one)).grid
    assert truth.resolution == ctrl.map.grid.resolution
    assert truth.inflation == pytest.approx(ctrl.map.grid.inflation, abs=1e-12)
    checked, first_plan = [], []

    def on_step(step, trace):
        g = ctrl.map.grid  # the episode's map (reset makes a new one)
        safe = g.safe()
        rec = ctrl.records[step]
        if rec.replan == "initial":
            # every disc centre of the pose the plan was made from stands in a safe cell
            pts = mpc.discs.centres(ctrl.estimate[None])[0]
            j = np.floor((pts[:, 0] - g.origin[0]) / g.resolution).astype(int)
            i = np.floor((pts[:, 1] - g.origin[1]) / g.resolution).astype(int)
            first_plan.append(bool(safe[i, j].all()))
        for r in rec.corridor_rects:
            cells = cells_of_box(r, g.origin, g.resolution, g.shape)
            assert safe[cells].all(), f"step {step}: corridor rectangle {r} holds unobserved or unsafe cells"
            assert not truth.occupied[cells].any(), f"step {step}: corridor rectangle {r} is not free in truth"
        if trace.status[step] in ("ok", "inexact") and "bs" in seen:
            centres0 = mpc.discs.centres(seen["guess0"][None])[0]
            for d, boxes in enumerate(seen["bs"]):
                p0 = centres0[d]
                below = np.maximum(boxes[0, :2] - p0, 0.0)
                above = np.maximum(p0 - boxes[0, 2:], 0.0)
                for b in boxes[1:] + np.concatenate([below, -above]):
                    cells = cells_of_box(b, g.origin, g.resolution, g.shape)
                    assert safe[cells].all(), f"step {step}: disc {d} stage box {b} holds unobserved or unsafe cells"
                    assert not truth.occupied[cells].any(), f"step {step}: disc {d} stage box {b} not free in truth"
            checked.append(step)
        seen.pop("bs", None)

    out = run_scenario(sc, seed=seed, sensing="lidar", controller_spec=DISCS, controller_obj=ctrl, on_step=on_step)
    return out, ctrl, checked, first_plan


def test_discs_lidar_run_keeps_every_disc_centre_in_observed_free_space():
    out, ctrl, checked, first_plan = _discs_checked_run("u_shape", seed=0)
    doc = out.document
    assert doc["success"] and doc["collisions"] == 0
    assert len(checked) > 50  # the per-disc check ran on the solved steps
    assert first_plan == [True]
    assert doc["sensing"] == "lidar" and doc["footprint"]["mode"] == "discs"
    # the sensed map is one grid of 0.05 / footprint_refine m cells; the chain grows into its
    # safe cells (the discs defaults: refine 2, grow 1 m)
    assert doc["footprint"]["refine"] == DISCS.sa_mpc.footprint_refine == 2
    assert doc["footprint"]["grow_m"] == DISCS.sa_mpc.footprint_grow == 1.0
    assert ctrl.config.grow == 1.0 and ctrl.map.grid.resolution == 0.025
    assert ctrl.map.grid.inflation == pytest.approx(
        robot_footprint(load_scenario("u_shape").model).discs(3)[1] + DISCS.sa_mpc.footprint_margin)


def test_discs_lidar_refuses_or_drops_known_map_only_settings():
    from dataclasses import replace

    sc = load_scenario("single_rect")
    spec = replace(DISCS, sa_mpc=replace(DISCS.sa_mpc, footprint_route="pose"))
    with pytest.raises(ValueError, match="footprint_route='corridor'"):
        lidar_controller(sc, spec)
    # refinement and growth keep their sensed-map meaning: cells of 0.05 / refine m everywhere,
    # the chain grown into the sensed safe cells; the disc mode has neither
    grown = replace(DISCS, sa_mpc=replace(DISCS.sa_mpc, footprint_grow=0.5, footprint_refine=4))
    used = lidar_spec(grown).sa_mpc
    assert (used.footprint_grow, used.footprint_refine) == (0.5, 4)
    ctrl = lidar_controller(sc, grown)
    assert ctrl.config.grow == 0.5 and ctrl.map.grid.resolution == 0.0125
    disc = lidar_controller(sc, footprint_spec())
    assert disc.config.grow == 0.0 and disc.map.grid.resolution == 0.05
    assert lidar_cell(0.05, grown) == 0.0125 and lidar_cell(0.05, footprint_spec()) == 0.05
    # the tightening's bound assumes the measured state is the true one: off with the localiser
    assert grown.sa_mpc.footprint_prediction.tighten and not used.footprint_prediction.tighten
    # the known map's footprint_box_margin (0) is sized from that map's measured error; the lidar run keeps box_margin
    assert grown.sa_mpc.footprint_box_margin == 0.0 and used.footprint_box_margin == grown.sa_mpc.box_margin == 0.02
    # and the derating it was measured with (stop 0.03; the known map's 0.02 stalled complex/2)
    assert grown.sa_mpc.footprint_prediction.stop == 0.02 and used.footprint_prediction.stop == 0.03
    # the open-space speed is kept: the lidar plans read it from the sensed safe cells
    assert used.footprint_open_speed == grown.sa_mpc.footprint_open_speed == 1.0
    assert used == replace(grown.sa_mpc, footprint_box_margin=0.02,
                           footprint_prediction=replace(grown.sa_mpc.footprint_prediction, tighten=False, stop=0.03))
    # a larger stop (a gentler derating) is kept; the tightening still goes
    own = replace(grown, sa_mpc=replace(grown.sa_mpc, footprint_prediction=PredictionDerating(stop=0.05)))
    assert lidar_spec(own).sa_mpc.footprint_prediction == PredictionDerating(stop=0.05, tighten=False)
    assert lidar_spec(lidar_spec(grown)) == lidar_spec(grown)
    assert lidar_spec(footprint_spec()) == footprint_spec()


def _first_plan(grow: float):
    """A discs-mode lidar controller (0.05 m cells) with ``footprint_grow`` = ``grow`` [m] after its first
    step at the origin with a full-circle scan of 3 m and no return."""
    from dataclasses import replace
    from types import SimpleNamespace

    from sanav_mj.control.base import Observation

    spec = replace(DISCS, sa_mpc=replace(DISCS.sa_mpc, footprint_grow=grow, footprint_refine=1))  # 0.05 m cells
    ctrl = lidar_controller(load_scenario("single_rect"), spec)
    ctrl.reset(np.zeros(3))
    a = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    scan = SimpleNamespace(ranges=np.full(720, 3.0), hit=np.zeros(720, bool), angles=a)
    ctrl.step(Observation(t=0.0, pose=np.zeros(3), velocity=np.zeros(2), scan=scan))
    assert ctrl.mpc is not None and ctrl.records[0].replan == "initial"
    return ctrl


def test_discs_lidar_plans_at_the_open_space_speed_only_where_the_sensed_map_is_open():
    from dataclasses import replace

    ctrl = _first_plan(1.0)  # open sensed space 3 m around the robot
    lim = DISCS.sa_mpc.limits(load_scenario("single_rect").robot)
    v = np.asarray(ctrl.mpc.plan.reference.inputs)[:, 0]
    assert ctrl.planner.open_speed_fraction is not None
    assert v.max() > 0.8 * lim.v_max + 0.05  # above the narrow-place cap: the open speed applied
    assert v.max() <= lim.v_max + 1e-9
    # without the option the same plan stays at 0.8 of the MPC's v_max
    spec = replace(DISCS, sa_mpc=replace(DISCS.sa_mpc, footprint_grow=1.0, footprint_refine=1, footprint_open_speed=None))
    from types import SimpleNamespace

    from sanav_mj.control.base import Observation

    other = lidar_controller(load_scenario("single_rect"), spec)
    other.reset(np.zeros(3))
    a = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    other.step(Observation(t=0.0, pose=np.zeros(3), velocity=np.zeros(2),
                           scan=SimpleNamespace(ranges=np.full(720, 3.0), hit=np.zeros(720, bool), angles=a)))
    v_slow = np.asarray(other.mpc.plan.reference.inputs)[:, 0]
    assert v_slow.max() == pytest.approx(0.8 * lim.v_max, rel=1e-3)
    # with the room of open space only inside the scanned disc, the reference is at rest at its end
    assert v[-1] == pytest.approx(0.0, abs=1e-9)


def test_the_chain_grows_into_the_safe_cells_of_the_step_it_planned_in():
    """A plan made in this step hands its table of safe cells (read for the open-space speed)
    to the chain's growth: it is the table of this step's safe grid, with the growth limit and
    tightening of the discs mode."""
    from sanav_mj.mapping.grow import FreeCells

    ctrl = _first_plan(1.0)
    used = ctrl.mpc.areas.free
    fresh = FreeCells.of(ctrl.map.grid.safe_grid(), 1.0, DISCS.sa_mpc.footprint_grow_tighten)
    assert np.array_equal(used.sat, fresh.sat) and np.array_equal(used.origin, fresh.origin)
    assert (used.resolution, used.limit, used.tighten) == (fresh.resolution, fresh.limit, fresh.tighten)


def _contains(outer, inner):
    return bool(np.all(outer[:2] <= inner[:2] + 1e-12) and np.all(outer[2:] >= inner[2:] - 1e-12))


def test_discs_lidar_grows_the_chain_into_safe_cells_and_replans_when_a_grown_box_is_hit():
    """The corridor chain's boxes grow to maximal rectangles of the sensed *safe* cells (the
    quadtree's staircase of areas around a disc of seen free space leaves room beside each
    rectangle); each grown box holds its plain member, only safe cells, and is checked at
    every scan: a return inside a grown box, outside every corridor rectangle, replans
    (``blocked``). Without growth the chain is the corridor's rectangles and bridges."""
    plain = _first_plan(0.0)
    assert len(plain.records[0].corridor_rects) == len(plain._plain_rects)
    ctrl = _first_plan(1.0)
    corridor, boxes = ctrl._plain_rects, np.asarray(ctrl.mpc.chain.boxes)
    np.testing.assert_array_equal(corridor, plain._plain_rects)  # the same corridor
    assert len(boxes) == 2 * len(corridor) - 1
    for k, r in enumerate(corridor):
        assert _contains(boxes[2 * k], r)
    assert any(not np.array_equal(b, p) for b, p in zip(boxes, np.asarray(plain.mpc.chain.boxes)))
    assert ctrl.map.rects_still_safe(boxes).all()
    np.testing.assert_array_equal(ctrl.records[0].corridor_rects, np.vstack([corridor, boxes]))
    # a return at (0.12, 0.9): inside the first grown box, farther than the inflation from
    # every corridor rectangle (the first ends at y = 0.2, the others start at x = 2.2)
    hit = np.array([0.12, 0.9])
    assert any(_contains(b, np.r_[hit, hit]) for b in boxes)
    assert not any(_contains(r, np.r_[hit, hit]) for r in corridor)
    pose = ctrl.estimate.copy()
    origin = pose[:2] + 0.12 * np.array([math.cos(pose[2]), math.sin(pose[2])])
    d = hit - origin
    up = ctrl.map.integrate(pose, np.array([np.hypot(*d)]), np.array([True]),
                            np.array([math.atan2(d[1], d[0]) - pose[2]]))
    assert up.changed
    assert ctrl.map.rects_still_safe(corridor).all()
    assert ctrl._replan_reason(True, pose) == "blocked"
    assert plain._replan_reason(False, plain.estimate) != "blocked"


def test_lidar_run_from_a_refined_prepared_map_uses_the_base_cells():
    prep = prepare("single_rect", controller=DISCS)  # refined: 0.025 m cells where narrow
    assert prep.grid.resolution == pytest.approx(0.025)
    out = run_scenario(prep, seed=0, sensing="lidar", controller_spec=DISCS, time_limit_s=0.3)
    assert out.sensed.map.grid.resolution == 0.025  # the base 0.05 m cells, refined by 2 everywhere


def test_discs_mode_counts_the_robot_in_safe_space_only_when_every_disc_centre_is():
    """The wall of the hand-made scan above: cells of columns <= 53 (x < 1.70 m) are safe in
    the discs map. A robot at x = 1.60 m facing the wall has its centre there (column 52) but
    its front disc centre at 1.767 m (column 55) is not: not in safe space (no first plan yet,
    the body is cleared again); at x = 1.45 m every centre is (columns 45, 49, 52)."""
    from sanav_mj.mapping.sensed_map import SensedMap, SensedMapConfig

    sc = load_scenario("single_rect")
    ctrl = lidar_controller(sc, DISCS)
    m = SensedMap((-1.0, -2.5, 4.0, 2.5), ctrl.map.grid.inflation, (0.0, 0.0), SensedMapConfig(resolution=0.05))
    m.integrate(np.zeros(3), *_wall_scan(2.025))
    ctrl.map = m
    assert not ctrl._own_safe(np.array([1.60, 0.025, 0.0]))
    assert ctrl._own_safe(np.array([1.45, 0.025, 0.0]))
    # the same position sideways (discs at y +- 0.167 m, all at x = 1.60 m): safe
    assert ctrl._own_safe(np.array([1.60, 0.025, math.pi / 2]))
    # the disc mode (its own map) checks the position alone
    disc = lidar_controller(sc)
    disc.map = m
    assert disc._own_safe(np.array([1.60, 0.025, 0.0]))


def test_discs_lidar_brakes_keeping_its_heading():
    """In discs mode with the lidar the braking fallback ramps speed and yaw rate to 0 at the
    rate bounds (no steering candidate); the disc mode keeps SA-MPC's steering brake."""
    from sanav_mj.control.sa_mpc import SAMPC
    from sanav_mj.control.sensed_footprint import StraightBrakeSAMPC

    sc = load_scenario("single_rect")
    mpc = lidar_controller(sc, DISCS)._spare
    assert type(mpc) is StraightBrakeSAMPC
    assert type(lidar_controller(sc)._spare) is SAMPC
    a, al = mpc._rate_step  # [m/s, rad/s] per step
    mpc._u_prev = np.array([4.5 * a, -2.5 * al])
    u = mpc.brake_plan(np.array([0.0, 0.0, 0.3]))
    assert u.shape == (mpc.N, 2)
    np.testing.assert_allclose(u[:6, 0], np.array([3.5, 2.5, 1.5, 0.5, 0.0, 0.0]) * a, rtol=0, atol=8 * np.finfo(float).eps)
    np.testing.assert_allclose(u[:4, 1], np.array([-1.5, -0.5, 0.0, 0.0]) * al, rtol=0, atol=8 * np.finfo(float).eps)
    assert not u[6:].any()


@pytest.mark.parametrize("lost, resolution, width", [
    (0.099, 0.05, 0.25),   # 2 lost = 0.198 m: strips of up to 4 cells (0.20 m) are narrow
    (0.100, 0.05, 0.25),   # 0.20 m exactly: 4 cells leave the circumscribed disc nothing
    (0.101, 0.05, 0.30),
    (0.0, 0.05, 0.0),      # the circumscribed-disc map itself: nothing is narrower
    (-0.01, 0.05, 0.0),
])
def test_sensed_narrow_width_counts_whole_cells(lost, resolution, width):
    from sanav_mj.eval.lidar import sensed_narrow_width

    assert sensed_narrow_width(lost, resolution) == pytest.approx(width, abs=4 * np.finfo(float).eps)


def test_discs_lidar_controller_narrow_width():
    sc = load_scenario("single_rect")
    from dataclasses import replace

    from sanav_mj.eval.lidar import sensed_narrow_width

    # at margin 0.05 m: 0.330 + 0.05 - (0.2305 + 0.05) = 0.0985 m lost, strips of up to 4 cells narrow
    m05 = replace(DISCS, sa_mpc=replace(DISCS.sa_mpc, footprint_margin=0.05, footprint_refine=1))  # 0.05 m cells
    ctrl = lidar_controller(sc, m05)
    lost = sc.robot.footprint_radius + DEFAULT_MARGIN_M - ctrl.map.grid.inflation
    assert 0.0975 < lost < 0.1
    assert ctrl.config.narrow_width == pytest.approx(0.25, abs=1e-15) == ctrl.body.narrow_width
    # the default's margin gives the width of its own lost inflation
    ctrl = lidar_controller(sc, DISCS)
    lost = sc.robot.footprint_radius + DEFAULT_MARGIN_M - ctrl.map.grid.inflation
    assert ctrl.map.grid.resolution == 0.025  # counted in the sensed cells: 0.05 / footprint_refine
    assert ctrl.config.narrow_width == sensed_narrow_width(lost, 0.025) == ctrl.body.narrow_width
    assert lidar_controller(sc).config.narrow_width == 0.0


@pytest.mark.parametrize("kwargs, match", [
    ({"narrow_width": -0.1}, "narrow_width"),
    ({"narrow_width": float("inf")}, "narrow_width"),
    ({"refresh": 1}, "refresh"),
    ({"straight_brake": "yes"}, "straight_brake"),
    ({"scan_turn_stop": 1}, "scan_turn_stop"),
    ({"scan_turn_route": None}, "scan_turn_route"),
    ({"scan_turn_creep": 0.0}, "scan_turn_creep"),
])
def test_sensing_config_discs_fields_are_validated(kwargs, match):
    from sanav_mj.control.sensing_config import SensingConfig

    with pytest.raises(ValueError, match=match):
        SensingConfig(**kwargs)


def test_scan_matcher_reaches_as_far_in_metres_on_the_finer_sensed_cells(monkeypatch):
    """On the discs mode's 0.025 m cells the matcher's cell-counted settings are doubled
    (:func:`lidar_match`), so it pairs returns as far as on 0.05 m cells. With the 0.05 m
    counts, the turn on the spot at 1 rad/s at the start of single_rect seed 3 (an open room:
    few returns) gave only ``few_points`` matches, its scans were not added and the robot
    turned for 7 s before its first plan; with them the matches are used and it plans after
    2.2 s. (At the default 2 rad/s both plan after 1.3 s: the turn sees the room sooner.)"""
    from dataclasses import replace

    import sanav_mj.eval.lidar as lidar
    from sanav_mj.mapping.scan_match import ScanMatchConfig

    base = ScanMatchConfig()
    assert lidar_match(1.0) == base
    assert (lidar_match(2.0).radius_cells, lidar_match(2.0).xy_window) == (2 * base.radius_cells, 2 * base.xy_window)
    sc = load_scenario("single_rect")
    ctrl = lidar_controller(sc, DISCS)
    assert ctrl.map.grid.resolution == 0.025 and ctrl.config.map.match == lidar_match(2.0)

    def run(ctrl):
        ctrl.config = replace(ctrl.config, scan_turn_rate=1.0)  # read at each step of the turn
        out = run_scenario(sc, seed=3, sensing="lidar", controller_spec=DISCS, controller_obj=ctrl, time_limit_s=8.0)
        first = next((i for i, r in enumerate(out.sensed.records) if r.replan == "initial"), None)
        return [m[0] for m in out.sensed.match_log].count("few_points"), first

    few, first = run(ctrl)
    assert few == 0 and first is not None and first * 0.1 < 3.0
    monkeypatch.setattr(lidar, "lidar_match", lambda refine: ScanMatchConfig())  # the 0.05 m counts
    unscaled = lidar.lidar_controller(sc, DISCS)
    assert unscaled.config.map.match == base
    few_base, first_base = run(unscaled)
    assert few_base > 20 and (first_base is None or first_base > first + 20)


def test_the_stopping_scan_turn_brakes_before_the_first_plan_which_still_waits_for_safe_own_points():
    """``SensingConfig.scan_turn_stop``: the turn on the spot brakes so as to stop where the
    lidar will have swept the unknown cells near the disc centres; the first plan still comes
    only once every disc centre stands in a safe cell, and the yaw rate it takes over is far
    below the plain turn's ``scan_turn_rate`` (which the SA-MPC then has to brake: the
    overshoot the option removes)."""
    from dataclasses import replace

    from sanav_mj.control.sensing import grid_cells

    sc = load_scenario("single_rect")

    def first_plan(stop: bool):
        ctrl = lidar_controller(sc, DISCS)
        ctrl.config = replace(ctrl.config, scan_turn_stop=stop)
        seen = []
        step = ctrl.step

        def logged(obs):
            cmd = step(obs)
            if ctrl.records[-1].replan == "initial":
                g = ctrl.map.grid
                seen.append((len(ctrl.records), ctrl._turn_w,
                             bool(g.safe_at(grid_cells(g, ctrl.body.own_points(ctrl.estimate))).all())))
            return cmd

        ctrl.step = logged
        out = run_scenario(sc, seed=0, sensing="lidar", controller_spec=DISCS, controller_obj=ctrl, time_limit_s=2.5)
        yaw = np.unwrap(np.asarray(out.episode.trace.pose)[:, 2])
        return seen[0] + (float(yaw[0] - yaw.min()),)  # the turn goes clockwise here

    k0, w0, safe0, swept0 = first_plan(False)
    k1, w1, safe1, swept1 = first_plan(True)
    assert safe0 and safe1
    assert abs(w0) == pytest.approx(2.0) and abs(w1) <= abs(w0) - 0.5
    assert k1 <= k0 + 5  # braking costs at most a few steps of the turn
    assert swept1 <= swept0 - 0.2  # [rad] the overshoot saved (about 0.4 rad here)
