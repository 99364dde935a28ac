"""The MuJoCo robot as a plant: (v, w) in, pose / velocity / contacts / ranges out.

One :class:`Plant` wraps an ``MjModel`` / ``MjData`` pair for one episode. Commands are
converted to wheel velocity set-points with the NOMINAL wheel radius and track
(``scenario.robot``), so a mismatched model (a modified copy passed as ``model``) shows up as
tracking error, as it would on a real robot. Everything is read from the model by name.

Readouts after :meth:`Plant.advance` are consistent with the final state: ``advance`` ends
with ``mj_forward`` so positions, contacts and sensors belong to the same ``qpos``.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from sanav_mj.scene import (
    ROBOT_BASE,
    WHEEL_NAMES,
    RobotParams,
    Scenario,
    robot_geom_ids,
    robot_params,
    robot_qpos,
)

#: Name of the site that is the origin of :meth:`Plant.ray_ranges`.
LIDAR_SITE = "lidar"

#: [m/s^2] bound on the robot's acceleration used to decide whether an obstacle contact is
#: possible within one :meth:`Plant.advance` (2 g, well above the torque and traction limits).
_ACCEL_BOUND = 20.0
#: [m] slack for tilt and contact softness in that decision.
_CONTACT_SLACK = 0.05


class Plant:
    """One episode of the MuJoCo differential-drive robot in a scenario.

    Args:
        scenario: the loaded scenario (obstacles, nominal robot parameters).
        model: the model to simulate; ``None`` uses ``scenario.model``. A modified copy
            (mismatch) must keep the scenario's names and geom numbering.

    Attributes:
        scenario: the scenario.
        model, data: the simulated MuJoCo model and its data.
        robot: nominal :class:`~sanav_mj.scene.RobotParams` used for command conversion.
        nonfinite_commands: number of :meth:`set_wheel_command` calls with a non-finite input.
        last_command_nonfinite: whether the last command was non-finite (replaced by 0, 0).
        last_command_scaled: whether the last command exceeded the wheel limits and was scaled.
    """

    def __init__(self, scenario: Scenario, model: mujoco.MjModel | None = None) -> None:
        self.scenario = scenario
        self.model = scenario.model if model is None else model
        m = self.model
        if m.ngeom != scenario.model.ngeom:
            raise ValueError(
                f"model must have the scenario's geoms: {m.ngeom} geoms, scenario has {scenario.model.ngeom}"
            )
        self.data = mujoco.MjData(m)
        self.robot: RobotParams = scenario.robot
        self.timestep = float(m.opt.timestep)

        self._base = m.body(ROBOT_BASE).id
        free = int(m.body_jntadr[self._base])
        self._qadr = int(m.jnt_qposadr[free])
        self._vadr = int(m.jnt_dofadr[free])
        self._wheel_dof = np.array([m.jnt_dofadr[m.joint(n).id] for n in WHEEL_NAMES])
        self._act = np.array([m.actuator(n).id for n in WHEEL_NAMES])
        self._ctrl_lo = m.actuator_ctrlrange[self._act, 0].copy()
        self._ctrl_hi = m.actuator_ctrlrange[self._act, 1].copy()
        self._lidar = m.site(LIDAR_SITE).id

        self._robot_geoms = robot_geom_ids(m)
        # footprint of the SIMULATED robot (a mismatched copy may be larger than nominal),
        # for the lower bounds that decide when exact contact / distance checks are needed
        self._reach_radius = max(self.robot.footprint_radius, robot_params(m).footprint_radius)
        self._obstacle_geoms = np.array([o.geom_id for o in scenario.obstacles], dtype=int)
        self._is_robot = np.zeros(m.ngeom, dtype=bool)
        self._is_robot[self._robot_geoms] = True
        self._is_obstacle = np.zeros(m.ngeom, dtype=bool)
        self._is_obstacle[self._obstacle_geoms] = True

        # 2-D footprint geometry of the obstacles (in scenario order), for the cheap
        # footprint clearance: boxes as rectangles, round geoms as rectangles of zero half
        # size rounded by their radius.
        obs = scenario.obstacles
        self._obs_c = np.array([o.center for o in obs], dtype=float).reshape(-1, 2)
        self._obs_rot = np.array([[math.cos(o.yaw), math.sin(o.yaw)] for o in obs], dtype=float).reshape(-1, 2)
        self._obs_h = np.array([o.half_size if o.kind == "box" else (0.0, 0.0) for o in obs],
                               dtype=float).reshape(-1, 2)
        self._obs_round = np.array([0.0 if o.kind == "box" else o.half_size[0] for o in obs], dtype=float)

        # Ray casting: one mj_multiRay call restricted to the obstacles' geom groups; rays
        # that hit something else (a robot geom sharing a group, decoration) are redone
        # exactly against the obstacles alone. mj_ray ignores invisible geoms (alpha 0), so
        # such obstacles force the exact path.
        groups = np.unique(m.geom_group[self._obstacle_geoms]) if len(obs) else np.array([], dtype=int)
        self._ray_groups = np.zeros(6, dtype=np.uint8)
        self._ray_groups[groups[(groups >= 0) & (groups < 6)]] = 1
        visible = all(m.geom_rgba[g, 3] > 0 for g in self._obstacle_geoms)
        self._rays_fast = bool(visible and np.all((groups >= 0) & (groups < 6)))

        self.nonfinite_commands = 0
        self.last_command_nonfinite = False
        self.last_command_scaled = False
        self._advance_contacts = 0
        self.reset(scenario.start)

    # ------------------------------------------------------------------ state

    @property
    def time(self) -> float:
        """[s] simulation time since :meth:`reset`."""
        return float(self.data.time)

    def reset(self, pose: np.ndarray | None = None) -> None:
        """Put the robot at rest at ``pose``, wheels on the floor, commands zero, time 0.

        Args:
            pose: (3,) [m, m, rad] x, y, yaw; ``None`` uses the scenario start.
        """
        pose = self.scenario.start if pose is None else np.asarray(pose, dtype=float).reshape(3)
        if not np.all(np.isfinite(pose)):
            raise ValueError(f"pose must be finite (3,) [m, m, rad], got {pose.tolist()}")
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = robot_qpos(self.model, pose)
        mujoco.mj_forward(self.model, self.data)
        self.nonfinite_commands = 0
        self.last_command_nonfinite = False
        self.last_command_scaled = False
        self._advance_contacts = 0

    def pose(self) -> np.ndarray:
        """(3,) [m, m, rad] x, y of the base origin (wheel-axle midpoint) and yaw in (-pi, pi]."""
        q = self.data.qpos
        w, x, y, z = q[self._qadr + 3 : self._qadr + 7]
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return np.array([q[self._qadr], q[self._qadr + 1], yaw])

    def body_velocity(self) -> np.ndarray:
        """(2,) [m/s, rad/s] measured forward speed (along the base x axis) and world yaw rate."""
        qv = self.data.qvel
        rot = self.data.xmat[self._base].reshape(3, 3)
        v = float(qv[self._vadr : self._vadr + 3] @ rot[:, 0])  # free joint: world-frame linear
        w = float(rot[2] @ qv[self._vadr + 3 : self._vadr + 6])  # free joint: body-frame angular
        return np.array([v, w])

    def wheel_speeds(self) -> np.ndarray:
        """(2,) [rad/s] measured left, right wheel angular speeds (positive rolls forward)."""
        return self.data.qvel[self._wheel_dof].copy()

    # ------------------------------------------------------------------ input

    def set_wheel_command(self, v: float, w: float) -> np.ndarray:
        """Hold wheel velocity set-points for forward speed ``v`` and yaw rate ``w``.

        Left/right wheel speeds ``(v -+ w * track / 2) / wheel_radius`` use the NOMINAL
        parameters. If either exceeds its actuator ``ctrlrange``, both are scaled by the same
        factor, which keeps the commanded path curvature (flag ``last_command_scaled``). A
        non-finite ``v`` or ``w`` becomes a stop (0, 0) and is counted.

        Args:
            v: [m/s] forward speed.
            w: [rad/s] yaw rate.

        Returns:
            (2,) [rad/s] the left, right wheel set-points applied.
        """
        v, w = float(v), float(w)
        self.last_command_nonfinite = not (math.isfinite(v) and math.isfinite(w))
        if self.last_command_nonfinite:
            self.nonfinite_commands += 1
            v, w = 0.0, 0.0
        half = 0.5 * self.robot.track * w
        cmd = np.array([v - half, v + half]) / self.robot.wheel_radius
        scale = 1.0
        for c, lo, hi in zip(cmd, self._ctrl_lo, self._ctrl_hi):
            if c > hi > 0:
                scale = min(scale, hi / c)
            elif c < lo < 0:
                scale = min(scale, lo / c)
        self.last_command_scaled = scale < 1.0
        cmd = np.clip(cmd * scale, self._ctrl_lo, self._ctrl_hi)
        self.data.ctrl[self._act] = cmd
        return cmd

    # ------------------------------------------------------------------ time

    def advance(self, duration_s: float) -> int:
        """Step the physics for ``round(duration_s / timestep)`` steps (at least one) holding the command.

        When the robot is close enough to an obstacle for a contact to be possible within
        the interval (judged from the 2-D footprint clearance of the simulated robot, the
        current speed and a 2 g acceleration bound), the steps run one at a time and robot-obstacle contacts are
        checked after each, so a brief touch between control steps is not missed (see
        :meth:`robot_obstacle_contacts`); otherwise they run in one ``mj_step`` call.

        Args:
            duration_s: [s] interval, > 0.

        Returns:
            The largest number of robot-obstacle contacts seen at any step of the interval.
        """
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be a finite number > 0 [s], got {duration_s!r}")
        n = max(1, math.floor(duration_s / self.timestep + 0.5))  # nearest whole step
        m, d = self.model, self.data
        speed = float(np.linalg.norm(d.qvel[self._vadr : self._vadr + 2]))
        reach = (speed + _ACCEL_BOUND * n * self.timestep) * n * self.timestep + _CONTACT_SLACK
        worst = 0
        gap = math.inf if len(self._obs_c) == 0 else float(self._obstacle_distances_2d().min()) - self._reach_radius
        if gap > reach:
            mujoco.mj_step(m, d, nstep=n)
        else:
            for _ in range(n):
                mujoco.mj_step(m, d)
                worst = max(worst, self._count_contacts())
        mujoco.mj_forward(m, d)
        worst = max(worst, self._count_contacts())
        self._advance_contacts = worst
        return worst

    # ------------------------------------------------------------------ contacts

    def _count_contacts(self) -> int:
        d = self.data
        if d.ncon == 0:
            return 0
        geom = d.contact.geom
        hit = (self._is_robot[geom[:, 0]] & self._is_obstacle[geom[:, 1]]) | (
            self._is_obstacle[geom[:, 0]] & self._is_robot[geom[:, 1]]
        )
        hit &= d.contact.dist <= 0.0  # contacts inside a geom margin are not touches
        return int(np.count_nonzero(hit))

    def robot_obstacle_contacts(self) -> int:
        """Number of touching contacts between any robot geom and any obstacle geom.

        The count at the current state, or, if larger, the largest count at any physics
        step of the last :meth:`advance`. Only contacts with ``dist <= 0`` count (a geom
        margin creates contacts before the surfaces touch).
        """
        return max(self._count_contacts(), self._advance_contacts)

    def clearance(self, distmax: float = 2.0) -> float:
        """[m] smallest 3-D distance between any robot collision geom and any obstacle.

        Exact MuJoCo geometry (``mj_geomDistance``) for the pairs whose 2-D footprint
        clearance is below ``distmax``; negative when geoms overlap. This is the physical
        gap; the planning-consistent (more conservative) measure is
        :meth:`footprint_clearance`.

        Args:
            distmax: [m] distances beyond this are reported as ``distmax``.

        Returns:
            The clearance, capped at ``distmax`` (also when there are no obstacles).
        """
        m, d = self.model, self.data
        best = float(distmax)
        if len(self._obs_c) == 0:
            return best
        # lower bounds on each obstacle's distance (slack for a slightly tilted robot)
        lower = self._obstacle_distances_2d() - self._reach_radius - _CONTACT_SLACK
        for k in np.argsort(lower):
            if lower[k] > best:
                break
            og = int(self._obstacle_geoms[k])
            for g in self._robot_geoms:
                best = min(best, float(mujoco.mj_geomDistance(m, d, int(g), og, best, None)))
        return best

    def footprint_clearance(self) -> float:
        """[m] distance from the robot's footprint circle to the nearest obstacle footprint.

        2-D and exact for the scenario's obstacles: the distance from the base origin to each
        box rectangle or disc, minus ``footprint_radius``. Negative when the circle overlaps
        an obstacle; ``inf`` without obstacles. Consistent with the planner's inflation.
        """
        if len(self._obs_c) == 0:
            return math.inf
        return float(self._obstacle_distances_2d().min()) - self.robot.footprint_radius

    def _obstacle_distances_2d(self) -> np.ndarray:
        """(n_obstacles,) [m] signed 2-D distance from the base origin to each obstacle footprint."""
        p = self.data.qpos[self._qadr : self._qadr + 2]
        dlt = p - self._obs_c
        c, s = self._obs_rot[:, 0], self._obs_rot[:, 1]
        local = np.abs(np.stack([c * dlt[:, 0] + s * dlt[:, 1], -s * dlt[:, 0] + c * dlt[:, 1]], axis=1))
        q = local - self._obs_h
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0) - self._obs_round

    # ------------------------------------------------------------------ range sensing

    def ray_ranges(self, n_rays: int, max_range: float, walls: bool = True) -> np.ndarray:
        """Horizontal range readings from the ``lidar`` site, ignoring the robot itself.

        Ray ``k`` points at yaw ``pose()[2] + 2 pi k / n_rays`` (ray 0 straight ahead,
        counter-clockwise). MuJoCo ray casts against the obstacle geoms (one
        ``mj_multiRay``; rays that hit a non-obstacle are recast against the obstacles
        alone with ``mju_rayGeom``). Obstacles lower than the site (0.1 m above the floor
        in ``models/diff_drive.xml``) are not seen.

        Args:
            n_rays: number of rays, >= 1.
            max_range: [m] range of a ray that hits nothing, > 0.
            walls: also stop rays at the workspace boundary (outside counts as occupied).

        Returns:
            (n_rays,) [m] distances in ``[0, max_range]``.
        """
        if not (isinstance(n_rays, (int, np.integer)) and n_rays >= 1):
            raise ValueError(f"n_rays must be an integer >= 1, got {n_rays!r}")
        if not (math.isfinite(max_range) and max_range > 0):
            raise ValueError(f"max_range must be a finite number > 0 [m], got {max_range!r}")
        m, d = self.model, self.data
        origin = d.site_xpos[self._lidar].copy()
        angles = self.pose()[2] + 2.0 * math.pi * np.arange(n_rays) / n_rays
        vec = np.zeros((n_rays, 3))
        vec[:, 0], vec[:, 1] = np.cos(angles), np.sin(angles)
        ranges = np.full(n_rays, float(max_range))
        if len(self._obstacle_geoms):
            redo = np.arange(n_rays)
            if self._rays_fast:
                geomid = np.full(n_rays, -1, dtype=np.int32)
                dist = np.full(n_rays, -1.0)
                mujoco.mj_multiRay(m, d, origin, vec.ravel(), self._ray_groups, 1, int(self._base),
                                   geomid, dist, None, n_rays, float(max_range))
                ok = (geomid < 0) | self._is_obstacle[np.maximum(geomid, 0)]
                hit = (geomid >= 0) & ok & (dist >= 0)
                ranges[hit] = np.minimum(dist[hit], max_range)
                redo = np.flatnonzero(~ok)
            for k in redo:
                ranges[k] = self._ray_exact(origin, vec[k], float(max_range))
        if walls:
            ranges = np.minimum(ranges, self._ray_to_walls(origin[:2], vec[:, :2]))
        return np.clip(ranges, 0.0, max_range)

    def _ray_exact(self, origin: np.ndarray, vec: np.ndarray, max_range: float) -> float:
        d = self.data
        best = max_range
        for g in self._obstacle_geoms:
            dist = mujoco.mju_rayGeom(d.geom_xpos[g], d.geom_xmat[g], self.model.geom_size[g],
                                      origin, vec, int(self.model.geom_type[g]), None)
            if 0.0 <= dist < best:
                best = float(dist)
        return best

    def _ray_to_walls(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        xmin, ymin, xmax, ymax = self.scenario.bounds
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(dirs[:, 0] > 0, (xmax - origin[0]) / dirs[:, 0],
                          np.where(dirs[:, 0] < 0, (xmin - origin[0]) / dirs[:, 0], np.inf))
            ty = np.where(dirs[:, 1] > 0, (ymax - origin[1]) / dirs[:, 1],
                          np.where(dirs[:, 1] < 0, (ymin - origin[1]) / dirs[:, 1], np.inf))
        return np.maximum(np.minimum(tx, ty), 0.0)
