"""Tests of the footprint disc rows for the MPC (NumPy vs CasADi twins, known answers)."""

from __future__ import annotations

import math

import casadi as cs
import numpy as np
import pytest

from sanav_mj.control.footprint import (
    disc_centres,
    disc_centres_cs,
    extreme_offsets,
    footprint_in_rect,
    footprint_rect_margin,
)
from sanav_mj.footprint import Footprint

FP = Footprint(-0.25, 0.25, -0.215, 0.215)


def test_twins_agree():
    offsets, _ = FP.discs(3)
    xs = cs.SX.sym("x", 3)
    f = cs.Function("f", [xs], [cs.horzcat(*disc_centres_cs(xs, offsets)).T])
    rng = np.random.default_rng(0)
    for x in rng.uniform([-5, -5, -7], [5, 5, 7], (20, 3)):
        np.testing.assert_allclose(np.array(f(x)), disc_centres(x, offsets), rtol=0, atol=1e-14)


def test_known_centres():
    offsets, r = FP.discs(3)
    c = disc_centres(np.array([1.0, 2.0, math.pi / 2]), offsets)
    np.testing.assert_allclose(c, [[1.0, 2.0 - 1 / 6], [1.0, 2.0], [1.0, 2.0 + 1 / 6]], atol=1e-15)
    assert r == pytest.approx(math.hypot(0.25 / 3, 0.215))


def test_extreme_offsets():
    offsets, _ = FP.discs(3)
    np.testing.assert_allclose(extreme_offsets(offsets), offsets[[0, 2]])
    np.testing.assert_allclose(extreme_offsets(offsets[:1]), offsets[:1])
    with pytest.raises(ValueError, match="collinear"):
        extreme_offsets([[0, 0], [1, 0], [0.5, 0.2]])
    with pytest.raises(ValueError, match=r"\(n, 2\)"):
        extreme_offsets([1.0, 2.0])


def test_extreme_discs_in_a_rect_imply_all_and_the_footprint():
    """Known answer + sampled check: end centres inside a rectangle shrunk by r from the free
    space put the whole rectangle footprint inside that free space."""
    offsets, r = FP.discs(3)
    ends = extreme_offsets(offsets)
    free = np.array([0.0, 0.0, 1.2, 0.55])  # a passage 0.55 m wide
    inner = free + np.array([r, r, -r, -r])
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(4000):
        x = np.array([rng.uniform(0, 1.2), rng.uniform(0, 0.55), rng.uniform(-0.3, 0.3)])
        if footprint_in_rect(x, inner, ends):
            seen += 1
            assert footprint_in_rect(x, inner, offsets)
            corners = FP.corners(x)
            assert np.all(corners >= free[:2] - 1e-12) and np.all(corners <= free[2:] + 1e-12)
    assert seen > 50
    # driving straight along the passage centre fits; turned by 90 degrees it does not
    assert footprint_in_rect(np.array([0.6, 0.275, 0.0]), inner, ends)
    assert not footprint_in_rect(np.array([0.6, 0.275, math.pi / 2]), inner, ends)
    assert footprint_rect_margin(np.array([0.6, 0.275, 0.0]), inner, ends) == pytest.approx(0.275 - 0.215 - (r - 0.215))
