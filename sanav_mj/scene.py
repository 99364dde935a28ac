"""Load a scenario (MJCF path or built-in name) into a :class:`Scenario`.

A scenario file includes the robot (``models/diff_drive.xml``) and adds a floor plane, static
obstacle geoms and ``<custom>`` numerics ``start`` (x [m], y [m], yaw [rad]) and ``goal``
(x [m], y [m]). See the design contract for the format.

Everything downstream (mapping, planning, control, sim) works from the :class:`Scenario`
returned here; nothing downstream re-parses the XML.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import mujoco
import numpy as np

ObstacleKind = Literal["box", "cylinder", "capsule"]


class ScenarioError(ValueError):
    """A scenario file or name is unusable. The message is one line naming the file and the rule."""


@dataclass(frozen=True)
class Obstacle:
    """A static obstacle in the world frame, projected to the floor plane.

    Attributes:
        name: geom name (``geom_<id>`` when the file leaves it unnamed).
        kind: ``"box"`` (any yaw), ``"cylinder"`` or ``"capsule"`` (both standing upright).
        center: (2,) [m] x, y of the geom centre.
        yaw: [rad] rotation about the world z axis (boxes; 0 for round geoms).
        half_size: (2,) [m] half extents along the geom's own x, y axes for boxes;
            ``(radius, radius)`` for cylinders and capsules.
        height: [m] top of the geom above the floor (informational).
        geom_id: MuJoCo geom id in the scenario's compiled model.
    """

    name: str
    kind: ObstacleKind
    center: np.ndarray
    yaw: float
    half_size: np.ndarray
    height: float
    geom_id: int

    def corners(self) -> np.ndarray:
        """(4, 2) [m] corners of a box's footprint, counter-clockwise. Boxes only."""
        if self.kind != "box":
            raise ValueError(f"corners() is defined for boxes, got a {self.kind}")
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        rot = np.array([[c, -s], [s, c]])
        hx, hy = self.half_size
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        return local @ rot.T + self.center


@dataclass(frozen=True)
class RobotParams:
    """Nominal robot parameters, read from the compiled model by name (never literals).

    Attributes:
        wheel_radius: [m] driven-wheel radius.
        track: [m] distance between the two driven wheels' contact points.
        footprint_radius: [m] radius of the circle around the base centre that covers the
            whole robot footprint (used to inflate obstacles).
        wheel_speed_max: [rad/s] actuator velocity limit of each wheel.
        v_max: [m/s] top forward speed.
        w_max: [rad/s] top yaw rate.
        a_max: [m/s^2] linear acceleration limit used by planning and control.
        alpha_max: [rad/s^2] yaw acceleration limit used by planning and control.
    """

    wheel_radius: float
    track: float
    footprint_radius: float
    wheel_speed_max: float
    v_max: float
    w_max: float
    a_max: float
    alpha_max: float


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario.

    Attributes:
        name: scenario name (file stem).
        path: absolute path of the MJCF file.
        model: compiled nominal ``mujoco.MjModel`` (never mutate: mismatch works on a copy).
        obstacles: static obstacles in the world frame.
        start: (3,) [m, m, rad] start pose x, y, yaw.
        goal: (2,) [m] goal position.
        bounds: (4,) [m] workspace ``xmin, ymin, xmax, ymax`` (the floor rectangle).
        robot: nominal robot parameters.
    """

    name: str
    path: Path
    model: mujoco.MjModel = field(repr=False)
    obstacles: tuple[Obstacle, ...]
    start: np.ndarray
    goal: np.ndarray
    bounds: np.ndarray
    robot: RobotParams


def load_scenario(spec: str | Path, margin: float = 0.05) -> Scenario:
    """Load a scenario from a path to an MJCF file or the name of a built-in one.

    Args:
        spec: path to an ``.xml`` file, or a built-in name such as ``"u_shape"``.
        margin: [m] extra clearance beyond the footprint radius used to check that start
            and goal are not inside an inflated obstacle.

    Raises:
        ScenarioError: one-line message naming the file and what is wrong.
    """
    raise NotImplementedError
