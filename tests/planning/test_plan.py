"""End-to-end planning: known answers and properties on random maps (sanav_mj/planning/__init__.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from planning_maps import ROBOT, areas_from_rects, clutter_areas, grid_to_rects, in_union

from sanav_mj.planning import PlannerConfig, plan, plan_document
from sanav_mj.planning.corridor import build_graph, reachable_from, rect_distance

CFG = PlannerConfig()
V_CAP = CFG.speed_fraction * ROBOT.v_max
W_CAP = CFG.yaw_rate_fraction * ROBOT.w_max
A_CAP = CFG.accel_fraction * ROBOT.a_max


def check_reference(p, areas, start_xy, goal_xy, v_cap=V_CAP):
    """The properties every successful plan must have (``v_cap`` [m/s]: the top speed)."""
    assert p.ok and p.reason == "ok"
    ref = p.reference
    rects = np.asarray(areas.rects)
    xy = ref.states[:, :2]
    dt = ref.dt
    # inside the corridor, each sample in its own assigned rectangle, monotone along the corridor
    assert in_union(rects[p.corridor], xy).all()
    r = rects[ref.area]
    tol = 1e-9
    assert np.all((xy[:, 0] >= r[:, 0] - tol) & (xy[:, 0] <= r[:, 2] + tol))
    assert np.all((xy[:, 1] >= r[:, 1] - tol) & (xy[:, 1] <= r[:, 3] + tol))
    pos = np.array([np.flatnonzero(p.corridor == a)[0] for a in ref.area])
    assert np.all(np.diff(pos) >= 0)  # never back along the corridor
    # same or next corridor area, unless the areas stepped over lie within one step of both samples
    for k in np.flatnonzero(np.diff(pos) > 1):
        skipped = rects[p.corridor[pos[k] + 1 : pos[k + 1]]]
        step_k = np.linalg.norm(xy[k + 1] - xy[k])
        assert np.all(rect_distance(skipped, xy[k]) <= step_k + 1e-9)
        assert np.all(rect_distance(skipped, xy[k + 1]) <= step_k + 1e-9)
    # the dense smoothed curve too
    assert in_union(rects[p.corridor], p.smoothed).all()
    # continuity and limits
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert np.all(step <= ROBOT.v_max * dt + 1e-6)
    assert np.all(step <= v_cap * dt + 1e-4)  # chord vs. arc length of the dense nodes
    v, w = ref.inputs[:, 0], ref.inputs[:, 1]
    assert np.all(v >= 0) and np.all(v <= v_cap + 1e-9)
    assert np.all(np.abs(w) <= W_CAP + 1e-9)
    assert np.all(np.abs(np.diff(v)) <= A_CAP * dt + 1e-9)
    assert np.all(np.abs(np.diff(ref.states[:, 2])) < np.pi)  # unwrapped yaw
    # ends: from the start, at rest at the goal
    np.testing.assert_allclose(xy[0], start_xy, atol=1e-9)
    np.testing.assert_allclose(xy[-1], goal_xy, atol=1e-9)
    assert v[0] == 0.0 and v[-1] == 0.0 and w[-1] == 0.0
    # length at least the straight-line distance
    length = float(np.sum(np.linalg.norm(np.diff(p.smoothed, axis=0), axis=1)))
    assert length >= np.linalg.norm(np.asarray(goal_xy) - np.asarray(start_xy)) - 1e-9
    assert ref.states.shape == (len(ref), 3) and ref.inputs.shape == (len(ref), 2) and ref.area.shape == (len(ref),)


def test_straight_corridor_known_answer():
    areas = areas_from_rects([[0, 0, 10, 2]])
    p = plan(areas, [1.0, 1.0, 2.0], [9.0, 1.0], ROBOT)
    check_reference(p, areas, [1, 1], [9, 1])
    assert p.corridor.tolist() == [0]
    np.testing.assert_allclose(p.waypoints, [[1, 1], [9, 1]])
    ref = p.reference
    np.testing.assert_allclose(ref.states[:, 1], 1.0, atol=1e-12)
    np.testing.assert_allclose(ref.states[:, 2], 0.0, atol=1e-12)  # yaw: the tangent, not the start yaw
    np.testing.assert_allclose(ref.inputs[:, 1], 0.0, atol=1e-9)
    assert p.info["path_length_m"] == pytest.approx(8.0, abs=1e-9)
    assert p.info["duration_s"] == pytest.approx(8.0 / V_CAP + V_CAP / A_CAP, rel=2e-3)
    assert np.all(np.diff(ref.states[:, 0]) >= 0)
    assert len(ref) == int(np.ceil(p.info["duration_s"] / CFG.dt - 1e-9)) + 1
    assert p.info["lambda_steps"] == 0 and p.info["fallback_length_m"] == 0.0


def test_l_turn_known_answer():
    areas = areas_from_rects([[0, 0, 4, 1], [3, 1, 4, 4]])
    p = plan(areas, [0.5, 0.5, 0.0], [3.5, 3.5], ROBOT)
    check_reference(p, areas, [0.5, 0.5], [3.5, 3.5])
    assert p.corridor.tolist() == [0, 1]
    np.testing.assert_allclose(p.waypoints, [[0.5, 0.5], [3.25, 1.0], [3.5, 3.5]])  # clearance 0.25 from (3, 1)
    yaw = p.reference.states[:, 2]
    assert yaw[0] == pytest.approx(np.arctan2(0.5, 2.75), abs=0.05)
    assert yaw[-1] == pytest.approx(np.arctan2(2.5, 0.25), abs=0.05)
    w = p.reference.inputs[:, 1]
    assert w.max() > 0.5 and w.min() > -0.1 * w.max()  # a left turn (small smoothing-spline ripple)
    assert p.reference.area[0] == 0 and p.reference.area[-1] == 1


# A U-shaped obstacle (arms at y 1.5..2 and 4.5..5, back wall at x 6..6.5) opening towards the
# start on the left; the goal is behind it. R4 is the pocket inside the U: the trap.
U_RECTS = [
    [0, 0, 4, 6],  # R0 left of the U (start)
    [4, 0, 10, 1.5],  # R1 below
    [4, 5, 10, 6],  # R2 above
    [6.5, 1.5, 10, 5],  # R3 behind the U (goal)
    [4, 2, 6, 4.5],  # R4 inside the U
]


def test_u_shape_goes_around_not_into_the_pocket():
    areas = areas_from_rects(U_RECTS)
    p = plan(areas, [2.0, 3.0, 0.0], [8.0, 3.0], ROBOT)
    check_reference(p, areas, [2, 3], [8, 3])
    # centre-distance weights (the paper's) make the route above the U the shorter corridor:
    # 5.590 + 2.574 < 5.483 + 2.795
    assert p.corridor.tolist() == [0, 2, 3]
    assert 4 not in p.reference.area
    xy = p.reference.states[:, :2]
    over_u = (xy[:, 0] > 4.0) & (xy[:, 0] < 6.5)
    assert np.all(xy[over_u, 1] >= 5.0 - 1e-9)  # passes above the U's top arm
    # at least the shortest detour over the arm: (2,3) -> (4,5) -> (6.5,5) -> (8,3)
    assert p.info["path_length_m"] >= np.hypot(2, 2) + 2.5 + np.hypot(1.5, 2) - 1e-9


def test_walled_off_goal_is_no_path():
    # a room [6,0,9,3] whose walls leave no free connection to the start area
    areas = areas_from_rects([[0, 0, 5, 3], [6, 0, 9, 3]])
    p = plan(areas, [1.0, 1.0, 0.0], [7.5, 1.5], ROBOT)
    assert not p.ok and p.reason == "no_path" and p.reference is None
    assert p.corridor.size == 0
    # the same from a grid: an enclosed cell block
    free = np.ones((7, 7), bool)
    free[2:5, 2:5] = False
    free[3, 3] = True
    areas = areas_from_rects(grid_to_rects(free))
    p = plan(areas, [0.5, 0.5, 0.0], [3.5, 3.5], ROBOT)
    assert not p.ok and p.reason == "no_path"


def test_goal_outside_is_projected_into_the_nearest_reachable_area():
    # rect 2 is nearer to the goal but not reachable; the goal goes to reachable rect 1
    areas = areas_from_rects([[0, 0, 4, 2], [4, 0, 6, 2], [6.5, 0, 8, 2]])
    p = plan(areas, [1.0, 1.0, 0.0], [6.3, 1.0], ROBOT)
    np.testing.assert_allclose(p.goal, [6.0 - CFG.goal_offset, 1.0])
    check_reference(p, areas, [1, 1], p.goal)
    assert p.corridor.tolist() == [0, 1]
    # too far from every reachable area
    p = plan(areas, [1.0, 1.0, 0.0], [6.3, 1.0], ROBOT, PlannerConfig(max_projection=0.2))
    assert not p.ok and p.reason == "no_path"


def test_start_outside_is_projected():
    areas = areas_from_rects([[0, 0, 4, 2]])
    p = plan(areas, [-0.05, 1.0, 0.0], [3.0, 1.0], ROBOT)
    np.testing.assert_allclose(p.waypoints[0], [CFG.goal_offset, 1.0])
    check_reference(p, areas, p.waypoints[0], [3, 1])


def test_start_at_goal_gives_one_sample():
    areas = areas_from_rects([[0, 0, 4, 2]])
    p = plan(areas, [1.0, 1.0, 0.7], [1.0, 1.0], ROBOT)
    assert p.ok and len(p.reference) == 1
    np.testing.assert_allclose(p.reference.states[0], [1.0, 1.0, 0.7])
    np.testing.assert_allclose(p.reference.inputs[0], [0.0, 0.0])


def test_search_backends_agree():
    areas = areas_from_rects(U_RECTS)
    a = plan(areas, [2.0, 3.0, 0.0], [8.0, 3.0], ROBOT, PlannerConfig(search="astar"))
    b = plan(areas, [2.0, 3.0, 0.0], [8.0, 3.0], ROBOT, PlannerConfig(search="dijkstra"))
    assert a.corridor.tolist() == b.corridor.tolist()
    np.testing.assert_array_equal(a.reference.states, b.reference.states)


def test_sharp_corner_triggers_adaptation_and_stays_inside():
    areas = areas_from_rects([[0, 0, 4, 1], [3, 1, 4, 4]])
    cfg = PlannerConfig(portal_clearance=0.02, lam=0.05)
    p = plan(areas, [0.5, 0.5, 0.0], [3.5, 3.5], ROBOT, cfg)
    assert p.info["lambda_steps"] > 0 or p.info["fallback_length_m"] > 0
    check_reference(p, areas, [0.5, 0.5], [3.5, 3.5])
    cfg = PlannerConfig(portal_clearance=0.02, lam=0.05, max_lambda_steps=0)
    p = plan(areas, [0.5, 0.5, 0.0], [3.5, 3.5], ROBOT, cfg)
    assert p.info["fallback_length_m"] > 0
    check_reference(p, areas, [0.5, 0.5], [3.5, 3.5])


def test_sample_check_catches_what_a_coarse_node_check_misses():
    """With nodes 0.5 m apart the node check passes a corner cut that the reference samples
    (every <= 0.16 m) reveal; the planner falls back there instead of returning them."""
    areas = areas_from_rects([[0, 0, 4, 1], [3, 1, 4, 4]])
    cfg = PlannerConfig(portal_clearance=0.02, lam=0.05, check_spacing=0.5)
    p = plan(areas, [0.5, 0.5, 0.0], [3.5, 3.5], ROBOT, cfg)
    assert p.info["sample_rounds"] > 0 and p.info["fallback_length_m"] > 0
    check_reference(p, areas, [0.5, 0.5], [3.5, 3.5])


def test_plan_document_is_plain_json():
    import json

    areas = areas_from_rects(U_RECTS)
    doc = plan_document(plan(areas, [2.0, 3.0, 0.0], [8.0, 3.0], ROBOT))
    text = json.dumps(doc)
    assert json.loads(text)["corridor"] == [0, 2, 3]
    assert len(doc["reference"]) == len(doc["inputs"]) == len(doc["area"])
    bad = plan_document(plan(areas_from_rects([[0, 0, 1, 1], [2, 0, 3, 1]]), [0.5, 0.5, 0], [2.5, 0.5], ROBOT))
    assert bad["ok"] is False and bad["reference"] == [] and json.dumps(bad)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(dt=0.0), "dt"),
        (dict(lam=-1.0), "lam"),
        (dict(spacing=0.3, knot_spacing=0.2), "knot_spacing"),
        (dict(speed_fraction=1.5), "speed_fraction"),
        (dict(lambda_factor=1.0), "lambda_factor"),
        (dict(search="bfs"), "search"),
        (dict(portal_clearance=float("nan")), "portal_clearance"),
    ],
)
def test_config_validation_names_the_field(kw, match):
    with pytest.raises(ValueError, match=match):
        PlannerConfig(**kw)


def test_bad_start_or_goal_is_a_clear_error():
    areas = areas_from_rects([[0, 0, 4, 2]])
    with pytest.raises(ValueError, match="start"):
        plan(areas, [1.0, 1.0], [3.0, 1.0], ROBOT)
    with pytest.raises(ValueError, match="goal"):
        plan(areas, [1.0, 1.0, 0.0], [np.nan, 1.0], ROBOT)


@st.composite
def grid_maps(draw):
    ny = draw(st.integers(3, 14))
    nx = draw(st.integers(3, 16))
    res = draw(st.sampled_from([0.25, 0.5, 1.0, 1.5]))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    free = rng.random((ny, nx)) < draw(st.floats(0.55, 0.95))
    cells = np.argwhere(free)
    if len(cells) < 2:
        free[0, 0] = free[-1, -1] = True
        cells = np.argwhere(free)
    a, b = rng.choice(len(cells), 2, replace=len(cells) < 2)
    # random points inside the start and goal cells (on the cell boundary sometimes)
    fa = rng.choice([0.0, 0.5, 1.0, rng.random()], 2)
    fb = rng.choice([0.0, 0.5, 1.0, rng.random()], 2)
    start = (cells[a][::-1] + fa) * res
    goal = (cells[b][::-1] + fb) * res
    return areas_from_rects(grid_to_rects(free, res)), start, goal


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(grid_maps(), st.sampled_from(["astar", "dijkstra"]))
def test_properties_on_random_maps(m, search):
    areas, start, goal = m
    p = plan(areas, np.r_[start, 0.3], goal, ROBOT, PlannerConfig(search=search))
    g = build_graph(areas)
    rects = np.asarray(areas.rects)
    s_areas = np.flatnonzero((rects[:, 0] <= start[0]) & (start[0] <= rects[:, 2]) & (rects[:, 1] <= start[1]) & (start[1] <= rects[:, 3]))
    g_areas = np.flatnonzero((rects[:, 0] <= goal[0]) & (goal[0] <= rects[:, 2]) & (rects[:, 1] <= goal[1]) & (goal[1] <= rects[:, 3]))
    # reference answer for connectivity: any start area reaches any goal area
    connected = any(reachable_from(g, int(s))[g_areas].any() for s in s_areas)
    if not connected:
        assert not p.ok and p.reason == "no_path"
        return
    check_reference(p, areas, start, goal)
    np.testing.assert_allclose(p.goal, goal)


@pytest.mark.parametrize("seed", range(8))
def test_properties_on_mapped_clutter(seed):
    """The same properties on safe areas built by the mapping stage (many small rectangles)."""
    areas, free = clutter_areas(seed)
    rng = np.random.default_rng(seed)
    g = build_graph(areas)
    for _ in range(3):
        a, b = rng.choice(len(free), 2, replace=False)
        p = plan(areas, np.r_[free[a], 0.0], free[b], ROBOT)
        if not reachable_from(g, int(a))[b]:
            assert not p.ok and p.reason == "no_path"
            continue
        check_reference(p, areas, free[a], free[b])


def _free_cells(occupied_boxes, bounds=(0.0, 0.0, 10.0, 2.0), h=0.1):
    """FreeCells of a grid over ``bounds`` with the cells of ``occupied_boxes`` (world boxes) occupied."""
    from sanav_mj.mapping.grow import FreeCells
    from sanav_mj.mapping.occupancy import OccupancyGrid

    nx, ny = round((bounds[2] - bounds[0]) / h), round((bounds[3] - bounds[1]) / h)
    occ = np.zeros((ny, nx), dtype=bool)
    for x0, y0, x1, y1 in occupied_boxes:
        occ[round((y0 - bounds[1]) / h):round((y1 - bounds[1]) / h), round((x0 - bounds[0]) / h):round((x1 - bounds[0]) / h)] = True
    return FreeCells.of(OccupancyGrid(occ, h, np.array(bounds[:2]), 0.0, np.array(bounds)))


def test_open_space_speed_is_faster_in_the_open_and_unchanged_where_narrow():
    import dataclasses

    base = areas_from_rects([[0, 0, 10, 2]])
    # occupied cells above the path between x = 4 and 6: the square of half-side 0.25 m around
    # a node at y = 1 touches them from x = 3.75 to 6.25
    areas = dataclasses.replace(base, free=_free_cells([[4.0, 1.2, 6.0, 1.3]]))
    cfg = PlannerConfig(open_speed_fraction=1.0, open_room=0.25)
    fast = plan(areas, [0.5, 1.0, 0.0], [9.5, 1.0], ROBOT, cfg)
    check_reference(fast, areas, [0.5, 1], [9.5, 1], v_cap=ROBOT.v_max)
    v, x = fast.reference.inputs[:, 0], fast.reference.states[:, 0]
    assert v.max() > V_CAP + 0.1 and v.max() <= ROBOT.v_max + 1e-9
    # samples between nodes lie between the two nodes' speeds: away from the narrow place's
    # edges (one sample spacing at v_max) the narrow cap holds
    inside = (x > 3.75 + ROBOT.v_max * CFG.dt) & (x < 6.25 - ROBOT.v_max * CFG.dt)
    assert inside.any() and v[inside].max() <= V_CAP + 1e-9
    slow = plan(areas, [0.5, 1.0, 0.0], [9.5, 1.0], ROBOT)
    assert fast.info["duration_s"] < slow.info["duration_s"]
    # without the option, or without the grid, the plan is the paper's, exactly
    ref = plan(base, [0.5, 1.0, 0.0], [9.5, 1.0], ROBOT)
    for other in (slow, plan(base, [0.5, 1.0, 0.0], [9.5, 1.0], ROBOT, cfg)):
        np.testing.assert_array_equal(other.reference.states, ref.reference.states)
        np.testing.assert_array_equal(other.reference.inputs, ref.reference.inputs)


@pytest.mark.parametrize("kw, match", [(dict(open_speed_fraction=0.0), "open_speed_fraction"),
                                       (dict(open_speed_fraction=1.2), "open_speed_fraction"),
                                       (dict(open_room=-0.1), "open_room")])
def test_open_space_config_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        PlannerConfig(**kw)
