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
from sanav_mj.control.safe_brake import choose_brake
from sanav_mj.control.sa_mpc import SAMPC
from sanav_mj.control.tracking import TrackingMPC, brake_inputs
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
    """:class:`SAMPC` whose braking fallback keeps every disc centre in the safe areas when
    some candidate manoeuvre does, and otherwise brakes straight.

    Given :attr:`free_areas` (the current safe areas; the sensing loop sets it), a braking
    step (status ``"fallback_stop"``: the solve was rejected and the shifted plan does not
    fit this step's problem, :meth:`TrackingMPC.shift_fits`) takes, in this order of
    preference, the first of these candidates whose predicted disc centres at stages 1..N
    all lie in the current safe areas (:func:`~sanav_mj.control.safe_brake.choose_brake`,
    within the acceptance tolerance):

    1. ``straight``: speed and yaw rate to zero at their rate bounds (the shortest stop);
    2. ``kept``: the rest of the plan being followed (the last accepted plan, or the last
       braking plan), then braking at the rate bounds (the warm start,
       :func:`~sanav_mj.control.problem.shift_inputs`), rolled out from the current state;
       only when it is within this step's input bounds (with the derating when
       ``fallback_derated``) and rate bounds (:meth:`kept_inputs`). An accepted plan ended at rest with its disc centres in
       observed-free boxes; the check against the *current* safe areas is what keeps that
       true when a scan has since removed free cells;
    3. ``steer``: the speed to zero at its rate bound while the yaw rate ramps towards
       +-w_max / 2, +-w_max (:func:`~sanav_mj.control.tracking.brake_inputs`).

    When none stays inside, the robot brakes straight, as it did before the check (``stats``
    counts ``brake_outside``; the chosen candidate's name is counted as ``brake_<name>``):
    taking the candidate whose worst centre lies least far outside instead turned the robot
    at up to 1.6 rad/s where no stop fitted and brought its corner within 6 mm of a cylinder
    (barn_0060 seed 3; braking straight there: 0.076 m). Each chosen plan becomes the plan
    followed, so the next braking step has its rest as its ``kept`` candidate: once a
    manoeuvre inside the safe areas is found, its continuation stays inside as long as the
    robot moves as predicted and those areas keep the cells it passes (up to the last padded
    step, which may still turn on the spot; docs/sensing.md states what is guaranteed).
    Without :attr:`free_areas` the robot brakes straight.

    Why not steer to the side deepest in the corridor (:meth:`SAMPC.brake_plan`): the
    robot brakes mostly after a scan made a corridor rectangle unsafe at speed, or after a
    replan whose corridor starts where the robot is; its chain is then too short to stop in,
    every steering candidate leaves it and the "deepest" one was a hard turn that swung the
    body's corners (5 cm of margin in this mode) into the obstacles beside the path: 2
    collisions in the first 77 BARN-like worlds (barn_0010, barn_0042, seed 0), both braking
    at 1.1-1.3 m/s while turning at up to 2 rad/s. Braking straight without a check carried
    the front disc centre 3.9 cm out of the safe areas (barn_0042 seed 3, seven rejected
    solves in a row from 1.43 m/s, true clearance 0.031 m; 2026-11-25, docs/results.md).

    Attributes:
        free_areas: a callable returning the current safe areas
            (:class:`~sanav_mj.mapping.safe_areas.SafeAreas`, their ``rects`` (R, 4) [m]),
            or None.
        last_brake: the :class:`~sanav_mj.control.safe_brake.BrakeChoice` of the last
            braking step (None before one, or without :attr:`free_areas`).
    """

    free_areas = None
    last_brake = None

    def straight_inputs(self) -> np.ndarray:
        """(N, 2) [m/s, rad/s] inputs braking at the rate limits from the previous input, the
        yaw rate ramping to 0."""
        k = np.arange(1, self.N + 1)
        a, al = float(self._rate_step[0]), float(self._rate_step[1])
        v0, w0 = float(self._u_prev[0]), float(self._u_prev[1])
        v = np.sign(v0) * np.maximum(abs(v0) - k * a, 0.0)
        w = np.sign(w0) * np.maximum(abs(w0) - k * al, 0.0)
        return np.stack((v, w), axis=1)

    def kept_inputs(self, prob) -> np.ndarray | None:
        """(N, 2) [m/s, rad/s] the rest of the plan being followed, then braking (the shifted
        plan of :meth:`TrackingMPC._guess_inputs`), when it lies within ``prob``'s fallback
        input bounds (``fb_lb``/``fb_ub``, (2N,)) and its increments, from the previous
        input on, within the current rate bounds (lowered by the traction limit since the
        plan was made, they may no longer hold), both within the acceptance tolerance; None
        without a plan or a problem, or outside those bounds."""
        if self._active is None or prob is None:
            return None
        u = TrackingMPC._guess_inputs(self)
        z = u.ravel()
        tol = self._check_tol
        if not (np.all(z >= prob.fb_lb - tol) and np.all(z <= prob.fb_ub + tol)):
            return None
        if np.any(np.abs(np.diff(np.vstack((self._u_prev, u)), axis=0)) > self._rate_step + tol):
            return None
        return u

    def brake_plan(self, x0: np.ndarray, prob=None) -> np.ndarray:
        """(N, 2) [m/s, rad/s] the braking manoeuvre from the state ``x0`` (3,) (see the class
        docstring); ``prob``: this step's problem (None: no ``kept`` candidate)."""
        straight = self.straight_inputs()
        if self.free_areas is None or not np.all(np.isfinite(x0)):
            return straight
        cands = [("straight", straight)]
        kept = self.kept_inputs(prob)
        if kept is not None:
            cands.append(("kept", kept))
        wm, gains = self.adaptation.brake_response(self.limits.w_max)
        for target in (0.5 * wm, -0.5 * wm, wm, -wm):
            cands.append(("steer", brake_inputs(self._u_prev, self._rate_step, self.N, target)))
        offsets = np.zeros((1, 2)) if self.discs is None else self.discs.offsets
        rects = np.asarray(self.free_areas().rects, dtype=float)
        choice = choose_brake(x0, cands, offsets, rects, self.dt, self._check_tol, gains)
        self.last_brake = choice
        self.stats.count("brake_" + choice.name)
        if not choice.inside:
            self.stats.count("brake_outside")
        return choice.u
