"""Scan matching: known rotations matched back, ambiguity flagged, failed matches refused;
the likelihood field's per-cell mean point; the cost's minimum."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from _helpers import run_without_kernels
from _mapping_reference import room_scan
from sanav_mj.mapping.occupancy import grid_shape
from sanav_mj.mapping.scan_match import LikelihoodField, ScanMatchConfig, ScanMatcher, scan_points

ANGLES = np.linspace(-0.75 * np.pi, 0.75 * np.pi, 541)  # the packaged lidar's fan
H = 0.05


def _world(pose, pts):
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.stack([c * pts[:, 0] - s * pts[:, 1] + pose[0], s * pts[:, 0] + c * pts[:, 1] + pose[1]], axis=1)


def _field(box, pose, bounds, cfg=ScanMatchConfig()):
    """The field of one noise-free scan of an axis-aligned room ``box`` taken at ``pose``."""
    b = np.asarray(bounds, dtype=float)
    f = LikelihoodField(grid_shape(b, H), b[:2], H, cfg.sigma, cfg.radius_cells)
    r, hit = room_scan(pose, ANGLES, box, 10.0)
    pts, _ = scan_points(r, hit, ANGLES)
    f.add_points(_world(pose, pts))
    return f


@pytest.mark.parametrize("dyaw", [0.03, -0.045, 0.05])
@pytest.mark.parametrize("shift", [(0.0, 0.0), (0.03, -0.02)])
def test_room_scan_rotated_by_a_known_yaw_is_matched_back(dyaw, shift):
    """The map: one scan of a 6 m x 4 m room from (2, 1.5, 0.3). The scan: the same room from
    a pose turned by ``dyaw`` and moved by ``shift``; the prior is the unturned, unmoved
    pose. The match recovers the true pose to within half the correlative search's steps
    (yaw_step / 2, half a cell), and says ok."""
    box = [0.0, 0.0, 6.0, 4.0]
    cfg = ScanMatchConfig()
    f = _field(box, (2.0, 1.5, 0.3), [-0.5, -0.5, 6.5, 4.5], cfg)
    true = np.array([2.0 + shift[0], 1.5 + shift[1], 0.3 + dyaw])
    r, hit = room_scan(true, ANGLES, box, 10.0)
    pts, normals = scan_points(r, hit, ANGLES, max_points=cfg.max_points)
    res = ScanMatcher(f, cfg).match(np.array([2.0, 1.5, 0.3]), pts, normals)
    assert res.ok and res.status == "ok"
    assert abs(res.pose[2] - true[2]) <= cfg.yaw_step / 2
    assert np.hypot(*(res.pose[:2] - true[:2])) <= H / 2
    assert res.inliers >= cfg.min_inliers and res.rms <= cfg.max_rms


def test_corridor_along_its_axis_is_flagged_ambiguous_and_keeps_the_prior_there():
    """Two parallel walls 2 m apart, longer than the range: nothing fixes the position along
    them. The match says ambiguous (smallest information eigenvalue 0: no return constrains
    x) and leaves x at the prior, while y and the yaw are matched."""
    box = [-50.0, -1.0, 50.0, 1.0]
    cfg = ScanMatchConfig()
    f = _field(box, (0.0, 0.0, 0.0), [-8.0, -1.5, 8.0, 1.5], cfg)
    true = np.array([0.3, 0.02, 0.02])
    r, hit = room_scan(true, ANGLES, box, 10.0)
    pts, normals = scan_points(r, hit, ANGLES, max_points=cfg.max_points)
    res = ScanMatcher(f, cfg).match(np.zeros(3), pts, normals)
    assert not res.ok and res.status == "ambiguous"
    assert res.eig[0] < cfg.min_eig
    assert abs(res.pose[0]) < 1e-3  # along the corridor: the prior
    assert abs(res.pose[1] - true[1]) <= H / 2 and abs(res.pose[2] - true[2]) <= cfg.yaw_step / 2


def test_scan_of_another_room_is_refused():
    """A scan of a 3 m x 3 m room taken at a yaw 0.7 rad from the prior's (far outside the
    search window) matched against the map of the 6 m x 4 m room: refused."""
    f = _field([0.0, 0.0, 6.0, 4.0], (2.0, 1.5, 0.3), [-0.5, -0.5, 6.5, 4.5])
    r, hit = room_scan((1.5, 1.0, 1.0), ANGLES, [0.0, 0.0, 3.0, 3.0], 10.0)
    pts, normals = scan_points(r, hit, ANGLES, max_points=100)
    res = ScanMatcher(f).match(np.array([2.0, 1.5, 0.3]), pts, normals)
    assert not res.ok and res.status in ("poor", "few_points")


def test_empty_field_returns_the_prior():
    f = LikelihoodField((10, 10), (0.0, 0.0), H, 0.05, 2)
    pts = np.array([[1.0, 0.0], [1.0, 0.1]])
    res = ScanMatcher(f).match(np.array([0.1, 0.2, 0.3]), pts, np.array([[1.0, 0.0], [1.0, 0.0]]))
    assert res.status == "empty" and not res.ok
    assert np.array_equal(res.pose, [0.1, 0.2, 0.3])


def test_field_point_is_the_mean_of_the_returns_in_the_cell():
    f = LikelihoodField((10, 10), (0.0, 0.0), H, 0.05, 2)
    assert f.add_points(np.array([[0.21, 0.31], [0.24, 0.34]])) == 1  # both in cell (6, 4)
    assert f.add_points(np.array([[0.225, 0.325]])) == 0  # same cell, no new one
    q, d2 = f.correspond(np.array([[0.225, 0.325], [0.45, 0.45]]))
    # mean of the three returns: (0.225, 0.325) up to the summation's rounding
    assert np.allclose(q[0], [0.225, 0.325], rtol=0, atol=4 * np.finfo(float).eps)
    assert d2[0] <= 8 * np.finfo(float).eps and math.isinf(d2[1])  # (0.45, 0.45): out of reach
    with pytest.raises(ValueError, match="normals"):
        ScanMatcher(f).match(np.zeros(3), np.zeros((2, 2)), np.zeros((3, 2)))


def test_cost_is_lowest_at_the_true_pose():
    box = [0.0, 0.0, 6.0, 4.0]
    f = _field(box, (2.0, 1.5, 0.3), [-0.5, -0.5, 6.5, 4.5])
    m = ScanMatcher(f)
    r, hit = room_scan((2.0, 1.5, 0.3), ANGLES, box, 10.0)
    pts, normals = scan_points(r, hit, ANGLES, max_points=100)
    c0 = m.cost(np.array([2.0, 1.5, 0.3]), pts, normals)
    for off in ([0.02, 0, 0], [0, -0.02, 0], [0, 0, 0.01]):
        assert m.cost(np.array([2.0, 1.5, 0.3]) + off, pts, normals) > c0 + 10
    res = m.match(np.array([2.01, 1.5, 0.3]), pts, normals, check=np.array([2.0, 1.5, 0.3]))
    assert res.check_delta <= 11.34  # the true pose passes the consistency test


def _cost_reference(m, pose, s, n):
    """The truncated point-to-line cost of one pose, written out (the single-pose version)."""
    c = m.config
    cth, sth = math.cos(pose[2]), math.sin(pose[2])
    pw = np.stack([cth * s[:, 0] - sth * s[:, 1] + pose[0], sth * s[:, 0] + cth * s[:, 1] + pose[1]], axis=1)
    q, d2 = m.field.correspond(pw, use_kernel=False)
    r = (cth * n[:, 0] - sth * n[:, 1]) * (pw[:, 0] - q[:, 0]) + (sth * n[:, 0] + cth * n[:, 1]) * (pw[:, 1] - q[:, 1])
    r2 = np.where(d2 <= c.max_pair_m ** 2, np.minimum(r * r, c.max_pair_m ** 2), c.max_pair_m ** 2)
    return float(r2.sum() / c.point_sigma ** 2)


@pytest.mark.parametrize("use_kernel", [True, False])
def test_costs_of_several_poses_equal_the_single_pose_cost_bit_for_bit(use_kernel):
    """Fast vs reference: one correspondence search for several poses (the match's
    consistency test) gives each pose's cost exactly as computed alone."""
    box = [0.0, 0.0, 6.0, 4.0]
    f = _field(box, (2.0, 1.5, 0.3), [-0.5, -0.5, 6.5, 4.5])
    m = ScanMatcher(f, use_kernel=use_kernel)
    r, hit = room_scan((2.0, 1.5, 0.3), ANGLES, box, 10.0)
    pts, normals = scan_points(r, hit, ANGLES)
    rng = np.random.default_rng(3)
    poses = [np.array([2.0, 1.5, 0.3])] + [np.array([2.0, 1.5, 0.3]) + rng.normal(0, [0.1, 0.1, 0.05])
                                           for _ in range(5)] + [np.array([9.0, 9.0, 1.0])]  # off the map
    got = m.costs(poses, pts, normals)
    want = [_cost_reference(m, p, pts, normals) for p in poses]
    assert got == want
    assert [m.cost(p, pts, normals) for p in poses] == want
    assert m.costs([], pts, normals) == []


