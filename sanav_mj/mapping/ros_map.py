"""Maps from elsewhere: the ROS ``map_server`` format (YAML + PGM/PNG image).

A map is a YAML file such as::

    image: building.pgm        # relative to the YAML file, or absolute
    resolution: 0.05           # [m/pixel]
    origin: [-10.0, -5.0, 0.0] # [m, m, rad] world pose of the lower-left pixel's corner
    negate: 0                  # 1: white is occupied
    occupied_thresh: 0.65      # occupancy probability above which a pixel is occupied
    free_thresh: 0.196         # below which it is free
    mode: trinary              # optional: trinary (default), scale or raw

Pixels are read as ROS does: the average of the colour channels ``x`` in 0..255 gives the
occupancy probability ``p = (255 - x) / 255`` (``x / 255`` when ``negate``); ``p >
occupied_thresh`` is occupied, ``p < free_thresh`` free, anything between unknown (in
``scale`` mode too: a probability between the thresholds is not free space for a planner
that must stay in observed free space; a transparent pixel is unknown). In ``raw`` mode the
value itself is the occupancy in percent (0..100), anything else unknown. The image's top
row is the map's far (+y) edge.

Only the flat ``key: value`` subset of YAML that map files use is read (numbers, strings,
``[a, b, c]`` lists, ``#`` comments); a rotated map (origin yaw != 0) is rejected, as most
ROS tools ignore that yaw.

:func:`load_ros_map` gives a :class:`RosMap` (free / occupied / unknown cells);
:func:`ros_map_grid` the inflated :class:`~sanav_mj.mapping.occupancy.OccupancyGrid` the
safe-area pipeline takes (unknown counts as occupied); :func:`scenario_xml_from_map` a
scenario MJCF whose obstacles are the map's merged occupied quadtree leaves, so the user's
map can be driven in MuJoCo.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from sanav_mj.mapping.live_grid import FREE, OCCUPIED, UNKNOWN, inflation_offsets
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.quadtree import build_quadtree
from sanav_mj.mapping.safe_areas import merge_rects

MODES = ("trinary", "scale", "raw")


class RosMapError(ValueError):
    """A ROS map file is unusable. The message is one line naming the file and the field."""


@dataclass(frozen=True)
class RosMap:
    """A map_server map in the world frame.

    Attributes:
        states: (ny, nx) int8 :data:`~sanav_mj.mapping.live_grid.FREE`,
            :data:`~sanav_mj.mapping.live_grid.OCCUPIED` or
            :data:`~sanav_mj.mapping.live_grid.UNKNOWN`; row 0 is the bottom (min y) row.
        resolution: [m] cell edge.
        origin: (2,) [m] world x, y of the lower-left cell's corner.
        path: the YAML file.
        image: the image file.
    """

    states: np.ndarray
    resolution: float
    origin: np.ndarray
    path: Path
    image: Path

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) cells."""
        return self.states.shape

    @property
    def bounds(self) -> np.ndarray:
        """(4,) [m] xmin, ymin, xmax, ymax of the map's extent."""
        ny, nx = self.shape
        x0, y0 = self.origin
        h = self.resolution
        return np.array([x0, y0, x0 + nx * h, y0 + ny * h])


def _scalar(text: str):
    t = text.strip()
    if len(t) >= 2 and t[0] == t[-1] and t[0] in "'\"":
        return t[1:-1]
    low = t.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def _parse_yaml(path: Path, text: str) -> dict:
    out: dict = {}
    for n, raw in enumerate(text.splitlines(), 1):
        line = re.sub(r"\s+#.*$|^#.*$", "", raw).rstrip()
        if not line.strip() or line.strip() == "---":
            continue
        if line[0].isspace():
            raise RosMapError(f"{path}: line {n}: nested YAML is not part of a map file: {raw.strip()!r}")
        key, sep, value = line.partition(":")
        if not sep or not key.strip():
            raise RosMapError(f"{path}: line {n}: expected 'key: value', got {raw.strip()!r}")
        value = value.strip()
        if value.startswith("["):
            if not value.endswith("]"):
                raise RosMapError(f"{path}: line {n}: unterminated list for {key.strip()!r}")
            inner = value[1:-1].strip()
            out[key.strip()] = [_scalar(v) for v in inner.split(",")] if inner else []
        else:
            out[key.strip()] = _scalar(value)
    return out


