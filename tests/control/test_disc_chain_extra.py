"""sanav_mj.control.disc_stages.member_chain_of with a plan's extra (sliver) boxes: known answers."""

from types import SimpleNamespace

import numpy as np
import pytest

from sanav_mj.control.disc_stages import member_chain_of


def test_member_chain_of_extra_boxes_and_their_areas():
    areas = SimpleNamespace(rects=np.array([[0.0, 0.0, 1.0, 1.0], [1.0, 0.0, 2.0, 1.0]]),
                            edges=np.array([[0, 1]]), free=None)
    extra = np.array([[0.8, 0.2, 1.2, 0.6]])
    ch = member_chain_of(areas, np.array([0, 3, 1]), 0.0, 0.0, extra, np.array([1]))
    np.testing.assert_array_equal(ch.boxes[1], extra[0])
    assert ch.rect_pair[1].tolist() == [1, 1]
    np.testing.assert_allclose(ch.advance[1], [0.8, 0.2, 1.0, 0.6])
    with pytest.raises(ValueError, match="member indices"):
        member_chain_of(areas, np.array([0, 3]), 0.0)


def test_member_chain_of_extra_boxes_need_their_areas():
    areas = SimpleNamespace(rects=np.array([[0.0, 0.0, 1.0, 1.0], [1.0, 0.0, 2.0, 1.0]]),
                            edges=np.array([[0, 1]]), free=None)
    with pytest.raises(ValueError, match="one safe area per extra box"):
        member_chain_of(areas, np.array([0, 3, 1]), 0.0, 0.0, np.array([[0.8, 0.2, 1.2, 0.6]]), None)
