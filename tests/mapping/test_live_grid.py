"""The growing map: exact beam traversal, log-odds states, incremental safe grid vs recomputation."""

from __future__ import annotations

import functools
from dataclasses import replace
import math

import numpy as np
import pytest
from _mapping_reference import room_scan

from sanav_mj.mapping.live_grid import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    LiveGrid,
    LiveGridConfig,
    dilate_count,
    centre_offsets,
    inflation_offsets,
    traverse,
)


def _crossed_reference(u0, v0, u1, v1):
    """Cells whose open square the segment meets (Liang-Barsky clip, positive length), plus
    the cells of the end points; plain loops over the bounding box."""
    cells = {(math.floor(v0), math.floor(u0)), (math.floor(v1), math.floor(u1))}
    for i in range(math.floor(min(v0, v1)) - 1, math.floor(max(v0, v1)) + 2):
        for j in range(math.floor(min(u0, u1)) - 1, math.floor(max(u0, u1)) + 2):
            t0, t1 = 0.0, 1.0
            ok = True
            for p, q0, lo, hi in ((u1 - u0, u0, j, j + 1), (v1 - v0, v0, i, i + 1)):
                if p == 0:
                    if not lo < q0 < hi:
                        ok = False
                    continue
                a, b = (lo - q0) / p, (hi - q0) / p
                t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
            if ok and t1 > t0:
                cells.add((i, j))
    return cells


def test_traverse_matches_reference_on_random_segments():
    rng = np.random.default_rng(0)
    n = 300
    u0, v0 = rng.uniform(-5, 5, n), rng.uniform(-5, 5, n)
    length = rng.uniform(0, 12, n)
    ang = rng.uniform(-np.pi, np.pi, n)
    u1, v1 = u0 + length * np.cos(ang), v0 + length * np.sin(ang)
    beam, i, j = traverse(u0, v0, u1, v1)
    for b in range(n):
        got = list(zip(i[beam == b].tolist(), j[beam == b].tolist()))
        assert len(got) == len(set(got)), b
        assert set(got) == _crossed_reference(u0[b], v0[b], u1[b], v1[b]), b


def test_crossed_cells_equal_traverse_inside_the_grid():
    from sanav_mj.mapping.live_grid import crossed_cells

    rng = np.random.default_rng(1)
    ny, nx = 23, 37
    n = 400
    u0, v0 = rng.uniform(-10, 47, n), rng.uniform(-10, 33, n)  # many start outside the grid
    length = rng.uniform(0, 40, n)
    ang = rng.uniform(-np.pi, np.pi, n)
    u1, v1 = u0 + length * np.cos(ang), v0 + length * np.sin(ang)
    beam, i, j = traverse(u0, v0, u1, v1)
    inside = (i >= 0) & (i < ny) & (j >= 0) & (j < nx)
    got = crossed_cells(u0, v0, u1, v1, ny, nx)
    assert got.min() >= 0 and got.max() < ny * nx
    assert set(got.tolist()) == set((i * nx + j)[inside].tolist())
    for b in range(0, n, 7):  # per segment too
        one = crossed_cells(u0[b:b + 1], v0[b:b + 1], u1[b:b + 1], v1[b:b + 1], ny, nx)
        sel = (beam == b) & inside
        assert sorted(one.tolist()) == sorted((i * nx + j)[sel].tolist()), b


def test_inflation_offsets_square_to_square_distance():
    off = inflation_offsets(0.12, 0.05)
    got = {tuple(o) for o in off.tolist()}
    # gap(di, dj) = hypot(max(|di|-1,0), max(|dj|-1,0)) * 0.05 <= 0.12: |d| - 1 <= 2.4 along an axis
    assert (3, 0) in got and (4, 0) not in got
    assert (3, 2) in got  # gap hypot(2, 1) * 0.05 = 0.112
    assert (3, 3) not in got  # gap hypot(2, 2) * 0.05 = 0.141
    assert (0, 0) in got and len(got) == len({(-a, -b) for a, b in got} & got)



def test_centre_offsets_centre_to_centre_distance():
    off = centre_offsets(0.12, 0.05)
    got = {tuple(o) for o in off.tolist()}
    # hypot(di, dj) * 0.05 <= 0.12: |di| <= 2 on an axis, (2, 1) at 0.112 in, (2, 2) at 0.141 out
    assert (2, 0) in got and (3, 0) not in got and (2, 1) in got and (2, 2) not in got
    assert (0, 0) in got and len(got) == 21  # 1 + 8 on the axes + 4 at (1, 1) + 8 at (2, 1)
    assert got <= {tuple(o) for o in inflation_offsets(0.12, 0.05).tolist()}
    with pytest.raises(ValueError, match="route_kernel must be 'centre' or 'square', got 'disc'"):
        LiveGridConfig(route_kernel="disc")