def test_scan_points_drop_returns_without_a_surface():
    """Returns at a depth jump (an edge) or without both neighbours get no normal; on a flat
    wall the normal is the wall's."""
    angles = np.linspace(-0.5, 0.5, 41)
    r = 2.0 / np.cos(angles)  # a wall at x = 2
    hit = np.ones(41, dtype=bool)
    hit[20] = False
    pts, normals = scan_points(r, hit, angles, stencil=3)
    assert len(pts) == 41 - 6 - 3  # 3 at each end, beam 20 and the two whose chord ends there
    assert np.allclose(np.abs(normals[:, 0]), 1.0, atol=1e-12) and np.allclose(pts[:, 0], 2.0, atol=1e-12)
    with pytest.raises(ValueError, match="ScanMatchConfig.yaw_step"):
        ScanMatchConfig(yaw_step=0.0)


def _random_field(rng, cfg=ScanMatchConfig()):
    """A field of 400 random return points (some cells hit several times) in a 4 m x 3 m
    grid; points outside the grid are ignored."""
    b = np.array([-0.2, -0.1, 3.8, 2.9])
    f = LikelihoodField(grid_shape(b, H), b[:2], H, cfg.sigma, cfg.radius_cells)
    pts = rng.uniform([-0.4, -0.3], [4.0, 3.1], size=(400, 2))
    f.add_points(np.concatenate([pts, pts[:50] + rng.normal(0, 0.01, (50, 2))]))
    return f


