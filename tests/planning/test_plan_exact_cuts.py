"""Fast-vs-reference checks of the exact cuts in the planning pipeline (issue 16, h16replan):
each new code path against the one it replaced, kept here as first written, bit for bit."""

import numpy as np
import pytest

from sanav_mj.mapping.safe_areas import SafeAreas, locate
from sanav_mj.planning import corridor
from sanav_mj.planning.smoothing import DEGREE, SmoothingProblem, collocation, cumulative_length, interpolate_uniform


def _candidates_reference(areas, rects, point):
    """``corridor._candidates`` as first written: ``locate``, then a second scan."""
    first = locate(areas, point, tol=corridor.CONTAIN_TOL)
    if first < 0:
        return np.zeros(0, dtype=np.int64)
    others = np.flatnonzero(corridor.contains(rects, point[None])[0])
    return np.concatenate([[first], others[others != first]]).astype(np.int64)


def _grid_areas(rng, n):
    """``n`` random rectangles on a 0.05 m lattice (overlapping, touching, nested)."""
    lo = rng.integers(0, 40, size=(n, 2)) * 0.05
    size = rng.integers(1, 12, size=(n, 2)) * 0.05
    rects = np.hstack([lo, lo + size])
    return SafeAreas(rects=rects, edges=np.zeros((0, 2), np.int64), weights=np.zeros(0), portals=np.zeros((0, 2, 2)))


def test_candidates_equal_locate_then_scan():
    rng = np.random.default_rng(16)
    checked = several = 0
    for trial in range(60):
        areas = _grid_areas(rng, int(rng.integers(0, 30)))
        rects = np.asarray(areas.rects, dtype=float).reshape(-1, 4)
        # lattice points (on edges and corners of several rectangles), points just off an
        # edge by less / more than the tolerance, random points, non-finite points
        pts = [rng.integers(0, 50, size=2) * 0.05 for _ in range(20)]
        pts += [rng.uniform(0, 2.5, size=2) for _ in range(10)]
        if len(rects):
            r = rects[int(rng.integers(len(rects)))]
            pts += [np.array([r[0] - 0.5e-9, r[1]]), np.array([r[2] + 2e-9, r[3]]), np.array([r[2] + 1e-9, r[1]])]
        pts += [np.array([np.nan, 0.1]), np.array([np.inf, 0.1])]
        for p in pts:
            got = corridor._candidates(areas, rects, p)
            ref = _candidates_reference(areas, rects, p)
            assert got.dtype == ref.dtype and np.array_equal(got, ref), (trial, p, got, ref)
            checked += 1
            several += got.size > 1
    assert checked > 1500 and several > 50  # shared edges and corners were exercised


class _ReferenceAssembly:
    """``SmoothingProblem``'s banded products and right-hand side as first written."""

    def __init__(self, u, points, knot_spacing):
        L = float(u[-1])
        n_int = max(1, int(round(L / knot_spacing)))
        n = n_int + DEGREE
        self.n, self.u, self.points = n, u, points
        self.h = L / max(len(u) - 1, 1)
        first, vals = collocation(L, n_int, u)
        rows, cols, bv = [], [], []
        for p in range(4):
            for q in range(p, 4):
                rows.append(first + p)
                cols.append(first + q)
                bv.append(vals[:, p] * vals[:, q])
        rows_a, cols_a = np.concatenate(rows), np.concatenate(cols)
        self.flat = (DEGREE + rows_a - cols_a) * n + cols_a
        self.prod = np.stack(bv)
        self.idx4 = (first[:, None] + np.arange(4)).ravel()
        self.vals = vals

    def assemble(self, weights):
        n = self.n
        wv = np.full(self.u.shape[0], self.h) if weights is None else self.h * weights
        btb = np.bincount(self.flat, weights=(self.prod * wv).ravel(), minlength=(DEGREE + 1) * n)
        wb = (self.vals * wv[:, None]).ravel()
        px = np.repeat(self.points[:, 0], 4)
        py = np.repeat(self.points[:, 1], 4)
        btp = np.column_stack([np.bincount(self.idx4, wb * px, minlength=n), np.bincount(self.idx4, wb * py, minlength=n)])
        return btb.reshape(DEGREE + 1, n), btp


def _bits(a):
    return np.ascontiguousarray(a).tobytes()


@pytest.mark.parametrize("seed", range(8))
def test_smoothing_assembly_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    for _ in range(10):
        w = int(rng.integers(2, 12))
        wp = np.cumsum(rng.normal(0.0, 0.6, size=(w, 2)), axis=0)
        spacing = float(rng.choice([0.05, 0.1, 0.13]))
        knot = spacing * float(rng.choice([1.0, 2.0, 3.5]))
        s = cumulative_length(wp)
        u, pts = interpolate_uniform(wp, spacing, s)
        u0, pts0 = interpolate_uniform(wp, spacing)
        assert _bits(u) == _bits(u0) and _bits(pts) == _bits(pts0)
        prob = SmoothingProblem(u, pts, knot)
        ref = _ReferenceAssembly(u, pts, knot)
        assert _bits(prob._flat) == _bits(ref.flat) and prob._flat.dtype == ref.flat.dtype
        assert _bits(prob._prod) == _bits(ref.prod)
        for weights in (None, rng.uniform(0.5, 40.0, size=u.size)):
            btb, btp = prob._assemble(weights)
            rb, rp = ref.assemble(weights)
            assert _bits(btb) == _bits(rb) and _bits(btp) == _bits(rp)
        b0, p0 = ref.assemble(None)
        assert _bits(prob.btb) == _bits(b0) and _bits(prob.btp) == _bits(p0)
