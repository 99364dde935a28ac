"""The time-parametrised reference that controllers track (output of planning)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Reference:
    """A reference trajectory sampled at the MPC step.

    Attributes:
        dt: [s] sampling period (the MPC step).
        states: (K, 3) [m, m, rad] reference x, y, yaw; yaw is unwrapped (continuous).
        inputs: (K, 2) [m/s, rad/s] reference v, w; the last sample is (0, 0) at the goal.
        area: (K,) int index into ``SafeAreas.rects`` of a safe area containing each sample;
            the areas follow the corridor order (a sample's corridor position is never before
            the previous sample's); consecutive samples share an area or lie in consecutive
            corridor areas, except that a corridor area the reference crosses in less than
            one step can be stepped over (no sample falls inside it).
        stops: None, or (S,) int increasing sample indices where the reference comes to rest
            between motions of different kinds (a pose route's cusps: forward / backward /
            turning on the spot); SA-MPC's horizon does not look past the next stop until
            the robot has reached it.
    """

    dt: float
    states: np.ndarray
    inputs: np.ndarray
    area: np.ndarray
    stops: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.states.shape[0])


@dataclass(frozen=True)
class Plan:
    """Result of planning from a start pose to a goal through the safe areas.

    Attributes:
        ok: False when no path exists; then ``reason`` says why and the arrays are empty.
        reason: ``"ok"`` or ``"no_path"`` (or another short machine-readable reason).
        corridor: (C,) int safe-area indices from the start area to the goal area.
        goal: (2,) [m] goal actually used (projected into the safe areas when needed).
        waypoints: (W, 2) [m] start, portal crossings, goal.
        path: (M, 2) [m] uniformly arc-length-interpolated waypoint polyline (eq. 5-6).
        smoothed: (S, 2) [m] dense samples of the smoothed B-spline (eq. 7).
        reference: the time-parametrised reference, or None when ``ok`` is False.
        info: diagnostics (plain numbers and strings): e.g. the smoothing weight finally
            used, how often it was halved, the length of path replaced by the interpolated
            polyline, path length and duration, per-stage wall times.
        disc_corridors: None, or (a pose route's plan, :func:`sanav_mj.planning.
            pose_reference.route_plan`) one (L_d,) int chain per disc of the footprint's
            cover: indices into :func:`sanav_mj.planning.pose_search.member_boxes` (the
            safe areas, then one portal bridge per edge of ``SafeAreas.edges``) of the
            member boxes that disc's centre walks, in order.
        extra_members: None, or (X, 4) [m] boxes of free cells the per-disc chains may also
            index (after the member boxes: index ``R + E + x`` is ``extra_members[x]``), the
            sliver boxes of :func:`sanav_mj.planning.pose_reference.sliver_boxes`.
        extra_areas: None, or (X,) int the safe area each extra box belongs to (for J_SA).
    """

    ok: bool
    reason: str
    corridor: np.ndarray
    goal: np.ndarray
    waypoints: np.ndarray
    path: np.ndarray
    smoothed: np.ndarray
    reference: Reference | None
    info: dict[str, Any] = field(default_factory=dict)
    disc_corridors: tuple[np.ndarray, ...] | None = None
    extra_members: np.ndarray | None = None
    extra_areas: np.ndarray | None = None
