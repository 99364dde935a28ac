"""MPCConfig's local-refinement and growth fields of the discs footprint mode: validated on construction."""

from __future__ import annotations

import pytest

from sanav_mj.control.config import MPCConfig


@pytest.mark.parametrize("kwargs, match", [
    (dict(footprint_refine=0), "footprint_refine"), (dict(footprint_refine=17), "footprint_refine"),
    (dict(footprint_refine=True), "footprint_refine"), (dict(footprint_refine=2.0), "footprint_refine"),
    (dict(footprint_refine_width=-0.01), "footprint_refine_width"),
    (dict(footprint_refine_width=float("inf")), "footprint_refine_width"),
    (dict(footprint_grow=-0.1), "footprint_grow"), (dict(footprint_grow=11.0), "footprint_grow"),
    (dict(footprint_grow=True), "footprint_grow"),
])
def test_refinement_fields_are_validated(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MPCConfig(**kwargs)


def test_refinement_fields_accept_their_range():
    c = MPCConfig(footprint="discs", footprint_refine=4, footprint_refine_width=0.0)
    assert (c.footprint_refine, c.footprint_refine_width) == (4, 0.0)


@pytest.mark.parametrize("value", [-0.01, 1.0, True, float("nan")])
def test_grow_tighten_is_validated(value):
    with pytest.raises(ValueError, match="footprint_grow_tighten"):
        MPCConfig(footprint_grow_tighten=value)