@pytest.mark.parametrize("seed", range(6))
def test_compiled_correspondence_and_iterations_equal_the_numpy_reference(seed):
    """The compiled loop (sanav_mj.mapping.match_kernel) does the same floating-point
    operations in the same order as the NumPy reference: nearest points, distances,
    inlier flags, residuals and Jacobian rows are bit-identical on seeded random fields and
    queries (including points outside the grid, ties at equal distances and unpaired points),
    and so are whole matches (pose, status, eigenvalues, rms, check delta)."""
    from sanav_mj.mapping import match_kernel

    if not match_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy path exists")
    rng = np.random.default_rng(seed)
    cfg = ScanMatchConfig()
    f = _random_field(rng, cfg)
    q = rng.uniform([-1.0, -1.0], [5.0, 4.0], size=(300, 2))
    q[:20] = f._px[np.isfinite(f._px)][:20, None] * [1.0, 0.0] + f._py[np.isfinite(f._py)][:20, None] * [0.0, 1.0]
    q[20] = [np.nan, 1.0]  # a NaN query pairs with nothing in both paths
    with np.errstate(invalid="ignore"):  # NumPy's cast of floor(NaN) to int64
        a, da = f.correspond(q, use_kernel=False)
    b, db = f.correspond(q)
    assert np.array_equal(a, b, equal_nan=True) and np.array_equal(da, db, equal_nan=True)
    assert np.isfinite(da).sum() > 50 and np.isinf(da).sum() > 50
    ref, fast = ScanMatcher(f, cfg, use_kernel=False), ScanMatcher(f, cfg)
    s = rng.uniform(-2.0, 2.0, size=(120, 2))
    ang = rng.uniform(-np.pi, np.pi, 120)
    n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    for _ in range(5):
        xi = np.array([rng.uniform(1.0, 2.5), rng.uniform(1.0, 2.0), rng.uniform(-np.pi, np.pi)])
        c, sn = math.cos(xi[2]), math.sin(xi[2])
        Ja, ra, ia = ref._pair_rows(xi, c, sn, s, n)
        Jb, rb, ib = match_kernel.pair_rows(f, s, n, float(xi[0]), float(xi[1]), c, sn, cfg.max_pair_m ** 2)
        assert np.array_equal(ia, ib) and np.array_equal(Ja, Jb) and np.array_equal(ra, rb)
        ma = ref.match(xi, s, n, anchor=xi + 0.01, anchor_sigma=(0.02, 0.03), check=xi - 0.005)
        mb = fast.match(xi, s, n, anchor=xi + 0.01, anchor_sigma=(0.02, 0.03), check=xi - 0.005)
        assert ma.status == mb.status and ma.inliers == mb.inliers
        for k in ("pose", "eig", "correction"):
            assert np.array_equal(getattr(ma, k), getattr(mb, k))
        assert ma.rms == mb.rms or (math.isinf(ma.rms) and math.isinf(mb.rms))
        assert ma.check_delta == mb.check_delta


