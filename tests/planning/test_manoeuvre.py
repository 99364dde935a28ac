"""Manoeuvres where the corridor reference leaves the disc rows (sanav_mj.planning.manoeuvre)."""

import math

import numpy as np
import pytest

from sanav_mj.planning.manoeuvre import (
    ManoeuvreConfig,
    bad_stretches,
    manoeuvre_route,
    primitive_poses,
    search_manoeuvre,
    union_admissible,
)

EPS = np.finfo(float).eps


def test_primitives_exact_end_poses():
    # straight move along yaw 0: x advances by ds
    p = primitive_poses((1.0, 2.0, 0.0), 0.1, 0.0, 4)
    np.testing.assert_allclose(p[-1], (1.1, 2.0, 0.0), atol=4 * EPS)
    np.testing.assert_allclose(p[:, 0], 1.0 + 0.1 * np.arange(1, 5) / 4, atol=4 * EPS)
    # quarter circle of radius 0.5 to the left from the origin ends at (0.5, 0.5, pi/2)
    q = primitive_poses((0.0, 0.0, 0.0), 0.5 * math.pi / 2, math.pi / 2, 3)
    np.testing.assert_allclose(q[-1], (0.5, 0.5, math.pi / 2), atol=8 * EPS)
    # backward arc: the reverse of the forward one
    b = primitive_poses(q[-1], -0.5 * math.pi / 2, -math.pi / 2, 3)
    np.testing.assert_allclose(b[-1], (0.0, 0.0, 0.0), atol=8 * EPS)
    # turn on the spot holds the position
    t = primitive_poses((0.3, -0.2, 1.0), 0.0, 0.2, 2)
    np.testing.assert_array_equal(t[:, :2], [[0.3, -0.2], [0.3, -0.2]])
    np.testing.assert_allclose(t[:, 2], [1.1, 1.2], atol=4 * EPS)


def test_search_free_space_goes_straight():
    cfg = ManoeuvreConfig(step=0.02)
    edges = search_manoeuvre(lambda P: np.ones(len(P), bool), (0.0, 0.0, 0.0), (0.1, 0.0, 0.0), cfg)
    assert edges is not None
    assert [e[1:] for e in edges[1:]] == [(0.02, 0.0)] * 5
    np.testing.assert_allclose(edges[-1][0], (0.1, 0.0, 0.0), atol=1e-12)


def test_search_backs_up_when_only_backward_is_free():
    # a slot |y| <= 5 mm, yaw within 2 deg of 0: only straight moves; the goal lies behind
    def adm(P):
        return (np.abs(P[:, 1]) <= 0.005) & (np.abs(P[:, 2]) <= math.radians(2))

    edges = search_manoeuvre(adm, (0.0, 0.0, 0.0), (-0.06, 0.0, 0.0), ManoeuvreConfig(goal_tol=0.005))
    assert [e[1:] for e in edges[1:]] == [(-0.02, 0.0)] * 3


def test_search_returns_none_when_boxed_in():
    def adm(P):
        return np.hypot(P[:, 0], P[:, 1]) <= 0.03  # a 3 cm pocket around the start

    assert search_manoeuvre(adm, (0.0, 0.0, 0.0), (0.5, 0.0, 0.0), ManoeuvreConfig(max_expansions=5000)) is None


def test_bad_stretches_anchors_and_merge():
    arc = np.arange(20) * 0.125  # exact binary fractions
    bad = np.zeros(20, bool)
    bad[[5, 6, 9]] = True
    # back 0.25 from sample 5 -> last good at arc <= 0.375: 3; ahead 0.25 after 6 -> first good >= 1.0: 8
    # the run at 9: back to <= 0.875: 7 (overlaps (3, 8): merged), ahead >= 1.375: 11
    assert bad_stretches(bad, arc, 0.25, 0.25) == [(3, 11)]
    assert bad_stretches(bad, arc, 0.0, 0.0) == [(4, 7), (8, 10)]
    bad[0] = True  # no good sample before it: left out
    assert bad_stretches(bad, arc, 0.0, 0.0)[0] == (4, 7)