def test_single_scan_states():
    g = LiveGrid((0, 0, 4, 4), 0.1, 0.0)
    assert np.all(g.states() == UNKNOWN)
    # one beam along +x from (1.05, 2.05) hitting x = 3.02; one beam along +y with no return (max 1 m)
    up = g.integrate((1.05, 2.05), 0.0, [1.97, 1.0], [True, False], [0.0, np.pi / 2])
    st = g.states()
    assert st[20, 30] == OCCUPIED
    assert np.all(st[20, 10:30] == FREE)
    assert np.all(st[20:31, 10] == FREE)  # 2.05 .. 3.05: rows 20 .. 30, nothing occupied
    assert st[31, 10] == UNKNOWN
    assert np.count_nonzero(st == FREE) == 20 + 10
    assert np.count_nonzero(st == OCCUPIED) == 1
    assert sorted(up.state_changed.tolist()) == sorted(np.flatnonzero(st.ravel() != UNKNOWN).tolist())
    # inflation 0 still excludes the cells touching a non-free one (closed squares meet):
    # a one-cell-wide line of free cells holds no safe cell
    assert not g.safe().any() and up.safe_changed.size == 0


def test_hit_needs_several_free_passes_and_unknown_between():
    c = LiveGridConfig(hit_floor=None)
    g = LiveGrid((0, 0, 4, 4), 0.1, 0.0, c)
    g.integrate((0.55, 0.55), 0.0, [2.0], [True], [0.0])  # end cell (5, 25)
    assert g.states()[5, 25] == OCCUPIED
    passes = 0
    while g.states()[5, 25] != FREE:
        g.integrate((0.55, 0.55), 0.0, [3.0], [True], [0.0])
        passes += 1
        if g.states()[5, 25] == UNKNOWN:
            assert not g.safe()[5, 25]
    # from l_occ down to free_thresh in steps of l_free
    assert passes == math.ceil((c.l_occ - c.free_thresh) / -c.l_free - 1e-9)


def test_a_hit_cell_never_turns_free_again():
    g = LiveGrid((0, 0, 4, 4), 0.1, 0.0)
    g.integrate((0.55, 0.55), 0.0, [2.0], [True], [0.0])  # end cell (5, 25)
    for _ in range(30):
        g.integrate((0.55, 0.55), 0.0, [3.0], [True], [0.0])
        assert g.states()[5, 25] != FREE
    assert g.states()[5, 25] == UNKNOWN and g.log_odds[5, 25] == g.config.hit_floor
    assert g.states()[5, 24] == FREE  # its never-hit neighbour on the beam is free
    with pytest.raises(ValueError, match="hit_floor"):
        LiveGridConfig(hit_floor=-0.5)


def test_one_return_makes_a_well_seen_free_cell_unsafe_without_floor_at():
    c = LiveGridConfig(l_min=-1.0, floor_at=None)  # the rule before floor_at: one return, non-free
    g = LiveGrid((0, 0, 4, 4), 0.1, 0.0, c)
    for _ in range(20):  # cell (5, 25) crossed 20 times: log-odds at the lower clamp
        g.integrate((0.55, 0.55), 0.0, [3.0], [True], [0.0])
    assert g.states()[5, 25] == FREE and g.log_odds[5, 25] == g.config.l_min
    up = g.integrate((0.55, 0.55), 0.0, [2.0], [True], [0.0])  # one return in it
    assert g.states()[5, 25] != FREE
    assert 5 * 40 + 25 in up.state_changed.tolist()
    with pytest.raises(ValueError, match="one return"):
        LiveGridConfig(l_min=-2.0, l_occ=1.0, floor_at=None)


@pytest.mark.parametrize("use_kernel", [True, False])
def test_a_well_seen_free_cell_needs_several_returns_then_keeps_its_floor(use_kernel):
    """Default (floor_at): a cell at l_min turns non-free only after the k-th return in a
    row, k = the least with l_min + k l_occ > free_thresh (5), and its floor is raised only
    once a return brings it to floor_at (the 6th): after that it never turns free again.
    A cell hit in one scan of five (hit fraction 0.2, below -l_free / (l_occ - l_free))
    stays free throughout; one hit in every other scan (0.5, above) makes it occupied."""
    c = LiveGridConfig()
    k = math.floor((c.free_thresh - c.l_min) / c.l_occ + 1e-9) + 1
    assert k == 5
    g = LiveGrid((0, 0, 4, 4), 0.1, 0.0, c)
    g._use_kernel = g._use_commit_kernel = use_kernel
    for _ in range(20):  # cell (5, 25) crossed 20 times: log-odds at the lower clamp
        g.integrate((0.55, 0.55), 0.0, [3.0], [True], [0.0])
    assert g.states()[5, 25] == FREE and g.log_odds[5, 25] == c.l_min
    for n in range(1, k + 2):
        g.integrate((0.55, 0.55), 0.0, [2.0], [True], [0.0])  # a return in cell (5, 25)
        assert (g.states()[5, 25] == FREE) == (n < k)
        assert (g._floor.reshape(g.shape)[5, 25] == c.hit_floor) == (n == k + 1)  # L = 1.0 >= floor_at
    for _ in range(30):
        g.integrate((0.55, 0.55), 0.0, [3.0], [True], [0.0])
        assert g.states()[5, 25] != FREE
    # a rare hit (1 scan in 5) leaves a free cell free: +l_occ, then 4 l_free back to l_min
    g2 = LiveGrid((0, 0, 4, 4), 0.1, 0.0, c)
    g2._use_kernel = g2._use_commit_kernel = use_kernel
    for n in range(60):
        g2.integrate((0.55, 0.55), 0.0, [2.0 if n % 5 == 4 else 3.0], [True], [0.0])
        if n >= 1:
            assert g2.states()[5, 25] == FREE
    # one hit in two scans: occupied, floor raised
    for n in range(20):
        g2.integrate((0.55, 0.55), 0.0, [2.0 if n % 2 else 3.0], [True], [0.0])
    assert g2.states()[5, 25] == OCCUPIED and g2._floor.reshape(g2.shape)[5, 25] == c.hit_floor
    with pytest.raises(ValueError, match="floor_at"):
        LiveGridConfig(floor_at=-0.5)
    with pytest.raises(ValueError, match="noise_cells"):
        LiveGridConfig(noise_cells=-1)


