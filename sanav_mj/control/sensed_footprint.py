"""SA-MPC's footprint mode (``MPCConfig.footprint``) on the map the lidar builds.

The sensed map (:class:`~sanav_mj.mapping.sensed_map.SensedMap`) is inflated by what the
mode needs (``"disc"``: the circumscribed radius + margin; ``"discs"``: the disc cover's
radius + ``footprint_margin``, set by the caller). :class:`SensedFootprint` holds the rest:

- the **own points**: where the robot counts as standing in safe space (its cell checks:
  waiting before the first plan, clearing the body when it is not safe): the base origin
  (``"disc"``), or every disc centre of the cover (``"discs"``: each centre's hard rows must
  lie in observed-free rectangles of a map inflated by the disc radius, so the first plan
  waits until every centre is in a safe cell);
- the footprint handed to :class:`~sanav_mj.control.sa_mpc.SAMPC` (``"discs"``: the body
  rectangle whose disc cover gives the constrained points; ``"disc"``: None);
- the corridor search's areas: ``"discs"`` adds ``footprint_narrow_penalty`` to every edge
  through a place narrower than ``narrow_width`` (as the known-map mode does,
  :func:`sanav_mj.planning.corridor.penalise_narrow`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sanav_mj.control.config import MPCConfig
from sanav_mj.control.sa_mpc import SAMPC
from sanav_mj.footprint import Footprint
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.corridor import penalise_narrow

__all__ = ["SensedFootprint", "StraightBrakeSAMPC"]


@dataclass(frozen=True)
class SensedFootprint:
    """The footprint mode's parts of the sensing loop.

    Attributes:
        offsets: (P, 2) [m] own points in the base frame (x forward, y left); None: the base
            origin alone (``"disc"``).
        mpc_footprint: the footprint rectangle the SA-MPC needs (``"discs"``), else None.
        narrow_width: [m] passages narrower than this get ``narrow_penalty`` per corridor edge.
        narrow_penalty: [m] (0: the corridor search runs on the areas as they are).
    """

    offsets: np.ndarray | None
    mpc_footprint: Footprint | None
    narrow_width: float = 0.0
    narrow_penalty: float = 0.0

    @staticmethod
    def of(mpc: MPCConfig, footprint: Footprint | None, narrow_width: float = 0.0) -> SensedFootprint:
        """The parts for ``mpc.footprint``.

        Args:
            mpc: the SA-MPC settings (``footprint``, ``footprint_discs``,
                ``footprint_narrow_penalty``).
            footprint: the robot's body rectangle (required in ``"discs"`` mode).
            narrow_width: [m] >= 0, the width below which the circumscribed disc does not
                fit in the discs map, ``2 (R + margin - inflation)`` (``"discs"`` only).

        Raises:
            ValueError: ``"discs"`` without a footprint, or a negative / non-finite width.
        """
        if mpc.footprint != "discs":
            return SensedFootprint(None, None)
        if not isinstance(footprint, Footprint):
            raise ValueError(f"footprint: MPCConfig.footprint='discs' with the lidar needs the robot's Footprint "
                             f"(SensingConfig.footprint), got {type(footprint).__name__}")
        if not (isinstance(narrow_width, (int, float)) and math.isfinite(narrow_width) and narrow_width >= 0):
            raise ValueError(f"narrow_width: expected a finite number >= 0 [m], got {narrow_width!r}")
        offsets, _ = footprint.discs(mpc.footprint_discs)
        return SensedFootprint(np.asarray(offsets, dtype=float), footprint, float(narrow_width),
                               float(mpc.footprint_narrow_penalty))

    def own_points(self, pose: np.ndarray) -> np.ndarray:
        """(P, 2) [m] world positions of the own points at ``pose`` (3,) [m, m, rad] (the
        position itself, unchanged, in ``"disc"`` mode)."""
        pose = np.asarray(pose, dtype=float)
        if self.offsets is None:
            return pose[None, :2]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        o = self.offsets
        return np.column_stack((pose[0] + c * o[:, 0] - s * o[:, 1], pose[1] + s * o[:, 0] + c * o[:, 1]))

    def planning_areas(self, areas: SafeAreas | None) -> SafeAreas | None:
        """The areas the corridor search runs on (``areas`` itself unless a narrow-passage
        penalty applies)."""
        if areas is None or self.narrow_penalty == 0 or self.narrow_width == 0:
            return areas
        return penalise_narrow(areas, self.narrow_width, self.narrow_penalty)


class StraightBrakeSAMPC(SAMPC):
    """:class:`SAMPC` whose braking fallback keeps the heading: speed and yaw rate both go to
    zero at their rate bounds (the first of :meth:`SAMPC.brake_plan`'s five candidates,
    without the steering to the side whose path stays deepest in the corridor).

    Why, with the lidar in ``"discs"`` mode: the robot brakes mostly after a scan made a
    corridor rectangle unsafe at speed (``blocked``); the new corridor starts where the robot
    is and is too short to stop in, so every steering candidate leaves its boxes and the
    "deepest" one was a hard turn that swung the body's corners (5 cm of margin in this
    mode) into the obstacles beside the path: 2 collisions in the first 77 BARN-like worlds
    (barn_0010, barn_0042, seed 0), both braking at 1.1-1.3 m/s while turning at up to 2
    rad/s. The path the robot was on had been planned inside observed-free space; keeping
    its heading while braking stays close to it.
    """

    def brake_plan(self, x0: np.ndarray) -> np.ndarray:
        """(N, 2) [m/s, rad/s] inputs braking at the rate limits from the previous input, the
        yaw rate ramping to 0 (``x0`` (3,) unused: the plan does not depend on the state)."""
        k = np.arange(1, self.N + 1)
        a, al = float(self._rate_step[0]), float(self._rate_step[1])
        v0, w0 = float(self._u_prev[0]), float(self._u_prev[1])
        v = np.sign(v0) * np.maximum(abs(v0) - k * a, 0.0)
        w = np.sign(w0) * np.maximum(abs(w0) - k * al, 0.0)
        return np.stack((v, w), axis=1)