def test_scan_match_runs_without_the_compiled_kernel():
    """With SANAV_MJ_NO_CKERNEL=1 (no compiled code) a fresh process matches a rotated room
    scan with the NumPy path alone and gets the same pose as the compiled path here."""
    here = Path(__file__).parent  # this module and the shared helpers, wherever pytest runs from
    code = (
        f"import math, numpy as np, sys; sys.path[:0] = [{str(here)!r}, {str(here.parent)!r}];"
        "import test_scan_match as t; from sanav_mj.mapping import match_kernel;"
        "assert not match_kernel.kernel_available();"
        "from _mapping_reference import room_scan; from sanav_mj.mapping.scan_match import *;"
        "cfg = ScanMatchConfig(); f = t._field([0, 0, 6, 4], (2.0, 1.5, 0.3), [-0.5, -0.5, 6.5, 4.5], cfg);"
        "r, hit = room_scan(np.array([2.03, 1.48, 0.34]), t.ANGLES, [0, 0, 6, 4], 10.0);"
        "p, n = scan_points(r, hit, t.ANGLES, max_points=cfg.max_points);"
        "m = ScanMatcher(f, cfg).match(np.array([2.0, 1.5, 0.3]), p, n); print(repr(m.pose.tolist()), m.status)"
    )
    out = run_without_kernels(code)
    box = [0.0, 0.0, 6.0, 4.0]
    cfg = ScanMatchConfig()
    f = _field(box, (2.0, 1.5, 0.3), [-0.5, -0.5, 6.5, 4.5], cfg)
    r, hit = room_scan(np.array([2.03, 1.48, 0.34]), ANGLES, box, 10.0)
    pts, normals = scan_points(r, hit, ANGLES, max_points=cfg.max_points)
    m = ScanMatcher(f, cfg).match(np.array([2.0, 1.5, 0.3]), pts, normals)
    assert m.status == "ok" and out.strip() == f"{m.pose.tolist()!r} {m.status}"