def test_noise_cells_widen_the_safe_and_route_kernels_by_whole_cells():
    h, infl = 0.025, 0.27
    g0 = LiveGrid((0, 0, 2, 2), h, infl)
    g1 = LiveGrid((0, 0, 2, 2), h, infl, LiveGridConfig(noise_cells=1))
    assert set(map(tuple, g1._offsets.tolist())) == set(map(tuple, inflation_offsets(infl + h, h).tolist()))
    assert set(map(tuple, g0._offsets.tolist())) < set(map(tuple, g1._offsets.tolist()))
    assert np.array_equal(g1._route_offsets, g1._offsets)


def test_sparse_and_dense_count_spreading_agree():
    """The two ways of spreading count changes (per kernel offset / by row runs over the
    bounding window) give the same counts and the same flipped cells."""
    import copy

    rng = np.random.default_rng(3)
    g = LiveGrid((0, 0, 5.0, 3.0), 0.05, 0.33)
    assert sum(2 * w + 1 for _, w in g._rows) == len(g._offsets)
    nx = g.shape[1]
    for _ in range(6):
        k = int(rng.integers(1, 400))
        cells = np.unique(rng.integers(0, g.shape[0] * nx, k))
        ci, cj = np.divmod(cells, nx)
        delta = rng.choice(np.array([-1, 1], dtype=np.int32), len(cells))
        a, b = copy.deepcopy(g), copy.deepcopy(g)
        fa = a._spread_sparse(a._pad, ci, cj, delta)
        fb = b._spread_dense(b._pad, ci, cj, delta, int(ci.min()), int(ci.max()) + 1, int(cj.min()),
                             int(cj.max()) + 1)
        assert np.array_equal(a._pad, b._pad)
        assert np.array_equal(np.sort(fa), np.sort(fb))
        assert len(fa) > 0
        g = a


def _brute_safe(states, inflation, h):
    ny, nx = states.shape
    bad = np.argwhere(states != FREE)
    out = np.zeros(states.shape, dtype=bool)
    for i in range(ny):
        for j in range(nx):
            if states[i, j] != FREE:
                continue
            gi = np.maximum(np.abs(bad[:, 0] - i) - 1, 0)
            gj = np.maximum(np.abs(bad[:, 1] - j) - 1, 0)
            out[i, j] = not np.any(np.hypot(gi, gj) * h <= inflation + 1e-9)
    return out


@pytest.mark.parametrize("seed,route_kernel,compiled", [(0, "square", True), (1, "square", True), (2, "square", True),
                                                     (0, "centre", True), (1, "centre", False), (2, "square", False)])
def test_incremental_safe_grid_equals_recomputation(seed, route_kernel, compiled):
    """Random scans in a room with a moving inner wall (cells go free -> occupied -> free):
    after every scan the incremental safe grid, the route grid (either kernel, compiled or
    NumPy commit) and the changed-cell lists are exact."""
    rng = np.random.default_rng(seed)
    h, infl = 0.1, 0.23
    bounds = (0.0, 0.0, 6.05, 4.0)  # not a whole number of cells wide: last column straddles
    g = LiveGrid(bounds, h, infl, LiveGridConfig(route_kernel=route_kernel))
    g._use_commit_kernel = compiled
    route_offsets = centre_offsets(infl, h) if route_kernel == "centre" else inflation_offsets(infl, h)
    assert np.all(g.states()[:, -1] == OCCUPIED)
    route_now = g.route_safe()
    n_route = 0
    angles = np.linspace(-2.3, 2.3, 181)
    for step in range(25):
        wall = rng.uniform(2.5, 5.9)
        room = (0.2, 0.2, wall, 3.8)
        pose = (rng.uniform(0.5, 2.3), rng.uniform(0.5, 3.5), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, room, max_range=rng.uniform(1.5, 6.0))
        ranges = np.where(hit, ranges + rng.normal(0, 0.03, len(ranges)), ranges)
        s_before, safe_before = g.states(), g.safe()
        up = g.integrate(pose[:2], pose[2], ranges, hit, angles)
        s_after, safe_after = g.states(), g.safe()
        assert sorted(up.state_changed.tolist()) == np.flatnonzero((s_before != s_after).ravel()).tolist()
        assert up.safe_changed.tolist() == np.flatnonzero((safe_before != safe_after).ravel()).tolist()
        assert np.array_equal(g.blocked, dilate_count(s_after != FREE, inflation_offsets(infl, h)))
        # the route grid: only occupied cells block (unknown is passable)
        route_before = route_now
        ever_hit = (g._floor == g.config.hit_floor).reshape(g.shape)
        route_now = dilate_count((s_after == OCCUPIED) | ever_hit, route_offsets) == 0
        assert np.array_equal(g.route_safe(), route_now)
        assert up.route_changed.tolist() == np.flatnonzero((route_before != route_now).ravel()).tolist()
        n_route += len(up.route_changed)
        assert np.all(g.route_safe() | ~g.safe())  # safe implies route-safe
        if step % 8 == 7:
            assert np.array_equal(safe_after, _brute_safe(s_after, infl, h))
    assert np.count_nonzero(g.safe()) > 100
    assert n_route > 100


