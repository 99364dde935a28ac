"""The sub-cell evidence of return cells (:mod:`sanav_mj.mapping.subcell_grid`): the evidence
of a cell from known end points, safe cells against material at known sub-cell positions
(exact distances), the incremental counts against a rebuild, compiled against NumPy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _mapping_reference import room_scan

from sanav_mj.mapping.live_grid import FREE, LiveGrid, LiveGridConfig
from sanav_mj.mapping.subcell_grid import SubcellGrid, subcell_kernels, subcells_hold

SUB = LiveGridConfig(sub_cells=2)


def _square_segment_distance(x0, y0, x1, y1, p, q) -> float:
    """Exact distance [m] between the closed square [x0, x1] x [y0, y1] and the segment p-q
    (plain geometry: 0 when the segment meets the square, else the least of the end points'
    distances to the square and the square's corners' distances to the segment)."""
    (px, py), (qx, qy) = p, q
    t0, t1 = 0.0, 1.0
    meets = True
    for d, a, lo, hi in ((qx - px, px, x0, x1), (qy - py, py, y0, y1)):
        if d == 0:
            if not lo <= a <= hi:
                meets = False
            continue
        ta, tb = (lo - a) / d, (hi - a) / d
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    if meets and t0 <= t1:
        return 0.0

    def pt_sq(x, y):
        return math.hypot(max(x0 - x, 0.0, x - x1), max(y0 - y, 0.0, y - y1))

    def pt_seg(x, y):
        dx, dy = qx - px, qy - py
        L2 = dx * dx + dy * dy
        t = 0.0 if L2 == 0 else min(1.0, max(0.0, ((x - px) * dx + (y - py) * dy) / L2))
        return math.hypot(x - px - t * dx, y - py - t * dy)

    return min(pt_sq(px, py), pt_sq(qx, qy), *(pt_seg(x, y) for x in (x0, x1) for y in (y0, y1)))


def _hit_at(g: LiveGrid, points) -> None:
    """A return exactly at each point (a zero-length beam from it: its cell and sub-cell hit,
    nothing crossed)."""
    for x, y in points:
        g.integrate((x, y), 0.0, np.array([0.0]), np.array([True]), np.array([0.0]))


def test_the_evidence_of_a_cell_from_known_end_points():
    """A wall at x = 1.0135 m, inside the second half of the cell column [1.0, 1.025): the
    returns land in the sub-cells [1.0125, 1.025); the beams cross the first halves. The
    return cells' material squares are those halves only (bits 1 and 3), so the safe cells
    reach one cell further than with the whole square: with a 0.1 m inflation the last safe
    column ends at 0.9 m (0.1125 m from the material squares) instead of 0.875 m."""
    h, infl, xw = 0.025, 0.1, 1.0135
    grids = [LiveGrid((0.0, 0.0, 2.0, 1.0), h, infl, LiveGridConfig()),
             SubcellGrid((0.0, 0.0, 2.0, 1.0), h, infl, SUB)]
    angles = np.radians(np.linspace(-50, 50, 401))
    for pose in ((0.55, 0.5), (0.6, 0.48), (0.65, 0.52)):
        ranges = (xw - pose[0]) / np.cos(angles)
        for g in grids:
            g.integrate(pose, 0.0, ranges, np.ones(len(angles), bool), angles)
    plain, sub = grids
    rows = np.arange(17, 23)  # y in [0.425, 0.575): well inside the fan at the wall
    col = 40  # [1.0, 1.025)
    assert np.all(sub.states()[rows, col] != FREE)
    assert np.all(sub.states()[rows, col - 1] == FREE)
    assert np.all(sub.material_squares()[rows, col] == 0b1010)  # sub-cells (a, b=1)
    assert np.all(sub.material_squares()[rows, col - 1] == 0)
    for i in rows:
        assert plain.safe()[i, 34] and not plain.safe()[i, 35]
        assert sub.safe()[i, 35] and not sub.safe()[i, 36]


def test_sub_cell_kernels_measure_square_to_square():
    """Each sub-cell kernel holds exactly the cells whose square is within the inflation of
    that sub-cell's square (brute force over a window, exact distances)."""
    h, infl = 0.025, 0.0706
    ks = subcell_kernels(infl, h)
    for k, off in enumerate(ks):
        a, b = divmod(k, 2)
        sx0, sy0 = b * h / 2, a * h / 2
        want = set()
        for di in range(-6, 7):
            for dj in range(-6, 7):
                gx = max(0.0, dj * h - (sx0 + h / 2), sx0 - (dj * h + h))
                gy = max(0.0, di * h - (sy0 + h / 2), sy0 - (di * h + h))
                if math.hypot(gx, gy) <= infl + 1e-9:
                    want.add((di, dj))
        assert set(map(tuple, off.tolist())) == want


