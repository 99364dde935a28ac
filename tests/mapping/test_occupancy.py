"""Tests for sanav_mj.mapping.occupancy: exact, conservative rasterisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _mapping_reference import cell_distances, point_obstacle_distance
from sanav_mj.mapping.occupancy import grid_shape, rasterise
from sanav_mj.scene import Obstacle

DELTA = 1e-7  # [m] ties closer than this to the inflation radius are not judged


def box(cx, cy, hx, hy, yaw=0.0) -> Obstacle:
    return Obstacle("b", "box", np.array([cx, cy], float), float(yaw), np.array([hx, hy], float), 1.0, -1)


def disc(cx, cy, r, kind="cylinder") -> Obstacle:
    return Obstacle("c", kind, np.array([cx, cy], float), 0.0, np.array([r, r], float), 1.0, -1)


coord = st.floats(-0.4, 2.4, allow_nan=False)


@st.composite
def obstacles(draw):
    kind = draw(st.sampled_from(["box", "box", "cylinder", "capsule"]))
    cx, cy = draw(coord), draw(coord)
    if kind == "box":
        hx = draw(st.floats(0.0, 0.6))
        hy = draw(st.floats(0.0, 0.6))
        yaw = draw(st.one_of(st.floats(-7.0, 7.0), st.sampled_from([0.0, math.pi / 4, math.pi / 2, -math.pi])))
        return box(cx, cy, hx, hy, yaw)
    return disc(cx, cy, draw(st.floats(0.0, 0.5)), kind)


@st.composite
def maps(draw):
    obs = draw(st.lists(obstacles(), min_size=0, max_size=3))
    res = draw(st.sampled_from([0.1, 0.125, 0.2]) | st.floats(0.09, 0.25))
    width = draw(st.floats(0.3, 2.0))
    height = draw(st.floats(0.3, 2.0))
    x0 = draw(st.sampled_from([0.0, -0.3]))
    infl = draw(st.sampled_from([0.0, 0.1]) | st.floats(0.0, 0.3))
    return obs, np.array([x0, 0.0, x0 + width, height]), res, infl


def inside_cells(grid) -> np.ndarray:
    """(ny, nx) bool: cells entirely inside the workspace (the others must be occupied)."""
    ny, nx = grid.shape
    h = grid.resolution
    x1 = grid.origin[0] + (np.arange(nx) + 1) * h
    y1 = grid.origin[1] + (np.arange(ny) + 1) * h
    return (y1[:, None] <= grid.bounds[3] + 1e-9) & (x1[None, :] <= grid.bounds[2] + 1e-9)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(maps())
def test_rasterise_matches_exact_reference(m):
    """Occupied iff the cell square is within `inflation` of an obstacle (slow exact reference)."""
    obs, bounds, res, infl = m
    grid = rasterise(obs, bounds, res, inflation=infl)
    dist = cell_distances(obs, grid.origin, res, grid.shape)
    inside = inside_cells(grid)
    assert np.all(grid.occupied[~inside])
    must = inside & (dist < infl - DELTA)
    must_not = inside & (dist > infl + DELTA)
    assert not np.any(must & ~grid.occupied), np.argwhere(must & ~grid.occupied)
    assert not np.any(must_not & grid.occupied), np.argwhere(must_not & grid.occupied)


@settings(max_examples=40, deadline=None)
@given(maps(), st.integers(0, 2**32 - 1))
def test_rasterise_contains_point_samples(m, seed):
    """Any sampled point of a cell lying in an inflated obstacle makes the cell occupied.

    Sampling can only under-approximate the occupied set, so only this direction is checked.
    Points: a 6 x 6 lattice on each closed cell (corners and edges included) plus random ones.
    """
    obs, bounds, res, infl = m
    grid = rasterise(obs, bounds, res, inflation=infl)
    ny, nx = grid.shape
    rng = np.random.default_rng(seed)
    u = np.concatenate([np.linspace(0.0, 1.0, 6), rng.random(4)])
    uu, vv = np.meshgrid(u, u)
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    px = grid.origin[0] + (jj[..., None] + uu.ravel()) * res
    py = grid.origin[1] + (ii[..., None] + vv.ravel()) * res
    hit = np.zeros((ny, nx), dtype=bool)
    for ob in obs:
        hit |= (point_obstacle_distance(ob, px, py) <= infl - DELTA).any(axis=-1)
    assert not np.any(hit & ~grid.occupied)


def test_axis_aligned_box_known_answer():
    """A box [0.3, 0.7] x [0.2, 0.4] on a 0.1 m grid, no inflation.

    Closed cells touching the closed box: columns 2..7 (cell 2 = [0.2, 0.3] touches x = 0.3,
    cell 7 = [0.7, 0.8] touches x = 0.7) and rows 1..4: 6 x 4 = 24 cells.
    """
    grid = rasterise([box(0.5, 0.3, 0.2, 0.1)], [0, 0, 1, 1], 0.1, inflation=0.0)
    expected = np.zeros((10, 10), dtype=bool)
    expected[1:5, 2:8] = True
    assert np.array_equal(grid.occupied, expected)


def test_inflated_box_corner_is_round():
    """Inflation rounds a box's corners: a cell diagonal to the corner at distance > r stays free."""
    # Box [0.4, 0.6]^2, inflation 0.15. Cell (i, j) = (1, 1) spans [0.1, 0.2]^2: its nearest point
    # (0.2, 0.2) is at distance 0.2 * sqrt(2) = 0.283 > 0.15 from the corner (0.4, 0.4): free.
    # Cell (2, 2) = [0.2, 0.3]^2: nearest point (0.3, 0.3) at 0.141 < 0.15: occupied.
    # Cell (1, 4) = [0.4, 0.5] x [0.1, 0.2]: straight below, distance 0.2 > 0.15: free.
    # Cell (2, 4) = [0.4, 0.5] x [0.2, 0.3]: distance 0.1 < 0.15: occupied.
    grid = rasterise([box(0.5, 0.5, 0.1, 0.1)], [0, 0, 1, 1], 0.1, inflation=0.15)
    assert not grid.occupied[1, 1]
    assert grid.occupied[2, 2]
    assert not grid.occupied[1, 4]
    assert grid.occupied[2, 4]
    # A square grown by a disc is symmetric under the square's symmetries.
    assert np.array_equal(grid.occupied, grid.occupied.T)
    assert np.array_equal(grid.occupied, grid.occupied[::-1, ::-1])