def test_safe_grid_is_occupancy_grid_compatible():
    from sanav_mj.mapping import build_safe_areas

    g = LiveGrid((0, 0, 3, 3), 0.05, 0.1)
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    ranges, hit = room_scan((1.5, 1.5, 0.0), angles, (0.3, 0.3, 2.7, 2.7), 10.0)
    g.integrate((1.5, 1.5), 0.0, ranges, hit, angles)
    sam = build_safe_areas(g.safe_grid())
    r = sam.areas.rects
    # every safe rectangle lies inside the room shrunk by the inflation (0.1 m) and a cell
    assert len(r) >= 1
    assert r[:, 0].min() >= 0.3 + 0.1 - 1e-9 and r[:, 2].max() <= 2.7 - 0.1 + 1e-9
    assert r[:, 1].min() >= 0.3 + 0.1 - 1e-9 and r[:, 3].max() <= 2.7 - 0.1 + 1e-9


def test_log_odds_match_a_per_cell_reference_over_many_scans():
    """Each cell changes once per scan however many beams cross it (the deduplication in
    integrate), by l_occ when a return lies in it, else by l_free; clamped, hit floor
    raised by a return that brings the cell to floor_at, and kept.
    Reference: plain per-cell loop over the distinct crossed cells (crossed_cells + set)."""
    from sanav_mj.mapping.live_grid import crossed_cells

    rng = np.random.default_rng(7)
    h, infl = 0.1, 0.23
    g = LiveGrid((0.0, 0.0, 6.05, 4.0), h, infl)
    ref = g.log_odds.astype(np.float32).copy().reshape(-1)
    floor = np.full(ref.shape, g.config.l_min, np.float32)
    c = g.config
    angles = np.linspace(-2.3, 2.3, 181)
    ny, nx = g.shape
    for _ in range(20):
        room = (0.2, 0.2, rng.uniform(2.5, 5.9), 3.8)
        pose = (rng.uniform(0.5, 2.3), rng.uniform(0.5, 3.5), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, room, max_range=rng.uniform(1.5, 6.0))
        ranges = np.where(hit, ranges + rng.normal(0, 0.03, len(ranges)), ranges)
        g.integrate(pose[:2], pose[2], ranges, hit, angles)
        a = pose[2] + angles
        u0, v0 = pose[0] / h, pose[1] / h
        u1, v1 = u0 + ranges * np.cos(a) / h, v0 + ranges * np.sin(a) / h
        free = set(crossed_cells(np.full(len(a), u0), np.full(len(a), v0), u1, v1, ny, nx).tolist())
        occ = {int(math.floor(v1[b])) * nx + int(math.floor(u1[b])) for b in np.flatnonzero(hit)
               if 0 <= math.floor(v1[b]) < ny and 0 <= math.floor(u1[b]) < nx}
        for cell in free | occ:
            d = np.float32(c.l_occ if cell in occ else c.l_free)
            v = np.clip(ref[cell] + d, c.l_min, c.l_max).astype(np.float32)
            if cell in occ and v >= np.float32(c.floor_at):
                floor[cell] = c.hit_floor
            ref[cell] = max(v, floor[cell])
        assert np.array_equal(g.log_odds.reshape(-1), ref)
    assert np.count_nonzero(ref < 0) > 200 and np.count_nonzero(ref > 1.5) > 20


