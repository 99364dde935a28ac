"""Stage boxes tightened by the prediction error with a capped relaxation (``stages.tighten_relax``): known answers."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.control.stages import relax_boxes, tighten_relax


# ---------------------------------------------------------------- tighten_relax (capped relaxation)



def _s(n=3):
    return np.tile(np.array([0.0, 0.0, 1.0, 0.4]), (n, 1))


def test_tighten_relax_inside_the_tightened_box_is_the_tightened_box():
    out, exc = tighten_relax(_s(), np.array([0.5, 0.2]), 0.03)
    np.testing.assert_allclose(out, np.tile([0.03, 0.03, 0.97, 0.37], (3, 1)), atol=1e-15)
    assert exc == 0.0


def test_tighten_relax_follows_within_the_untightened_box():
    # 0.01 beyond the tightened top side (0.37): stages 1..N widened to 0.38 < 0.4
    out, exc = tighten_relax(_s(), np.array([0.5, 0.38]), 0.03)
    np.testing.assert_allclose(out[1:, 3], 0.38, atol=1e-15)
    np.testing.assert_allclose(out[1:, [0, 1, 2]], np.tile([0.03, 0.03, 0.97], (2, 1)), atol=1e-15)
    assert exc == 0.0  # inside the untightened box: no excursion for the derating


def test_tighten_relax_is_capped_at_the_untightened_box():
    p0 = np.array([[0.5, 0.43], [1.02, 0.1]])  # 0.03 above, 0.02 right of the untightened box
    out, exc = tighten_relax(_s(), p0, 0.03)
    np.testing.assert_allclose(out[1:], np.tile([0.03, 0.03, 1.0, 0.4], (2, 1)), atol=1e-15)
    assert exc == pytest.approx(0.03, abs=1e-15)  # the farthest point outside the untightened box
    # the plain relaxation follows the points out; so does the capped one at rest (follow)
    plain, _ = relax_boxes(_s(), p0)
    np.testing.assert_allclose(plain[1:, 2:], np.tile([1.02, 0.43], (2, 1)), atol=1e-15)
    fol, _ = tighten_relax(_s(), p0, 0.03, follow=True)
    np.testing.assert_allclose(fol[1:], np.tile([0.03, 0.03, 1.02, 0.43], (2, 1)), atol=1e-15)


def test_tighten_relax_takes_at_most_a_quarter_of_a_narrow_box():
    b = np.tile(np.array([0.0, 0.0, 1.0, 0.04]), (2, 1))  # 4 cm wide: at most 1 cm per side
    out, _ = tighten_relax(b, np.array([0.5, 0.02]), 0.03)
    np.testing.assert_allclose(out[:, 1::2], np.tile([0.01, 0.03], (2, 1)), atol=1e-15)
