"""The discs mode's corridor reference with its footprint kept inside the chain (footprint_reference)."""

from __future__ import annotations

import numpy as np

from sanav_mj.control.disc_stages import DiscCover, footprint_reference
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig
from sanav_mj.control.stages import CorridorChain
from sanav_mj.footprint import Footprint

from mpc_cases import ROBOT, make_areas, make_plan

FP = Footprint(-0.25, 0.25, -0.215, 0.215)
COVER = DiscCover.of(FP, 3)


def test_a_pose_off_the_strip_moves_to_the_nearest_pose_inside_and_the_others_stay():
    areas = make_areas([[0.0, -0.05, 2.0, 0.05]])
    chain = CorridorChain.build(areas, np.array([0]))
    states = np.array([[0.5, 0.0, 0.0], [1.0, 0.07, 0.0], [1.5, 0.0, 0.0]])
    inputs = np.array([[0.5, 0.0], [0.5, 0.0], [0.5, 0.0]])
    out, u = footprint_reference(COVER, chain, states, inputs, 0.1)
    np.testing.assert_array_equal(out[[0, 2]], states[[0, 2]])  # inside already: untouched
    # moved straight down to the nearest lattice pose inside (0.05 m, or one 1 cm step more
    # where 0.07 - 0.02 rounds above 0.05)
    assert out[1, 0] == 1.0 and out[1, 2] == 0.0 and 0.04 - 1e-12 <= out[1, 1] <= 0.05
    assert np.all(COVER.clearance(chain, out) >= 0.0)
    np.testing.assert_array_equal(states[1], [1.0, 0.07, 0.0])  # the input arrays are not modified
    np.testing.assert_allclose(u[:, 1], 0.0, atol=1e-12)  # the yaw did not change
    same, u2 = footprint_reference(COVER, chain, states[[0, 2]], inputs[:2], 0.1)
    np.testing.assert_array_equal(same, states[[0, 2]])


def test_a_tilted_pose_is_turned_to_fit_and_the_yaw_rate_follows():
    areas = make_areas([[0.0, -0.05, 2.0, 0.05]])
    chain = CorridorChain.build(areas, np.array([0]))
    states = np.array([[0.9, 0.0, 0.0], [1.0, 0.0, 0.6], [1.1, 0.0, 0.0]])  # 0.6 rad: discs at y +-0.09
    out, u = footprint_reference(COVER, chain, states, np.zeros((2, 2)), 0.1)
    assert np.all(COVER.clearance(chain, out) >= 0.0)
    assert abs(out[1, 2]) < 0.6 and np.hypot(*(out[1, :2] - states[1, :2])) <= 0.05 * np.sqrt(2) + 1e-12
    np.testing.assert_allclose(u[:, 1], np.diff(out[:, 2]) / 0.1, atol=1e-12)


def test_discs_controller_on_an_l_turn_into_a_narrow_passage_tracks_a_reference_that_fits():
    """A 0.25 m passage turning into a 0.1 m one: the path's tangent poses near the corner leave
    a disc centre outside both areas; the discs-mode controller's reference does not."""
    areas = make_areas([[0.0, 0.0, 2.0, 0.25], [1.9, 0.25, 2.0, 2.0]])
    plan = make_plan(areas, [0, 1], [[0.3, 0.125], [1.95, 0.125], [1.95, 1.8]])
    cfg = MPCConfig(footprint="discs", footprint_box_margin=0.0)
    plain = SAMPC(ROBOT, areas, plan, MPCConfig(box_margin=0.0))  # the disc mode keeps the plan's reference
    ctl = SAMPC(ROBOT, areas, plan, cfg, footprint=FP)
    assert np.any(COVER.clearance(ctl.chain, plain.ref_states) < 0.0)
    assert np.all(ctl.discs.clearance(ctl.chain, ctl.ref_states) >= 0.0)
    moved = np.any(ctl.ref_states != plain.ref_states, axis=1)
    assert moved.any() and np.all(COVER.clearance(ctl.chain, plain.ref_states[~moved]) >= 0.0)