def test_compiled_and_numpy_traversal_give_the_same_cells_and_grid():
    """The compiled beam loop (when a C compiler exists) and the NumPy fallback: the same
    distinct cells as crossed_cells on random segments (inside, leaving and outside the grid,
    axis-parallel, degenerate), and bit-identical grids over a sequence of scans."""
    from sanav_mj.mapping.beam_kernel import free_cells, kernel_available
    from sanav_mj.mapping.live_grid import crossed_cells, segment_columns

    rng = np.random.default_rng(3)
    ny, nx = 37, 53
    u0, v0 = rng.uniform(-5, nx + 5, 400), rng.uniform(-5, ny + 5, 400)
    u1, v1 = rng.uniform(-5, nx + 5, 400), rng.uniform(-5, ny + 5, 400)
    u1[:40], v1[40:80] = u0[:40], v0[40:80]  # vertical and horizontal segments
    u1[80:90], v1[80:90] = u0[80:90], v0[80:90]  # points
    u0[90:140], v0[90:140] = np.round(u0[90:140]), np.round(v0[90:140])  # on cell corners
    expect = np.unique(crossed_cells(u0, v0, u1, v1, ny, nx))
    for use in (True, False):
        mark = np.zeros(ny * nx, np.int8)
        got = free_cells(segment_columns(u0, v0, u1, v1, ny, nx), mark, use_kernel=use)
        assert len(got) == len(np.unique(got)) and np.array_equal(np.sort(got), expect)
        assert np.array_equal(np.flatnonzero(mark), expect)
    if kernel_available():  # the compiled loop checks every index it writes
        with pytest.raises(IndexError, match="left the grid"):
            free_cells(segment_columns([1.5], [1.5], [9.5], [1.5], ny, nx), np.zeros(5, np.int8))
    grids = [LiveGrid((0.0, 0.0, 6.05, 4.0), 0.1, 0.23) for _ in range(2)]
    grids[1]._use_kernel = False
    angles = np.linspace(-2.3, 2.3, 181)
    for _ in range(10):
        room = (0.2, 0.2, rng.uniform(2.5, 5.9), 3.8)
        pose = (rng.uniform(0.5, 2.3), rng.uniform(0.5, 3.5), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, room, max_range=rng.uniform(1.5, 6.0))
        ups = [g.integrate(pose[:2], pose[2], ranges, hit, angles) for g in grids]
        assert np.array_equal(np.sort(ups[0].state_changed), np.sort(ups[1].state_changed))
        assert np.array_equal(ups[0].safe_changed, ups[1].safe_changed)
        assert np.array_equal(ups[0].route_changed, ups[1].route_changed)
        assert np.array_equal(grids[0].log_odds, grids[1].log_odds)
        assert np.array_equal(grids[0]._pad, grids[1]._pad) and np.array_equal(grids[0]._route, grids[1]._route)



@pytest.mark.parametrize("how", ["no compiler", "switched off"])
def test_the_traversal_falls_back_to_numpy_without_a_compiler_or_when_switched_off(how, tmp_path, monkeypatch):
    """The kernel is compiled by sanav_mj.native into $SANAV_MJ_CACHE; with no compiler
    (NoCompilerError inside) or SANAV_MJ_NO_CKERNEL=1 it is unavailable, nothing is written and
    free_cells still returns the crossed cells (NumPy)."""
    from sanav_mj.mapping import beam_kernel
    from sanav_mj.mapping.live_grid import crossed_cells, segment_columns

    # a fresh load-once loader (restored after the test): the next call compiles or fails anew
    monkeypatch.setattr(beam_kernel, "_load", functools.cache(beam_kernel._load.__wrapped__))
    monkeypatch.setenv("SANAV_MJ_CACHE", str(tmp_path / "cache"))
    if how == "no compiler":
        monkeypatch.setenv("CC", "/nonexistent/cc")
    else:
        monkeypatch.setenv(beam_kernel.NO_KERNEL_ENV, "1")
    assert not beam_kernel.kernel_available()
    assert not (tmp_path / "cache").exists()
    u0, v0, u1, v1 = [0.5, 3.2], [0.5, 7.9], [8.7, 3.2], [4.1, 0.3]
    mark = np.zeros(10 * 12, np.int8)
    got = beam_kernel.free_cells(segment_columns(u0, v0, u1, v1, 10, 12), mark)
    assert np.array_equal(np.sort(got), np.unique(crossed_cells(u0, v0, u1, v1, 10, 12)))


def test_the_compiled_traversal_lands_in_the_cache_folder(tmp_path, monkeypatch):
    """With a C compiler, the kernel is compiled once into $SANAV_MJ_CACHE as beams_<hash>.so."""
    from sanav_mj.mapping import beam_kernel
    from sanav_mj.native import NoCompilerError, find_compiler

    try:
        find_compiler()
    except NoCompilerError:
        pytest.skip("no C compiler on this machine")
    # a fresh load-once loader (restored after the test): the next call compiles or fails anew
    monkeypatch.setattr(beam_kernel, "_load", functools.cache(beam_kernel._load.__wrapped__))
    monkeypatch.delenv(beam_kernel.NO_KERNEL_ENV, raising=False)
    monkeypatch.setenv("SANAV_MJ_CACHE", str(tmp_path / "cache"))
    assert beam_kernel.kernel_available()
    assert [p.name[:6] for p in (tmp_path / "cache").iterdir()] == ["beams_"]


@pytest.mark.parametrize("config, inflation", [(LiveGridConfig(), 0.23), (LiveGridConfig(hit_floor=None), 0.23),
                                               (LiveGridConfig(l_min=-1.0, floor_at=None, noise_cells=1), 0.23),
                                               (LiveGridConfig(l_free=-0.7, l_occ=2.0, l_min=-2.0), 0.0)])