@pytest.mark.parametrize("seed", range(4))
def test_compiled_field_update_equals_the_numpy_reference(seed):
    """LikelihoodField.add_points with the compiled loops (match_kernel.accumulate and
    spread) leaves the same sums, counts, hit points, field S and values, bit for bit, as the
    NumPy reference, and returns the same counts, over a seeded sequence of batches: returns
    in new cells, in cells hit before, several in one cell, outside the grid, NaN, empty."""
    from sanav_mj.mapping import match_kernel

    if not match_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy path exists")
    rng = np.random.default_rng(seed)
    cfg = ScanMatchConfig()
    b = np.array([-0.2, -0.1, 3.8, 2.9])
    ref, fast = (LikelihoodField(grid_shape(b, H), b[:2], H, cfg.sigma, cfg.radius_cells) for _ in range(2))
    seen = np.zeros((0, 2))
    counts = []
    for k in range(12):
        pts = rng.uniform([-0.4, -0.3], [4.0, 3.1], size=(int(rng.integers(0, 300)), 2))
        if len(seen):  # returns again in cells hit before, a little apart
            pts = np.concatenate([pts, seen[rng.integers(0, len(seen), 80)] + rng.normal(0, 0.01, (80, 2))])
        if k % 4 == 3:
            pts = np.concatenate([pts, [[np.nan, 1.0], [1.0, np.inf], [-5.0, 1.0]]])
        if k == 5:
            pts = np.zeros((0, 2))
        with np.errstate(invalid="ignore"):  # NumPy's cast of floor(NaN) to int64
            na = ref.add_points(pts, use_kernel=False)
        nb = fast.add_points(pts)
        assert na == nb
        counts.append(na)
        seen = np.concatenate([seen, pts[np.all(np.isfinite(pts), axis=1)]])
    for name in ("_sx", "_sy", "_n", "_px", "_py", "_hit", "_S", "values"):
        assert np.array_equal(getattr(ref, name), getattr(fast, name)), name
    assert ref.count == fast.count == sum(counts) and min(counts) == 0 and max(counts) > 50
    assert not fast._mark.any()


@pytest.mark.parametrize("seed", range(3))
def test_compiled_scan_points_equal_the_numpy_reference(seed):
    """scan_points with the compiled loop (match_kernel.scan_surface; the beam angles'
    cosines reused while the angles repeat) gives the same points and normals, bit for bit,
    as the NumPy reference: random scans with gaps, NaN ranges and a non-finite angle, the
    same angles several scans in a row and then other angles, with and without the pick of
    max_points, stencils 1 and 3."""
    from sanav_mj.mapping import match_kernel

    if not match_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy path exists")
    rng = np.random.default_rng(seed)
    angles = np.linspace(-2.356, 2.356, 541)
    checked = 0
    for k in range(40):
        if k % 10 == 9:  # other angles (another lidar): the cached cosines must not be reused
            angles = np.sort(rng.uniform(-2.4, 2.4, int(rng.integers(0, 700))))
        b = len(angles)
        a = angles.copy()
        r = np.where(rng.uniform(size=b) < 0.7, 2.0 + np.cumsum(rng.normal(0, 0.02, b)), rng.uniform(0.1, 8, b))
        hit = rng.uniform(size=b) < 0.85
        if k % 4 == 1 and b > 5:
            r[rng.integers(0, b, 3)] = np.nan
            a[rng.integers(0, b)] = np.inf
        for mp, st in ((None, 3), (120, 3), (None, 1)):
            with np.errstate(invalid="ignore"):  # cos(inf), NaN * 0 in both paths
                pa, na = scan_points(r, hit, a, (0.12, 0.01), mp, stencil=st, use_kernel=False)
                pb, nb = scan_points(r, hit, a, (0.12, 0.01), mp, stencil=st)
            assert np.array_equal(pa, pb) and np.array_equal(na, nb)
            checked += len(pa)
    assert checked > 10000