# an L of two boxes 0.2 m wide: along x for x <= 0.6, along y for y >= -0.1 (touching along
# x in [0.4, 0.6]); a two-disc body with centres at +-0.15 m on its long axis
L_BOXES = np.array([[-0.5, -0.1, 0.6, 0.1], [0.4, -0.1, 0.6, 1.0]])
OFFSETS = np.array([[-0.15, 0.0], [0.15, 0.0]])


def test_union_admissible_exact_answers():
    f = union_admissible(L_BOXES, OFFSETS)
    poses = np.array([[0.0, 0.0, 0.0],        # both centres in the first box
                      [0.5, 0.5, math.pi / 2],  # both in the second
                      [0.5, 0.0, math.pi / 4],  # the corner at 45 deg: (0.606, 0.106) is outside both
                      [0.45, 0.0, 0.0],       # front centre at x = 0.6, on the closed edge
                      [0.46, 0.0, 0.0]])      # front centre at x = 0.61: outside
    assert f(poses).tolist() == [True, True, False, True, False]


def _l_reference():
    a = np.stack([np.arange(0, 21) * 0.025, np.zeros(21), np.zeros(21)], axis=1)
    b = np.stack([np.full(9, 0.5), np.zeros(9), np.arange(1, 10) * math.pi / 20], axis=1)
    c = np.stack([np.full(16, 0.5), np.arange(1, 17) * 0.025, np.full(16, math.pi / 2)], axis=1)
    return np.concatenate([a, b, c])


def test_manoeuvre_route_replaces_a_turn_on_the_spot_without_room():
    # along x to the corner, a turn on the spot there (its 45 deg poses leave the L), then along y
    states = _l_reference()
    f = union_admissible(L_BOXES, OFFSETS)
    assert not f(states).all()
    before = states.copy()
    cfg = ManoeuvreConfig(back=0.1, ahead=0.1, slack=0.0)
    poses, kinds, n = manoeuvre_route(L_BOXES, states, OFFSETS, cfg)
    np.testing.assert_array_equal(states, before)  # the given states untouched
    assert n == 1 and len(kinds) == len(poses) - 1 and set(kinds.tolist()) <= {-1, 0, 1}
    # every pose of the route and every pose sampled along its manoeuvre moves is admissible
    assert f(poses).all()
    np.testing.assert_array_equal(poses[-5:], states[-5:])  # the reference after it as it was
    np.testing.assert_array_equal(poses[:5], states[:5])


def test_manoeuvre_route_none_without_a_manoeuvre_and_unchanged_without_need():
    states = _l_reference()
    narrow = np.array([[-0.5, -0.1, 0.6, 0.1], [0.45, -0.1, 0.55, 1.0]])  # a 0.1 m vertical strip
    assert manoeuvre_route(narrow, states, np.array([[-0.3, 0.0], [0.3, 0.0]]),
                           ManoeuvreConfig(back=0.1, ahead=0.1, max_expansions=3000)) is None
    straight = states[:15]
    poses, kinds, n = manoeuvre_route(L_BOXES, straight, OFFSETS)
    assert n == 0 and kinds.tolist() == [1] * 14
    np.testing.assert_array_equal(poses, straight)


@pytest.mark.parametrize("field,value", [("step", 0.0), ("turn", -1.0), ("samples", 0), ("reverse_factor", 0.5),
                                         ("cusp_cost", -1.0), ("max_expansions", True)])
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        ManoeuvreConfig(**{field: value})


@pytest.mark.parametrize("field", ["sliver_width", "slow_clearance"])
def test_config_rejects_negative_sliver_settings(field):
    with pytest.raises(ValueError, match=field):
        ManoeuvreConfig(**{field: -0.01})
    assert getattr(ManoeuvreConfig(**{field: 0.0}), field) == 0.0