def test_rotated_box_matches_its_quarter_turns():
    """A box at yaw t and at t + pi/2 with swapped half sizes is the same set."""
    a = rasterise([box(1.03, 0.97, 0.5, 0.2, 0.3)], [0, 0, 2, 2], 0.05, inflation=0.1)
    b = rasterise([box(1.03, 0.97, 0.2, 0.5, 0.3 + math.pi / 2)], [0, 0, 2, 2], 0.05, inflation=0.1)
    c = rasterise([box(1.03, 0.97, 0.5, 0.2, 0.3 - 3 * math.pi)], [0, 0, 2, 2], 0.05, inflation=0.1)
    assert np.array_equal(a.occupied, b.occupied)
    assert np.array_equal(a.occupied, c.occupied)
    assert 0 < a.occupied.sum() < a.occupied.size


def test_disc_known_answer():
    """A cylinder of radius 0.1 at the corner shared by four cells, inflation 0.05.

    The grown disc has radius 0.15 around (0.5, 0.5). Cells 3..6 in each direction are
    occupied: the 4 cells sharing the corner (distance 0), the 8 next to them along an axis
    (distance 0.1) and the 4 diagonal ones (distance 0.1 * sqrt(2) = 0.141 < 0.15): 16
    cells. Cells 2 or 7 along an axis are at 0.2 > 0.15: free.
    """
    grid = rasterise([disc(0.5, 0.5, 0.1)], [0, 0, 1, 1], 0.1, inflation=0.05)
    expected = np.zeros((10, 10), dtype=bool)
    expected[3:7, 3:7] = True
    assert np.array_equal(grid.occupied, expected)
    capsule = rasterise([disc(0.5, 0.5, 0.1, "capsule")], [0, 0, 1, 1], 0.1, inflation=0.05)
    assert np.array_equal(capsule.occupied, expected)


def test_grid_geometry_and_boundary():
    """10 m at 0.05 m is 200 cells despite rounding; a workspace 1.05 m wide at 0.1 m is 11 cells
    of which the last column straddles the boundary and is occupied."""
    assert grid_shape([0.0, 0.0, 10.0, 3.0], 0.05) == (60, 200)
    assert grid_shape([-0.3, 0.1, 0.7, 0.4], 0.1) == (3, 10)
    grid = rasterise([], [0.0, 0.0, 1.05, 1.0], 0.1, inflation=0.3)
    assert grid.shape == (10, 11)
    assert np.all(grid.occupied[:, -1])
    assert not np.any(grid.occupied[:, :-1])
    np.testing.assert_array_equal(grid.origin, [0.0, 0.0])  # exact: the workspace's lower-left corner, copied
    assert grid.inflation == 0.3 and grid.resolution == 0.1


