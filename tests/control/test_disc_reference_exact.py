"""footprint_reference against the straightforward search it replaced, bit for bit.

The reference below evaluates ``DiscCover.clearance`` on all 11 x 11 x 91 candidate poses of
each sample whose disc centres leave the chain and takes the first acceptable one in the
stable cost order (the algorithm of footprint_reference before the per-axis test); the fast
version must return the same states and inputs, byte for byte, on random chains, covers and
references, with samples already inside, samples moved and samples with no acceptable pose.
"""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.control import disc_stages, repair_kernel
from sanav_mj.control.disc_stages import (
    REPAIR_REACH_M,
    REPAIR_STEP_M,
    REPAIR_YAW_SPAN,
    REPAIR_YAW_STEP,
    DiscCover,
    footprint_reference,
    repair_lattice,
)
from sanav_mj.control.stages import CorridorChain
from sanav_mj.footprint import Footprint


def reference_footprint_reference(cover, chain, states, inputs, dt):
    """The search as first written: every candidate's clearance, the first >= 0 in cost order."""
    states = np.asarray(states, dtype=float)
    bad = np.flatnonzero(cover.clearance(chain, states) < 0.0)
    if bad.size == 0:
        return states, inputs
    n, m = int(round(REPAIR_REACH_M / REPAIR_STEP_M)), int(REPAIR_YAW_SPAN // REPAIR_YAW_STEP)
    r = REPAIR_STEP_M * np.arange(-n, n + 1)
    a = REPAIR_YAW_STEP * np.arange(-m, m + 1)
    dx, dy, da = (g.ravel() for g in np.meshgrid(r, r, a, indexing="ij"))
    order = np.argsort(dx * dx + dy * dy + (cover.sweep * da) ** 2, kind="stable")
    dx, dy, da = dx[order], dy[order], da[order]
    out = states.copy()
    for i in bad:
        cand = np.column_stack((states[i, 0] + dx, states[i, 1] + dy, states[i, 2] + da))
        ok = np.flatnonzero(cover.clearance(chain, cand) >= 0.0)
        if ok.size:
            out[i] = cand[ok[0]]
    inputs = np.asarray(inputs, dtype=float).copy()
    touched = np.unique(np.concatenate((bad - 1, bad)))
    touched = touched[(touched >= 0) & (touched < min(len(inputs), len(out) - 1))]
    inputs[touched, 1] = (out[touched + 1, 2] - out[touched, 2]) / dt
    return out, inputs


def _chain(boxes: np.ndarray) -> CorridorChain:
    boxes = np.asarray(boxes, dtype=float)
    pairs = np.zeros((len(boxes), 2), dtype=int)
    return CorridorChain(boxes, pairs, boxes.copy(), boxes.copy())


def _random_case(rng: np.random.Generator):
    """A cover, a chain of narrow boxes along a random walk, and a reference along the walk."""
    length, width = rng.uniform(0.2, 0.7), rng.uniform(0.15, 0.5)
    cx, cy = rng.uniform(-0.05, 0.05, 2)
    fp = Footprint(cx - length / 2, cx + length / 2, cy - width / 2, cy + width / 2)
    cover = DiscCover.of(fp, int(rng.integers(1, 5)))
    members = int(rng.integers(1, 10))
    pts = np.cumsum(rng.uniform(-0.6, 0.6, (members + 1, 2)), axis=0)
    boxes = []
    for p, q in zip(pts[:-1], pts[1:]):  # an axis-aligned strip around each leg, random width
        half = rng.uniform(0.0, 0.3, 2) * rng.uniform(0.1, 1.0)
        boxes.append([min(p[0], q[0]) - half[0], min(p[1], q[1]) - half[1],
                      max(p[0], q[0]) + half[0], max(p[1], q[1]) + half[1]])
    k = int(rng.integers(2, 25))
    leg = rng.integers(0, members, k)
    t = rng.uniform(0.0, 1.0, k)[:, None]
    xy = pts[leg] * (1 - t) + pts[leg + 1] * t + rng.normal(0.0, 0.08, (k, 2))
    d = pts[leg + 1] - pts[leg]
    yaw = np.arctan2(d[:, 1], d[:, 0]) + rng.normal(0.0, 0.6, k)
    states = np.column_stack((xy, yaw))
    inputs = rng.uniform(-1.0, 1.0, (k - int(rng.integers(0, 2)), 2))
    return cover, _chain(np.array(boxes)), states, inputs


def _assert_same(got, want):
    for g, w in zip(got, want):
        g, w = np.asarray(g), np.asarray(w)
        assert g.shape == w.shape and g.dtype == w.dtype
        assert g.tobytes() == w.tobytes()


@pytest.fixture(params=["compiled", "numpy"])
def path(request, monkeypatch):
    """Run footprint_reference's compiled search, or its NumPy path (the kernel reported absent)."""
    if request.param == "numpy":
        monkeypatch.setattr(disc_stages, "first_acceptable", lambda *args: None)
    elif not repair_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy path exists")
    return request.param


def test_random_chains_give_the_reference_result_bit_for_bit(path):
    rng = np.random.default_rng(16)
    kinds = {"inside": 0, "moved": 0, "none": 0}
    for _ in range(60):
        cover, chain, states, inputs = _random_case(rng)
        want = reference_footprint_reference(cover, chain, states, inputs, 0.1)
        _assert_same(footprint_reference(cover, chain, states, inputs, 0.1), want)
        bad = cover.clearance(chain, states) < 0.0
        moved = np.any(want[0] != states, axis=1)
        kinds["inside"] += int(np.sum(~bad))
        kinds["moved"] += int(np.sum(moved))
        kinds["none"] += int(np.sum(bad & ~moved))
    # the cases exercised all three outcomes, many times
    assert min(kinds.values()) >= 20, kinds


def test_per_disc_chains_and_many_bad_samples_give_the_reference_result(path):
    """One chain per disc (as DiscCover.stages takes), and more bad samples than one batch."""
    rng = np.random.default_rng(7)
    for _ in range(6):
        cover, chain, states, inputs = _random_case(rng)
        chains = [_chain(chain.boxes + rng.normal(0.0, 0.02, chain.boxes.shape)) for _ in cover.offsets]
        many = np.repeat(states, 4, axis=0) + rng.normal(0.0, 0.03, (4 * len(states), 3))
        u = np.zeros((len(many) - 1, 2))
        for ch in (chains, chain):
            _assert_same(footprint_reference(cover, ch, many, u, 0.1),
                         reference_footprint_reference(cover, ch, many, u, 0.1))


def test_a_centre_exactly_on_a_member_edge_counts_as_inside(path):
    """Box edges placed on the centres a candidate computes: a slack of exactly 0 is >= 0, and
    the centres are the reference's to the last bit (a reordered sum moves some by an ulp)."""
    rng = np.random.default_rng(11)
    r = REPAIR_STEP_M * np.arange(-5, 6)  # the lattice's offsets, as footprint_reference makes them
    m = int(REPAIR_YAW_SPAN // REPAIR_YAW_STEP)
    a = REPAIR_YAW_STEP * np.arange(-m, m + 1)
    for trial in range(40):
        fp = Footprint(-0.25, 0.25 + 0.1 * (trial % 3), -0.215, 0.215 + 0.05 * (trial % 2))
        cover = DiscCover.of(fp, 3)
        state = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-np.pi, np.pi)])
        i, j, k = rng.integers(0, 11), rng.integers(0, 11), rng.integers(0, 2 * m + 1)
        pose = np.array([state[0] + r[i], state[1] + r[j], state[2] + a[k]])  # one candidate
        c = cover.centres(pose[None])[0]
        chain = _chain([[c[:, 0].min(), c[:, 1].min(), c[:, 0].max(), c[:, 1].max()]])
        want = reference_footprint_reference(cover, chain, state[None], np.zeros((1, 2)), 0.1)
        got = footprint_reference(cover, chain, state[None], np.zeros((1, 2)), 0.1)
        _assert_same(got, want)
        assert np.any(got[0] != state) or cover.clearance(chain, state[None])[0] >= 0.0  # found


