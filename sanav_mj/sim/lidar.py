"""A 2-D scanning lidar on the robot, declared in its MJCF and cast with ``mujoco.mj_multiRay``.

The sensor is the ``lidar_2d`` site of ``models/diff_drive.xml`` (on the deck, scan plane
0.28 m above the floor; the ``lidar`` site 0.1 m up is the DQN's ray origin) and five ``<custom><numeric>``
fields of the robot file (read by name, see :func:`lidar_config`):

    lidar_fov    [deg]  angular field of view, centred on the site's heading
    lidar_beams  [-]    number of beams (evenly spaced over the field of view, ends included)
    lidar_range  [m]    maximum range; a beam that hits nothing within it has no return
    lidar_rate   [Hz]   scans per second
    lidar_noise  [m]    standard deviation of the Gaussian range noise of a return

Only obstacles that cross the scan plane are seen, and only their cross-section in that
plane (e.g. a capsule's rounded end below the plane is narrower there). The fan is
horizontal whatever the robot's tilt: beam ``k`` points at world yaw
``heading + angles[k]`` with zero vertical component, where ``heading`` is the site's x axis
projected on the floor. The floor is a horizontal plane below the site, so a horizontal ray
cannot meet it; in addition, any ray whose first hit is not a scenario obstacle (the floor,
the robot itself, decoration) is cast again against the obstacles alone with
``mju_rayGeom``, so the returns are exactly the distances to the obstacles (tested).

Noise is drawn from a ``numpy.random.Generator`` passed in by the caller (seeded), never
from global state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from sanav_mj.scene import ROBOT_BASE, Obstacle

#: Name of the sensor's site in the robot model.
LIDAR_SITE = "lidar_2d"
#: Names of the custom numerics holding the sensor's parameters (one value each).
LIDAR_FIELDS = ("lidar_fov", "lidar_beams", "lidar_range", "lidar_rate", "lidar_noise")


@dataclass(frozen=True)
class LidarConfig:
    """Parameters of the 2-D lidar.

    Attributes:
        fov: [rad] angular field of view, in (0, 2 pi], centred on the sensor heading.
        beams: number of beams, integer >= 2, evenly spaced over ``fov`` with both ends
            included (for ``fov = 2 pi`` the last beam would repeat the first, so the spacing
            is ``fov / beams`` instead).
        max_range: [m] maximum range, > 0.
        rate: [Hz] scan rate, > 0.
        noise_std: [m] standard deviation of the Gaussian noise added to each return, >= 0.
        offset: (2,) [m] position of the sensor in the robot base frame (x forward, y left).
    """

    fov: float = math.radians(270.0)
    beams: int = 541
    max_range: float = 10.0
    rate: float = 20.0
    noise_std: float = 0.02
    offset: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not (isinstance(self.fov, (int, float)) and 0.0 < self.fov <= 2 * math.pi + 1e-12):
            raise ValueError(f"LidarConfig.fov must be in (0, 2 pi] [rad], got {self.fov!r}")
        if isinstance(self.beams, bool) or not isinstance(self.beams, (int, np.integer)) or self.beams < 2:
            raise ValueError(f"LidarConfig.beams must be an integer >= 2, got {self.beams!r}")
        for name in ("max_range", "rate"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"LidarConfig.{name} must be a finite number > 0, got {v!r}")
        if not (isinstance(self.noise_std, (int, float)) and math.isfinite(self.noise_std) and self.noise_std >= 0):
            raise ValueError(f"LidarConfig.noise_std must be a finite number >= 0 [m], got {self.noise_std!r}")
        off = tuple(float(v) for v in self.offset)
        if len(off) != 2 or not all(math.isfinite(v) for v in off):
            raise ValueError(f"LidarConfig.offset must be 2 finite numbers [m], got {self.offset!r}")
        object.__setattr__(self, "offset", off)

    @property
    def angles(self) -> np.ndarray:
        """(beams,) [rad] beam directions relative to the sensor heading, increasing (CCW)."""
        full = self.fov >= 2 * math.pi - 1e-12
        step = self.fov / self.beams if full else self.fov / (self.beams - 1)
        return -0.5 * self.fov + step * np.arange(self.beams)

    @property
    def period(self) -> float:
        """[s] time between scans."""
        return 1.0 / self.rate


def lidar_config(model: mujoco.MjModel) -> LidarConfig:
    """The lidar parameters declared in a compiled model (site ``lidar_2d`` + custom numerics).

    Args:
        model: a model including ``models/diff_drive.xml`` (or any robot with a ``lidar_2d``
            site on its base body and the numerics :data:`LIDAR_FIELDS`).

    Returns:
        The configuration; ``offset`` is the site's position in its body (the base) frame.

    Raises:
        ValueError: a field or the site is missing or holds a bad value (names it).
    """
    vals = {}
    for name in LIDAR_FIELDS:
        try:
            num = model.numeric(name)
        except KeyError:
            raise ValueError(f"robot model has no <numeric name={name!r}> (lidar parameter)") from None
        data = np.asarray(num.data, dtype=float)
        if data.size != 1:
            raise ValueError(f"numeric {name!r} must hold 1 value, got {data.size}")
        vals[name] = float(data[0])
    try:
        site = model.site(LIDAR_SITE)
    except KeyError:
        raise ValueError(f"robot model has no site {LIDAR_SITE!r}") from None
    beams = vals["lidar_beams"]
    if beams != round(beams):
        raise ValueError(f"numeric 'lidar_beams' must be an integer, got {beams!r}")
    return LidarConfig(
        fov=math.radians(vals["lidar_fov"]),
        beams=int(round(beams)),
        max_range=vals["lidar_range"],
        rate=vals["lidar_rate"],
        noise_std=vals["lidar_noise"],
        offset=(float(site.pos[0]), float(site.pos[1])),
    )


@dataclass(frozen=True)
class LidarScan:
    """One scan.

    Attributes:
        ranges: (B,) [m] measured range of each beam (with noise, clipped to
            ``[0, max_range]``); ``max_range`` where there is no return.
        hit: (B,) bool, True where the beam returned from an obstacle within ``max_range``.
        angles: (B,) [rad] beam directions relative to the sensor heading.
        max_range: [m] the sensor's maximum range.
    """

    ranges: np.ndarray
    hit: np.ndarray
    angles: np.ndarray
    max_range: float


class Lidar:
    """Casts the configured fan from the ``lidar_2d`` site of a simulated model.

    Args:
        model: the simulated MuJoCo model (it must contain the site ``lidar_2d``).
        obstacles: the scenario's obstacles (``Scenario.obstacles``): only these are seen.
        config: the sensor parameters (usually :func:`lidar_config` of the model).
    """

    def __init__(self, model: mujoco.MjModel, obstacles: tuple[Obstacle, ...] | list[Obstacle],
                 config: LidarConfig) -> None:
        self.model = model
        self.config = config
        self._site = model.site(LIDAR_SITE).id
        self._base = model.body(ROBOT_BASE).id
        self._angles = config.angles
        self._obstacles = np.array([o.geom_id for o in obstacles], dtype=np.int64)
        self._is_obstacle = np.zeros(model.ngeom, dtype=bool)
        self._is_obstacle[self._obstacles] = True
        groups = np.unique(model.geom_group[self._obstacles]) if len(self._obstacles) else np.array([], int)
        self._groups = np.zeros(6, dtype=np.uint8)
        self._groups[groups[(groups >= 0) & (groups < 6)]] = 1
        n = config.beams
        self._vec = np.zeros((n, 3))
        self._geomid = np.full(n, -1, dtype=np.int32)
        self._dist = np.full(n, -1.0)

    def true_ranges(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noise-free distances from the site to the obstacles along each beam.

        Args:
            data: the simulation state (kinematics must be current, e.g. after ``mj_forward``).

        Returns:
            ranges: (B,) [m] distance to the first obstacle, ``inf`` where none within range.
            origin: (3,) [m] the site's world position.
            heading: [rad] world yaw of the site's x axis projected on the floor.
        """
        m = self.model
        origin = data.site_xpos[self._site].copy()
        xmat = data.site_xmat[self._site]
        heading = math.atan2(xmat[3], xmat[0])  # x axis = first column of the row-major matrix
        a = heading + self._angles
        vec = self._vec
        vec[:, 0] = np.cos(a)
        vec[:, 1] = np.sin(a)
        rng = self.config.max_range
        out = np.full(len(a), np.inf)
        if not len(self._obstacles):
            return out, origin, heading
        gid, dist = self._geomid, self._dist
        mujoco.mj_multiRay(m, data, origin, vec.ravel(), self._groups, 1, int(self._base),
                           gid, dist, None, len(a), float(rng))
        valid = gid >= 0
        obst = valid & self._is_obstacle[np.maximum(gid, 0)]
        good = obst & (dist >= 0) & (dist <= rng)
        out[good] = dist[good]
        # A first hit that is not an obstacle (floor, robot, decoration, invisible geoms are
        # skipped by mj_ray) hides what is behind it: cast those beams at the obstacles alone.
        redo = np.flatnonzero(valid & ~obst)
        invisible = m.geom_rgba[self._obstacles, 3] <= 0
        if np.any(invisible):  # mj_ray ignores alpha-0 geoms: check every beam exactly
            redo = np.arange(len(a))
        for k in redo:
            best = np.inf
            for g in self._obstacles:
                d = mujoco.mju_rayGeom(data.geom_xpos[g], data.geom_xmat[g], m.geom_size[g],
                                       origin, vec[k], int(m.geom_type[g]), None)
                if 0.0 <= d <= rng and d < best:
                    best = float(d)
            out[k] = best
        return out, origin, heading

    def scan(self, data: mujoco.MjData, rng: np.random.Generator) -> LidarScan:
        """One noisy scan.

        Each return gets independent Gaussian noise of std ``noise_std`` from ``rng`` (one
        draw per beam, returns or not, so the stream does not depend on the scene), and is
        clipped to ``[0, max_range]``. Beams without a return read ``max_range``, ``hit`` False.

        Args:
            data: the simulation state.
            rng: the noise source.
        """
        true, _, _ = self.true_ranges(data)
        noise = rng.normal(0.0, self.config.noise_std, size=true.shape) if self.config.noise_std > 0 \
            else np.zeros(true.shape)
        hit = np.isfinite(true)
        ranges = np.full(true.shape, float(self.config.max_range))
        ranges[hit] = np.clip(true[hit] + noise[hit], 0.0, self.config.max_range)
        return LidarScan(ranges=ranges, hit=hit, angles=self._angles.copy(), max_range=float(self.config.max_range))