def test_obstacle_outside_workspace_is_clipped():
    grid = rasterise([box(-1.0, 0.5, 0.3, 0.3), disc(0.5, 5.0, 0.2)], [0, 0, 1, 1], 0.1, inflation=0.1)
    assert not grid.occupied.any()
    # Box x in [-0.35, 0.05], y in [0.45, 0.55]: only column 0, rows 4 ([0.4, 0.5]) and 5.
    grid = rasterise([box(-0.15, 0.5, 0.2, 0.05)], [0, 0, 1, 1], 0.1, inflation=0.0)
    assert grid.occupied[4:6, 0].all() and grid.occupied.sum() == 2


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(bounds=[0, 0, 1], resolution=0.1, inflation=0.0), "bounds"),
        (dict(bounds=[0, 0, -1, 1], resolution=0.1, inflation=0.0), "xmax > xmin"),
        (dict(bounds=[0, 0, 1, 1], resolution=0.0, inflation=0.0), "resolution"),
        (dict(bounds=[0, 0, 1, 1], resolution=float("nan"), inflation=0.0), "resolution"),
        (dict(bounds=[0, 0, 1, 1], resolution=0.1, inflation=-0.1), "inflation"),
    ],
)
def test_rasterise_rejects_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=message):
        rasterise([], **kwargs)


@pytest.mark.parametrize(
    "obstacle, message",
    [
        (Obstacle("s", "sphere", np.zeros(2), 0.0, np.array([0.1, 0.1]), 1.0, -1), "'s'.*sphere"),  # type: ignore[arg-type]
        (box(0.5, float("nan"), 0.1, 0.1), "'b'.*finite"),
        (box(0.5, 0.5, 0.1, 0.1, float("inf")), "'b'.*finite"),
        (box(0.5, 0.5, -0.1, 0.1), "'b'.*half_size must be >= 0"),
        (disc(0.5, 0.5, -0.1), "'c'.*half_size must be >= 0"),
    ],
)
def test_rasterise_rejects_bad_obstacles(obstacle, message):
    with pytest.raises(ValueError, match=message):
        rasterise([obstacle], [0, 0, 1, 1], 0.1, inflation=0.0)


@pytest.mark.parametrize("name", ["single_rect", "double_rect", "u_shape", "v_shape", "complex"])
def test_builtin_scenarios_free_cells_are_clear(name):
    """On the built-in scenarios, every point of a free cell (corners, edge midpoints, centre)
    is farther than the inflation from every obstacle (Obstacle.signed_distance)."""
    from sanav_mj.scene import load_scenario

    scenario = load_scenario(name)
    inflation = scenario.robot.footprint_radius + 0.05
    grid = rasterise(scenario.obstacles, scenario.bounds, 0.05, inflation=inflation)
    ii, jj = np.nonzero(~grid.occupied)
    assert ii.size > 0.3 * grid.occupied.size
    for u in (0.0, 0.5, 1.0):
        for v in (0.0, 0.5, 1.0):
            pts = np.stack([grid.origin[0] + (jj + u) * 0.05, grid.origin[1] + (ii + v) * 0.05], axis=1)
            for ob in scenario.obstacles:
                assert ob.signed_distance(pts).min() > inflation - 1e-9


# ------------------------------------------------------------------ memory (issue 12)


def _scattered_boxes(n: int, width: float, height: float, seed: int = 0) -> tuple[Obstacle, ...]:
    rng = np.random.default_rng(seed)
    return tuple(Obstacle(f"o{k}", "box", rng.uniform([0, 0], [width, height]), float(rng.uniform(0, 3)),
                          rng.uniform(0.2, 5.0, 2), 1.0, k) for k in range(n))


