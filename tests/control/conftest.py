"""Fixtures of the control tests: hand-made L- and U-shaped corridors (see mpc_cases.py)."""

from __future__ import annotations

import pytest
from mpc_cases import L_RECTS, L_WAYPOINTS, U_RECTS, U_WAYPOINTS, make_areas, make_plan


@pytest.fixture(scope="session")
def l_case():
    """L corridor: R0 = [0,4]x[0,1] then R1 = [3,4]x[1,4]; a third area off the corridor."""
    areas = make_areas(L_RECTS)
    return areas, make_plan(areas, [0, 1], L_WAYPOINTS)


@pytest.fixture(scope="session")
def u_case():
    """U corridor: up the left leg, across the top, down the right leg."""
    areas = make_areas(U_RECTS)
    return areas, make_plan(areas, [0, 1, 2], U_WAYPOINTS)
