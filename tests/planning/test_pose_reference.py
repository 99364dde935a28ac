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