def test_batched_rasterisation_equals_one_batch(monkeypatch):
    """The (obstacle, row) and run batches only bound the temporaries: the grid is the same."""
    from sanav_mj.mapping import occupancy

    obs = _scattered_boxes(30, 40.0, 30.0) + (disc(20.0, 15.0, 3.0),)
    one = rasterise(obs, [0, 0, 40, 30], 0.05, inflation=0.38).occupied
    monkeypatch.setattr(occupancy, "_PAIR_CHUNK", 7)
    monkeypatch.setattr(occupancy, "_RUN_CHUNK", 5)
    many = rasterise(obs, [0, 0, 40, 30], 0.05, inflation=0.38).occupied
    assert one.sum() > 10_000 and np.array_equal(one, many)


def test_memory_estimate_matches_what_mapping_allocates():
    """tracemalloc peak of the whole mapping stage on a 6000 x 4000 grid vs map_memory_bytes.

    Here the per-cell arrays dominate (24 MB grid + 8 MB count pyramid); the estimate also
    counts the batch temporaries at their bound (~10 MB), which a few obstacles do not reach,
    and not the per-leaf arrays (a few MB for 20 boxes). Stated factor: peak in [0.6, 1.25] x
    estimate (measured 0.82).
    """
    import tracemalloc

    from sanav_mj.mapping import MapConfig, build_map
    from sanav_mj.mapping.occupancy import map_memory_bytes

    bounds = np.array([0.0, 0.0, 300.0, 200.0])
    obs = _scattered_boxes(20, 300.0, 200.0)
    est = map_memory_bytes(*grid_shape(bounds, 0.05))
    tracemalloc.start()
    try:
        build_map(obs, bounds, 0.38, MapConfig())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert 0.6 * est <= peak <= 1.25 * est, (peak, est)


def test_count_pyramid_allocates_what_pyramid_bytes_says():
    import tracemalloc

    from sanav_mj.mapping.quadtree import count_pyramid, pyramid_bytes

    occ = np.zeros((140, 40_000), dtype=bool)  # a 2 km x 7 m corridor at 0.05 m
    occ[::7, ::13] = True
    tracemalloc.start()
    try:
        levels = count_pyramid(occ)
        current = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    want = pyramid_bytes(*occ.shape)
    assert sum(level.nbytes for level in levels[1:]) == want
    assert want < 0.35 * occ.size  # no padding to the 65 536^2 root square (4.3 GB)
    assert current <= want + 64 * 1024


def test_map_over_budget_is_refused_before_allocating():
    import tracemalloc

    from sanav_mj.mapping import MapConfig, MapMemoryError, build_map
    from sanav_mj.mapping.occupancy import check_map_memory, map_memory_bytes

    bounds = [0.0, 0.0, 10_000.0, 10_000.0]  # 10 km x 10 km at 0.05 m: 4e10 cells
    tracemalloc.start()
    try:
        with pytest.raises(MapMemoryError) as err:
            build_map((), bounds, 0.38, MapConfig())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000
    msg = str(err.value)
    assert "\n" not in msg and "200000 x 200000 = 4e+10 cells" in msg and "GiB" in msg
    fit = float(msg.split("use --resolution ")[1].split()[0])
    budget = MapConfig().memory_budget_bytes
    assert map_memory_bytes(*grid_shape(bounds, fit)) <= budget
    assert map_memory_bytes(*grid_shape(bounds, fit - 0.01)) > budget  # two significant digits: the smallest
    assert check_map_memory(bounds, fit) <= budget
    # a smaller budget refuses a smaller map, a larger one lets it through
    small = [0.0, 0.0, 100.0, 100.0]
    with pytest.raises(MapMemoryError, match="use --resolution"):
        build_map((), small, 0.38, MapConfig(memory_budget_bytes=14_000_000))  # 4e6 cells: 15.9 MB
    build_map((), small, 0.38, MapConfig(memory_budget_bytes=30_000_000))
    with pytest.raises(MapMemoryError, match="below the .* bytes the mapping needs for any grid"):
        build_map((), small, 0.38, MapConfig(memory_budget_bytes=1_000_000))
    with pytest.raises(ValueError, match="memory_budget_bytes must be an integer > 0"):
        MapConfig(memory_budget_bytes=0)


def test_cli_refuses_a_huge_workspace_in_one_line(tmp_path, capsys, make_scenario_xml):
    from sanav_mj.cli import main

    path = tmp_path / "huge.xml"
    path.write_text(make_scenario_xml(floor='<geom name="floor" type="plane" pos="0 0 0" size="5000 5000 0.1"/>'))
    assert main(["areas", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "--resolution 0.05" in err[0] and "use --resolution" in err[0]
