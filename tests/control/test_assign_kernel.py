"""The compiled disc assignment (sanav_mj.control.assign_kernel) against the NumPy path of
``sa_mpc._assign_shared`` (its reference): the same assignments and stage boxes, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import run_without_kernels

from sanav_mj.control import assign_kernel, sa_mpc
from sanav_mj.control.sa_mpc import REANCHOR_M, _assign_shared


class _Chain:
    """A corridor chain's stay / advance boxes (what the assignment reads)."""

    def __init__(self, stay: np.ndarray, advance: np.ndarray):
        self.stay, self.advance = stay, advance

    def __len__(self) -> int:
        return len(self.stay)


def _chain(rng, n_m: int) -> _Chain:
    """A staircase of n_m overlapping boxes (0.05 m grid edges, so centres land on edges)."""
    lo = np.cumsum(rng.integers(2, 9, (n_m, 2)), axis=0) * 0.05
    size = rng.integers(10, 20, (n_m, 2)) * 0.05  # wider than a step: neighbours overlap
    stay = np.hstack((lo, lo + size))
    advance = stay.copy()  # the advance box: the member met with its predecessor's box
    advance[1:, :2] = np.maximum(stay[1:, :2], stay[:-1, :2] - 0.1)
    advance[1:, 2:] = np.minimum(stay[1:, 2:], stay[:-1, 2:] + 0.1)
    return _Chain(stay, advance)


def _reference(monkeypatch, *args):
    with monkeypatch.context() as m:
        m.setattr(sa_mpc, "assign_discs", lambda *a: None)
        return _assign_shared(*args)


def _centres(rng, chain, n1: int, n_d: int) -> np.ndarray:
    """(n1, n_d, 2) centres walking along the chain (some on box edges, some far outside)."""
    n_m = len(chain)
    path = np.concatenate([chain.stay[j, :2] + rng.uniform(0, 1, (4, 2)) * (chain.stay[j, 2:] - chain.stay[j, :2])
                           for j in range(n_m)])
    start = rng.integers(0, max(1, len(path) - n1))
    base = path[start:start + n1]
    base = np.vstack((base, np.repeat(base[-1:], n1 - len(base), axis=0)))
    pts = base[:, None, :] + rng.normal(0.0, rng.choice([0.0, 0.01, 0.05, 0.3]), (n1, n_d, 2))
    snap = rng.random((n1, n_d, 2)) < 0.2  # onto the 0.05 m grid of the box edges
    pts[snap] = np.round(pts[snap] / 0.05) * 0.05
    near = rng.random((n1, n_d, 2)) < 0.1  # within the tolerance of an edge
    pts[near] += rng.choice([-1.0, 1.0], near.sum()) * rng.uniform(0, 2e-6, near.sum())
    return pts


@pytest.mark.skipif(not assign_kernel.kernel_available(), reason="no C compiler (the NumPy path runs)")
@pytest.mark.parametrize("n_m", [1, 3, 9, 40, 62])
def test_kernel_matches_the_numpy_path_bit_for_bit(monkeypatch, n_m):
    rng = np.random.default_rng(n_m)
    dp = ok = 0
    for trial in range(300):
        chain = _chain(rng, n_m)
        both = np.concatenate((chain.stay, chain.advance))
        n1, n_d = 21, int(rng.choice([1, 3]))
        pts = _centres(rng, chain, n1, n_d)
        s_prev = None if trial % 3 == 0 else np.sort(rng.integers(0, n_m, (n_d, n1)), axis=1)
        tol = 1e-6
        ss_ref, plain_ref = _reference(monkeypatch, chain, both, pts, s_prev, tol)
        ss, plain = _assign_shared(chain, both, pts, s_prev, tol)
        assert ss.dtype == ss_ref.dtype and np.array_equal(ss, ss_ref)
        assert plain.dtype == plain_ref.dtype and np.array_equal(plain, plain_ref)
        fast = assign_kernel.assign_discs(both, n_m, pts, s_prev, tol, REANCHOR_M)
        dp += int((~fast[2]).sum())
        ok += int(fast[2].sum())
    assert ok > 0 and (n_m == 1 or dp > 0)  # both the bit sets and the dynamic programme decided


def test_kernel_declines_what_it_does_not_handle():
    chain = _chain(np.random.default_rng(0), 3)
    both = np.concatenate((chain.stay, chain.advance))
    pts = np.zeros((21, 3, 2))
    pts[4, 1, 0] = np.nan
    assert assign_kernel.assign_discs(both, 3, pts, None, 1e-6, REANCHOR_M) is None
    assert assign_kernel.assign_discs(np.zeros((126, 4)), 63, np.zeros((21, 3, 2)), None, 1e-6, REANCHOR_M) is None
    bad = both.copy()
    bad[2, 3] = np.inf
    assert assign_kernel.assign_discs(bad, 3, np.zeros((21, 3, 2)), None, 1e-6, REANCHOR_M) is None


