"""Tests of the footprint rectangle and its disc cover."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from sanav_mj.footprint import Footprint, robot_footprint
from sanav_mj.resources import robot_model_path
from sanav_mj.scene import robot_params


def test_robot_footprint_matches_the_circumradius_of_robot_params():
    model = mujoco.MjModel.from_xml_path(str(robot_model_path()))
    fp = robot_footprint(model)
    assert fp.circumradius == pytest.approx(robot_params(model).footprint_radius, abs=1e-12)
    assert fp.inradius == pytest.approx(0.215)
    assert fp.half_size == pytest.approx([0.25, 0.215])


@pytest.mark.parametrize("n", [1, 2, 3, 5])
@pytest.mark.parametrize("fp", [Footprint(-0.25, 0.25, -0.215, 0.215), Footprint(-0.1, 0.3, -0.4, 0.2)])
def test_discs_cover_the_rectangle_and_are_tight(n, fp):
    centres, r = fp.discs(n)
    g = np.linspace(0, 1, 41)
    pts = np.array([[fp.xmin + a * (fp.xmax - fp.xmin), fp.ymin + b * (fp.ymax - fp.ymin)] for a in g for b in g])
    d = np.min(np.linalg.norm(pts[:, None, :] - centres[None], axis=-1), axis=1)
    assert d.max() <= r + 1e-12
    # tight: a corner is exactly on the first disc's boundary
    assert d.max() == pytest.approx(r, abs=1e-12)
    if n == 1:
        assert r == pytest.approx(math.hypot(*fp.half_size))


def test_footprint_rejects_bad_input():
    with pytest.raises(ValueError, match="xmin < xmax"):
        Footprint(0.2, 0.1, -1, 1)
    with pytest.raises(ValueError, match="integer >= 1"):
        Footprint(-1, 1, -1, 1).discs(0)


def test_corners_at_a_pose():
    fp = Footprint(-0.25, 0.25, -0.2, 0.2)
    c = fp.corners((1.0, 2.0, math.pi / 2))
    np.testing.assert_allclose(c, [[1.2, 1.75], [1.2, 2.25], [0.8, 2.25], [0.8, 1.75]], atol=1e-12)