@pytest.mark.parametrize("seed", range(6))
def test_a_safe_cell_keeps_the_inflation_from_material_at_known_sub_cell_positions(seed):
    """Material (random segments, at random sub-cell positions) whose every cell and sub-cell
    holds two returns, all else observed free three times (log-odds -1.2, a sub-cell free at
    ``sub_free_thresh``): the evidence assumptions of the module hold exactly. Every safe cell's square is then more than the inflation from every segment
    (exact distance), and the safe cells include every safe cell of the plain rule."""
    rng = np.random.default_rng(seed)
    h, infl = 0.025, 0.0706
    bounds = (0.0, 0.0, 1.2, 0.9)
    plain = LiveGrid(bounds, h, infl, LiveGridConfig())
    sub = SubcellGrid(bounds, h, infl, SUB)
    ny, nx = sub.shape
    cells = np.arange(ny * nx)
    for g in (plain, sub):
        for _ in range(3):  # log-odds -1.2: free, and a sub-cell at sub_free_thresh
            g.observe_free(cells)
    segs = [(tuple(rng.uniform(0.1, 1.1, 2)), tuple(rng.uniform(0.1, 0.8, 2))) for _ in range(3)]
    segs = [((p[0], p[1]), (p[0] + 0.25 * (q[0] - 0.5), q[1])) for p, q in segs]
    pts = []
    for p, q in segs:
        n = int(math.hypot(q[0] - p[0], q[1] - p[1]) / 5e-4) + 2
        pts += [(p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])) for t in np.linspace(0, 1, n)]
    for g in (plain, sub):
        _hit_at(g, pts + pts)  # two returns: -1.2 + 2 = 0.8, occupied and a return cell
    safe = sub.safe()
    assert np.all(safe | ~plain.safe())  # never fewer safe cells than the plain rule
    for i, j in zip(*np.nonzero(safe)):
        x0, y0 = j * h, i * h
        for p, q in segs:
            assert _square_segment_distance(x0, y0, x0 + h, y0 + h, p, q) > infl
    # the exact rule from the material squares (distances between closed squares)
    mat = sub.material_squares()
    sq = []
    for i, j in zip(*np.nonzero(mat)):
        for k in range(4):
            if mat[i, j] >> k & 1:
                a, b = divmod(k, 2)
                sq.append(((j + b / 2) * h, (i + a / 2) * h))
    sq = np.array(sq)
    ii, jj = np.mgrid[0:ny, 0:nx]
    ref = sub.states() == FREE
    for x, y in sq:  # sub-square [x, x + h/2] x [y, y + h/2] against each cell square
        gx = np.maximum(0, np.maximum(jj * h - (x + h / 2), x - (jj + 1) * h))
        gy = np.maximum(0, np.maximum(ii * h - (y + h / 2), y - (ii + 1) * h))
        ref &= np.hypot(gx, gy) > infl + 1e-9
    assert np.array_equal(safe, ref)


def test_the_sub_cell_rule_opens_more_cells_than_the_plain_rule():
    """Over the random material of the test above, the sub-cell rule has strictly more safe
    cells than the plain rule (it is not the plain rule again)."""
    h, infl = 0.025, 0.0706
    gained = 0
    for seed in range(3):
        rng = np.random.default_rng(seed)
        plain = LiveGrid((0.0, 0.0, 1.2, 0.9), h, infl, LiveGridConfig())
        sub = SubcellGrid((0.0, 0.0, 1.2, 0.9), h, infl, SUB)
        for g in (plain, sub):
            for _ in range(3):
                g.observe_free(np.arange(g.shape[0] * g.shape[1]))
        pts = [tuple(rng.uniform(0.2, 0.9, 2) * (1.2, 0.9)) for _ in range(20)]
        for g in (plain, sub):
            _hit_at(g, pts + pts)
        gained += int(sub.safe().sum()) - int(plain.safe().sum())
    assert gained > 0


@pytest.mark.parametrize("seed,compiled", [(0, True), (1, True), (2, False)])
def test_incremental_counts_equal_a_rebuild(seed, compiled):
    """Random noisy scans in a room with a moving inner wall, body clearings in between:
    after every update the counts equal a recount from scratch, the reported safe flips are
    exactly the cells whose safe state changed, and the safe grid is the rule's (no free
    cell, or a material square within the inflation, square to square)."""
    rng = np.random.default_rng(seed)
    h, infl = 0.05, 0.17
    g = SubcellGrid((0.0, 0.0, 6.05, 4.0), h, infl, SUB)  # last column straddles the boundary
    for grid in (g, g.fine):
        grid._use_kernel = grid._use_commit_kernel = compiled
    g._use_sub_kernel = compiled
    assert np.array_equal(g.blocked, g.blocked_reference())
    angles = np.linspace(-2.3, 2.3, 181)
    flips = 0
    for step in range(20):
        room = (0.2, 0.2, rng.uniform(2.5, 5.9), 3.8)
        pose = (rng.uniform(0.5, 2.3), rng.uniform(0.5, 3.5), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, room, max_range=rng.uniform(1.5, 6.0))
        ranges = np.where(hit, ranges + rng.normal(0, 0.03, len(ranges)), ranges)
        before = g.safe().copy()
        if step % 5 == 4:
            up = g.observe_free(rng.integers(0, g.shape[0] * g.shape[1], 300))
        else:
            up = g.integrate(pose[:2], pose[2], ranges, hit, angles)
        assert np.array_equal(g.blocked, g.blocked_reference())
        assert up.safe_changed.tolist() == np.flatnonzero((before != g.safe()).ravel()).tolist()
        flips += len(up.safe_changed)
    assert flips > 100 and g.safe().sum() > 100