def test_without_kernels_the_numpy_path_gives_the_same_answer():
    code = (
        "import numpy as np, sys; sys.path.insert(0, 'tests/control'); sys.path.insert(0, 'tests');"
        "from test_assign_kernel import _chain, _centres;"
        "from sanav_mj.control import assign_kernel; from sanav_mj.control.sa_mpc import _assign_shared;"
        "assert not assign_kernel.kernel_available();"
        "rng = np.random.default_rng(7); out = [];\n"
        "for t in range(40):\n"
        "    c = _chain(rng, 9); b = np.concatenate((c.stay, c.advance)); p = _centres(rng, c, 21, 3)\n"
        "    sp = None if t % 2 else np.sort(rng.integers(0, 9, (3, 21)), axis=1)\n"
        "    ss, pl = _assign_shared(c, b, p, sp, 1e-6); out.append(ss.tolist()); out.append(pl.tobytes().hex())\n"
        "import hashlib; print(hashlib.sha256(str(out).encode()).hexdigest())"
    )
    got = run_without_kernels(code).split()[-1]
    import hashlib

    rng = np.random.default_rng(7)
    out = []
    for t in range(40):
        c = _chain(rng, 9)
        b = np.concatenate((c.stay, c.advance))
        p = _centres(rng, c, 21, 3)
        sp = None if t % 2 else np.sort(rng.integers(0, 9, (3, 21)), axis=1)
        ss, pl = _assign_shared(c, b, p, sp, 1e-6)
        out.append(ss.tolist())
        out.append(pl.tobytes().hex())
    assert got == hashlib.sha256(str(out).encode()).hexdigest()


@pytest.mark.parametrize("n_m", [1, 4, 12, 62])
def test_single_point_assignment_matches_assign_stages(n_m):
    """``"disc"`` mode (sa_mpc._assign_point: the kernel with one point per stage, else
    assign_stages) against assign_stages + stage_boxes, bit for bit, on both decision paths."""
    from sanav_mj.control.sa_mpc import _assign_point
    from sanav_mj.control.stages import assign_stages, first_candidates, stage_boxes

    rng = np.random.default_rng(100 + n_m)
    fits = 0
    for trial in range(300):
        chain = _chain(rng, n_m)
        both = np.concatenate((chain.stay, chain.advance))
        guess = np.concatenate((_centres(rng, chain, 21, 1)[:, 0], rng.normal(size=(21, 1))), axis=1)
        s_prev = None if trial % 3 == 0 else np.sort(rng.integers(0, n_m, 21))
        s_ref = assign_stages(chain, guess[:, :2], first_candidates(n_m, s_prev), tol=1e-6)
        s, boxes = _assign_point(chain, both, guess, s_prev, 1e-6)
        assert s.dtype == s_ref.dtype and np.array_equal(s, s_ref)
        assert np.array_equal(boxes, stage_boxes(chain, s_ref))
        fast = assign_kernel.assign_discs(both, n_m, guess[:, None, :2], None if s_prev is None else s_prev[None],
                                          1e-6, REANCHOR_M)
        fits += fast is not None and bool(fast[2][0])
    assert fits > 0 and (n_m == 1 or fits < 300) or not assign_kernel.kernel_available()


@pytest.mark.skipif(not assign_kernel.kernel_available(), reason="no C compiler (the NumPy path runs)")
@pytest.mark.parametrize("tighten", [None, (0.0, False), (0.0, True), (0.012, False), (0.03, True), (0.5, False)])
def test_relaxation_kernel_matches_the_numpy_path_bit_for_bit(monkeypatch, tighten):
    """sa_mpc._relax_all with the kernel against its NumPy path: the same floats, bit for bit
    except the sign of an exact zero (NumPy's vectorised max/min return either zero where
    both operands are zeros; the sides here are rounded to 0.1 m, so many are -0.0 or 0.0),
    and the same excursion; centres on, inside and beyond the stage-0 box."""
    from sanav_mj.control.sa_mpc import _relax_all

    rng = np.random.default_rng(5)
    moved = 0
    for _ in range(400):
        n_d, n1 = int(rng.choice([1, 3])), 21
        lo = np.round(rng.uniform(-1, 1, (n_d, n1, 2)), 1)  # zeros among the sides
        plain = np.concatenate((lo, lo + np.round(rng.uniform(0, 0.6, (n_d, n1, 2)), 2)), axis=2)
        box0 = plain[:, 0]
        pts0 = rng.uniform(box0[:, :2] - 0.1, box0[:, 2:] + 0.1)
        on_edge = rng.random(n_d) < 0.3
        pts0[on_edge] = box0[on_edge, 2:]
        with monkeypatch.context() as m:
            m.setattr(sa_mpc, "relax_discs", lambda *a: None)
            ref, exc_ref = _relax_all(plain, pts0, tighten)
        out, exc = _relax_all(plain, pts0, tighten)
        assert exc == exc_ref and type(exc) is float and np.array_equal(out, ref)
        differ = out.view(np.int64) != ref.view(np.int64)  # only zeros of opposite sign
        assert np.all(out[differ] == 0.0) and np.all(ref[differ] == 0.0)
        nonzero = ref != 0.0
        assert out[nonzero].tobytes() == ref[nonzero].tobytes()
        moved += exc > 0
    assert 50 < moved < 350
    assert assign_kernel.relax_discs(np.full((3, 21, 4), np.nan), np.zeros((3, 2)), None) is None
