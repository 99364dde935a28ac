"""Seeded random cluttered scenarios in the scenario MJCF format of docs/scenarios.md.

A generated scenario is a rectangular floor (the workspace) with the start near its left
edge, the goal near its right edge, and a random number of static obstacles in between:
boxes at random sizes and yaws, upright cylinders and upright capsules. Everything random
comes from ``numpy.random.default_rng(seed)``, so a seed always gives the same file.

Obstacles are placed one at a time by rejection. A candidate is rejected when

* it comes closer than ``footprint radius + margin + endpoint_clearance`` to the start or
  the goal (exact footprint distance, :meth:`sanav_mj.scene.Obstacle.signed_distance`), or
* with it, the start and goal stop being connected: the obstacles are rasterised
  (:func:`sanav_mj.mapping.occupancy.rasterise`, conservative) at ``check_resolution_m``
  and inflated by the robot's footprint radius plus ``margin_m``, and the free cells holding
  start and goal must lie in the same 4-connected component (``scipy.ndimage.label``).

Since the rasterisation is conservative, a 4-connected chain of free cells is a corridor
the robot's inflated footprint really fits through, so every generated map is solvable for
a robot of that footprint (with the margin to spare). The footprint radius is read from the
robot model (:func:`sanav_mj.scene.robot_params`), never a literal.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import mujoco
import numpy as np
from scipy import ndimage

from sanav_mj.mapping.occupancy import rasterise
from sanav_mj.resources import robot_model_path
from sanav_mj.scene import Obstacle, RobotParams, robot_params

KINDS = ("box", "cylinder", "capsule")

_DECIMALS = 4  # positions and sizes are written (and checked) rounded to 0.1 mm


@dataclass(frozen=True)
class ClutterConfig:
    """Settings of the random clutter generator (lengths in metres).

    Attributes:
        width_m: [m] workspace extent along x (the floor spans ``[0, width_m]``).
        height_m: [m] workspace extent along y (the floor spans ``[-height_m/2, height_m/2]``).
        n_min: fewest obstacles (>= 0).
        n_max: most obstacles (>= n_min); the count is drawn uniformly in [n_min, n_max].
        kind_weights: relative frequencies of box, cylinder, capsule (>= 0, not all zero).
        box_half_min_m: [m] smallest box half-extent (each side drawn independently).
        box_half_max_m: [m] largest box half-extent.
        radius_min_m: [m] smallest cylinder / capsule radius.
        radius_max_m: [m] largest cylinder / capsule radius.
        top_min_m: [m] lowest obstacle top above the floor (capsules: plus their radius).
        top_max_m: [m] highest obstacle top above the floor (capsules: plus their radius).
        start_x_m: [m] distance of the start from the left edge.
        goal_x_m: [m] distance of the goal from the right edge.
        endpoint_y_fraction: start and goal y are uniform in
            ``+-endpoint_y_fraction * height_m / 2`` (in [0, 1)).
        endpoint_clearance_m: [m] extra free distance around start and goal beyond the
            inflated footprint.
        margin_m: [m] inflation beyond the footprint radius for the solvability check
            (passages are at least ``2 (footprint radius + margin_m)`` wide).
        check_resolution_m: [m] cell size of the solvability check.
        max_attempts: candidate obstacles tried before giving up.
    """

    width_m: float = 10.0
    height_m: float = 6.0
    n_min: int = 8
    n_max: int = 14
    kind_weights: tuple[float, float, float] = (0.6, 0.25, 0.15)
    box_half_min_m: float = 0.1
    box_half_max_m: float = 0.6
    radius_min_m: float = 0.1
    radius_max_m: float = 0.4
    top_min_m: float = 0.3
    top_max_m: float = 0.8
    start_x_m: float = 1.0
    goal_x_m: float = 1.0
    endpoint_y_fraction: float = 0.5
    endpoint_clearance_m: float = 0.3
    margin_m: float = 0.15
    check_resolution_m: float = 0.1
    max_attempts: int = 2000

    def __post_init__(self) -> None:
        positive = ("width_m", "height_m", "box_half_min_m", "radius_min_m", "top_min_m",
                    "start_x_m", "goal_x_m", "check_resolution_m")
        for name in positive:
            _check(name, getattr(self, name), "finite and > 0", lambda x: math.isfinite(x) and x > 0)
        for name in ("endpoint_clearance_m", "margin_m"):
            _check(name, getattr(self, name), "finite and >= 0", lambda x: math.isfinite(x) and x >= 0)
        _check("endpoint_y_fraction", self.endpoint_y_fraction, "in [0, 1)", lambda x: 0 <= x < 1)
        for lo, hi in (("box_half_min_m", "box_half_max_m"), ("radius_min_m", "radius_max_m"),
                       ("top_min_m", "top_max_m")):
            low = float(getattr(self, lo))
            _check(hi, getattr(self, hi), f">= {lo} ({low})", lambda x, low=low: math.isfinite(x) and x >= low)
        for name in ("n_min", "n_max", "max_attempts"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < (1 if name == "max_attempts" else 0):
                rule = ">= 1" if name == "max_attempts" else ">= 0"
                raise ValueError(f"ClutterConfig.{name}: expected an integer {rule}, got {value!r}")
        if self.n_max < self.n_min:
            raise ValueError(f"ClutterConfig.n_max: expected >= n_min ({self.n_min}), got {self.n_max!r}")
        w = tuple(self.kind_weights)
        if len(w) != 3 or not all(math.isfinite(float(x)) and float(x) >= 0 for x in w) or sum(w) <= 0:
            raise ValueError(
                f"ClutterConfig.kind_weights: expected 3 finite weights >= 0 (box, cylinder, capsule), "
                f"not all zero, got {self.kind_weights!r}"
            )
        if self.start_x_m + self.goal_x_m >= self.width_m:
            raise ValueError(
                f"ClutterConfig.start_x_m + goal_x_m: expected < width_m ({self.width_m}), "
                f"got {self.start_x_m + self.goal_x_m!r}"
            )

    @property
    def bounds(self) -> np.ndarray:
        """(4,) [m] workspace xmin, ymin, xmax, ymax."""
        return np.array([0.0, -0.5 * self.height_m, self.width_m, 0.5 * self.height_m])


def _check(name: str, value, rule: str, ok) -> None:
    try:
        good = bool(ok(float(value)))
    except (TypeError, ValueError):
        good = False
    if not good:
        raise ValueError(f"ClutterConfig.{name}: expected {rule}, got {value!r}")


@lru_cache(maxsize=1)
def nominal_robot() -> RobotParams:
    """Robot parameters of the packaged robot model (``models/diff_drive.xml``), read by name."""
    return robot_params(mujoco.MjModel.from_xml_path(str(robot_model_path())))


@dataclass(frozen=True)
class ClutterLayout:
    """A generated layout, before it is written as MJCF.

    Attributes:
        seed: the seed it was generated from.
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        start: (3,) [m, m, rad] start pose (facing the goal).
        goal: (2,) [m] goal position.
        obstacles: the obstacles (``geom_id`` is their index; heights are their tops).
        attempts: candidate obstacles drawn (accepted + rejected).
    """

    seed: int
    bounds: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    obstacles: tuple[Obstacle, ...]
    attempts: int


def _r(x: float) -> float:
    return round(float(x), _DECIMALS)


def connected(obstacles, bounds, start, goal, inflation: float, resolution: float) -> bool:
    """Whether ``start`` and ``goal`` lie in one 4-connected free component of the grid.

    Args:
        obstacles: obstacles to rasterise.
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        start: (2,) [m] start position.
        goal: (2,) [m] goal position.
        inflation: [m] obstacle inflation (footprint radius + margin).
        resolution: [m] cell size.

    Returns:
        False when either point is outside the grid or in an occupied cell, or the two are
        in different components.
    """
    grid = rasterise(tuple(obstacles), bounds, resolution, inflation=inflation)
    free = ~grid.occupied
    ny, nx = free.shape
    cells = []
    for p in (start, goal):
        j = math.floor((float(p[0]) - grid.origin[0]) / grid.resolution)
        i = math.floor((float(p[1]) - grid.origin[1]) / grid.resolution)
        if not (0 <= i < ny and 0 <= j < nx) or not free[i, j]:
            return False
        cells.append((i, j))
    labels, _ = ndimage.label(free)  # 4-connectivity (the default structure)
    return bool(labels[cells[0]] == labels[cells[1]])


def generate_layout(seed: int, config: ClutterConfig = ClutterConfig()) -> ClutterLayout:
    """Draw a solvable random layout (see the module docstring for the rules).

    Args:
        seed: integer seed (>= 0) of ``numpy.random.default_rng``.
        config: generator settings.

    Raises:
        ValueError: bad seed, or fewer than the drawn number of obstacles could be placed
            within ``config.max_attempts`` candidates (the config is too crowded).
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed: expected an integer >= 0, got {seed!r}")
    c = config
    rng = np.random.default_rng(int(seed))
    robot = nominal_robot()
    inflation = robot.footprint_radius + c.margin_m
    keep_out = inflation + c.endpoint_clearance_m
    bounds = c.bounds
    half_h = 0.5 * c.height_m
    span = c.endpoint_y_fraction * half_h
    sx, sy = _r(c.start_x_m), _r(rng.uniform(-span, span))
    gx, gy = _r(c.width_m - c.goal_x_m), _r(rng.uniform(-span, span))
    start = np.array([sx, sy, _r(math.atan2(gy - sy, gx - sx))])
    goal = np.array([gx, gy])
    # The endpoints themselves must be valid for a robot of this footprint.
    for what, p in (("start", start[:2]), ("goal", goal)):
        if not (bounds[0] + inflation <= p[0] <= bounds[2] - inflation and bounds[1] + inflation <= p[1] <= bounds[3] - inflation):
            raise ValueError(
                f"ClutterConfig: the {what} {p.tolist()} is closer than the inflated footprint {inflation:.3f} m "
                "to the workspace edge; enlarge the workspace or move start_x_m / goal_x_m"
            )
    n = int(rng.integers(c.n_min, c.n_max + 1))
    weights = np.asarray(c.kind_weights, dtype=float)
    weights = weights / weights.sum()
    obstacles: list[Obstacle] = []
    attempts = 0
    while len(obstacles) < n:
        if attempts >= c.max_attempts:
            raise ValueError(
                f"ClutterConfig: placed only {len(obstacles)} of {n} obstacles in max_attempts={c.max_attempts} "
                f"candidates (seed {seed}); lower n_max or the obstacle sizes"
            )
        attempts += 1
        kind = KINDS[int(rng.choice(3, p=weights))]
        cx = _r(rng.uniform(bounds[0], bounds[2]))
        cy = _r(rng.uniform(bounds[1], bounds[3]))
        half_z = _r(rng.uniform(0.5 * c.top_min_m, 0.5 * c.top_max_m))
        if kind == "box":
            half = np.array([_r(rng.uniform(c.box_half_min_m, c.box_half_max_m)),
                             _r(rng.uniform(c.box_half_min_m, c.box_half_max_m))])
            yaw = _r(rng.uniform(0.0, math.pi))
        else:
            radius = _r(rng.uniform(c.radius_min_m, c.radius_max_m))
            half = np.array([radius, radius])
            yaw = 0.0
        # boxes and cylinders are 2 half_z tall; a capsule's straight part is, plus its top cap
        top = 2.0 * half_z + (float(half[0]) if kind == "capsule" else 0.0)
        cand = Obstacle(f"obs_{len(obstacles):02d}", kind, np.array([cx, cy]), yaw, half, top, len(obstacles))
        if float(cand.signed_distance(start[:2])) < keep_out or float(cand.signed_distance(goal)) < keep_out:
            continue
        trial = obstacles + [cand]
        if not connected(trial, bounds, start, goal, inflation, c.check_resolution_m):
            continue
        obstacles.append(cand)
    return ClutterLayout(int(seed), bounds, start, goal, tuple(obstacles), attempts)


