"""ROS map_server maps: loading (PGM / PNG, modes, negate), errors, inflated grid, scenario MJCF."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sanav_mj.mapping.live_grid import FREE, OCCUPIED, UNKNOWN, dilate_count, inflation_offsets
from sanav_mj.mapping.occupancy import rasterise
from sanav_mj.mapping.ros_map import (
    RosMapError,
    load_ros_map,
    occupied_boxes,
    ros_map_grid,
    scenario_xml_from_map,
)
from sanav_mj.mapping.safe_areas import build_safe_areas
from sanav_mj.resources import robot_model_path
from sanav_mj.scene import load_scenario

YAML = """# a test map
image: {image}
resolution: {res}
origin: [{ox}, {oy}, 0.0]   # lower-left corner
negate: {negate}
occupied_thresh: 0.65
free_thresh: 0.196
{extra}"""


def _write_pgm(path: Path, pixels: np.ndarray) -> None:
    """Binary PGM (P5), written by hand (not with Pillow)."""
    h, w = pixels.shape
    path.write_bytes(f"P5\n# test\n{w} {h}\n255\n".encode() + pixels.astype(np.uint8).tobytes())


def _write(tmp_path, pixels, name="m", ext="pgm", negate=0, res=0.1, ox=-1.0, oy=2.0, extra="", image=None):
    img = tmp_path / f"{name}.{ext}"
    if ext == "pgm":
        _write_pgm(img, pixels)
    else:
        Image.fromarray(pixels).save(img)
    y = tmp_path / f"{name}.yaml"
    y.write_text(YAML.format(image=image or img.name, res=res, ox=ox, oy=oy, negate=negate, extra=extra))
    return y


def _room(h=30, w=40):
    """White (free) room with a black (occupied) border, a grey (unknown) block, a pillar."""
    px = np.full((h, w), 254, dtype=np.uint8)
    px[0, :] = px[-1, :] = px[:, 0] = px[:, -1] = 0
    px[2:5, 30:36] = 205  # unknown (p = 0.196..., just above free_thresh)
    px[15:18, 10:13] = 0  # pillar, image rows 15..17 = map rows h-18..h-16
    return px


def test_pgm_trinary_states_and_frame(tmp_path):
    px = _room()
    m = load_ros_map(_write(tmp_path, px))
    assert m.shape == (30, 40)
    assert m.resolution == 0.1
    np.testing.assert_array_equal(m.origin, [-1.0, 2.0])
    np.testing.assert_allclose(m.bounds, [-1.0, 2.0, 3.0, 5.0], atol=1e-12)
    st = m.states
    # image row r is map row h-1-r
    assert np.all(st[30 - 1 - 15:30 - 1 - 14, 10:13] == OCCUPIED)
    assert np.all(st[30 - 5:30 - 2, 30:36] == UNKNOWN)
    assert st[10, 20] == FREE
    assert np.count_nonzero(st == OCCUPIED) == 2 * 40 + 2 * 28 + 9
    assert np.count_nonzero(st == UNKNOWN) == 18


def test_negate_png_and_raw_and_scale_alpha(tmp_path):
    px = _room()
    neg = load_ros_map(_write(tmp_path, 255 - px, name="n", ext="png", negate=1))
    ref = load_ros_map(_write(tmp_path, px, name="r"))
    assert np.array_equal(neg.states, ref.states)
    # rgb: channel average
    rgb = np.stack([px, px, px], axis=2)
    assert np.array_equal(load_ros_map(_write(tmp_path, rgb, name="c", ext="png")).states, ref.states)
    # scale mode: transparent pixels are unknown
    rgba = np.dstack([rgb, np.full(px.shape, 255, np.uint8)])
    rgba[10, 20, 3] = 0
    sc = load_ros_map(_write(tmp_path, rgba, name="a", ext="png", extra="mode: scale\n"))
    expect = ref.states.copy()
    expect[30 - 1 - 10, 20] = UNKNOWN
    assert np.array_equal(sc.states, expect)
    # raw mode: the pixel is the occupancy in percent, above 100 unknown
    raw = np.array([[0, 50, 100, 255]], dtype=np.uint8)
    r = load_ros_map(_write(tmp_path, raw, name="w", extra="mode: raw\n"))
    assert r.states.tolist() == [[FREE, UNKNOWN, OCCUPIED, UNKNOWN]]


@pytest.mark.parametrize("edit,field", [
    (lambda t: t.replace("resolution: 0.1\n", ""), "'resolution' is missing"),
    (lambda t: t.replace("resolution: 0.1", "resolution: -0.1"), "'resolution' must be in"),
    (lambda t: t.replace("resolution: 0.1", "resolution: fine"), "'resolution' must be a finite number"),
    (lambda t: t.replace("[-1.0, 2.0, 0.0]", "[-1.0, 2.0]"), "'origin' must be [x, y, yaw]"),
    (lambda t: t.replace("[-1.0, 2.0, 0.0]", "[-1.0, 2.0, 0.5]"), "'origin': yaw must be 0"),
    (lambda t: t.replace("negate: 0", "negate: 2"), "'negate' must be 0 or 1"),
    (lambda t: t.replace("free_thresh: 0.196", "free_thresh: 0.7"), "must satisfy free_thresh < occupied_thresh"),
    (lambda t: t.replace("occupied_thresh: 0.65", "occupied_thresh: 1.5"), "'occupied_thresh' must be in"),
    (lambda t: t + "mode: fuzzy\n", "'mode' must be one of"),
    (lambda t: t.replace("image: m.pgm", "image: missing.pgm"), "'image': file"),
    (lambda t: t.replace("image: m.pgm\n", ""), "'image' is missing"),
    (lambda t: t + "nested:\n  a: 1\n", "nested YAML"),
    (lambda t: t + "just text\n", "expected 'key: value'"),
])
def test_errors_name_file_and_field(tmp_path, edit, field):
    y = _write(tmp_path, _room())
    y.write_text(edit(y.read_text()))
    with pytest.raises(RosMapError) as exc:
        load_ros_map(y)
    msg = str(exc.value)
    assert field in msg and str(y) in msg and "\n" not in msg


def test_unreadable_image_and_missing_yaml(tmp_path):
    y = _write(tmp_path, _room())
    (tmp_path / "m.pgm").write_bytes(b"not an image")
    with pytest.raises(RosMapError, match="'image': cannot read"):
        load_ros_map(y)
    with pytest.raises(RosMapError, match="cannot read map file"):
        load_ros_map(tmp_path / "nope.yaml")


def test_inflated_grid_and_safe_areas(tmp_path):
    m = load_ros_map(_write(tmp_path, _room(), res=0.05))
    infl = 0.12
    grid = ros_map_grid(m, infl)
    ref = dilate_count(m.states != FREE, inflation_offsets(infl, 0.05)) > 0
    assert np.array_equal(grid.occupied, ref)
    sam = build_safe_areas(grid)
    assert len(sam.areas.rects) > 0
    # every safe rectangle keeps more than the inflation from every non-free cell's square
    bad = np.argwhere(m.states != FREE)
    sq = np.stack([m.origin[0] + 0.05 * bad[:, 1], m.origin[1] + 0.05 * bad[:, 0]], axis=1)
    for x0, y0, x1, y1 in sam.areas.rects:
        dx = np.maximum(np.maximum(sq[:, 0] - x1, x0 - (sq[:, 0] + 0.05)), 0)
        dy = np.maximum(np.maximum(sq[:, 1] - y1, y0 - (sq[:, 1] + 0.05)), 0)
        assert np.hypot(dx, dy).min() > infl - 1e-9


def test_occupied_boxes_cover_exactly_the_blocked_cells(tmp_path):
    m = load_ros_map(_write(tmp_path, _room()))
    boxes = occupied_boxes(m)
    paint = np.zeros(m.shape, dtype=int)
    for x0, y0, x1, y1 in boxes:
        j0, i0 = round((x0 - m.origin[0]) / 0.1), round((y0 - m.origin[1]) / 0.1)
        j1, i1 = round((x1 - m.origin[0]) / 0.1), round((y1 - m.origin[1]) / 0.1)
        paint[i0:i1, j0:j1] += 1
    assert paint.max() == 1
    assert np.array_equal(paint == 1, m.states != FREE)
    assert len(boxes) < np.count_nonzero(m.states != FREE) // 4
    only_occ = occupied_boxes(m, unknown_occupied=False)
    assert len(only_occ) < len(boxes)


def test_scenario_from_map_loads_and_matches_the_map(tmp_path):
    m = load_ros_map(_write(tmp_path, _room(), res=0.1))
    xml = scenario_xml_from_map(m, (-0.4, 2.6, 0.3), (2.2, 3.5), include=str(robot_model_path()))
    path = tmp_path / "from_map.xml"
    path.write_text(xml)
    sc = load_scenario(path)
    np.testing.assert_allclose(sc.bounds, m.bounds, atol=1e-9)
    assert len(sc.obstacles) == len(occupied_boxes(m))
    np.testing.assert_allclose(sc.goal, [2.2, 3.5])
    # the obstacles cover exactly the map's blocked cells: rasterised without inflation, the
    # grid is the blocked cells plus the cells whose closed squares touch them
    blocked = m.states != FREE
    grid = rasterise(sc.obstacles, sc.bounds, 0.1, inflation=0.0)
    touch = dilate_count(blocked, inflation_offsets(0.0, 0.1)) > 0
    assert np.array_equal(grid.occupied, touch)
    # the default include names the packaged robot, so the file can be written anywhere
    portable = tmp_path / "portable.xml"
    portable.write_text(scenario_xml_from_map(m, (-0.4, 2.6, 0.3), (2.2, 3.5)))
    assert len(load_scenario(portable).obstacles) == len(sc.obstacles)
    with pytest.raises(ValueError, match="outside the map"):
        scenario_xml_from_map(m, (10.0, 3.5, 0.0), (2.2, 3.5))
    with pytest.raises(ValueError, match="goal must be 2"):
        scenario_xml_from_map(m, (0.0, 3.5, 0.0), (2.2,))
