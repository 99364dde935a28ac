"""Arc-length interpolation (paper eq. 5-6) and cubic B-spline smoothing (eq. 7), with a
safety adaptation that keeps the smoothed curve inside the corridor.

Interpolation. The waypoint polyline ``w_0 .. w_M`` is parametrised by its cumulative arc
length ``u`` [m]; points are sampled uniformly in ``u`` (:func:`interpolate_uniform`).

Smoothing (eq. 7). A cubic B-spline ``S(u) = sum_i c_i B_i(u)`` on uniform knots
``k * delta`` (``k = -3 .. n + 3``, ``delta = L / n``), used on ``[0, L]``, minimises

    J(c) = h * sum_j |S(u_j) - p_j|^2 + lam * integral_0^L |S''(u)|^2 du
    subject to S(0) = w_0 (start) and S(L) = w_M (goal)

with ``p_j`` the interpolated points at spacing ``h`` [m]. Multiplying the data term by ``h``
makes it approximate ``integral |S - p|^2 du``, so ``lam`` [m^4] does not depend on the
sampling density: ``lam ** 0.25`` is the length scale [m] over which the path is smoothed.
This is eq. 7 with the spline parameter ``mu = u / L`` and ``lambda_eq7 = lam / (h L^3)``.

The minimiser solves the banded equations ``(h B^T B + lam G) c = h B^T p - H^T mu`` with the
two end constraints ``H c = d`` eliminated through their Lagrange multipliers ``mu``. ``B`` is
the collocation matrix (4 non-zeros a row, from the closed-form uniform cubic pieces;
checked against ``scipy.interpolate.BSpline`` in the tests) and ``G`` the exact Gram matrix of
the basis' second derivatives: on every knot interval the second derivatives of the four
pieces are linear, so each interval adds the same exact 4 x 4 block ``/ delta^3``. Both
matrices have bandwidth 3; ``scipy.linalg.solveh_banded`` solves for both coordinates and
the constraint columns at once.

Safety (see :func:`safe_curve`). The interpolated polyline lies in the union of the corridor
rectangles by construction; the spline may cut corners. The curve used downstream is
``c(u) = (1 - beta(u)) S(u) + beta(u) P(u)``, with ``P`` the interpolated polyline and
``beta`` a smooth blend that is 0 where the spline is safe. It is checked on a dense grid:
first ``lam`` is reduced around each violation (the data points within a window of the
offending samples get a larger weight; refit) up to a limit; if samples still leave the
corridor, ``beta`` is raised to 1 over each offending stretch (plus a margin, with smooth
ramps), widening it until the whole dense curve is inside. In the limit ``beta == 1`` the curve is the polyline,
which is safe, so the procedure always ends with a curve whose checked samples lie in the
corridor, never silently with an unsafe one. The planner checks the final reference samples
the same way (exact curve points) and widens the fallback if one is outside. Between two
checked nodes (``check_spacing`` apart) the continuous curve is not checked; near a reflex
corner it can graze outside by a fraction of a millimetre (0.5 mm measured in the tight test
case with 0.02 m spacing).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgError
from scipy.linalg.lapack import dpbsv

import sanav_mj.planning.assign_kernel as assign_kernel
from sanav_mj.planning.corridor import CONTAIN_TOL

DEGREE = 3
_FOUR = np.arange(4)
# the 10 (p, q) pairs, q >= p, p-major: the banded products of SmoothingProblem
_PQ_P, _PQ_Q = (np.array(v, dtype=np.int64) for v in zip(*[(p, q) for p in range(4) for q in range(p, 4)]))


# --------------------------------------------------------------------------------------
# interpolation (eq. 5-6)
# --------------------------------------------------------------------------------------


def cumulative_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length ``s_i`` [m] of the polyline through (W, 2) points; (W,), s_0 = 0."""
    p = np.asarray(points, dtype=float)
    s = np.zeros(p.shape[0])
    if p.shape[0] > 1:
        np.cumsum(np.hypot(p[1:, 0] - p[:-1, 0], p[1:, 1] - p[:-1, 1]), out=s[1:])
    return s


