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
from collections.abc import Callable
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


def layout_mjcf(layout, include: str, *, model: str | None = None, comment: str | None = None) -> str:
    """MJCF text of a layout, including the robot from ``include`` (a path as written in the file).

    Boxes and cylinders stand on the floor with their top at ``height``; a capsule's lower
    hemisphere is centred on the floor, so its straight part spans ``[0, height - radius]``.
    Yaws are written as quaternions (independent of the compiler's angle unit).
    ``model`` and ``comment`` default to the clutter generator's model name and comment.
    """
    b = layout.bounds
    cx, cy = 0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3])
    hx, hy = 0.5 * (b[2] - b[0]), 0.5 * (b[3] - b[1])
    if comment is None:
        comment = (f"Random clutter scenario generated by sanav_mj.generate (seed {layout.seed}, "
                   f"{len(layout.obstacles)} obstacles).")
    lines = [
        f"<!-- {comment} -->",
        f'<mujoco model="{model or f"clutter_{layout.seed:04d}"}">',
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
    return _write_with_robot(path, lambda include: generate_scenario(seed, config, include=include))


def _write_with_robot(path: str | os.PathLike, text_of: Callable[[str], str]) -> Path:
    """Write ``text_of(include)`` to ``path`` (parents created), ``include`` being the packaged
    robot's path relative to the file's folder (absolute when none exists, e.g. another
    drive); returns the absolute path written."""
    out = Path(path).expanduser().resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        include = Path(os.path.relpath(robot_model_path(), out.parent)).as_posix()
    except ValueError:
        include = str(robot_model_path())
    out.write_text(text_of(include))
    return out


# --------------------------------------------------------------------------------------
# BARN-like worlds: cellular-automaton cylinder fields (Perille et al. 2020)
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BarnConfig:
    """Settings of the BARN-like world generator (lengths in metres).

    The world is a ``field_width_m`` wide strip along x; a field of upright cylinders of
    radius ``cylinder_radius_m`` sits on a square lattice of pitch ``lattice_m`` between
    ``field_x0_m`` and ``field_x0_m + field_length_m``; the start (facing +x) is at
    ``(start_x_m, 0)``, the goal at ``(goal_x_m, 0)``, both in open space outside the field.
    Which lattice cells hold a cylinder comes from a cellular automaton: each cell is filled
    with probability ``fill`` (drawn uniformly in ``fill_range``), then ``iterations``
    (drawn uniformly in ``iterations_range``) smoothing rounds make a cell with at least
    ``birth`` filled neighbours (of 8) filled and one with at most ``death`` empty.

    Attributes:
        field_width_m: [m] workspace extent along y (the floor spans ``+-field_width_m / 2``).
        field_x0_m: [m] x of the field's first lattice cell's lower edge.
        field_length_m: [m] field extent along x (a whole number of lattice cells).
        x_min_m: [m] workspace lower x.
        x_max_m: [m] workspace upper x.
        start_x_m: [m] start x (y = 0, yaw 0).
        goal_x_m: [m] goal x (y = 0).
        lattice_m: [m] lattice pitch.
        cylinder_radius_m: [m] cylinder radius.
        cylinder_height_m: [m] cylinder height.
        fill_range: (lo, hi) initial fill probability range, 0 <= lo <= hi <= 1.
        iterations_range: (lo, hi) smoothing rounds range (integers, 0 <= lo <= hi).
        birth: a cell with at least this many filled neighbours becomes filled.
        death: a cell with at most this many filled neighbours becomes empty.
        slack_m: [m] clearance each side of the footprint the solvability check demands.
        check_resolution_m: [m] cell size of the configuration-space check.
        yaw_bins: yaw cells of the configuration-space check over [0, pi) (the footprint is
            symmetric under a half turn).
        max_tries: fields drawn per seed before giving up.
    """

    field_width_m: float = 5.0
    field_x0_m: float = 2.0
    field_length_m: float = 6.0
    x_min_m: float = -1.0
    x_max_m: float = 11.0
    start_x_m: float = 0.0
    goal_x_m: float = 10.0
    lattice_m: float = 0.15
    cylinder_radius_m: float = 0.075
    cylinder_height_m: float = 0.5
    fill_range: tuple[float, float] = (0.35, 0.5)
    iterations_range: tuple[int, int] = (2, 5)
    birth: int = 5
    death: int = 3
    slack_m: float = 0.01
    check_resolution_m: float = 0.0125
    yaw_bins: int = 48
    max_tries: int = 200

    def __post_init__(self) -> None:
        for name in ("field_width_m", "field_length_m", "lattice_m", "cylinder_radius_m", "cylinder_height_m",
                     "check_resolution_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"BarnConfig.{name}: expected a finite number > 0 [m], got {v!r}")
        if not (isinstance(self.slack_m, (int, float)) and math.isfinite(self.slack_m) and self.slack_m >= 0):
            raise ValueError(f"BarnConfig.slack_m: expected a finite number >= 0 [m], got {self.slack_m!r}")
        if not (self.x_min_m < self.start_x_m < self.field_x0_m
                and self.field_x0_m + self.field_length_m < self.goal_x_m < self.x_max_m):
            raise ValueError(
                "BarnConfig: expected x_min_m < start_x_m < field_x0_m and field end < goal_x_m < x_max_m, got "
                f"{(self.x_min_m, self.start_x_m, self.field_x0_m, self.field_x0_m + self.field_length_m, self.goal_x_m, self.x_max_m)!r}"
            )
        lo, hi = self.fill_range
        if not (0 <= lo <= hi <= 1):
            raise ValueError(f"BarnConfig.fill_range: expected 0 <= lo <= hi <= 1, got {self.fill_range!r}")
        lo, hi = self.iterations_range
        if not (isinstance(lo, int) and isinstance(hi, int) and 0 <= lo <= hi):
            raise ValueError(f"BarnConfig.iterations_range: expected integers 0 <= lo <= hi, got {self.iterations_range!r}")
        for name, lo_v in (("birth", 0), ("death", -1), ("yaw_bins", 1), ("max_tries", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo_v:
                raise ValueError(f"BarnConfig.{name}: expected an integer >= {lo_v}, got {v!r}")

    @property
    def bounds(self) -> np.ndarray:
        """(4,) [m] workspace xmin, ymin, xmax, ymax."""
        h = 0.5 * self.field_width_m
        return np.array([self.x_min_m, -h, self.x_max_m, h])

    @property
    def lattice_shape(self) -> tuple[int, int]:
        """(rows along y, columns along x) of the cylinder lattice."""
        return (int(math.floor(self.field_width_m / self.lattice_m + 1e-9)),
                int(math.floor(self.field_length_m / self.lattice_m + 1e-9)))


def cellular_automaton(rng: np.random.Generator, shape: tuple[int, int], fill: float, iterations: int,
                       birth: int = 5, death: int = 1) -> np.ndarray:
    """A random bool lattice smoothed by a cellular automaton.

    Args:
        rng: random generator (one ``random`` draw per cell, row-major).
        shape: (rows, columns).
        fill: probability that a cell starts filled.
        iterations: smoothing rounds.
        birth: a cell with >= ``birth`` filled neighbours (of 8; outside counts empty) becomes filled.
        death: a cell with <= ``death`` filled neighbours becomes empty; others keep their state.

    Returns:
        (rows, columns) bool, True where a cylinder stands.
    """
    cells = rng.random(shape) < fill
    kernel = np.ones((3, 3), dtype=np.int64)
    kernel[1, 1] = 0
    for _ in range(iterations):
        n = ndimage.convolve(cells.astype(np.int64), kernel, mode="constant", cval=0)
        cells = np.where(n >= birth, True, np.where(n <= death, False, cells))
    return cells


def footprint_free_space(obstacles, bounds, footprint, *, slack: float, resolution: float,
                         yaw_bins: int) -> np.ndarray:
    """Conservative configuration-space free set of a rectangular footprint.

    Cell ``(k, i, j)`` is free only if the footprint, grown by ``slack``, is clear of every
    obstacle and inside the workspace for *every* pose with its reference point in grid cell
    ``(i, j)`` (of :func:`sanav_mj.mapping.occupancy.rasterise` at ``resolution`` over
    ``bounds``) and yaw in ``[k pi / K, (k + 1) pi / K]`` (K = ``yaw_bins``; the footprint
    must be symmetric under a half turn about the reference point, as the rectangle of
    :class:`sanav_mj.footprint.Footprint` centred on the base origin is).

    Why it is conservative: the footprint at yaw ``theta`` and position ``p`` meets an
    obstacle ``O`` iff ``p`` lies in ``O (+) (-F(theta))``; for a disc obstacle of radius r
    and a centred rectangle that set is the rectangle at yaw ``theta`` around the disc centre
    grown by r. Turning by at most ``delta = pi / (2K)`` from the bin's middle yaw moves
    every footprint point by at most ``R delta`` (R the circumradius), so growing by
    ``r + slack + R delta`` covers the whole yaw bin; the rasteriser marks every cell whose
    closed square meets the grown set, which covers every position in the cell. Cylinders
    and capsules are treated this way; boxes are grown by the footprint's circumradius plus
    ``slack`` (the footprint at any yaw lies in that disc), a cruder but still conservative
    bound.

    Adjacent free cells (4-neighbours at one yaw, or one position at neighbouring yaws,
    yaw bin K-1 next to 0) are joined by a motion that stays in their union, so a path of
    free cells is a collision-free motion of the footprint.

    Args:
        obstacles: obstacles (:class:`sanav_mj.scene.Obstacle`).
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        footprint: :class:`sanav_mj.footprint.Footprint` centred on the reference point.
        slack: [m] clearance demanded on every side (>= 0).
        resolution: [m] position cell size.
        yaw_bins: K, yaw cells over [0, pi).

    Returns:
        (K, ny, nx) bool, True where free.
    """
    if np.linalg.norm(footprint.center) > 1e-12:
        raise ValueError(f"footprint_free_space: expected a footprint centred on the reference point, "
                         f"got centre {footprint.center.tolist()}")
    b = np.asarray(bounds, dtype=float)
    hx, hy = (float(v) for v in footprint.half_size)
    big = footprint.circumradius
    delta = 0.5 * math.pi / yaw_bins
    sweep = big * delta
    round_obs = [o for o in obstacles if o.kind in ("cylinder", "capsule")]
    boxes = [o for o in obstacles if o.kind == "box"]
    ny, nx = rasterise((), b, resolution, inflation=0.0).occupied.shape
    free = np.zeros((yaw_bins, ny, nx), dtype=bool)
    for k in range(yaw_bins):
        th = (k + 0.5) * math.pi / yaw_bins
        occ = np.zeros((ny, nx), dtype=bool)
        # group round obstacles by radius: one rasterisation per distinct radius
        radii = sorted({float(o.half_size[0]) for o in round_obs})
        for r in radii:
            rects = tuple(Obstacle(o.name, "box", np.asarray(o.center, float), th, np.array([hx, hy]), o.height, o.geom_id)
                          for o in round_obs if float(o.half_size[0]) == r)
            occ |= rasterise(rects, b, resolution, inflation=r + slack + sweep).occupied
        if boxes:
            occ |= rasterise(tuple(boxes), b, resolution, inflation=big + slack).occupied
        # the footprint stays inside the workspace: reference point at least the footprint's
        # extent (over the bin) from each edge
        ext_x = hx * abs(math.cos(th)) + hy * abs(math.sin(th)) + sweep + slack
        ext_y = hx * abs(math.sin(th)) + hy * abs(math.cos(th)) + sweep + slack
        xs = b[0] + resolution * np.arange(nx)
        ys = b[1] + resolution * np.arange(ny)
        bad_x = (xs < b[0] + ext_x) | (xs + resolution > b[2] - ext_x)
        bad_y = (ys < b[1] + ext_y) | (ys + resolution > b[3] - ext_y)
        occ[:, bad_x] = True
        occ[bad_y, :] = True
        free[k] = ~occ
    return free


def footprint_connected(free: np.ndarray, bounds, resolution: float, start, goal) -> bool:
    """Whether some yaw at ``start`` connects to some yaw at ``goal`` in a free set of
    :func:`footprint_free_space` (4-neighbours in position, neighbouring yaw bins, wrapping).

    Args:
        free: (K, ny, nx) bool.
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        resolution: [m] cell size.
        start, goal: (2,) [m] positions.
    """
    structure = ndimage.generate_binary_structure(3, 1)
    labels, n = ndimage.label(free, structure=structure)
    if n == 0:
        return False
    # yaw wraps: bins K-1 and 0 are neighbours
    both = free[0] & free[-1]
    parent = np.arange(n + 1)

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b_ in {(int(a), int(b_)) for a, b_ in zip(labels[0][both], labels[-1][both])}:
        ra, rb = find(a), find(b_)
        if ra != rb:
            parent[ra] = rb
    b = np.asarray(bounds, dtype=float)
    ends = []
    for p in (start, goal):
        j = math.floor((float(p[0]) - b[0]) / resolution)
        i = math.floor((float(p[1]) - b[1]) / resolution)
        if not (0 <= i < free.shape[1] and 0 <= j < free.shape[2]):
            return False
        ends.append({find(int(v)) for v in labels[:, i, j] if v})
    return bool(ends[0] & ends[1])


@dataclass(frozen=True)
class BarnLayout:
    """A generated BARN-like world.

    Attributes:
        seed: the seed it was generated from.
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
        start: (3,) [m, m, rad] start pose.
        goal: (2,) [m] goal position.
        obstacles: the cylinders.
        cells: (rows, columns) bool lattice the cylinders stand on.
        fill: initial fill probability drawn.
        iterations: smoothing rounds drawn.
        tries: fields drawn until one passed the solvability check (1 = the first).
    """

    seed: int
    bounds: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    obstacles: tuple[Obstacle, ...]
    cells: np.ndarray
    fill: float
    iterations: int
    tries: int


@lru_cache(maxsize=1)
def nominal_footprint():
    """:class:`sanav_mj.footprint.Footprint` of the packaged robot model."""
    from sanav_mj.footprint import robot_footprint

    return robot_footprint(mujoco.MjModel.from_xml_path(str(robot_model_path())))


def barn_obstacles(cells: np.ndarray, config: BarnConfig) -> tuple[Obstacle, ...]:
    """Cylinders standing on the filled lattice cells (centres at cell centres)."""
    c = config
    y0 = -0.5 * c.field_width_m + 0.5 * (c.field_width_m - cells.shape[0] * c.lattice_m)
    out = []
    for i, j in zip(*np.nonzero(cells)):
        x = _r(c.field_x0_m + (j + 0.5) * c.lattice_m)
        y = _r(y0 + (i + 0.5) * c.lattice_m)
        r = c.cylinder_radius_m
        out.append(Obstacle(f"cyl_{len(out):04d}", "cylinder", np.array([x, y]), 0.0, np.array([r, r]),
                            c.cylinder_height_m, len(out)))
    return tuple(out)


def barn_solvable(obstacles, config: BarnConfig, footprint=None) -> bool:
    """The conservative configuration-space check of :func:`footprint_free_space` from the
    config's start to its goal (footprint: the packaged robot's unless given)."""
    c = config
    fp = nominal_footprint() if footprint is None else footprint
    free = footprint_free_space(obstacles, c.bounds, fp, slack=c.slack_m, resolution=c.check_resolution_m,
                                yaw_bins=c.yaw_bins)
    return footprint_connected(free, c.bounds, c.check_resolution_m, (c.start_x_m, 0.0), (c.goal_x_m, 0.0))


def generate_barn_layout(seed: int, config: BarnConfig = BarnConfig()) -> BarnLayout:
    """Draw cylinder fields from ``default_rng(seed)`` until one passes :func:`barn_solvable`.

    Raises:
        ValueError: bad seed, or ``config.max_tries`` fields all failed.
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed: expected an integer >= 0, got {seed!r}")
    c = config
    rng = np.random.default_rng(int(seed))
    for tries in range(1, c.max_tries + 1):
        fill = float(rng.uniform(*c.fill_range))
        iterations = int(rng.integers(c.iterations_range[0], c.iterations_range[1] + 1))
        cells = cellular_automaton(rng, c.lattice_shape, fill, iterations, c.birth, c.death)
        obstacles = barn_obstacles(cells, c)
        if barn_solvable(obstacles, c):
            return BarnLayout(int(seed), c.bounds, np.array([c.start_x_m, 0.0, 0.0]), np.array([c.goal_x_m, 0.0]),
                              obstacles, cells, fill, iterations, tries)
    raise ValueError(f"BarnConfig: no solvable field in max_tries={c.max_tries} draws (seed {seed}); "
                     "lower fill_range or raise max_tries")


def generate_barn_scenario(seed: int, config: BarnConfig = BarnConfig(), include: str | os.PathLike | None = None) -> str:
    """MJCF text of a solvable BARN-like world (see :func:`generate_barn_layout`);
    ``include`` as in :func:`generate_scenario`."""
    inc = str(robot_model_path()) if include is None else os.fspath(include)
    layout = generate_barn_layout(seed, config)
    return layout_mjcf(layout, inc, model=f"barn_{layout.seed:04d}",
                       comment=(f"BARN-like cylinder field generated by sanav_mj.generate (seed {layout.seed}, "
                                f"fill {layout.fill:.3f}, {layout.iterations} CA rounds, {len(layout.obstacles)} cylinders)"))


def write_barn_scenario(seed: int, path: str | os.PathLike, config: BarnConfig = BarnConfig()) -> Path:
    """Write :func:`generate_barn_scenario` to ``path`` with the robot included relative to it."""
    return _write_with_robot(path, lambda include: generate_barn_scenario(seed, config, include=include))
