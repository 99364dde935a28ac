"""Scan-to-map matching: the robot pose from a lidar scan and the map built so far.

A scan placed at a wrong pose draws the world wrong: at a yaw off by 2 deg a wall 4 m away
lands 14 cm (3 cells) off, its free rays cut through obstacles and its returns mark free
space occupied. A real robot therefore corrects the pose its odometry predicts by matching
each scan against its map before adding it. This module does that around a prior pose (the
odometry prediction), in :meth:`ScanMatcher.match`:

1. **Gauss-Newton** (point-to-line, below) from the prior; when that match fails (``poor``
   or ``few_points``: the prior was outside its basin),
2. **correlative search**: every yaw in ``prior +- yaw_window`` (step ``yaw_step``) and
   every whole-cell shift in ``+- xy_window`` cells is scored by the sum of the likelihood
   field (below) at the scan's return points, nearest cell; the best candidate (ties: the
   one closest to the prior) starts Gauss-Newton again. Cost ~ candidates x points
   lookups, vectorised.

**Gauss-Newton** (ICP, point-to-line): each return ``s_i`` (base frame) with its surface
normal ``n_i`` from the scan itself (:func:`scan_points`) is paired with the nearest map
point ``q_i`` within ``max_pair_m`` (the map keeps one point per hit cell, below), and
``sum_i (n_i^T (T(xi) s_i - q_i))^2 / point_sigma^2 + (xi - xi_prior)^T Lambda (xi - xi_prior)``
is minimised over ``xi = (x, y, yaw)`` (pairs re-found each iteration), ``Lambda`` the
prior's information (``1 / prior_xy^2``, ``1 / prior_yaw^2``): in a direction the scan does
not constrain (a featureless corridor along its axis) the result stays at the prior. An
optional absolute measurement (``anchor``) adds a second such prior.

**Map points and likelihood field** (:class:`LikelihoodField`): one point per cell that
ever held a return, the mean of the returns that landed there (sub-cell: a wall is where
its returns are, not at cell centres up to half a cell off; a point of a cell's first
returns only would bias the yaw); for the correlative search ``M(p) = 1 - exp(-S(p))`` at
the cell centres, ``S(p) = sum_q exp(-|p - q|^2 / (2 sigma^2))`` over the points ``q``
within ``radius_cells``. It only grows (the worlds are static): a scan adds its new hit cells in
``O(new cells x kernel)``.

**Quality** (:class:`MatchResult`): ``inliers`` (points with a map point within
``max_pair_m`` at the result), the data information ``H = J^T J`` (3 x 3, yaw scaled by ``yaw_scale_m`` so that all
three axes are in metres) and its smallest / largest eigenvalue ratio. A match is ``ok``
when it has at least ``min_inliers`` inliers, their RMS point-to-line residual is at most
``max_rms`` and ``H`` constrains every direction (``eig_min >= min_eig`` and
``eig_min / eig_max >= min_eig_ratio``); else ``few_points``, ``poor`` or ``ambiguous``
(too weak in some direction); an empty field gives ``empty``. What to do
with a scan whose match is not ok is the caller's decision
(:class:`sanav_mj.control.sensing.SensingSAMPC` uses an ambiguous match and adds no scan
whose match is ``poor`` or ``few_points`` to the map).

:meth:`ScanMatcher.cost` (truncated point-to-line cost) lets the caller test another pose
against the match (``check``: e.g. whether the measured pose explains the scan as well).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import sanav_mj.mapping.match_kernel as match_kernel

__all__ = ["LikelihoodField", "MatchResult", "ScanMatchConfig", "ScanMatcher", "scan_points"]


@dataclass(frozen=True)
class ScanMatchConfig:
    """Settings of the scan matcher.

    Attributes:
        sigma: [m] width of the likelihood field's Gaussian around each hit cell, > 0.
        radius_cells: [cells] the field is zero beyond this many cells from every hit cell, >= 1.
        yaw_window: [rad] half width of the correlative yaw search around the prior, >= 0.
        yaw_step: [rad] yaw step of the correlative search, > 0.
        xy_window: [cells] half width of the correlative shift search, integer >= 0.
        max_points: largest number of return points used (evenly subsampled), >= 10.
        iterations: Gauss-Newton iterations at most, >= 1.
        prior_xy: [m] standard deviation of the prior's position (odometry prediction), > 0.
        prior_yaw: [rad] standard deviation of the prior's yaw, > 0.
        point_sigma: [m] standard deviation of a return's distance to the mapped surface
            (range noise and the map's one point per cell), > 0.
        max_pair_m: [m] a return pairs with a map point at most this far away (an inlier), > 0.
        max_rms: [m] largest root-mean-square point-to-line residual of the inliers for an
            ``ok`` match (a scan placed a few degrees off pairs with wrong surfaces), > 0.
        min_inliers: fewest inliers for an ``ok`` match, >= 3.
        yaw_scale_m: [m] length that converts yaw information to metres (a point this far
            from the base moves ``yaw_scale_m * dyaw``), > 0.
        min_eig: [points] smallest eigenvalue of ``J^T J`` (each inlier adds the square of
            its normal's component along a direction: 8 = eight returns facing that
            direction squarely) for ``ok``, >= 0.
        min_eig_ratio: smallest eigenvalue ratio (min / max) for ``ok``, in [0, 1).
    """

    sigma: float = 0.05
    radius_cells: int = 2
    yaw_window: float = 0.06
    yaw_step: float = 0.01
    xy_window: int = 1
    max_points: int = 120
    iterations: int = 6
    prior_xy: float = 0.01
    prior_yaw: float = 0.02
    point_sigma: float = 0.015
    max_rms: float = 0.03
    max_pair_m: float = 0.1
    min_inliers: int = 20
    yaw_scale_m: float = 1.0
    min_eig: float = 8.0
    min_eig_ratio: float = 0.0

    def __post_init__(self) -> None:
        pos = ("sigma", "yaw_step", "prior_xy", "prior_yaw", "yaw_scale_m", "point_sigma", "max_pair_m", "max_rms")
        for name in pos:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"ScanMatchConfig.{name}: expected a finite number > 0, got {v!r}")
        for name in ("yaw_window", "min_eig"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"ScanMatchConfig.{name}: expected a finite number >= 0, got {v!r}")
        for name, lo in (("radius_cells", 1), ("xy_window", 0), ("max_points", 10), ("iterations", 1),
                         ("min_inliers", 3)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"ScanMatchConfig.{name}: expected an integer >= {lo}, got {v!r}")
        if not 0 <= self.min_eig_ratio < 1:
            raise ValueError(f"ScanMatchConfig.min_eig_ratio: expected a number in [0, 1), got {self.min_eig_ratio!r}")


@dataclass(frozen=True)
class MatchResult:
    """The outcome of one match.

    Attributes:
        pose: (3,) [m, m, rad] matched robot pose (the prior when ``status == "empty"``).
        ok: the match is trusted (``status == "ok"``).
        status: ``"ok"``, ``"ambiguous"`` (some direction too weakly constrained),
            ``"few_points"`` (fewer than ``min_inliers`` inliers), ``"poor"`` (residuals above
            ``max_rms``) or ``"empty"`` (no field yet, or no return point).
        inliers: return points on mapped structure at ``pose``.
        points: return points used.
        eig: (3,) ascending eigenvalues [1/m^2] of the scaled data information ``J^T J``.
        correction: (3,) [m, m, rad] ``pose - prior`` (yaw wrapped).
        rms: [m] root-mean-square point-to-line residual of the inliers (inf without any).
        check_delta: :meth:`ScanMatcher.cost` of the ``check`` pose minus that of ``pose``
            (inf without one): about chi-square with 3 degrees of freedom when the check pose
            is the true one.
    """

    pose: np.ndarray
    ok: bool
    status: str
    inliers: int
    points: int
    eig: np.ndarray
    correction: np.ndarray
    rms: float = math.inf
    check_delta: float = math.inf


def scan_points(ranges, hit, angles, sensor_offset=(0.0, 0.0), max_points: int | None = None,
                stencil: int = 3, max_gap: float = 0.3, use_kernel: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The return points of a scan in the robot base frame, with the scan's own surface normals.

    A return's normal is perpendicular to the chord between the returns ``stencil`` beams
    before and after it; a return without both neighbours, or whose chord is longer than
    ``max_gap + 3 r dphi`` (``r`` its range, ``dphi`` the angle between the two neighbours'
    beams: three times the chord of a surface facing the sensor; longer means an edge or two
    surfaces), has none and is left out.

    Args:
        ranges: (B,) [m]; hit: (B,) bool (True where the beam returned); angles: (B,) [rad]
            relative to the robot heading, in scan order; sensor_offset: (2,) [m] sensor in
            the base frame.
        max_points: keep at most this many, evenly spread over the returns (None: all).
        stencil: [beams] half width of the normal's chord, >= 1.
        max_gap: [m] chord allowance beyond ``3 r dphi``, > 0.
        use_kernel: False forces the NumPy reference (else the compiled loop of
            :func:`~sanav_mj.mapping.match_kernel.scan_surface` when available and the
            arrays have the same length; the same results, bit for bit).

    Returns:
        points: (P, 2) [m] x forward, y left; normals: (P, 2) unit vectors.
    """
    r = np.asarray(ranges, dtype=float)
    a = np.asarray(angles, dtype=float)
    off = np.asarray(sensor_offset, dtype=float).reshape(2)
    k = int(stencil)
    hit = np.asarray(hit, dtype=bool)
    fast = None
    if use_kernel and r.ndim == a.ndim == hit.ndim == 1 and len(r) == len(a) == len(hit):
        fast = match_kernel.scan_surface(r, a, hit, off, k, float(max_gap))
    if fast is not None:
        px, py, idx, tx, ty, length = fast
    else:
        good = hit & np.isfinite(r) & np.isfinite(a)
        px = off[0] + np.where(good, r, 0.0) * np.cos(a)
        py = off[1] + np.where(good, r, 0.0) * np.sin(a)
        n = len(r)
        idx = np.arange(k, n - k)
        tx = px[idx + k] - px[idx - k]
        ty = py[idx + k] - py[idx - k]
        length = np.hypot(tx, ty)
        limit = max_gap + 3.0 * np.where(good[idx], r[idx], 0.0) * np.abs(a[idx + k] - a[idx - k])
        ok = good[idx] & good[idx + k] & good[idx - k] & (length <= limit) & (length > 0)
        idx, tx, ty, length = idx[ok], tx[ok], ty[ok], length[ok]
    if max_points is not None and len(idx) > max_points:
        pick = np.linspace(0, len(idx) - 1, max_points).round().astype(np.int64)
        idx, tx, ty, length = idx[pick], tx[pick], ty[pick], length[pick]
    pts = np.stack([px[idx], py[idx]], axis=1)
    normals = np.stack([-ty / length, tx / length], axis=1)
    return pts, normals


class LikelihoodField:
    """The likelihood field of the map's hit points (see the module docstring).

    One point per hit cell (the mean of the returns that landed in it, sub-cell; the
    correlative lookup ``values`` keeps the cell's first mean). The field at a
    point ``p`` is ``M(p) = 1 - exp(-S(p))`` with ``S(p) = sum_q exp(-|p - q|^2 / (2 sigma^2))``
    over the hit points ``q`` of the cells within ``radius_cells`` of ``p``'s cell: a smooth
    ridge along a wall that peaks where its returns are, evaluated exactly (a field sampled
    at the cell centres and interpolated bilinearly is flat across a wall for up to a cell,
    no information there), with its exact gradient.

    Args:
        shape: (ny, nx) grid shape; origin: (2,) [m] lower-left corner; resolution: [m].
        sigma: [m] Gaussian width; radius_cells: reach of a hit point [cells].

    Attributes:
        count: hit cells added so far.
        values: (ny + 2 pad, nx + 2 pad) float64 ``M`` at the cell centres (padded), the
            correlative search's lookup.
    """

    def __init__(self, shape, origin, resolution: float, sigma: float, radius_cells: int) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        self.origin = np.asarray(origin, dtype=float).reshape(2).copy()
        self.resolution = float(resolution)
        self.sigma = float(sigma)
        self.pad = int(radius_cells) + 2
        ny, nx = self.shape
        self._pw = nx + 2 * self.pad
        self._S = np.zeros((ny + 2 * self.pad) * self._pw, dtype=np.float64)  # S at cell centres
        self.values = np.zeros((ny + 2 * self.pad, self._pw), dtype=np.float64)
        self._px = np.full(self._S.size, np.inf)  # the hit point of each hit cell (inf: none)
        self._py = np.full(self._S.size, np.inf)
        self._sx = np.zeros(self._S.size)  # sums and count of the returns in each cell
        self._sy = np.zeros(self._S.size)
        self._n = np.zeros(self._S.size, dtype=np.int64)
        self._hit = np.zeros(self._S.size, dtype=bool)
        self._mark = np.zeros(self._S.size, dtype=np.uint8)  # scratch of the compiled spreading (zeroed)
        r = int(radius_cells)
        di, dj = np.mgrid[-r:r + 1, -r:r + 1]
        keep = di * di + dj * dj <= r * r
        self._kij = (di[keep].astype(np.int64), dj[keep].astype(np.int64))
        self._koff = self._kij[0] * self._pw + self._kij[1]
        self._inv2s2 = 1.0 / (2.0 * sigma * sigma)
        self.count = 0

    def add_points(self, pts, use_kernel: bool = True) -> int:
        """Add return points: each cell's hit point is the mean of the returns that landed in it.

        Args:
            pts: (P, 2) [m] world positions of returns (points outside the grid are ignored).
            use_kernel: False forces the NumPy reference for the sums, counts and new cells
                (else the compiled loop of :func:`~sanav_mj.mapping.match_kernel.accumulate`
                when available; the same results, bit for bit).

        Returns:
            The number of new hit cells.
        """
        p = np.asarray(pts, dtype=float).reshape(-1, 2)
        new = match_kernel.accumulate(self, p) if use_kernel else None
        if new is None:
            new = self._accumulate(p)
        if not new.size:
            return 0
        if not (use_kernel and match_kernel.spread(self, new)):
            self._spread_values(new)
        self.count += int(new.size)
        return int(new.size)

    def _accumulate(self, p: np.ndarray) -> np.ndarray:
        """NumPy reference of :func:`~sanav_mj.mapping.match_kernel.accumulate`: sums, counts
        and hit points of the cells the (P, 2) [m] points ``p`` land in; returns the padded
        flat indices of the cells hit for the first time (sorted), now marked hit."""
        ny, nx = self.shape
        h = self.resolution
        j = np.floor((p[:, 0] - self.origin[0]) / h).astype(np.int64)
        i = np.floor((p[:, 1] - self.origin[1]) / h).astype(np.int64)
        inside = (i >= 0) & (i < ny) & (j >= 0) & (j < nx)
        flat = (i[inside] + self.pad) * self._pw + (j[inside] + self.pad)
        p = p[inside]
        if not flat.size:
            return np.zeros(0, np.int64)
        np.add.at(self._sx, flat, p[:, 0])
        np.add.at(self._sy, flat, p[:, 1])
        np.add.at(self._n, flat, 1)
        cells = np.unique(flat)
        self._px[cells] = self._sx[cells] / self._n[cells]
        self._py[cells] = self._sy[cells] / self._n[cells]
        new = cells[~self._hit[cells]]
        self._hit[new] = True
        return new

    def _spread_values(self, new: np.ndarray) -> None:
        """Spread the hit points of the ``new`` (K,) hit cells (padded flat indices, sorted)
        over the cells within reach (the field ``S`` and ``values``); NumPy reference of
        :func:`~sanav_mj.mapping.match_kernel.spread`."""
        h = self.resolution
        i, j = np.divmod(new, self._pw)
        ki, kj = self._kij
        ci = (i[:, None] + ki[None, :]).ravel()  # padded rows / columns of the cells around
        cj = (j[:, None] + kj[None, :]).ravel()
        src = new[np.repeat(np.arange(len(new)), len(ki))]
        cx = self.origin[0] + (cj - self.pad + 0.5) * h
        cy = self.origin[1] + (ci - self.pad + 0.5) * h
        d2 = (cx - self._px[src]) ** 2 + (cy - self._py[src]) ** 2
        idx = ci * self._pw + cj
        np.add.at(self._S, idx, np.exp(-d2 * self._inv2s2))
        u = np.unique(idx)
        self.values.reshape(-1)[u] = 1.0 - np.exp(-self._S[u])

    def _cell(self, pts: np.ndarray) -> np.ndarray:
        """Padded flat cell index of (..., 2) [m] points (clamped to stay ``radius`` inside the
        padded grid)."""
        h = self.resolution
        ny, nx = self.values.shape
        r = self.pad - 2
        j = np.floor((pts[..., 0] - self.origin[0]) / h).astype(np.int64) + self.pad
        i = np.floor((pts[..., 1] - self.origin[1]) / h).astype(np.int64) + self.pad
        np.maximum(j, r, out=j)
        np.minimum(j, nx - 1 - r, out=j)
        np.maximum(i, r, out=i)
        np.minimum(i, ny - 1 - r, out=i)
        return i * nx + j

    def nearest(self, pts: np.ndarray) -> np.ndarray:
        """``M`` at the centre of the cell holding each point, (...,) for (..., 2) [m] points."""
        return self.values.reshape(-1)[self._cell(pts)]

    def correspond(self, pts: np.ndarray, use_kernel: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The hit point nearest to each query point among the hit cells within ``radius_cells``
        of its cell (ties: the first cell of the kernel offsets).

        Args:
            pts: (P, 2) [m] query points.
            use_kernel: False forces the NumPy reference (else the compiled loop of
                :mod:`~sanav_mj.mapping.match_kernel` when available; the same results).

        Returns:
            q: (P, 2) [m] nearest hit points (the query point itself where none is in reach);
            d2: (P,) [m^2] squared distances (inf where none is in reach).
        """
        if use_kernel:
            fast = match_kernel.correspond(self, pts)
            if fast is not None:
                return fast
        k = self._cell(pts)[:, None] + self._koff[None, :]  # (P, K)
        dx = pts[:, 0, None] - self._px[k]
        dy = pts[:, 1, None] - self._py[k]
        d2 = dx * dx + dy * dy  # cells without a hit point hold inf coordinates: d2 = inf
        a = np.argmin(d2, axis=1)
        rows = np.arange(len(pts))
        best = d2[rows, a]
        ka = k[rows, a]
        found = np.isfinite(best)
        q = np.stack([np.where(found, self._px[ka], pts[:, 0]), np.where(found, self._py[ka], pts[:, 1])], axis=1)
        return q, best


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class ScanMatcher:
    """Matches scans against a :class:`LikelihoodField` (see the module docstring).

    Args:
        field: the map's likelihood field (updated by the caller as the map grows).
        config: search window, prior and acceptance settings.
    """

    def __init__(self, field: LikelihoodField, config: ScanMatchConfig = ScanMatchConfig(),
                 use_kernel: bool = True) -> None:
        self.field = field
        self.config = config
        self.use_kernel = use_kernel  # False: the NumPy reference of every iteration (tests)
        nyaw = int(math.floor(config.yaw_window / config.yaw_step + 1e-9))
        self._dyaw = np.arange(-nyaw, nyaw + 1) * config.yaw_step
        w = config.xy_window
        si, sj = np.mgrid[-w:w + 1, -w:w + 1]
        self._shift = np.stack([sj.ravel(), si.ravel()], axis=1) * field.resolution  # (S, 2) [m] x, y

    def cost(self, pose, points, normals) -> float:
        """Truncated point-to-line cost of a scan at ``pose`` (3,) [m, m, rad]:
        ``sum_i min(r_i^2, max_pair_m^2) / point_sigma^2`` with ``r_i`` the distance along the
        return's normal to its nearest map point (``max_pair_m`` for a return without a map
        point within ``max_pair_m``: returns in unmapped space cost the same at any pose).

        Args:
            pose: (3,) robot pose; points, normals: (P, 2) as :meth:`match`.

        Returns:
            The cost [dimensionless, a chi-square-like sum].
        """
        return self.costs((pose,), points, normals)[0]

    def costs(self, poses, points, normals) -> list[float]:
        """:meth:`cost` of one scan at each of several poses (K, 3), with one correspondence
        search for all of them; each value equal to :meth:`cost` at that pose, bit for bit
        (the same arithmetic per pose, each pose's sum over its own points)."""
        c = self.config
        s = np.asarray(points, dtype=float).reshape(-1, 2)
        n = np.asarray(normals, dtype=float).reshape(-1, 2)
        if not len(poses):
            return []
        cs = [(math.cos(pose[2]), math.sin(pose[2])) for pose in poses]
        pw = np.concatenate([np.stack([cth * s[:, 0] - sth * s[:, 1] + pose[0], sth * s[:, 0] + cth * s[:, 1] + pose[1]],
                                      axis=1) for pose, (cth, sth) in zip(poses, cs)])
        q, d2 = self.field.correspond(pw, self.use_kernel)
        out = []
        m = len(s)
        for k, (cth, sth) in enumerate(cs):
            pk, qk, dk = pw[k * m:(k + 1) * m], q[k * m:(k + 1) * m], d2[k * m:(k + 1) * m]
            r = (cth * n[:, 0] - sth * n[:, 1]) * (pk[:, 0] - qk[:, 0]) + (sth * n[:, 0] + cth * n[:, 1]) * (pk[:, 1] - qk[:, 1])
            r2 = np.where(dk <= c.max_pair_m ** 2, np.minimum(r * r, c.max_pair_m ** 2), c.max_pair_m ** 2)
            out.append(float(r2.sum() / c.point_sigma ** 2))
        return out

    def match(self, prior, points, normals, anchor=None, anchor_sigma=(math.inf, math.inf), check=None
              ) -> MatchResult:
        """Match return points (base frame) to the map around a prior pose.

        Args:
            prior: (3,) [m, m, rad] predicted robot pose.
            points: (P, 2) [m] return points in the robot base frame; normals: (P, 2) their
                unit surface normals (both from :func:`scan_points`).
            anchor: optional (3,) [m, m, rad] an independent absolute pose measurement (e.g.
                the measured pose), added to the cost as a second prior with standard
                deviations ``anchor_sigma`` ([m], [rad]).
            check: optional (3,) [m, m, rad] a pose to test against the match:
                ``MatchResult.check_delta`` is its :meth:`cost` minus the matched pose's.

        Returns:
            The :class:`MatchResult`.
        """
        prior = np.asarray(prior, dtype=float).reshape(3)
        s = np.asarray(points, dtype=float).reshape(-1, 2)
        normals = np.asarray(normals, dtype=float).reshape(-1, 2)
        if normals.shape != s.shape:
            raise ValueError(f"normals must have the shape of points {s.shape}, got {normals.shape}")
        zero3 = np.zeros(3)
        if self.field.count == 0 or len(s) == 0:
            return MatchResult(prior.copy(), False, "empty", 0, len(s), zero3, zero3)
        # Gauss-Newton from the prior first (the odometry prediction is usually within its
        # basin); the correlative search only when that fails
        xi, status, inliers, eig, corr, rms = self._refine(prior, prior, s, normals, anchor, anchor_sigma)
        if status in ("poor", "few_points") and len(self._dyaw) * len(self._shift) > 1:
            xi, status, inliers, eig, corr, rms = self._refine(self._search(prior, s), prior, s, normals, anchor,
                                                               anchor_sigma)
        delta = math.inf
        if check is not None:
            chk = np.asarray(check, dtype=float).reshape(3)
            if math.isfinite(chk[0]) and math.isfinite(chk[1]) and math.isfinite(chk[2]):
                c_chk, c_xi = self.costs((chk, xi), s, normals)
                delta = c_chk - c_xi
        return MatchResult(xi, status == "ok", status, inliers, len(s), eig, corr, rms, delta)

    def _search(self, prior: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Correlative search: (Y yaws) x (S shifts) candidates around ``prior``, scored by
        nearest-cell field sums; the best (ties: closest to the prior)."""
        c = self.config
        yaws = prior[2] + self._dyaw
        cy, sy = np.cos(yaws), np.sin(yaws)
        px = cy[:, None] * s[None, :, 0] - sy[:, None] * s[None, :, 1] + prior[0]  # (Y, P)
        py = sy[:, None] * s[None, :, 0] + cy[:, None] * s[None, :, 1] + prior[1]
        cand = np.stack([px[:, None, :] + self._shift[None, :, 0, None],
                         py[:, None, :] + self._shift[None, :, 1, None]], axis=-1)  # (Y, S, P, 2)
        score = self.field.nearest(cand).sum(axis=2)  # (Y, S)
        dist = (self._dyaw[:, None] * c.yaw_scale_m) ** 2 + (self._shift ** 2).sum(axis=1)[None, :]
        best = np.flatnonzero(score == score.max())
        k = best[np.argmin(dist.ravel()[best])]
        ky, ks = divmod(int(k), len(self._shift))
        xi = np.array([prior[0] + self._shift[ks, 0], prior[1] + self._shift[ks, 1], yaws[ky]])
        return xi

    def _pair_rows(self, xi: np.ndarray, cth: float, sth: float, s: np.ndarray, normals: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One Gauss-Newton iteration's rows (NumPy reference of
        :func:`~sanav_mj.mapping.match_kernel.pair_rows`): J (m, 3), res (m,) [m] of the m
        inliers, inl (P,) bool."""
        rx = cth * s[:, 0] - sth * s[:, 1]
        ry = sth * s[:, 0] + cth * s[:, 1]
        pw = np.stack([rx + xi[0], ry + xi[1]], axis=1)
        q, d2 = self.field.correspond(pw, use_kernel=False)
        inl = d2 <= self.config.max_pair_m ** 2
        nxw = cth * normals[:, 0] - sth * normals[:, 1]
        nyw = sth * normals[:, 0] + cth * normals[:, 1]
        res = (nxw * (pw[:, 0] - q[:, 0]) + nyw * (pw[:, 1] - q[:, 1]))[inl]
        # d res / d xi = (n_x, n_y, n . dp/dyaw) with dp/dyaw = (-ry, rx) (the normal turns
        # with the scan too; its term n' . (p - q) is second order at the solution: dropped)
        J = np.stack([nxw, nyw, -nxw * ry + nyw * rx], axis=1)[inl]
        return J, res, inl

    def _refine(self, start: np.ndarray, prior: np.ndarray, s: np.ndarray, normals: np.ndarray, anchor,
                anchor_sigma) -> tuple[np.ndarray, str, int, np.ndarray, np.ndarray, float]:
        """Point-to-line Gauss-Newton from ``start``, regularised towards ``prior`` (and the
        anchor); returns pose, status, inliers, eigenvalues, correction, rms."""
        c = self.config
        xi = start.copy()
        lam = np.array([1.0 / c.prior_xy ** 2, 1.0 / c.prior_xy ** 2, 1.0 / c.prior_yaw ** 2])
        if anchor is not None:
            anchor = np.asarray(anchor, dtype=float).reshape(3)
            lam_a = np.array([anchor_sigma[0] ** -2, anchor_sigma[0] ** -2, anchor_sigma[1] ** -2])
        inv_r2 = 1.0 / c.point_sigma ** 2
        lam_diag = np.diag(lam)  # the same matrices every iteration: built once
        lam_a_diag = np.diag(lam_a) if anchor is not None else None
        H_data = np.zeros((3, 3))
        inl = np.zeros(len(s), dtype=bool)
        fast = self.use_kernel and match_kernel.kernel_available()
        if fast:
            s = np.ascontiguousarray(s, dtype=np.float64)
            normals = np.ascontiguousarray(normals, dtype=np.float64)
        for _ in range(c.iterations):
            cth, sth = math.cos(xi[2]), math.sin(xi[2])
            if fast:  # the same arithmetic as below, in one compiled call
                J, res, inl = match_kernel.pair_rows(self.field, s, normals, float(xi[0]), float(xi[1]), cth, sth,
                                                     c.max_pair_m ** 2)
            else:
                J, res, inl = self._pair_rows(xi, cth, sth, s, normals)
            H_data = inv_r2 * (J.T @ J)
            e = xi - prior
            e[2] = _wrap(e[2])
            g = inv_r2 * (J.T @ res) + lam * e
            H = H_data + lam_diag
            if anchor is not None:
                ea = xi - anchor
                ea[2] = _wrap(ea[2])
                g += lam_a * ea
                H += lam_a_diag
            step = -np.linalg.solve(H, g)
            xi = xi + step
            if abs(step[0]) + abs(step[1]) < 1e-3 and abs(step[2]) < 5e-4:
                break
        inliers = int(np.count_nonzero(inl))
        rms = float(np.sqrt(np.mean(res * res))) if inliers else math.inf
        scale = np.array([1.0, 1.0, 1.0 / c.yaw_scale_m])
        eig = np.linalg.eigvalsh(H_data * scale[:, None] * scale[None, :] / inv_r2)  # [points]
        xi[2] = _wrap(xi[2])
        corr = xi - prior
        corr[2] = _wrap(corr[2])
        if inliers < c.min_inliers:
            status = "few_points"
        elif rms > c.max_rms:
            status = "poor"
        elif eig[0] < c.min_eig or eig[0] < c.min_eig_ratio * eig[2]:
            status = "ambiguous"
        else:
            status = "ok"
        return xi, status, inliers, eig, corr, rms
