"""docs/scenarios.md: its complete example loads as the text says, and its rejection rules hold."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import sanav_mj
from sanav_mj.scene import ScenarioError, load_scenario

DOC = Path(__file__).resolve().parents[1] / "docs" / "scenarios.md"


def example_xml() -> str:
    blocks = re.findall(r"^```xml\n(.*?)^```", DOC.read_text(), flags=re.S | re.M)
    assert len(blocks) == 1, "docs/scenarios.md should have exactly one complete example"
    return blocks[0]


@pytest.fixture
def example(tmp_path) -> Path:
    path = tmp_path / "my_room.xml"  # no diff_drive.xml next to it: the packaged robot is used
    path.write_text(example_xml())
    return path


def test_the_example_loads_as_documented(example):
    sc = load_scenario(example)
    assert [o.name for o in sc.obstacles] == ["wall", "pillar", "bollard", "shelf_left", "shelf_right"]
    assert [o.kind for o in sc.obstacles] == ["box", "cylinder", "capsule", "box", "box"]
    np.testing.assert_array_equal(sc.bounds, [-1.0, -3.0, 8.0, 3.0])
    np.testing.assert_array_equal(sc.start, [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(sc.goal, [7.0, 1.0])
    wall = sc.obstacles[0]
    assert math.isclose(wall.yaw, math.radians(20), abs_tol=1e-12)
    np.testing.assert_allclose(wall.half_size, [0.15, 1.5])
    # the static body's frame moves its geoms: centre (6, -2.4) + R(10 deg) (-0.6, 0)
    c, s = math.cos(math.radians(10)), math.sin(math.radians(10))
    shelf_left = sc.obstacles[3]
    np.testing.assert_allclose(shelf_left.center, [6 - 0.6 * c, -2.4 - 0.6 * s], atol=1e-12)
    assert math.isclose(shelf_left.yaw, math.radians(10), abs_tol=1e-12)
    assert 0.3 < sc.robot.footprint_radius < 0.35  # "0.33 m for the shipped robot"


def test_the_example_has_a_plan(example):
    assert sanav_mj.plan(example).ok


def replaced(xml: str, old: str, new: str) -> str:
    assert old in xml
    return xml.replace(old, new)


DECORATION = '<geom name="marking" type="sphere" pos="1 -2 0.01" size="0.1" contype="0" conaffinity="0"/>'


@pytest.mark.parametrize(
    "old, new, match",
    [
        (DECORATION, '<geom name="marking" type="sphere" pos="1 -2 0.01" size="0.1"/>', "unsupported obstacle geom 'marking'"),
        ('<body name="shelf" pos="6 -2.4 0" euler="0 0 10">',
         '<body name="shelf" pos="6 -2.4 0" euler="0 0 10"><joint name="slide" type="slide"/>', "moving body 'shelf'"),
        ('size="0.3 0.4"/>', 'size="0.3 0.4" euler="30 0 0"/>', "cylinder 'pillar' is tilted"),
        ('<numeric name="goal"  data="7 1"/>', "", "missing goal"),
        ('data="7 1"', 'data="2.5 0.5"', "goal .* is inside obstacle 'wall'"),
        ('size="4.5 3 0.1"', 'size="0 0 0.1"', "floor plane 'floor'"),
        ('size="4.5 3 0.1"', 'size="-4.5 3 0.1"', "floor plane 'floor' has a negative size"),
        ('pos="5 -1.2 0.4"', 'pos="5 nan 0.4"', "geom 'pillar': pos must be finite"),
        ('euler="0 0 20"', 'euler="0 0 inf"', "geom 'wall': orientation"),
        ('<include file="diff_drive.xml"/>', '<include file="diff_drive.xml"/><option timestep="0"/>', r"<option timestep>"),
    ],
)
def test_documented_rejections(tmp_path, old, new, match):
    path = tmp_path / "bad.xml"
    path.write_text(replaced(example_xml(), old, new))
    with pytest.raises(ScenarioError, match=match):
        load_scenario(path)
