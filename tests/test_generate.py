"""Tests of the seeded random clutter scenario generator and its script."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from sanav_mj.generate import (
    ClutterConfig,
    connected,
    generate_layout,
    generate_scenario,
    nominal_robot,
    write_scenario,
)
from sanav_mj.mapping.occupancy import rasterise
from sanav_mj.resources import robot_model_path
from sanav_mj.scene import Obstacle, load_scenario

REPO = Path(__file__).resolve().parents[1]
SEEDS = range(12)


def wall(x, y0, y1, name="w"):
    return Obstacle(name, "box", np.array([x, 0.5 * (y0 + y1)]), 0.0, np.array([0.1, 0.5 * (y1 - y0)]), 0.5, 0)


def test_same_seed_same_text_and_different_seeds_differ():
    texts = [generate_scenario(s) for s in SEEDS]
    assert texts[3] == generate_scenario(3)
    assert len(set(texts)) == len(texts)


@pytest.mark.parametrize("seed", SEEDS)
def test_generated_file_loads_and_matches_the_layout(seed, tmp_path):
    config = ClutterConfig()
    layout = generate_layout(seed, config)
    scenario = load_scenario(write_scenario(seed, tmp_path / f"c{seed}.xml", config))
    assert config.n_min <= len(scenario.obstacles) <= config.n_max
    np.testing.assert_allclose(scenario.bounds, [0.0, -3.0, 10.0, 3.0])
    np.testing.assert_allclose(scenario.start, layout.start, atol=1e-12)
    np.testing.assert_allclose(scenario.goal, layout.goal, atol=1e-12)
    assert scenario.start[0] == pytest.approx(config.start_x_m)
    assert scenario.goal[0] == pytest.approx(config.width_m - config.goal_x_m)
    assert len(scenario.obstacles) == len(layout.obstacles)
    for got, want in zip(scenario.obstacles, layout.obstacles):
        assert (got.name, got.kind) == (want.name, want.kind)
        # exact: the layout's numbers are rounded to the digits written, so the file parses back to
        # the same doubles, and a world-body geom's position and size pass through MuJoCo unchanged
        np.testing.assert_array_equal(got.center, want.center)
        np.testing.assert_array_equal(got.half_size, want.half_size)
        assert got.height == pytest.approx(want.height, abs=1e-9)
        if got.kind == "box":
            # a box's yaw is defined modulo pi. The quaternion (cos, 0, 0, sin)(yaw / 2) is written
            # with 9 decimals (each component off by <= 5e-10): yaw / 2 moves by <= (|c| + |s|) 5e-10
            # <= sqrt(2) 5e-10, the yaw by twice that (1.41e-9; measured 1.28e-9 over 40 seeds)
            assert np.sin(got.yaw - want.yaw) == pytest.approx(0.0, abs=2 * math.sqrt(2) * 0.5e-9 + 1e-14)


@pytest.mark.parametrize("seed", SEEDS)
def test_generated_maps_are_solvable_at_the_episode_resolution(seed, tmp_path):
    """Start and goal are 4-connected on the 0.05 m grid inflated as in an episode."""
    scenario = load_scenario(write_scenario(seed, tmp_path / "c.xml"))
    grid = rasterise(scenario.obstacles, scenario.bounds, 0.05, inflation=scenario.robot.footprint_radius + 0.05)
    labels, _ = ndimage.label(~grid.occupied)
    cell = [tuple(np.floor((p[::-1] - grid.origin[::-1]) / grid.resolution).astype(int))
            for p in (scenario.start[:2], scenario.goal)]
    assert labels[cell[0]] != 0
    assert labels[cell[0]] == labels[cell[1]]


def test_start_and_goal_keep_their_clearance():
    config = ClutterConfig()
    keep_out = nominal_robot().footprint_radius + config.margin_m + config.endpoint_clearance_m
    for seed in SEEDS:
        layout = generate_layout(seed, config)
        for ob in layout.obstacles:
            assert ob.signed_distance(layout.start[:2]) >= keep_out
            assert ob.signed_distance(layout.goal) >= keep_out


def test_all_kinds_appear_and_counts_follow_the_config():
    config = ClutterConfig(n_min=3, n_max=5)
    kinds, counts = set(), set()
    for seed in range(30):
        layout = generate_layout(seed, config)
        counts.add(len(layout.obstacles))
        kinds |= {ob.kind for ob in layout.obstacles}
    assert counts <= {3, 4, 5} and len(counts) > 1
    assert kinds == {"box", "cylinder", "capsule"}
    only_cylinders = ClutterConfig(kind_weights=(0.0, 1.0, 0.0))
    assert {ob.kind for ob in generate_layout(0, only_cylinders).obstacles} == {"cylinder"}


def test_footprint_radius_comes_from_the_robot_model():
    import mujoco

    from sanav_mj.scene import robot_params

    model = mujoco.MjModel.from_xml_path(str(robot_model_path()))
    assert nominal_robot().footprint_radius == robot_params(model).footprint_radius


def test_connected_known_answers():
    bounds = np.array([0.0, -3.0, 10.0, 3.0])
    start, goal = np.array([1.0, 0.0]), np.array([9.0, 0.0])
    infl = 0.4
    assert connected([], bounds, start, goal, infl, 0.1)
    # a full-height wall cuts the map
    assert not connected([wall(5.0, -3.0, 3.0)], bounds, start, goal, infl, 0.1)
    # a 1.2 m gap (wider than 2 x 0.4 m plus the cell rounding) connects; a 0.6 m gap does not
    assert connected([wall(5.0, -3.0, -0.6), wall(5.0, 0.6, 3.0)], bounds, start, goal, infl, 0.1)
    assert not connected([wall(5.0, -3.0, -0.3), wall(5.0, 0.3, 3.0)], bounds, start, goal, infl, 0.1)
    # a goal inside an inflated obstacle is never connected
    assert not connected([wall(9.2, -0.5, 0.5)], bounds, start, goal, infl, 0.1)


@pytest.mark.parametrize(
    ("field", "value"),
    [("width_m", 0.0), ("n_min", -1), ("n_max", 1.5), ("margin_m", -0.1), ("endpoint_y_fraction", 1.0),
     ("box_half_max_m", 0.05), ("kind_weights", (0.0, 0.0, 0.0)), ("max_attempts", 0)],
)
def test_config_rejects_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        ClutterConfig(**{field: value})


def test_config_rejects_endpoints_that_do_not_fit():
    with pytest.raises(ValueError, match="start_x_m"):
        ClutterConfig(width_m=2.0, start_x_m=1.0, goal_x_m=1.0)
    with pytest.raises(ValueError, match="start"):
        generate_layout(0, ClutterConfig(start_x_m=0.2))


def test_too_crowded_config_is_a_clear_error():
    crowded = ClutterConfig(n_min=200, n_max=200, box_half_min_m=1.0, box_half_max_m=1.5, max_attempts=60)
    with pytest.raises(ValueError, match="max_attempts"):
        generate_layout(0, crowded)


def test_bad_seed_is_rejected():
    with pytest.raises(ValueError, match="seed"):
        generate_layout(-1)


def test_default_include_is_absolute_and_written_include_is_relative(tmp_path):
    assert f'<include file="{robot_model_path()}"/>' in generate_scenario(0)
    path = write_scenario(0, tmp_path / "deep" / "dir" / "c.xml")
    text = path.read_text()
    include = text.split('<include file="', 1)[1].split('"', 1)[0]
    assert not Path(include).is_absolute()
    assert (path.parent / include).resolve() == robot_model_path().resolve()
    assert load_scenario(path).name == "c"
    # the rest of the text is the same as with the absolute include
    assert text.replace(include, str(robot_model_path())) == generate_scenario(0)


def test_script_writes_count_files(tmp_path):
    out = tmp_path / "maps"
    proc = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "gen_scenarios.py"), "--count", "3", "--seed", "5", "--out", str(out)],
        capture_output=True, text=True, check=False, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    files = sorted(p.name for p in out.glob("*.xml"))
    assert files == ["clutter_0005.xml", "clutter_0006.xml", "clutter_0007.xml"]
    assert (out / "clutter_0006.xml").read_text() == write_scenario(6, tmp_path / "x" / "clutter_0006.xml").read_text()
    bad = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "gen_scenarios.py"), "--count", "2", "--n-min", "5", "--n-max", "2",
         "--out", str(out)],
        capture_output=True, text=True, check=False, timeout=120,
    )
    assert bad.returncode == 2 and "n_max" in bad.stderr and "Traceback" not in bad.stderr


def test_replace_keeps_validation():
    with pytest.raises(ValueError, match="n_max"):
        replace(ClutterConfig(), n_min=10, n_max=2)