def test_compiled_commit_equals_the_numpy_commit(config, inflation):
    """The compiled log-odds commit and count spreading (sanav_commit) against the NumPy
    reference, from the same traversal: the same state changes in the same order, the same
    sorted safe / route flips, bit-identical log-odds, floors and counts, over scans that
    change thousands of cells at once (the first) and a few (later, saturated cells), with
    and without the hit floor."""
    from sanav_mj.mapping.beam_kernel import kernel_available

    if not kernel_available():
        pytest.skip("no C compiler: only the NumPy commit exists")
    rng = np.random.default_rng(11)
    grids = [LiveGrid((0.0, 0.0, 8.05, 5.0), 0.05, inflation, config) for _ in range(2)]
    grids[1]._use_commit_kernel = False
    angles = np.linspace(-2.3, 2.3, 271)
    n_big = n_flips = 0
    for k in range(14):
        room = (0.2, 0.2, rng.uniform(3.0, 7.9), 4.8)
        pose = (rng.uniform(0.5, 2.8), rng.uniform(0.5, 4.5), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, room, max_range=rng.uniform(1.5, 6.0))
        ranges = ranges + rng.normal(0.0, 0.03, len(ranges)) * hit  # returns spread over cells
        ups = [g.integrate(pose[:2], pose[2], ranges, hit, angles) for g in grids]
        assert np.array_equal(ups[0].state_changed, ups[1].state_changed)
        assert np.array_equal(ups[0].safe_changed, ups[1].safe_changed)
        assert np.array_equal(ups[0].route_changed, ups[1].route_changed)
        for a in ("log_odds", "_floor", "_pad", "_route", "_mark"):
            assert np.array_equal(getattr(grids[0], a), getattr(grids[1], a)), a
        n_big += ups[0].state_changed.size > 1000
        n_flips += ups[0].safe_changed.size
    assert n_big >= 1 and n_flips > 0
    assert np.count_nonzero(grids[0].safe()) > 100


def test_the_grid_update_falls_back_to_numpy_without_a_compiler(tmp_path, monkeypatch):
    """Without a C compiler LiveGrid.integrate runs the NumPy traversal and commit and gives
    the grid the compiled path gives."""
    from sanav_mj.mapping import beam_kernel

    angles = np.linspace(-2.3, 2.3, 181)
    scans = [((1.0 + 0.2 * k, 2.0, 0.3 * k), *room_scan((1.0 + 0.2 * k, 2.0, 0.3 * k), angles, (0.2, 0.2, 5.5, 3.8),
                                                        max_range=4.0)) for k in range(5)]
    fast = LiveGrid((0.0, 0.0, 6.05, 4.0), 0.05, 0.23)
    ups_fast = [fast.integrate(p[:2], p[2], r, h, angles) for p, r, h in scans]
    # a fresh load-once loader (restored after the test): the next call compiles or fails anew
    monkeypatch.setattr(beam_kernel, "_load", functools.cache(beam_kernel._load.__wrapped__))
    monkeypatch.setenv("SANAV_MJ_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", "/nonexistent/cc")
    slow = LiveGrid((0.0, 0.0, 6.05, 4.0), 0.05, 0.23)
    assert beam_kernel.commit_cells(np.zeros(0, np.int64), slow._mark, slow.log_odds.reshape(-1), slow._floor,
                                    slow._params, True, slow.shape, slow._r, slow._koff, slow._pad, slow._route,
                                    slow._scratch) is None
    for (p, r, h), up in zip(scans, ups_fast):
        got = slow.integrate(p[:2], p[2], r, h, angles)
        assert np.array_equal(got.safe_changed, up.safe_changed)
        assert np.array_equal(np.sort(got.state_changed), np.sort(up.state_changed))
    assert np.array_equal(slow.log_odds, fast.log_odds) and np.array_equal(slow._pad, fast._pad)
    assert not (tmp_path / "cache").exists()


def test_compiled_scan_traversal_equals_segment_columns_and_free_cells():
    """scan_free_cells (clipping and set-up in C) against the NumPy segment_columns +
    free_cells: the same distinct cells and marks for fans from points inside, on cell
    corners and outside the grid, axis-parallel and zero-length beams, with and without
    skipping cells at a given value."""
    from sanav_mj.mapping.beam_kernel import free_cells, kernel_available, scan_free_cells
    from sanav_mj.mapping.live_grid import segment_columns

    if not kernel_available():
        pytest.skip("no C compiler: only the NumPy traversal exists")
    rng = np.random.default_rng(8)
    ny, nx = 41, 67
    values = np.where(rng.random(ny * nx) < 0.3, np.float32(-1.0), np.float32(0.5)).astype(np.float32)
    origins = [(rng.uniform(0, nx), rng.uniform(0, ny)) for _ in range(6)] + [(10.0, 20.0), (-4.2, 13.3),
                                                                              (nx + 3.0, ny + 0.5), (0.0, 0.0)]
    for u0, v0 in origins:
        a = np.concatenate([rng.uniform(-np.pi, np.pi, 300), np.arange(8) * np.pi / 4])
        r = np.concatenate([rng.uniform(0, 90, 300), rng.uniform(0, 30, 8)])
        r[:5] = 0.0
        u1, v1 = u0 + r * np.cos(a), v0 + r * np.sin(a)
        u1[5:10] = np.round(u1[5:10])  # ends on cell corners
        for skip in (None, (values, -1.0)):
            mark_ref, mark = np.zeros(ny * nx, np.int8), np.zeros(ny * nx, np.int8)
            want = free_cells(segment_columns(np.full(len(a), u0), np.full(len(a), v0), u1, v1, ny, nx), mark_ref,
                              use_kernel=False, skip=skip)
            got = scan_free_cells(u0, v0, u1, v1, (ny, nx), mark, skip)
            assert len(got) == len(np.unique(got)) and np.array_equal(np.sort(got), np.sort(want))
            assert np.array_equal(mark, mark_ref) and len(got) > 0
            if skip is not None:
                assert not np.any(values[got] == np.float32(-1.0))
            # with returns: the cells of the hit ends marked 2, those not crossed appended, sorted
            hit = rng.random(len(a)) < 0.6
            mark2 = np.zeros(ny * nx, np.int8)
            got2 = scan_free_cells(u0, v0, u1, v1, (ny, nx), mark2, skip, hit=hit)
            ei, ej = np.floor(v1[hit]).astype(np.int64), np.floor(u1[hit]).astype(np.int64)
            ein = (ei >= 0) & (ei < ny) & (ej >= 0) & (ej < nx)
            occ = (ei * nx + ej)[ein]
            extra = np.unique(occ[mark_ref[occ] == 0])
            assert np.array_equal(got2[:len(got)], got) and np.array_equal(got2[len(got):], extra)
            expect = mark_ref.copy()
            expect[occ] = 2
            assert np.array_equal(mark2, expect)


