"""Maps from elsewhere: ROS ``map_server`` maps (YAML + PGM/PNG) as safe areas and as scenarios.

- :func:`ros_areas_document`: the ``areas --json`` document of a map alone (no start or goal:
  no corridor), on the map's own grid inflated by the packaged robot's footprint radius plus
  :data:`~sanav_mj.eval.prepare.DEFAULT_MARGIN_M` (unknown cells count as occupied).
- :func:`ros_scenario_xml` / :func:`scenario_from_ros_map`: a scenario MJCF made from the map
  (one box per merged block of occupied or unknown cells, the map's extent as the floor,
  the packaged robot) with a start and a goal given by the user, so every command that takes
  a scenario (``run``, ``bench``, ...) drives SA-MPC on the user's map in MuJoCo.

Errors are :class:`~sanav_mj.scene.ScenarioError` (one line naming the file and what is wrong).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from sanav_mj.scene import Scenario, ScenarioError

#: file suffixes of a ROS map_server map description
ROS_MAP_SUFFIXES = (".yaml", ".yml")


def is_ros_map(spec: str | Path) -> bool:
    """Whether ``spec`` names a ROS map YAML file (by its suffix)."""
    return Path(str(spec)).suffix.lower() in ROS_MAP_SUFFIXES


def _load(path: str | Path):
    from sanav_mj.mapping.ros_map import RosMapError, load_ros_map

    try:
        return load_ros_map(path)
    except (RosMapError, ValueError, OSError) as exc:
        text = str(exc)
        raise ScenarioError(text if str(path) in text else f"{path}: {text}") from None


def _robot_inflation() -> float:
    """[m] the packaged robot's footprint radius plus the known-map margin."""
    import mujoco

    from sanav_mj.eval.prepare import DEFAULT_MARGIN_M
    from sanav_mj.resources import robot_model_path
    from sanav_mj.scene import robot_params

    model = mujoco.MjModel.from_xml_path(str(robot_model_path()))
    return robot_params(model).footprint_radius + DEFAULT_MARGIN_M


def ros_areas_document(path: str | Path) -> dict[str, Any]:
    """The ``areas --json`` document of a ROS map without start and goal.

    The grid is the map's own (its resolution and origin), inflated by the packaged robot's
    footprint radius plus the margin; ``corridor`` and ``reference`` are empty.

    Args:
        path: the map's YAML file.

    Raises:
        ScenarioError: the map cannot be read (one line naming the file and the field).
    """
    import time

    from sanav_mj.mapping.ros_map import ros_map_grid
    from sanav_mj.mapping.safe_areas import build_safe_areas

    m = _load(path)
    t0 = time.perf_counter()
    grid = ros_map_grid(m, _robot_inflation())
    t1 = time.perf_counter()
    sam = build_safe_areas(grid)
    doc = {"scenario": Path(path).stem, **sam.to_json()}
    doc["corridor"] = []
    doc["reference"] = []
    timing = {"rasterise": 1e3 * (t1 - t0), **{k: float(v) for k, v in sam.timing_ms.items()}}
    timing["total"] = timing["rasterise"] + timing.get("total", 0.0)
    doc["timing_ms"] = timing
    return doc


def ros_scenario_xml(path: str | Path, start, goal) -> str:
    """The scenario MJCF of a ROS map with the given start (3,) [m, m, rad] and goal (2,) [m]
    (see :func:`sanav_mj.mapping.ros_map.scenario_xml_from_map`).

    Raises:
        ScenarioError: unreadable map, or start / goal not finite or outside the map.
    """
    from sanav_mj.mapping.ros_map import scenario_xml_from_map

    m = _load(path)
    try:
        return scenario_xml_from_map(m, start=np.asarray(start, float), goal=np.asarray(goal, float))
    except ValueError as exc:
        raise ScenarioError(f"{path}: {exc}") from None


def scenario_from_ros_map(path: str | Path, start, goal) -> Scenario:
    """Load the scenario made from a ROS map with a start and a goal (the MJCF is written to
    a temporary folder, compiled and removed; the scenario's name is the YAML file's stem).

    Raises:
        ScenarioError: unreadable map, start / goal outside the map or inside an inflated
            obstacle (checked by :func:`sanav_mj.scene.load_scenario`).
    """
    from sanav_mj.scene import load_scenario

    xml = ros_scenario_xml(path, start, goal)
    with tempfile.TemporaryDirectory(prefix="sanav_mj_map_") as tmp:
        file = Path(tmp) / f"{Path(path).stem}.xml"
        file.write_text(xml)
        try:
            return load_scenario(file)
        except ScenarioError as exc:
            raise ScenarioError(f"{path}: {str(exc).replace(str(file), 'scenario made from the map')}") from None
