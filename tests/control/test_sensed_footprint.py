"""The footprint mode's parts of the sensing loop (:mod:`sanav_mj.control.sensed_footprint`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sanav_mj.control.config import MPCConfig
from sanav_mj.control.sensed_footprint import SensedFootprint
from sanav_mj.footprint import Footprint
from sanav_mj.mapping.safe_areas import SafeAreas

BODY = Footprint(-0.25, 0.25, -0.2, 0.2)  # 0.5 m x 0.4 m, centred on the axle


def _areas() -> SafeAreas:
    # a wide room (short side 2 m) joined by a 0.1 m wide strip to a second room
    rects = np.array([[0.0, 0.0, 2.0, 2.0], [2.0, 0.95, 3.0, 1.05], [3.0, 0.0, 5.0, 2.0]])
    edges = np.array([[0, 1], [1, 2]])
    portals = np.array([[[2.0, 0.95], [2.0, 1.05]], [[3.0, 0.95], [3.0, 1.05]]])
    return SafeAreas(rects, edges, np.array([1.5, 1.5]), portals)


def test_disc_mode_is_the_position_alone_and_the_areas_as_they_are():
    fp = SensedFootprint.of(MPCConfig(), BODY, narrow_width=0.2)
    pose = np.array([1.25, -0.5, 0.7])
    pts = fp.own_points(pose)
    assert pts.shape == (1, 2) and np.array_equal(pts[0], pose[:2])
    assert fp.mpc_footprint is None
    areas = _areas()
    assert fp.planning_areas(areas) is areas


def test_discs_mode_own_points_are_the_disc_centres():
    fp = SensedFootprint.of(MPCConfig(footprint="discs"), BODY, narrow_width=0.2)
    assert fp.mpc_footprint is BODY
    # 3 discs along the 0.5 m side: centres at -1/3, 0, +1/3 of the half length 0.25 m ... x = -1/6, 0, 1/6 m
    pose = np.array([1.0, 2.0, math.pi / 2])
    pts = fp.own_points(pose)
    # a rotation and an addition of numbers up to 2 m: a few ulps of 2 (cos(pi/2) = 6e-17, not 0)
    np.testing.assert_allclose(pts, [[1.0, 2.0 - 1 / 6], [1.0, 2.0], [1.0, 2.0 + 1 / 6]], rtol=0,
                               atol=8 * np.finfo(float).eps)


def test_discs_mode_penalises_edges_through_narrow_places():
    fp = SensedFootprint.of(MPCConfig(footprint="discs", footprint_narrow_penalty=2.0), BODY, narrow_width=0.2)
    out = fp.planning_areas(_areas())
    # both edges touch the 0.1 m strip (narrower than 0.2 m): each weight + 2 m
    np.testing.assert_array_equal(out.weights, [3.5, 3.5])
    assert fp.planning_areas(None) is None
    # a width below the strip's: nothing is narrow
    wide = SensedFootprint.of(MPCConfig(footprint="discs"), BODY, narrow_width=0.05)
    np.testing.assert_array_equal(wide.planning_areas(_areas()).weights, [1.5, 1.5])


@pytest.mark.parametrize("footprint, width, match", [
    (None, 0.2, "needs the robot's Footprint"),
    (BODY, -0.1, "narrow_width"),
    (BODY, float("nan"), "narrow_width"),
])
def test_discs_mode_bad_arguments(footprint, width, match):
    with pytest.raises(ValueError, match=match):
        SensedFootprint.of(MPCConfig(footprint="discs"), footprint, narrow_width=width)
