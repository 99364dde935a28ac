"""SA-MPC's discs mode with a pose route: per-disc chains, repeated areas, progress in (x, y, yaw)."""

from __future__ import annotations

import math

import numpy as np

from sanav_mj.control.sa_mpc import SAMPC, MPCConfig, _plan_tables
from sanav_mj.footprint import Footprint
from sanav_mj.planning.reference import Plan, Reference

from mpc_cases import ROBOT, make_areas

FP = Footprint(-0.25, 0.25, -0.215, 0.215)
DISCS = MPCConfig(footprint="discs", footprint_discs=3, footprint_box_margin=0.0)
# A on the left; B (lower) and C (upper) on the right, both adjacent to A and to each other
RECTS = [[0.0, 0.0, 1.0, 1.0], [1.0, 0.0, 2.0, 0.5], [1.0, 0.5, 2.0, 1.0]]


def _plan(states, areas_idx, corridor, disc_corridors=None):
    states = np.asarray(states, float)
    ref = Reference(0.1, states, np.zeros((len(states), 2)), np.asarray(areas_idx, int))
    return Plan(True, "ok", np.asarray(corridor, int), states[-1, :2].copy(), states[:, :2], states[:, :2],
                states[:, :2], ref, {}, disc_corridors)


def test_each_disc_walks_its_own_corridor():
    """A pose straddling three areas: rear disc in A, centre in C, front in B. One chain
    (A, C) for every disc leaves the front disc outside its boxes; each disc on its own
    chain of areas and bridges (A; A, A-C, C; A, A-B, B) is inside."""
    areas = make_areas(RECTS)
    x = np.array([1.05, 0.55, -0.6])
    guess = np.tile(x, (DISCS.horizon + 1, 1))
    states = [[0.5, 0.5, 0.0], [1.05, 0.55, -0.6], [1.5, 0.75, 0.0]]
    one = SAMPC(ROBOT, areas, _plan(states, [0, 2, 2], [0, 2]), DISCS, footprint=FP)
    assert one.disc_chains is None
    c = one.discs.centres(x[None])[0]
    assert c[0, 0] < 1.0 and c[1, 1] > 0.5 and c[2, 0] > 1.0 and c[2, 1] < 0.5  # A, C, B
    _, _, exc = one.discs.stages(one._chains(), guess, None, 1e-9)
    assert exc > 0.01
    # member indices: the areas, then one bridge per edge
    bridge = {tuple(e): 3 + i for i, e in enumerate(np.asarray(areas.edges).tolist())}
    members = ([0], [0, bridge[(0, 2)], 2], [0, bridge[(0, 1)], 1])
    per = SAMPC(ROBOT, areas, _plan(states, [0, 2, 2], [0, 2], members), DISCS, footprint=FP)
    assert len(per.disc_chains) == 3 and len(per.disc_chains[0]) == 1 and len(per.disc_chains[2]) == 3
    np.testing.assert_allclose(per.disc_chains[2].boxes[1], [0.0, 0.0, 2.0, 0.5])  # the A-B bridge
    ss, bs, exc = per.discs.stages(per._chains(), guess, None, 1e-9)
    assert exc == 0.0
    assert np.all(per.discs.margins(guess, bs) >= 0)
    assert ss[2, 0] == 2 and ss[1, 0] == 2 and ss[0, 0] == 0  # front in B, centre in C, rear in A
    assert per.state_clearance(x[None])[0] >= 0 > one.state_clearance(x[None])[0]


def test_repeated_areas_take_the_next_occurrence():
    """A route that backs up passes A, B, A, C: each reference sample gets the chain
    position of the first occurrence of its area at or after the previous sample's."""
    areas = make_areas(RECTS)
    states = [[0.5, 0.5, 0]] * 2 + [[1.5, 0.25, 0]] * 2 + [[0.5, 0.5, 0]] * 2 + [[1.5, 0.75, 0]]
    _, _, _, pos = _plan_tables(areas, _plan(states, [0, 0, 1, 1, 0, 0, 2], [0, 1, 0, 2]), 0.0, 0.1)
    np.testing.assert_array_equal(pos, [0, 0, 2, 2, 4, 4, 6])
    # a corridor without repeats keeps the lookup (the default path)
    _, _, _, pos = _plan_tables(areas, _plan(states[:4], [0, 0, 1, 1], [0, 1]), 0.0, 0.1)
    np.testing.assert_array_equal(pos, [0, 0, 2, 2])