def polyline_at(points: np.ndarray, s_nodes: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Points on the polyline at arc lengths ``u`` (eq. 5: w'(s) = (1-alpha) w_i + alpha w_{i+1}).

    Args:
        points: (W, 2) [m] polyline vertices.
        s_nodes: (W,) [m] their cumulative arc length (non-decreasing).
        u: (K,) [m] query arc lengths, clipped to ``[0, s_nodes[-1]]``.

    Returns:
        (K, 2) [m].
    """
    return np.column_stack([np.interp(u, s_nodes, points[:, 0]), np.interp(u, s_nodes, points[:, 1])])


def segment_of(s_nodes: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Index ``i`` of the polyline segment ``[s_i, s_{i+1}]`` containing each ``u`` (K,) int.

    Zero-length segments are never returned (a point at a repeated vertex is given the
    following non-empty segment, or the last one at the end)."""
    n_seg = s_nodes.shape[0] - 1
    i = np.searchsorted(s_nodes, u, side="right") - 1
    return np.minimum(np.maximum(i, 0), max(n_seg - 1, 0))


def interpolate_uniform(waypoints: np.ndarray, spacing: float,
                        s_nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Uniform arc-length samples of the waypoint polyline (paper eq. 5-6).

    Args:
        waypoints: (W, 2) [m], W >= 1.
        spacing: [m] target distance between samples (> 0); the actual spacing is
            ``L / (M - 1)`` with ``M = ceil(L / spacing) + 1`` so both ends are samples.
        s_nodes: (W,) [m] ``cumulative_length(waypoints)`` when already computed (None:
            computed here).

    Returns:
        ``(u, points)``: (M,) [m] arc lengths from 0 to L and (M, 2) [m] the samples.
    """
    s = cumulative_length(waypoints) if s_nodes is None else s_nodes
    L = float(s[-1])
    m = max(2, int(np.ceil(L / spacing - 1e-9)) + 1)
    u = np.linspace(0.0, L, m)
    return u, polyline_at(np.asarray(waypoints, dtype=float), s, u)


# --------------------------------------------------------------------------------------
# B-spline smoothing (eq. 7)
# --------------------------------------------------------------------------------------

# Second derivatives of the uniform cubic B-spline pieces on one knot interval are linear in
# the local coordinate t in [0, 1]: N0'' = 1 - t, N1'' = 3t - 2, N2'' = 1 - 3t, N3'' = t.
# Their exact Gram matrix (integral over t of N_p'' N_q'') is:
_LOCAL_GRAM = np.array([[2.0, -3.0, 0.0, 1.0], [-3.0, 6.0, -3.0, 0.0], [0.0, -3.0, 6.0, -3.0], [1.0, 0.0, -3.0, 2.0]]) / 6.0


def uniform_basis(t: np.ndarray) -> np.ndarray:
    """The four non-zero uniform cubic B-spline basis values at local coordinates ``t``.

    Args:
        t: (K,) local coordinate in [0, 1] within a knot interval.

    Returns:
        (K, 4) values of the pieces ``(1-t)^3/6, (3t^3-6t^2+4)/6, (-3t^3+3t^2+3t+1)/6, t^3/6``
        (they sum to 1).
    """
    t2 = t * t
    t3 = t2 * t
    s = 1.0 - t
    out = np.empty((t.shape[0], 4))
    out[:, 0] = s * s * s
    out[:, 1] = 3.0 * t3 - 6.0 * t2 + 4.0
    out[:, 2] = -3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0
    out[:, 3] = t3
    out *= 1.0 / 6.0
    return out


def knot_vector(length: float, n_intervals: int) -> np.ndarray:
    """The uniform knot vector ``k * delta``, ``k = -3 .. n_intervals + 3`` [m] (``delta =
    length / n_intervals``) of the splines used here; their domain is ``[0, length]``. This is
    the knot vector to give ``scipy.interpolate.BSpline`` to evaluate the same spline."""
    return np.arange(-DEGREE, n_intervals + DEGREE + 1) * (length / n_intervals)


def collocation(length: float, n_intervals: int, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Collocation matrix of the uniform cubic basis at ``u`` in compact form.

    Args:
        length: [m] domain length L.
        n_intervals: number of knot intervals on ``[0, L]``.
        u: (M,) [m] parameters in ``[0, L]`` (clipped).

    Returns:
        ``(first, vals)``: (M,) int index of the first of the 4 basis functions non-zero at
        each ``u`` and (M, 4) their values (row k of B is ``vals[k]`` at columns
        ``first[k] .. first[k] + 3``).
    """
    x = np.minimum(np.maximum(u, 0.0), length) * (n_intervals / length)
    first = np.minimum(x.astype(np.int64), n_intervals - 1)
    return first, uniform_basis(x - first)


def second_derivative_gram(length: float, n_intervals: int) -> np.ndarray:
    """Exact Gram matrix ``G_ij = integral_0^L B_i''(u) B_j''(u) du`` of the uniform cubic
    basis, in upper banded storage for ``scipy.linalg.solveh_banded`` (``ab[3 + i - j, j] =
    G[i, j]``). Each knot interval contributes the same local 4 x 4 block ``/ delta^3``.

    Returns:
        (4, n_intervals + 3) [1/m^3].
    """
    n = n_intervals + DEGREE
    delta = length / n_intervals
    ab = np.zeros((DEGREE + 1, n))
    scale = 1.0 / delta**3
    for p in range(4):
        for q in range(p, 4):
            ab[DEGREE - (q - p), q : q + n_intervals] += _LOCAL_GRAM[p, q] * scale
    return ab


@dataclass(frozen=True)
class SmoothingSpline:
    """A fitted cubic B-spline ``S(u)`` on uniform knots, u in ``[0, L]`` [m].

    Attributes:
        length: [m] L.
        n_intervals: number of knot intervals.
        coeffs: (n_intervals + 3, 2) [m] control points.
        lam: [m^4] smoothing weight used.
    """

    length: float
    n_intervals: int
    coeffs: np.ndarray
    lam: float

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(K, 2) [m] points at arc-length parameters ``u`` (K,) [m] (clipped to [0, L])."""
        return self.at_collocation(*collocation(self.length, self.n_intervals, np.asarray(u, dtype=float)))

    def at_collocation(self, first: np.ndarray, vals: np.ndarray) -> np.ndarray:
        """(K, 2) [m] points at parameters given by their collocation ``(first, vals)``
        ((K,) int, (K, 4): :func:`collocation` with this spline's ``length`` and
        ``n_intervals``), the same arithmetic as calling the spline; for evaluating several
        splines of one knot layout at the same parameters."""
        idx = first[:, None] + _FOUR
        out = np.empty((vals.shape[0], 2))
        out[:, 0] = np.einsum("ij,ij->i", vals, self.coeffs[:, 0].take(idx))
        out[:, 1] = np.einsum("ij,ij->i", vals, self.coeffs[:, 1].take(idx))
        return out

    @property
    def knots(self) -> np.ndarray:
        """The knot vector (see :func:`knot_vector`)."""
        return knot_vector(self.length, self.n_intervals)


class SmoothingProblem:
    """The equations of eq. 7 for one data set, reusable for several ``lam``.

    Minimises ``h sum_j |S(u_j) - p_j|^2 + lam integral_0^L |S''|^2 du`` subject to
    ``S(0) = p_0`` and ``S(L) = p_{M-1}`` (two linear equality constraints ``H c = d``, solved
    exactly with Lagrange multipliers: ``c = A^-1 (r - H^T mu)``, ``mu`` from a 2 x 2 system;
    one banded Cholesky solve with four right-hand sides).

    Args:
        u: (M,) [m] arc-length parameters of the data (from 0 to L > 0).
        points: (M, 2) [m] data points; ``points[0]`` and ``points[-1]`` are the clamped ends.
        knot_spacing: [m] target knot interval (the number of intervals is
            ``max(1, round(L / knot_spacing))``).
    """

    def __init__(self, u: np.ndarray, points: np.ndarray, knot_spacing: float) -> None:
        self.u = np.asarray(u, dtype=float)
        self.points = np.asarray(points, dtype=float)
        L = float(self.u[-1])
        self.length = L
        n_int = max(1, int(round(L / knot_spacing)))
        self.n_intervals = n_int
        n = n_int + DEGREE
        self.n = n
        h = L / max(len(self.u) - 1, 1)
        self.h = h
        first, vals = collocation(L, n_int, self.u)
        # the 10 products vals[:, p] * vals[:, q], q >= p, p-major (rows of _prod), and
        # their banded positions (DEGREE + p - q) * n + first + q, flattened in that order
        self._flat = ((DEGREE + _PQ_P - _PQ_Q) * n + _PQ_Q)[:, None] + first[None, :]
        self._flat = self._flat.ravel()
        self._prod = np.ascontiguousarray((vals[:, _PQ_P] * vals[:, _PQ_Q]).T)  # (10, M)
        self._idx4 = (first[:, None] + _FOUR).ravel()
        self._vals = vals
        self._px4 = np.repeat(self.points[:, 0], 4)  # each point once per basis function
        self._py4 = np.repeat(self.points[:, 1], 4)
        self.btb, self.btp = self._assemble(None)
        self.gram = second_derivative_gram(L, n_int)
        # end constraints: S(0) = (c0 + 4 c1 + c2) / 6, S(L) = (c_{n-3} + 4 c_{n-2} + c_{n-1}) / 6
        H = np.zeros((n, 2))
        H[0:3, 0] = (1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0)
        H[n - 3 : n, 1] += (1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0)
        self.H = H
        self.d = np.stack([self.points[0], self.points[-1]])  # (2 constraints, 2 coords)

    def _assemble(self, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``h B^T W B`` (banded) and ``h B^T W p`` for data weights ``W = diag(weights)``."""
        n = self.n
        wv = np.full(self.u.shape[0], self.h) if weights is None else self.h * weights
        btb = np.bincount(self._flat, weights=(self._prod * wv).ravel(), minlength=(DEGREE + 1) * n)
        wb = (self._vals * wv[:, None]).ravel()
        btp = np.column_stack([np.bincount(self._idx4, wb * self._px4, minlength=n),
                               np.bincount(self._idx4, wb * self._py4, minlength=n)])
        return btb.reshape(DEGREE + 1, n), btp

    def solve(self, lam: float, weights: np.ndarray | None = None) -> SmoothingSpline:
        """Fit with smoothing weight ``lam`` [m^4] (> 0); ``S(0)``, ``S(L)`` equal the end points.

        Args:
            lam: [m^4] smoothing weight.
            weights: (M,) positive data weights (the data term becomes
                ``h sum_j weights_j |S(u_j) - p_j|^2``; a weight ``k`` over a stretch acts there
                like ``lam / k``), or None for all ones.
        """
        btb, btp = (self.btb, self.btp) if weights is None else self._assemble(weights)
        ab = btb + lam * self.gram
        # LAPACK dpbsv directly: what scipy.linalg.solveh_banded(ab, rhs) calls, without its
        # argument checks (about 40 us a call); the same result, bit for bit
        _, sol, info = dpbsv(ab, np.hstack([btp, self.H]), lower=0, overwrite_ab=1, overwrite_b=1)
        if info != 0:
            raise LinAlgError(f"smoothing system: dpbsv info {info} (expected 0: a positive definite matrix)")
        x, z = sol[:, :2], sol[:, 2:]  # A^-1 r, A^-1 H^T
        hz = self.H.T @ z  # (2, 2) H A^-1 H^T
        mu = np.linalg.solve(hz, self.H.T @ x - self.d)  # (2 constraints, 2 coords)
        c = x - z @ mu
        return SmoothingSpline(self.length, self.n_intervals, c, float(lam))


# --------------------------------------------------------------------------------------
# safety: membership along the corridor, blending towards the polyline
# --------------------------------------------------------------------------------------


def corridor_assignment(
    corridor_rects: np.ndarray, points: np.ndarray, hint: np.ndarray, band: int = 2, use_kernel: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Monotone assignment of points (in curve order) to corridor positions.

    ``hint`` (non-decreasing) is the corridor position of the corresponding point of the
    interpolated polyline. A point inside its hint rectangle keeps the hint; any other point
    takes the earliest rectangle containing it among ``hint - band .. hint + band``. The
    assignment is the running maximum of these (so it never goes back along the corridor),
    and a point is ``ok`` only if the rectangle finally assigned contains it.

    Args:
        corridor_rects: (C, 4) [m] rectangles of the corridor, in corridor order.
        points: (K, 2) [m] points along the curve.
        hint: (K,) int non-decreasing expected corridor position of each point.
        band: how many positions either side of the hint are tried for a point outside its
            hint rectangle.
        use_kernel: False forces the NumPy reference (else the compiled loop of
            :mod:`~sanav_mj.planning.assign_kernel` when available; the same results).

    Returns:
        ``(pos, ok)``: (K,) int corridor position assigned and (K,) bool, False where the
        point lies outside the assigned rectangle (outside the corridor, or only in a
        rectangle that would make the assignment go backwards).
    """
    if use_kernel:
        fast = assign_kernel.assign(corridor_rects, points, hint, band, CONTAIN_TOL)
        if fast is not None:
            return fast
    x = points[:, 0]
    y = points[:, 1]
    tol = CONTAIN_TOL
    r = corridor_rects.take(hint, axis=0)
    ok = (x >= r[:, 0] - tol) & (x <= r[:, 2] + tol) & (y >= r[:, 1] - tol) & (y <= r[:, 3] + tol)
    if ok.all():
        return hint, ok
    C = corridor_rects.shape[0]
    first = hint.copy()
    bad = np.flatnonzero(~ok)
    xb = x[bad, None]
    yb = y[bad, None]
    cand = hint[bad, None] + np.arange(-band, band + 1)
    valid = (cand >= 0) & (cand < C)
    rb = corridor_rects.take(np.clip(cand, 0, C - 1), axis=0)
    mem = valid & (xb >= rb[..., 0] - tol) & (xb <= rb[..., 2] + tol) & (yb >= rb[..., 1] - tol) & (yb <= rb[..., 3] + tol)
    found = mem.any(axis=1)
    first[bad] = np.where(found, cand[np.arange(bad.size), np.argmax(mem, axis=1)], hint[bad])
    pos = np.maximum.accumulate(first)
    moved = np.flatnonzero(pos != first)
    ok[bad] = found
    if moved.size:
        rm = corridor_rects.take(pos[moved], axis=0)
        xm, ym = x[moved], y[moved]
        ok[moved] = (xm >= rm[:, 0] - tol) & (xm <= rm[:, 2] + tol) & (ym >= rm[:, 1] - tol) & (ym <= rm[:, 3] + tol)
    return pos, ok


def smoothstep(x: np.ndarray) -> np.ndarray:
    """C2 ramp ``6x^5 - 15x^4 + 10x^3`` on [0, 1] (clipped outside)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


@dataclass(frozen=True)
class Blend:
    """``beta(u)``: 1 on the closed intervals ``[a_k, b_k]``, C2 ramps of width ``ramp`` [m]."""

    intervals: tuple[tuple[float, float], ...] = ()
    ramp: float = 0.5

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(K,) blend weights in [0, 1] at ``u`` (K,) [m]."""
        beta = np.zeros(np.shape(u))
        for a, b in self.intervals:
            if self.ramp > 0:
                w = np.minimum(smoothstep((u - (a - self.ramp)) / self.ramp), smoothstep(((b + self.ramp) - u) / self.ramp))
            else:
                w = ((u >= a) & (u <= b)).astype(float)
            beta = np.maximum(beta, w)
        return beta

    def widened(self, bad_u: np.ndarray, margin: float, length: float) -> Blend:
        """A blend that also covers ``[u - margin, u + margin]`` (clipped to ``[0, length]``)
        around every ``bad_u`` (K,) [m]; overlapping or nearly touching intervals merge."""
        bad_u = np.sort(np.asarray(bad_u, dtype=float).reshape(-1))
        iv = list(self.intervals)
        if bad_u.size:
            gap = np.flatnonzero(np.diff(bad_u) > 2.0 * margin)
            lo = bad_u[np.r_[0, gap + 1]] - margin
            hi = bad_u[np.r_[gap, bad_u.size - 1]] + margin
            iv += [(max(0.0, float(a)), min(length, float(b))) for a, b in zip(lo, hi)]
        iv.sort()
        merged: list[list[float]] = []
        for a, b in iv:
            if merged and a <= merged[-1][1] + 2.0 * self.ramp:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        return Blend(tuple((a, b) for a, b in merged), self.ramp)

    @property
    def covered(self) -> float:
        """[m] total length where beta == 1."""
        return float(sum(b - a for a, b in self.intervals))


@dataclass(frozen=True)
class SafeCurve:
    """The curve handed to time-parametrisation: ``c(u) = (1-beta) S(u) + beta P(u)``.

    Attributes:
        spline: the fitted smoothing spline ``S``.
        blend: ``beta`` (no intervals when the spline is safe everywhere it was checked).
        waypoints: (W, 2) [m] polyline ``P`` vertices.
        s_nodes: (W,) [m] their cumulative arc length.
        seg_area: (W-1,) int corridor position of each polyline segment.
        length: [m] polyline length L (the parameter range of ``u``).
        lambda_steps: how many times ``lam`` was reduced before this fit.
    """

    spline: SmoothingSpline
    blend: Blend
    waypoints: np.ndarray
    s_nodes: np.ndarray
    seg_area: np.ndarray
    length: float
    lambda_steps: int

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(K, 2) [m] points at ``u`` (K,) [m]."""
        u = np.asarray(u, dtype=float)
        s = self.spline(u)
        if not self.blend.intervals:
            return s
        beta = self.blend(u)[:, None]
        p = polyline_at(self.waypoints, self.s_nodes, u)
        return (1.0 - beta) * s + beta * p

    def hint(self, u: np.ndarray) -> np.ndarray:
        """(K,) int corridor position of the polyline at ``u`` (where the curve should be)."""
        return self.seg_area[segment_of(self.s_nodes, u)]

    def with_blend(self, blend: Blend) -> SafeCurve:
        """The same spline and polyline with another blend."""
        return SafeCurve(self.spline, blend, self.waypoints, self.s_nodes, self.seg_area, self.length, self.lambda_steps)

    def widened(self, bad_u: np.ndarray, margin: float) -> SafeCurve:
        """Fall back to the polyline over ``[u - margin, u + margin]`` around each ``bad_u`` [m]."""
        return self.with_blend(self.blend.widened(bad_u, margin, self.length))

    def as_polyline(self) -> SafeCurve:
        """The same curve with ``beta == 1`` everywhere (the interpolated polyline)."""
        return self.with_blend(Blend(((0.0, self.length),), 0.0))


@dataclass(frozen=True)
class SmoothingResult:
    """Output of :func:`safe_curve`.

    Attributes:
        curve: the safe curve.
        u_path: (M,) [m] arc lengths of the interpolated path.
        path: (M, 2) [m] the interpolated path (eq. 5-6) the spline was fitted to.
        u_nodes: (N,) [m] parameters of the dense check.
        nodes: (N, 2) [m] ``curve(u_nodes)``.
        hint: (N,) int corridor position of the polyline at each node.
        safe: True when every node lies in the corridor (always, unless even the polyline
            failed the check, which its construction excludes up to rounding).
    """

    curve: SafeCurve
    u_path: np.ndarray
    path: np.ndarray
    u_nodes: np.ndarray
    nodes: np.ndarray
    hint: np.ndarray
    safe: bool


def safe_curve(
    waypoints: np.ndarray,
    seg_area: np.ndarray,
    corridor_rects: np.ndarray,
    spacing: float,
    knot_spacing: float,
    lam: float,
    check_spacing: float,
    lambda_factor: float,
    max_lambda_steps: int,
    blend_margin: float,
    blend_ramp: float,
    lambda_window: float = 0.5,
    max_blend_rounds: int = 12,
) -> SmoothingResult:
    """Interpolate (eq. 5-6), smooth (eq. 7) and keep the curve inside the corridor.

    Adaptation, in this order, until every dense sample lies in the corridor (monotonically
    along it, see :func:`corridor_assignment`): divide the weight of the data points within
    ``lambda_window`` of every offending sample by ``lambda_factor`` (locally the same as
    multiplying ``lam`` by it; ``lambda_window = inf`` reduces ``lam`` everywhere) and refit,
    at most ``max_lambda_steps`` times; then blend to the interpolated polyline over each
    offending stretch (half-width ``blend_margin``, doubled every round); after
    ``max_blend_rounds`` rounds the whole curve is the polyline (safe by construction).

    Args:
        waypoints: (W, 2) [m] polyline, W >= 2, length > 0; segment k lies in corridor
            rectangle ``seg_area[k]``.
        seg_area: (W-1,) int non-decreasing corridor position of each segment.
        corridor_rects: (C, 4) [m] corridor rectangles in corridor order.
        spacing: [m] interpolation spacing h (eq. 5-6).
        knot_spacing: [m] B-spline knot interval.
        lam: [m^4] initial smoothing weight.
        check_spacing: [m] spacing in ``u`` of the dense safety check.
        lambda_factor: in (0, 1), factor applied to the local ``lam`` at each refit.
        max_lambda_steps: refits allowed before blending.
        blend_margin: [m] initial half-width of the fallback stretch around a violation.
        blend_ramp: [m] ramp length of the blend.
        lambda_window: [m] half-width of the stretch around a violation where ``lam`` is
            reduced (``math.inf``: the whole path).
        max_blend_rounds: widening rounds before falling back to the whole polyline.

    Returns:
        The :class:`SmoothingResult`.
    """
    wp = np.asarray(waypoints, dtype=float)
    s_nodes = cumulative_length(wp)
    L = float(s_nodes[-1])
    u_path, path = interpolate_uniform(wp, spacing, s_nodes)
    problem = SmoothingProblem(u_path, path, knot_spacing)
    n_check = max(3, int(np.ceil(L / check_spacing)) + 1)
    u_chk = np.linspace(0.0, L, n_check)
    seg_area = np.asarray(seg_area, dtype=np.int64)
    hint = seg_area[segment_of(s_nodes, u_chk)]

    steps = 0
    cur_lam = lam
    weights = None
    # every refit has the same knots: the check's collocation is computed once (an
    # unblended curve is its spline, so curve(u_chk) is spline.at_collocation(*chk))
    chk = collocation(problem.length, problem.n_intervals, u_chk)
    while True:
        spl = problem.solve(cur_lam, weights)
        curve = SafeCurve(spl, Blend((), blend_ramp), wp, s_nodes, seg_area, L, steps)
        nodes = spl.at_collocation(*chk)
        _, ok = corridor_assignment(corridor_rects, nodes, hint)
        if ok.all() or steps >= max_lambda_steps:
            break
        steps += 1
        # lam / weight within lambda_window of every violation (math.inf: everywhere)
        bad = u_chk[~ok]
        k = np.searchsorted(bad, u_path)
        near = np.minimum(np.abs(u_path - bad[np.minimum(k, bad.size - 1)]), np.abs(u_path - bad[np.maximum(k - 1, 0)]))
        if weights is None:
            weights = np.ones(u_path.shape[0])
        weights[near <= lambda_window] /= lambda_factor
    safe = bool(ok.all())
    if not safe:
        curve, nodes, safe = blend_until_inside(
            curve, u_chk, hint, corridor_rects, u_chk[~ok], blend_margin, max_blend_rounds
        )
    return SmoothingResult(curve, u_path, path, u_chk, nodes, hint, safe)


def blend_until_inside(
    curve: SafeCurve,
    u_nodes: np.ndarray,
    hint: np.ndarray,
    corridor_rects: np.ndarray,
    bad_u: np.ndarray,
    margin: float,
    max_rounds: int = 12,
) -> tuple[SafeCurve, np.ndarray, bool]:
    """Fall back to the polyline around ``bad_u`` [m] (half-width ``margin`` [m], doubled each
    round) until every node ``curve(u_nodes)`` lies in the corridor; after ``max_rounds``
    rounds the whole curve becomes the polyline.

    Returns:
        ``(curve, nodes, safe)``: the widened curve, (N, 2) [m] its nodes, and whether they
        all lie in the corridor (see :func:`corridor_assignment`).
    """
    rounds = 0
    while True:
        curve = curve.as_polyline() if rounds >= max_rounds else curve.widened(bad_u, margin)
        nodes = curve(u_nodes)
        _, ok = corridor_assignment(corridor_rects, nodes, hint)
        if ok.all() or rounds >= max_rounds:
            return curve, nodes, bool(ok.all())
        bad_u = u_nodes[~ok]
        margin *= 2.0
        rounds += 1