def _cast_boxes(o, ang, boxes, rmax):
    """Ranges [m] and hit flags of beams from ``o`` at world angles ``ang`` against
    axis-aligned boxes (x0, y0, x1, y1) (slab method, written for this test)."""
    d = np.stack([np.cos(ang), np.sin(ang)], 1)
    best = np.full(len(ang), np.inf)
    for x0, y0, x1, y1 in boxes:
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.stack([(x0 - o[0]) / d[:, 0], (x1 - o[0]) / d[:, 0]], 1)
            ty = np.stack([(y0 - o[1]) / d[:, 1], (y1 - o[1]) / d[:, 1]], 1)
        tn = np.maximum(tx.min(1), ty.min(1))
        tf = np.minimum(tx.max(1), ty.max(1))
        ok = (tf >= tn) & (tn > 0)
        best = np.where(ok & (tn < best), tn, best)
    hit = best <= rmax
    return np.where(hit, best, rmax), hit


@pytest.mark.parametrize("seed", [0, 1])
def test_route_grid_keeps_a_gap_the_known_map_passes(seed):
    """A 0.63 m gap in a wall, scanned with 0.02 m range noise at 0.025 m cells and 0.27 m
    inflation (the discs mode's): the known map (true boxes, same inflation) passes it; so
    do the default grid's route and safe cells (floor_at: rare returns in front of the
    surface, the minimum of many noisy ranges, are outvoted by the beams passing there), and
    no safe cell is one the known map calls occupied. Without floor_at (every return raises
    the floor: such cells are never free again) the square route kernel closes the gap, the
    centre kernel (opt-in) keeps the route open; the safe grid is the same with either."""
    from scipy import ndimage

    from sanav_mj.mapping.occupancy import rasterise
    from sanav_mj.scene import Obstacle

    h, infl, gap = 0.025, 0.27, 0.63
    bounds = (0.0, 0.0, 3.0, 3.0)
    boxes = [(0.0, 2.0, 1.5 - gap / 2, 2.3), (1.5 + gap / 2, 2.0, 3.0, 2.3)]
    old = LiveGridConfig(l_min=-1.0, floor_at=None)
    grids = {k: LiveGrid(bounds, h, infl, replace(old, route_kernel=k)) for k in ("square", "centre")}
    grids["default"] = LiveGrid(bounds, h, infl)
    rng = np.random.default_rng(seed)
    ang = np.linspace(-np.pi, np.pi, 1080, endpoint=False)
    for _ in range(20):
        o = np.array([1.5 + rng.uniform(-0.6, 0.6), rng.uniform(0.6, 1.4)])
        r, hit = _cast_boxes(o, ang, boxes, 5.0)
        r = np.where(hit, r + rng.normal(0, 0.02, len(r)), r)
        for g in grids.values():
            g.integrate(o, 0.0, r, hit, ang)
    obs = [Obstacle(f"b{i}", "box", np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2]), 0.0,
                    np.array([(b[2] - b[0]) / 2, (b[3] - b[1]) / 2]), 0.4, i) for i, b in enumerate(boxes)]
    known_free = ~rasterise(obs, bounds, h, inflation=infl).occupied

    def through(free):
        lab, _ = ndimage.label(free)
        a, b = lab[int(1.0 / h), int(1.5 / h)], lab[int(2.8 / h), int(1.5 / h)]
        return bool(a and a == b)

    assert through(known_free)
    assert through(grids["default"].route_safe()) and through(grids["default"].safe())
    assert not np.any(grids["default"].safe() & ~known_free)
    assert not through(grids["square"].route_safe())
    assert through(grids["centre"].route_safe())
    # the kernel choice leaves the map and the safe grid alone; safe implies route-safe
    assert np.array_equal(grids["centre"].log_odds, grids["square"].log_odds)
    assert np.array_equal(grids["centre"].safe(), grids["square"].safe())
    assert np.all(grids["centre"].route_safe() | ~grids["centre"].safe())