def test_progress_follows_a_turn_on_the_spot():
    """A reference turning on the spot holds its position: a pose route's progress finds the
    sample of the measured yaw; by position alone (every other plan's rule) it stays at the first."""
    areas = make_areas(RECTS)
    yaw = np.linspace(0.0, math.pi / 2, 8)
    states = np.column_stack([np.full(8, 0.5), np.full(8, 0.5), yaw])
    plan = _plan(np.vstack([states, [[0.5, 0.9, math.pi / 2]]]), [0] * 9, [0], ([0], [0], [0]))  # a pose route
    ctl = SAMPC(ROBOT, areas, plan, DISCS, footprint=FP)
    ctl.reset(np.array([0.5, 0.5, 0.0]), progress=0)
    assert ctl._progress(np.array([0.5, 0.5, yaw[5] + 0.01])) == 5
    disc = SAMPC(ROBOT, areas, plan, MPCConfig(box_margin=0.0))
    disc.reset(np.array([0.5, 0.5, 0.0]), progress=0)
    assert disc._progress(np.array([0.5, 0.5])) == 0
    corridor = SAMPC(ROBOT, areas, _plan(plan.reference.states, [0] * 9, [0]), DISCS, footprint=FP)
    corridor.reset(np.array([0.5, 0.5, 0.0]), progress=0)
    corridor.reference(np.array([0.5, 0.5, yaw[5] + 0.01]))
    assert corridor.progress_index == 0


def test_config_rejects_an_unknown_route():
    import pytest

    with pytest.raises(ValueError, match="footprint_route"):
        MPCConfig(footprint_route="lattice")
    assert MPCConfig().footprint_route == "corridor"


def test_member_chain_must_overlap():
    import pytest

    from sanav_mj.control.disc_stages import member_chain_of

    areas = make_areas(RECTS)
    with pytest.raises(ValueError, match="overlap"):
        member_chain_of(areas, [0, 2], 0.0)  # A and C only touch
    with pytest.raises(ValueError, match="member indices"):
        member_chain_of(areas, [0, 99], 0.0)


def test_horizon_holds_at_the_next_stop_until_the_robot_arrives():
    """A route that drives forward to a stop, then on: the horizon repeats the stop pose
    with zero inputs until the robot is within STOP_REACHED_M of it."""
    from sanav_mj.control.sa_mpc import STOP_REACHED_M

    areas = make_areas([[0.0, 0.0, 4.0, 1.0]])
    x = np.concatenate([np.linspace(0.5, 1.4, 10), [1.49, 1.5], np.linspace(1.6, 3.5, 20)])  # stop: sample 11
    states = np.column_stack([x, np.full(x.size, 0.5), np.zeros(x.size)])
    ref = Reference(0.1, states, np.column_stack([np.full(x.size, 1.0), np.zeros(x.size)]), np.zeros(x.size, int),
                    stops=np.array([11]))
    plan = Plan(True, "ok", np.array([0]), states[-1, :2].copy(), states[:, :2], states[:, :2], states[:, :2], ref)
    ctl = SAMPC(ROBOT, areas, plan, DISCS, footprint=FP)
    ctl.reset(np.array([0.5, 0.5, 0.0]), progress=0)
    xr, ur = ctl.reference(np.array([0.9, 0.5, 0.0]))
    assert ctl.progress_index == 4
    np.testing.assert_array_equal(xr[7:], np.tile(states[11], (ctl.N + 1 - 7, 1)))
    assert np.all(ur[7:] == 0) and np.all(ur[:7, 0] == 1.0)
    # nearest to the sample before the stop, but within the arrival distance of the stop:
    # the motion after it comes into view
    xr, ur = ctl.reference(np.array([1.5 - 0.8 * STOP_REACHED_M, 0.5, 0.0]))
    assert abs(1.5 - 0.8 * STOP_REACHED_M - 1.49) < 0.8 * STOP_REACHED_M  # nearer the sample before
    assert ctl.progress_index == 11
    np.testing.assert_array_equal(xr[1:4, 0], x[12:15])
    # without stops (the corridor planner's reference) the horizon runs on
    plain = SAMPC(ROBOT, areas, Plan(True, "ok", np.array([0]), states[-1, :2].copy(), states[:, :2], states[:, :2],
                                     states[:, :2], Reference(0.1, states, ref.inputs, ref.area)), DISCS, footprint=FP)
    plain.reset(np.array([0.5, 0.5, 0.0]), progress=0)
    xr, _ = plain.reference(np.array([0.9, 0.5, 0.0]))
    np.testing.assert_array_equal(xr[:, 0], x[np.minimum(np.arange(4, 4 + plain.N + 1), x.size - 1)])