def _num(v: float, digits: int = _DECIMALS) -> str:
    text = f"{float(v):.{digits}f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def _nums(*values: float, digits: int = _DECIMALS) -> str:
    return " ".join(_num(v, digits) for v in values)


def layout_mjcf(layout: ClutterLayout, include: str) -> str:
    """MJCF text of a layout, including the robot from ``include`` (a path as written in the file).

    Boxes and cylinders stand on the floor with their top at ``height``; a capsule's lower
    hemisphere is centred on the floor, so its straight part spans ``[0, height - radius]``.
    Yaws are written as quaternions (independent of the compiler's angle unit).
    """
    b = layout.bounds
    cx, cy = 0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3])
    hx, hy = 0.5 * (b[2] - b[0]), 0.5 * (b[3] - b[1])
    lines = [
        (f"<!-- Random clutter scenario generated by sanav_mj.generate (seed {layout.seed}, "
         f"{len(layout.obstacles)} obstacles). -->"),
        f'<mujoco model="clutter_{layout.seed:04d}">',
        f'  <include file="{include}"/>',
        "  <custom>",
        f'    <numeric name="start" data="{_nums(*layout.start)}"/>',
        f'    <numeric name="goal" data="{_nums(*layout.goal)}"/>',
        "  </custom>",
        "  <worldbody>",
        f'    <light name="sun" pos="{_nums(cx, cy, 6)}" dir="0 0 -1" directional="true"/>',
        f'    <geom name="floor" type="plane" pos="{_nums(cx, cy, 0)}" size="{_nums(hx, hy, 0.1)}" rgba="0.8 0.8 0.8 1"/>',
    ]
    for ob in layout.obstacles:
        x, y = ob.center
        if ob.kind == "box":
            hz = 0.5 * ob.height
            quat = _nums(math.cos(0.5 * ob.yaw), 0, 0, math.sin(0.5 * ob.yaw), digits=9)
            lines.append(
                f'    <geom name="{ob.name}" type="box" pos="{_nums(x, y, hz)}" '
                f'size="{_nums(ob.half_size[0], ob.half_size[1], hz)}" quat="{quat}" rgba="0.7 0.2 0.2 1"/>'
            )
        elif ob.kind == "cylinder":
            hz = 0.5 * ob.height
            lines.append(
                f'    <geom name="{ob.name}" type="cylinder" pos="{_nums(x, y, hz)}" '
                f'size="{_nums(ob.half_size[0], hz)}" rgba="0.7 0.3 0.2 1"/>'
            )
        else:
            r = float(ob.half_size[0])
            half_len = 0.5 * (ob.height - r)  # exact: height was built as 2 half_len + r
            lines.append(
                f'    <geom name="{ob.name}" type="capsule" pos="{_nums(x, y, half_len)}" '
                f'size="{_nums(r, half_len)}" rgba="0.7 0.2 0.3 1"/>'
            )
    lines += [
        f'    <site name="goal" pos="{_nums(layout.goal[0], layout.goal[1], 0.01)}" size="0.1" rgba="0.1 0.8 0.1 1"/>',
        "  </worldbody>",
        "</mujoco>",
        "",
    ]
    return "\n".join(lines)


