"""ROS map_server maps on the command line: ``areas map.yaml``, ``scenario map.yaml -o``, ``run map.yaml``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sanav_mj.cli import main
from sanav_mj.eval.maps import is_ros_map, ros_areas_document, scenario_from_ros_map
from sanav_mj.scene import ScenarioError, load_scenario


def _room(tmp_path: Path) -> Path:
    """A 6 m x 4 m room at 0.05 m (origin (-1, -2)): black border, a 0.5 m pillar in the middle,
    a grey (unknown) patch in a corner."""
    px = np.full((80, 120), 254, dtype=np.uint8)
    px[:2, :] = px[-2:, :] = px[:, :2] = px[:, -2:] = 0
    px[30:50, 50:60] = 0  # pillar: x in [1.5, 2.0], y in [-0.5, 0.5]
    px[3:10, 100:115] = 205  # unknown
    img = tmp_path / "room.pgm"
    h, w = px.shape
    img.write_bytes(f"P5\n{w} {h}\n255\n".encode() + px.tobytes())
    y = tmp_path / "room.yaml"
    y.write_text("image: room.pgm\nresolution: 0.05\norigin: [-1.0, -2.0, 0.0]\nnegate: 0\n"
                 "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return y


def test_areas_on_a_ros_map(tmp_path, capsys):
    y = _room(tmp_path)
    assert is_ros_map(y) and not is_ros_map("u_shape")
    out = tmp_path / "areas.json"
    assert main(["areas", str(y), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["grid"]["resolution"] == 0.05 and doc["grid"]["shape"] == [80, 120]
    assert doc["corridor"] == [] and len(doc["rects"]) > 0
    assert doc == {**ros_areas_document(y), "timing_ms": doc["timing_ms"]}
    rects = np.array(doc["rects"])
    # no safe area touches the pillar inflated by the robot's radius
    infl = doc["grid"]["inflation"]
    dx = np.maximum(np.maximum(1.5 - rects[:, 2], rects[:, 0] - 2.0), 0)
    dy = np.maximum(np.maximum(-0.5 - rects[:, 3], rects[:, 1] - 0.5), 0)
    assert np.hypot(dx, dy).min() >= infl - 0.05  # the grid rasterises at the map's 0.05 m cells
    assert "room:" in capsys.readouterr().out


def test_scenario_command_and_run_on_a_ros_map(tmp_path, capsys):
    y = _room(tmp_path)
    xml = tmp_path / "room_scen.xml"
    assert main(["scenario", str(y), "--start", "0", "0", "0", "--goal", "4", "0", "-o", str(xml)]) == 0
    sc = load_scenario(xml)
    assert np.allclose(sc.start, [0, 0, 0]) and np.allclose(sc.goal, [4, 0])
    assert len(sc.obstacles) >= 5  # four walls (merged blocks), the pillar, the unknown patch
    js = tmp_path / "run.json"
    code = main(["run", str(y), "--start", "0", "0", "0", "--goal", "4", "0", "--json", str(js)])
    doc = json.loads(js.read_text())
    assert code == 0 and doc["success"] and doc["collisions"] == 0 and doc["scenario"] == "room"
    code = main(["run", str(y), "--start", "0", "0", "0", "--goal", "4", "0", "--sensing", "lidar", "--json", str(js)])
    doc = json.loads(js.read_text())
    assert code == 0 and doc["success"] and doc["collisions"] == 0 and doc["sensing"] == "lidar"


@pytest.mark.parametrize("argv, needle", [
    (["run", "{y}", "--start", "0", "0", "0"], "--goal"),
    (["run", "u_shape", "--goal", "1", "1"], "only for a ROS map"),
    (["scenario", "{y}", "--start", "0", "0", "0", "--goal", "1.75", "0", "-o", "{tmp}/x.xml"], "goal"),
    (["scenario", "{y}", "--start", "0", "0", "0", "--goal", "40", "0", "-o", "{tmp}/x.xml"], "goal"),
    (["areas", "{tmp}/missing.yaml"], "missing.yaml"),
    (["areas", "{y}", "--plot", "{tmp}/p.png"], "--plot"),
])
def test_ros_map_errors_are_one_line_exit_2(tmp_path, capsys, argv, needle):
    y = _room(tmp_path)
    argv = [a.format(y=y, tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err
    assert not (tmp_path / "x.xml").exists()


def test_scenario_from_ros_map_rejects_start_in_an_obstacle(tmp_path):
    with pytest.raises(ScenarioError, match="room.yaml"):
        scenario_from_ros_map(_room(tmp_path), (1.75, 0.0, 0.0), (4.0, 0.0))
