"""Helpers shared by test modules in more than one folder (imported as ``_helpers``: pytest puts
``tests/`` on the path for ``tests/conftest.py``)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np

from sanav_mj.eval.prepare import Prepared
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.quadtree import QuadtreeLeaves
from sanav_mj.mapping.safe_areas import SafeAreaMap, SafeAreas
from sanav_mj.native import NO_KERNEL_ENV
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.resources import robot_model_path
from sanav_mj.scene import Obstacle, RobotParams, Scenario


def make_prep(post: str = "cylinder") -> Prepared:
    """A small hand-made map and plan (tests/test_record.py, tests/eval/test_plots.py): workspace
    x [-1, 5] m, y [-2, 2] m, goal (4, 0); 2 obstacles (a box "wall", a ``post`` of that geom type
    at (1, 1.2)), a 8 x 12 occupancy grid of 0.5 m cells, 6 quadtree leaves, 3 safe areas, a plan
    through areas 1, 0, 2 with a 21-point reference (dt 0.1 s)."""
    model = mujoco.MjModel.from_xml_path(str(robot_model_path()))
    robot = RobotParams(0.1, 0.38, 0.33, 20.0, 2.0, 3.0, 1.5, 4.0)
    obstacles = (
        Obstacle("wall", "box", np.array([2.0, 0.0]), 0.3, np.array([0.1, 0.8]), 0.5, 1),
        Obstacle("post", post, np.array([1.0, 1.2]), 0.0, np.array([0.2, 0.2]), 0.5, 2),
    )
    bounds = np.array([-1.0, -2.0, 5.0, 2.0])
    sc = Scenario("fixture", Path("fixture.xml"), model, obstacles, np.zeros(3), np.array([4.0, 0.0]), bounds, robot)
    occ = np.zeros((8, 12), dtype=bool)
    occ[2:6, 5:7] = True
    grid = OccupancyGrid(occ, 0.5, np.array([-1.0, -2.0]), 0.38, bounds)
    boxes = np.array([[0, 0, 4, 4], [0, 4, 4, 8], [0, 8, 4, 12], [4, 0, 8, 4], [4, 4, 8, 8], [4, 8, 8, 12]])
    leaves = QuadtreeLeaves(boxes, np.array([True, False, True, True, False, True]), np.ones(6, dtype=np.int64))
    rects = np.array([[-1, -2, 5, -1], [-1, -1, 1.5, 2], [2.5, -1, 5, 2]], dtype=float)
    areas = SafeAreas(rects, np.array([[0, 1], [0, 2]]), np.array([2.0, 2.5]), np.zeros((2, 2, 2)))
    wp = np.array([[0.0, 0.0], [1.0, -1.0], [3.0, -1.0], [4.0, 0.0]])
    s = np.linspace(0.0, 1.0, 21)
    states = np.column_stack((4.0 * s, -0.8 * np.sin(np.pi * s), np.zeros(21)))
    ref = Reference(0.1, states, np.zeros((21, 2)), np.zeros(21, dtype=int))
    plan = Plan(True, "ok", np.array([1, 0, 2]), np.array([4.0, 0.0]), wp, wp, states[:, :2], ref)
    return Prepared(sc, SafeAreaMap(grid, leaves, np.zeros((0, 4), np.int64), areas, 1, "paper"), plan, {"total": 1.0})


def cells_of_box(box, origin, h: float, shape: tuple[int, int]) -> tuple[slice, slice]:
    """Row and column slices of the cells of a grid (``origin`` (2,) [m], cells of ``h`` [m],
    ``shape`` (ny, nx)) whose interior meets the box (xmin, ymin, xmax, ymax) [m]; tolerance
    1e-9 of a cell (box edges lie on cell boundaries up to float rounding of origin + k h)
    (tests/eval/test_sensing_loop.py, tests/eval/test_sensing_discs.py)."""
    ny, nx = shape
    j0 = int(np.clip(math.floor((box[0] - origin[0]) / h + 1e-9), 0, nx))
    i0 = int(np.clip(math.floor((box[1] - origin[1]) / h + 1e-9), 0, ny))
    j1 = int(np.clip(math.ceil((box[2] - origin[0]) / h - 1e-9), 0, nx))
    i1 = int(np.clip(math.ceil((box[3] - origin[1]) / h - 1e-9), 0, ny))
    return slice(i0, i1), slice(j0, j1)


def run_without_kernels(code: str) -> str:
    """The standard output of ``code`` run by a fresh Python process with the compiled
    kernels switched off (:data:`sanav_mj.native.NO_KERNEL_ENV` = 1; the NumPy reference
    paths run instead), from the current directory; raises CalledProcessError when it fails."""
    env = dict(os.environ, **{NO_KERNEL_ENV: "1"})
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
