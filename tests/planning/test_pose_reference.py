"""Known answers of sanav_mj.planning.pose_reference.member_chain's tolerance."""

import numpy as np

from sanav_mj.planning.pose_reference import member_chain

#: two overlapping boxes [m]: x in [0, 1] and x in [0.9, 2], y in [0, 1]
BOXES = np.array([[0.0, 0.0, 1.0, 1.0], [0.9, 0.0, 2.0, 1.0]])


def _walk(y_first: float) -> np.ndarray:
    """A disc centre walking along y = 0.5 from x = 0.5 to 1.5 every 1 cm, its first point at ``y_first``."""
    pts = np.column_stack((np.arange(0.5, 1.5 + 1e-9, 0.01), np.full(101, 0.5)))
    pts[0, 1] = y_first
    return pts


def test_member_chain_inside():
    assert member_chain(BOXES, _walk(0.5), 0.0).tolist() == [0, 1]
    assert member_chain(BOXES, _walk(0.5), 0.02).tolist() == [0, 1]


def test_member_chain_grazing_point_at_zero_margin():
    # 2 mm outside box 0 (within the 5 mm tolerance): accepted also with box_margin 0
    # (it was clipped to a 0 shrink there, so the tolerance vanished and the chain was None)
    assert member_chain(BOXES, _walk(1.002), 0.0).tolist() == [0, 1]
    # 6 mm outside: beyond the tolerance
    assert member_chain(BOXES, _walk(1.006), 0.0) is None


def test_member_chain_margin_unchanged_above_tolerance():
    # margin 0.02: the stay boxes are shrunk by 0.015 (margin - tol); 1.5 cm from the edge is the limit
    assert member_chain(BOXES, _walk(0.985), 0.02).tolist() == [0, 1]
    assert member_chain(BOXES, _walk(0.986), 0.02) is None


#: a diagonal staircase [m]: B is A moved one unit along (1, -1), C two units
STAIRS = np.array([[0.0, 0.0, 3.0, 3.0], [1.0, -1.0, 4.0, 2.0], [2.0, -2.0, 5.0, 1.0]])


def _diagonal_walk() -> np.ndarray:
    """Points along y = 2 - x from x = 0.5 to 4 every 0.25 m."""
    x = np.arange(0.5, 4.0 + 1e-9, 0.25)
    return np.column_stack((x, 2.0 - x))


def test_member_chain_longest_run_jumps_to_the_corner_square():
    # leaving A at (2.25, -0.25): B holds the points up to x = 3, C up to x = 4: C is taken,
    # and A and C meet in a 1 x 1 corner square
    assert member_chain(STAIRS, _diagonal_walk(), 0.0).tolist() == [0, 2]


def test_member_chain_overlap_rule_in_slivers():
    # with the overlap rule: A meets B in a 2 x 2 square, C in 1 x 1: B, then C
    pts = _diagonal_walk()
    assert member_chain(STAIRS, pts, 0.0, overlap_at=np.ones(len(pts), bool)).tolist() == [0, 1, 2]
    # the rule applies only at the points marked
    assert member_chain(STAIRS, pts, 0.0, overlap_at=np.zeros(len(pts), bool)).tolist() == [0, 2]


def test_sliver_boxes_only_where_no_wide_member_holds_the_point():
    from sanav_mj.mapping.grow import FreeCells
    from sanav_mj.mapping.occupancy import OccupancyGrid
    from sanav_mj.planning.pose_reference import sliver_boxes

    r, c = np.mgrid[0:8, 0:8]
    occ = ~((c - r >= 0) & (c - r <= 3))  # free: a diagonal strip, 0 <= column - row <= 3
    grid = OccupancyGrid(occ, 0.1, np.zeros(2), 0.0, np.array([0.0, 0.0, 0.8, 0.8]))
    cells = FreeCells.of(grid)
    members = np.array([[0.0, 0.0, 0.4, 0.1],    # row 0, columns 0-3: 0.1 m thin
                        [0.3, 0.3, 0.7, 0.4]])   # row 3, columns 3-6: 0.1 m thin
    pts = np.array([[0.05, 0.05], [0.55, 0.32], [0.56, 0.33], [0.35, 0.35]])
    # width 0.1: both members are wide, every point is in one or none: (0.55, 0.32) and
    # (0.56, 0.33) are in member 1, (0.05, 0.05) in member 0, (0.35, 0.35) in member 1
    assert sliver_boxes(members, pts, cells, 0.1, 1.0).shape == (0, 4)
    # width 0.2: no member is wide: a box per distinct grown box, in order of the points
    out = sliver_boxes(members, pts, cells, 0.2, 1.0)
    np.testing.assert_allclose(out[1], [0.4, 0.3, 0.7, 0.5], atol=1e-12)  # the two points in cell (3, 5)
    assert out.shape == (3, 4)
    for p, b in zip(pts[[0, 1, 3]], out):
        assert b[0] <= p[0] <= b[2] and b[1] <= p[1] <= b[3]