def _number(path: Path, meta: dict, name: str, lo: float, hi: float, lo_open=False, hi_open=False) -> float:
    if name not in meta:
        raise RosMapError(f"{path}: field {name!r} is missing")
    v = meta[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise RosMapError(f"{path}: field {name!r} must be a finite number, got {v!r}")
    if (v <= lo if lo_open else v < lo) or (v >= hi if hi_open else v > hi):
        rng = f"{'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
        raise RosMapError(f"{path}: field {name!r} must be in {rng}, got {v!r}")
    return float(v)


def _read_image(path: Path, image: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Channel average (ny, nx) float in 0..255 and alpha (or None), top row first."""
    from PIL import Image, UnidentifiedImageError

    if not image.is_file():
        raise RosMapError(f"{path}: field 'image': file {image} does not exist")
    try:
        with Image.open(image) as im:
            im.load()
            mode = im.mode
            arr = np.asarray(im)
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise RosMapError(f"{path}: field 'image': cannot read {image}: {exc}".replace("\n", " ")) from None
    if arr.dtype != np.uint8:
        raise RosMapError(f"{path}: field 'image': {image} must be an 8-bit grey or colour image, "
                          f"got mode {mode}")
    if arr.ndim == 2:
        return arr.astype(float), None
    if arr.ndim == 3 and arr.shape[2] in (2, 4):  # LA / RGBA
        return arr[..., :-1].astype(float).mean(axis=2), arr[..., -1]
    if arr.ndim == 3 and arr.shape[2] == 3:
        return arr.astype(float).mean(axis=2), None
    raise RosMapError(f"{path}: field 'image': {image} has an unsupported layout {arr.shape} (mode {mode})")


def load_ros_map(path) -> RosMap:
    """Load a ROS map_server map (YAML + image).

    Args:
        path: the YAML file.

    Returns:
        The map (states bottom row first, in the world frame).

    Raises:
        RosMapError: one line naming the file and the field (missing file or field, bad
            value, unreadable image).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RosMapError(f"{path}: cannot read map file: {exc.strerror or exc}") from None
    meta = _parse_yaml(path, text)
    if not meta:
        raise RosMapError(f"{path}: empty map file (expected image, resolution, origin, ...)")
    img = meta.get("image")
    if not isinstance(img, str) or not img:
        raise RosMapError(f"{path}: field 'image' is missing or not a file name (got {img!r})")
    res = _number(path, meta, "resolution", 0.0, math.inf, lo_open=True, hi_open=True)
    origin = meta.get("origin")
    if not (isinstance(origin, list) and len(origin) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in origin)):
        raise RosMapError(f"{path}: field 'origin' must be [x, y, yaw] (3 finite numbers), got {origin!r}")
    if abs(origin[2]) > 1e-12:
        raise RosMapError(f"{path}: field 'origin': yaw must be 0 (rotated maps are not supported), "
                          f"got {origin[2]!r}")
    negate = meta.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise RosMapError(f"{path}: field 'negate' must be 0 or 1, got {negate!r}")
    occ_t = _number(path, meta, "occupied_thresh", 0.0, 1.0)
    free_t = _number(path, meta, "free_thresh", 0.0, 1.0)
    if not free_t < occ_t:
        raise RosMapError(f"{path}: fields 'free_thresh' ({free_t}) and 'occupied_thresh' ({occ_t}) "
                          "must satisfy free_thresh < occupied_thresh")
    mode = meta.get("mode", "trinary")
    if mode not in MODES:
        raise RosMapError(f"{path}: field 'mode' must be one of {MODES}, got {mode!r}")
    image = Path(img) if Path(img).is_absolute() else path.parent / img
    value, alpha = _read_image(path, image)
    if mode == "raw":
        v = value if not negate else 255.0 - value
        states = np.where((v >= 0) & (v <= 100), np.where(v / 100.0 > occ_t, OCCUPIED,
                                                           np.where(v / 100.0 < free_t, FREE, UNKNOWN)), UNKNOWN)
    else:
        p = value / 255.0 if negate else (255.0 - value) / 255.0
        states = np.where(p > occ_t, OCCUPIED, np.where(p < free_t, FREE, UNKNOWN))
        if mode == "scale" and alpha is not None:
            states = np.where(alpha < 255, UNKNOWN, states)
    states = np.ascontiguousarray(states[::-1]).astype(np.int8)  # image top row = max y
    return RosMap(states=states, resolution=res, origin=np.array(origin[:2], dtype=float),
                  path=path, image=image)


def ros_map_grid(ros_map: RosMap, inflation: float) -> OccupancyGrid:
    """The inflated occupancy grid of a map (unknown counts as occupied).

    A cell is occupied when an occupied or unknown cell lies within ``inflation`` of it,
    square to square (:func:`~sanav_mj.mapping.live_grid.inflation_offsets`), as the lidar
    map inflates. The map's border is not inflated (as the known-map grid's workspace
    border is not).

    Args:
        ros_map: the map.
        inflation: [m] robot footprint radius + margin, >= 0.
    """
    if not (isinstance(inflation, (int, float)) and math.isfinite(inflation) and inflation >= 0):
        raise ValueError(f"inflation must be a finite number >= 0 [m], got {inflation!r}")
    off = inflation_offsets(float(inflation), ros_map.resolution)
    r = int(np.abs(off).max())
    kernel = np.zeros((2 * r + 1, 2 * r + 1), dtype=bool)
    kernel[off[:, 0] + r, off[:, 1] + r] = True
    occupied = ndimage.binary_dilation(ros_map.states != FREE, structure=kernel, border_value=0)
    return OccupancyGrid(occupied=occupied, resolution=ros_map.resolution, origin=ros_map.origin.copy(),
                         inflation=float(inflation), bounds=ros_map.bounds)


def occupied_boxes(ros_map: RosMap, unknown_occupied: bool = True) -> np.ndarray:
    """Occupied cells as few disjoint boxes: the merged occupied quadtree leaves.

    Args:
        ros_map: the map.
        unknown_occupied: count unknown cells as occupied (walls where the map knows nothing).

    Returns:
        (K, 4) float [m] world ``xmin, ymin, xmax, ymax`` whose union is exactly the
        occupied (and unknown) cells.
    """
    blocked = ros_map.states == OCCUPIED
    if unknown_occupied:
        blocked |= ros_map.states == UNKNOWN
    leaves = build_quadtree(~blocked)  # "occupied" leaves of the complement = blocked leaves
    free_of_complement = leaves.boxes[leaves.free]
    boxes = merge_rects(free_of_complement) if len(free_of_complement) else free_of_complement
    h = ros_map.resolution
    x0, y0 = ros_map.origin
    return np.stack([x0 + h * boxes[:, 1], y0 + h * boxes[:, 0], x0 + h * boxes[:, 3], y0 + h * boxes[:, 2]],
                    axis=1).astype(float) if len(boxes) else np.zeros((0, 4))


def scenario_xml_from_map(ros_map: RosMap, start, goal, *, height: float = 0.5,
                          include: str = "diff_drive.xml", unknown_occupied: bool = True,
                          name: str | None = None) -> str:
    """A scenario MJCF (the format of docs/scenarios.md) whose world is the map.

    The floor is the map's extent; every merged block of occupied (and, by default, unknown)
    cells is a static box ``height`` tall.

    Args:
        ros_map: the map.
        start: (3,) [m, m, rad] robot start x, y, yaw.
        goal: (2,) [m] goal x, y.
        height: [m] obstacle height, > 0 (the lidar sees obstacles taller than 0.1 m).
        include: the robot file to include (``diff_drive.xml`` resolves to the packaged robot).
        unknown_occupied: unknown cells become obstacles too.
        name: model name (default: the YAML file's stem).

    Returns:
        The MJCF text. :func:`sanav_mj.scene.load_scenario` checks start and goal against the
        obstacles when the file is loaded.

    Raises:
        ValueError: start / goal not finite or outside the map, height not > 0.
    """
    s = np.asarray(start, dtype=float).reshape(-1)
    g = np.asarray(goal, dtype=float).reshape(-1)
    if s.shape != (3,) or not np.all(np.isfinite(s)):
        raise ValueError(f"start must be 3 finite numbers x, y, yaw, got {list(np.atleast_1d(start))}")
    if g.shape != (2,) or not np.all(np.isfinite(g)):
        raise ValueError(f"goal must be 2 finite numbers x, y, got {list(np.atleast_1d(goal))}")
    if not (isinstance(height, (int, float)) and math.isfinite(height) and height > 0):
        raise ValueError(f"height must be a finite number > 0 [m], got {height!r}")
    b = ros_map.bounds
    for what, p in (("start", s[:2]), ("goal", g)):
        if not (b[0] < p[0] < b[2] and b[1] < p[1] < b[3]):
            raise ValueError(f"{what} ({p[0]:g}, {p[1]:g}) lies outside the map {ros_map.path} "
                             f"x [{b[0]:g}, {b[2]:g}], y [{b[1]:g}, {b[3]:g}]")
    boxes = occupied_boxes(ros_map, unknown_occupied)
    cx, cy = 0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3])
    hx, hy = 0.5 * (b[2] - b[0]), 0.5 * (b[3] - b[1])
    f = "{:.10g}".format
    lines = [
        f'<mujoco model="{name or ros_map.path.stem}">',
        f"  <!-- made from the ROS map {ros_map.path.name} ({ros_map.shape[1]} x {ros_map.shape[0]} cells at "
        f"{f(ros_map.resolution)} m) by sanav_mj.mapping.ros_map -->",
        f'  <include file="{include}"/>',
        "  <custom>",
        f'    <numeric name="start" data="{f(s[0])} {f(s[1])} {f(s[2])}"/>',
        f'    <numeric name="goal" data="{f(g[0])} {f(g[1])}"/>',
        "  </custom>",
        "  <worldbody>",
        f'    <geom name="floor" type="plane" pos="{f(cx)} {f(cy)} 0" size="{f(hx)} {f(hy)} 0.1" '
        'rgba="0.8 0.8 0.8 1"/>',
    ]
    hz = 0.5 * height
    for k, (x0, y0, x1, y1) in enumerate(boxes.tolist()):
        lines.append(f'    <geom name="map_{k}" type="box" pos="{f(0.5 * (x0 + x1))} {f(0.5 * (y0 + y1))} {f(hz)}" '
                     f'size="{f(0.5 * (x1 - x0))} {f(0.5 * (y1 - y0))} {f(hz)}" rgba="0.5 0.5 0.5 1"/>')
    lines += [f'    <site name="goal" pos="{f(g[0])} {f(g[1])} 0.01" size="0.1" rgba="0.1 0.8 0.1 1"/>',
              "  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)