def generate_scenario(seed: int, config: ClutterConfig = ClutterConfig(), include: str | os.PathLike | None = None) -> str:
    """MJCF text of a random solvable clutter scenario.

    Args:
        seed: integer seed (>= 0); the same seed and config give the same text.
        config: generator settings.
        include: the robot include path written into the file; default the absolute path
            of the packaged robot (:func:`sanav_mj.resources.robot_model_path`), so the text
            loads from anywhere. Use :func:`write_scenario` for a relative include.

    Raises:
        ValueError: see :func:`generate_layout`.
    """
    inc = str(robot_model_path()) if include is None else os.fspath(include)
    return layout_mjcf(generate_layout(seed, config), inc)


def write_scenario(seed: int, path: str | os.PathLike, config: ClutterConfig = ClutterConfig()) -> Path:
    """Write :func:`generate_scenario` to ``path`` with the robot included relative to it.

    The include is the path of the packaged robot relative to the file's folder (absolute
    when no relative path exists, e.g. another drive). Parent folders are created.

    Returns:
        The absolute path written.
    """
    out = Path(path).expanduser().resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        include = Path(os.path.relpath(robot_model_path(), out.parent)).as_posix()
    except ValueError:
        include = str(robot_model_path())
    out.write_text(generate_scenario(seed, config, include=include))
    return out