def test_the_per_axis_test_equals_the_clearance_of_every_candidate():
    rng = np.random.default_rng(3)
    for _ in range(10):
        cover, chain, states, _ = _random_case(rng)
        order, dx, dy, da = repair_lattice(cover.sweep)
        got = disc_stages._acceptable(cover, chain, states)[:, order]
        for i in range(len(states)):
            cand = np.column_stack((states[i, 0] + dx, states[i, 1] + dy, states[i, 2] + da))
            np.testing.assert_array_equal(got[i], cover.clearance(chain, cand) >= 0.0)


def test_the_lattice_is_cached_and_read_only():
    a = repair_lattice(0.3)
    assert repair_lattice(0.3)[0] is a[0]
    with pytest.raises(ValueError):
        a[1][0] = 1.0
    n, m = int(round(REPAIR_REACH_M / REPAIR_STEP_M)), int(REPAIR_YAW_SPAN // REPAIR_YAW_STEP)
    assert a[0].size == (2 * n + 1) ** 2 * (2 * m + 1)  # 11 x 11 x 89 (44 steps of 2 deg either side)
    assert a[1][0] == 0.0 and a[2][0] == 0.0 and a[3][0] == 0.0  # the zero offset first


def test_the_compiled_search_finds_the_numpy_paths_first_candidate():
    if not repair_kernel.kernel_available():
        pytest.skip("no C compiler: only the NumPy path exists")
    rng = np.random.default_rng(5)
    found = 0
    for _ in range(20):
        cover, chain, states, _ = _random_case(rng)
        order = repair_lattice(cover.sweep)[0]
        ok = disc_stages._acceptable(cover, chain, states)[:, order]
        want = np.where(ok.any(axis=1), ok.argmax(axis=1), -1)
        xs, ys, cos, sin = disc_stages._lattice_axes(states)
        got = repair_kernel.first_acceptable(xs, ys, cos, sin, cover.offsets, [chain.boxes] * len(cover.offsets), order)
        np.testing.assert_array_equal(got, want)
        found += int(np.sum((want > 0) & (want < order.size - 1)))
    assert found >= 20  # first candidates inside the order, not only its ends
