"""The robot's footprint seen from above: its bounding rectangle and a cover by discs.

The footprint is the union of the robot's collision geoms projected on the floor. Here it is
bounded by the axis-aligned rectangle (in the base frame) of the corners of every colliding
robot geom's bounding box (``geom_aabb``), the same corners
:func:`sanav_mj.scene.robot_params` uses for the circumscribed radius; for the packaged robot
(``models/diff_drive.xml``) that is the deck, 0.50 m x 0.43 m, centred on the base origin.

A rectangle of half sizes ``(hx, hy)`` with ``hx >= hy`` is covered by ``n`` equal discs
with centres on its long axis at ``x_k = -hx + (2k + 1) hx / n`` and radius
``sqrt((hx / n)^2 + hy^2)`` (each disc covers a ``2 hx / n`` long slice, corners included).
A robot whose disc centres each keep a distance of at least that radius from every obstacle
is collision-free: that is what lets a planner inflate obstacles by the small disc radius
instead of the circumscribed one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from sanav_mj.scene import ROBOT_BASE, robot_geom_ids


@dataclass(frozen=True)
class Footprint:
    """Axis-aligned bounding rectangle of the robot footprint in the base frame.

    Attributes:
        xmin, xmax: [m] extent along the base x axis (forward).
        ymin, ymax: [m] extent along the base y axis (left).
    """

    xmin: float
    xmax: float
    ymin: float
    ymax: float

    def __post_init__(self) -> None:
        vals = (self.xmin, self.xmax, self.ymin, self.ymax)
        if not all(math.isfinite(float(v)) for v in vals) or not (self.xmax > self.xmin and self.ymax > self.ymin):
            raise ValueError(f"Footprint: expected finite xmin < xmax and ymin < ymax [m], got {vals!r}")

    @property
    def center(self) -> np.ndarray:
        """(2,) [m] centre of the rectangle in the base frame."""
        return np.array([0.5 * (self.xmin + self.xmax), 0.5 * (self.ymin + self.ymax)])

    @property
    def half_size(self) -> np.ndarray:
        """(2,) [m] half length (x) and half width (y)."""
        return np.array([0.5 * (self.xmax - self.xmin), 0.5 * (self.ymax - self.ymin)])

    @property
    def circumradius(self) -> float:
        """[m] largest distance of a rectangle corner from the base origin."""
        return float(max(math.hypot(x, y) for x in (self.xmin, self.xmax) for y in (self.ymin, self.ymax)))

    @property
    def inradius(self) -> float:
        """[m] radius of the largest disc about the base origin inside the rectangle (0 if outside)."""
        return float(max(0.0, min(-self.xmin, self.xmax, -self.ymin, self.ymax)))

    def discs(self, n: int) -> tuple[np.ndarray, float]:
        """Cover of the rectangle by ``n`` equal discs along its long axis.

        Args:
            n: number of discs, >= 1.

        Returns:
            centres: (n, 2) [m] disc centres in the base frame.
            radius: [m] common radius; the union of the discs contains the rectangle.
        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"Footprint.discs: n must be an integer >= 1, got {n!r}")
        hx, hy = self.half_size
        c = self.center
        along_x = hx >= hy
        long_h, short_h = (hx, hy) if along_x else (hy, hx)
        t = -long_h + (2 * np.arange(n) + 1) * long_h / n
        centres = np.zeros((n, 2))
        centres[:, 0 if along_x else 1] = t
        return centres + c, float(math.hypot(long_h / n, short_h))

    def corners(self, pose) -> np.ndarray:
        """(4, 2) [m] world corners of the rectangle at ``pose`` (x [m], y [m], yaw [rad]), CCW."""
        x, y, th = (float(v) for v in pose)
        local = np.array([[self.xmin, self.ymin], [self.xmax, self.ymin], [self.xmax, self.ymax], [self.xmin, self.ymax]])
        c, s = math.cos(th), math.sin(th)
        return local @ np.array([[c, s], [-s, c]]) + np.array([x, y])


def robot_footprint(model: mujoco.MjModel) -> Footprint:
    """Bounding rectangle of the colliding robot geoms of a compiled model, in the base frame.

    Args:
        model: a compiled model containing the robot (body ``base``).
    """
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    base = model.body(ROBOT_BASE).id
    rot = data.xmat[base].reshape(3, 3)
    origin = data.xpos[base]
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    pts = []
    for g in robot_geom_ids(model):
        aabb = model.geom_aabb[g]
        local = aabb[:3] + corners * aabb[3:]
        world = local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        pts.append((world - origin) @ rot)
    p = np.concatenate(pts)
    return Footprint(float(p[:, 0].min()), float(p[:, 0].max()), float(p[:, 1].min()), float(p[:, 1].max()))