def test_the_default_threshold_separates_material_cells_from_cells_in_front():
    """The sensor model behind LiveGridConfig.floor_at, at the robot's lidar (0.02 m range
    noise, models/diff_drive.xml) on the discs mode's 0.025 m cells: every cell holding
    obstacle material, and the one just in front, is hit by more than f* = -l_free /
    (l_occ - l_free) of the beams reaching it (the log-odds drift up: locked non-free), every
    cell 1.5 cells or more in front by fewer (they end free). Exact values: the cell
    entirely in front with the surface at its back edge 0.4409, at 2 cells in front 0.1001."""
    from sanav_mj.mapping.live_grid import beam_hit_fraction

    c, sigma = 0.025, 0.02
    cfg = LiveGridConfig()
    f_star = -cfg.l_free / (cfg.l_occ - cfg.l_free)
    material = beam_hit_fraction(np.linspace(-0.05, c, 201), c, sigma)  # up to the cell just in front
    front = beam_hit_fraction(np.linspace(1.5 * c, 10 * c, 201), c, sigma)
    assert material.min() > 0.44 > f_star + 0.15 and front.max() < f_star
    assert beam_hit_fraction(c, c, sigma) == pytest.approx(0.4409349, abs=1e-6)
    assert beam_hit_fraction(2 * c, c, sigma) == pytest.approx(0.1000615, abs=1e-6)
    # monotone: deeper into the obstacle, more of the reaching beams end in the cell
    d = np.linspace(-0.05, 0.1, 301)
    assert np.all(np.diff(beam_hit_fraction(d, c, sigma)[::-1]) >= -1e-12)
    with pytest.raises(ValueError, match="sigma"):
        beam_hit_fraction(0.0, c, 0.0)


@pytest.mark.parametrize("compiled", [True, False])
def test_integrate_tails_is_integrate_for_long_tails_and_crosses_less_for_short(compiled):
    """``integrate_tails`` with a tail longer than every beam gives the grid ``integrate``
    gives (the same log-odds, counts and flips); with a short tail, only cells near the
    beams' ends get free observations (never more than with whole beams), returns alike."""
    rng = np.random.default_rng(4)
    angles = np.linspace(-2.3, 2.3, 181)
    gs = [LiveGrid((0.0, 0.0, 6.0, 4.0), 0.05, 0.2) for _ in range(3)]
    for g in gs:
        g._use_kernel = g._use_commit_kernel = compiled
    for step in range(8):
        pose = (rng.uniform(0.5, 2.3), rng.uniform(0.5, 3.5), rng.uniform(-np.pi, np.pi))
        ranges, hit = room_scan(pose, angles, (0.2, 0.2, 5.8, 3.8), 5.0)
        ranges = np.where(hit, ranges + rng.normal(0, 0.02, len(ranges)), ranges)
        a = gs[0].integrate(pose[:2], pose[2], ranges, hit, angles)
        b = gs[1].integrate_tails(pose[:2], pose[2], ranges, hit, angles, 100.0)
        gs[2].integrate_tails(pose[:2], pose[2], ranges, hit, angles, 0.3)
        assert np.array_equal(gs[0].log_odds, gs[1].log_odds)
        assert np.array_equal(gs[0].blocked, gs[1].blocked)
        assert np.array_equal(np.sort(a.state_changed), np.sort(b.state_changed))
        assert np.array_equal(a.safe_changed, b.safe_changed)
    assert np.all(gs[2].log_odds >= gs[0].log_odds)  # fewer free observations, the same returns
    assert np.count_nonzero(gs[2].log_odds > gs[0].log_odds) > 100


def test_unknown_near_is_the_unknown_part_of_the_kernels():
    """:meth:`LiveGrid.unknown_near`: the unknown cells within the safe kernel of the given
    cells, equal to a brute-force union of kernels over :meth:`states` (a hit cell, occupied,
    and the free cells of a scan are left out; kernels clipped at the grid's edges)."""
    g = LiveGrid((0, 0, 2, 2), 0.1, 0.25)
    g.integrate((0.55, 1.05), 0.0, [0.87, 0.6], [True, False], [0.0, np.pi / 2])
    st = g.states()
    assert (st == OCCUPIED).any() and (st == FREE).any()
    ny, nx = g.shape
    cells = np.array([10 * nx + 5, 10 * nx + 6, 0])  # two beside the beam and the corner cell
    ref = set()
    for c in cells:
        i, j = divmod(int(c), nx)
        for di, dj in inflation_offsets(0.25, 0.1):
            if 0 <= i + di < ny and 0 <= j + dj < nx and st[i + di, j + dj] == UNKNOWN:
                ref.add((i + di) * nx + j + dj)
    got = g.unknown_near(cells)
    assert got.tolist() == sorted(ref) and len(ref) > 0
    # a cell whose kernel holds no unknown cell returns none
    g2 = LiveGrid((0, 0, 1, 1), 0.1, 0.1)
    g2.observe_free(np.arange(100))
    assert g2.unknown_near([55]).size == 0