def test_compiled_and_numpy_give_the_same_counts_and_flips():
    rng = np.random.default_rng(7)
    gs = [SubcellGrid((0.0, 0.0, 4.0, 3.0), 0.05, 0.17, SUB) for _ in range(2)]
    gs[1]._use_sub_kernel = False
    angles = np.linspace(-2.3, 2.3, 181)
    for step in range(10):
        room = (0.2, 0.2, rng.uniform(2.0, 3.8), 2.8)
        pose = (rng.uniform(0.5, 1.8), rng.uniform(0.5, 2.5), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, room, max_range=4.0)
        ranges = np.where(hit, ranges + rng.normal(0, 0.03, len(ranges)), ranges)
        ups = [g.integrate(pose[:2], pose[2], ranges, hit, angles) for g in gs]
        assert np.array_equal(ups[0].safe_changed, ups[1].safe_changed)
        assert np.array_equal(gs[0].blocked, gs[1].blocked)


def test_the_sensed_map_keeps_the_sub_cell_safe_areas_incrementally():
    """A SensedMap with ``sub_cells`` 2: its incremental safe areas cover exactly the safe
    cells of its SubcellGrid after every scan."""
    from sanav_mj.mapping.sensed_map import SensedMap, SensedMapConfig

    m = SensedMap((0.0, 0.0, 4.0, 3.0), 0.17, config=SensedMapConfig(resolution=0.05, grid=SUB))
    assert isinstance(m.grid, SubcellGrid)
    rng = np.random.default_rng(3)
    angles = np.linspace(-2.3, 2.3, 181)
    for step in range(8):
        pose = (rng.uniform(0.8, 3.2), rng.uniform(0.8, 2.2), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, (0.3, 0.3, 3.7, 2.7), 4.0)
        m.integrate(pose, ranges + rng.normal(0, 0.02, len(ranges)) * hit, hit, angles)
        paint = np.zeros(m.grid.shape, int)
        for i0, j0, i1, j1 in m.boxes_now().tolist():
            paint[i0:i1, j0:j1] += 1
        assert paint.max() <= 1 and np.array_equal(paint == 1, m.grid.safe())


def test_where_the_noise_keeps_slivers_occupied():
    """A sliver sub-cell holds 0.319 of the beams reaching it at 0.02 m noise on 0.0125 m
    sub-cells, above f* = 0.4 / 1.4; at 0.025 m noise 0.277, below."""
    assert subcells_hold(0.025, 0.02) and subcells_hold(0.025, 0.0)
    assert not subcells_hold(0.025, 0.025)
    with pytest.raises(ValueError, match="sigma"):
        subcells_hold(0.025, -1.0)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="sub_cells"):
        LiveGridConfig(sub_cells=3)
    with pytest.raises(ValueError, match="sub_tail"):
        LiveGridConfig(sub_tail=0.0)
    with pytest.raises(ValueError, match="sub_cells == 2"):
        SubcellGrid((0, 0, 1, 1), 0.05, 0.1, LiveGridConfig())
    with pytest.raises(ValueError, match="floor_at"):
        SubcellGrid((0, 0, 1, 1), 0.05, 0.1, LiveGridConfig(sub_cells=2, floor_at=None))
    with pytest.raises(ValueError, match="sub_free_thresh"):
        LiveGridConfig(sub_cells=2, l_min=-1.0)
    with pytest.raises(ValueError, match="sub_margin"):
        LiveGridConfig(sub_margin=-0.01)
    with pytest.raises(ValueError, match="tail"):
        LiveGrid((0, 0, 1, 1), 0.05, 0.1).integrate_tails((0.5, 0.5), 0.0, [0.3], [True], [0.0], -1.0)


def test_the_counts_fall_back_to_numpy_without_the_kernel(monkeypatch):
    """With the compiled spreading unavailable (no compiler, SANAV_MJ_NO_CKERNEL=1) the
    NumPy path keeps the same counts."""
    from sanav_mj.mapping import subcell_kernel

    monkeypatch.setattr(subcell_kernel, "_load", lambda: None)
    assert not subcell_kernel.kernel_available()
    g = SubcellGrid((0.0, 0.0, 4.0, 3.0), 0.05, 0.17, SUB)
    angles = np.linspace(-2.3, 2.3, 181)
    for pose in ((1.0, 1.0, 0.3), (2.5, 1.8, 2.0), (3.2, 0.9, -1.0)):
        ranges, hit = room_scan(pose, angles, (0.2, 0.2, 3.8, 2.8), 4.0)
        g.integrate(pose[:2], pose[2], ranges, hit, angles)
        assert np.array_equal(g.blocked, g.blocked_reference())
    assert g.safe().sum() > 100
