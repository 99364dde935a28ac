"""Reachable positions of the unicycle model under box input bounds: a cheap proof that an
MPC problem's position rows cannot be met, so the solver need not be asked.

The model (:func:`~sanav_mj.control.unicycle.rollout_np`) moves at step ``k`` by the chord
``ds_k = v_k dt sinc(w_k dt / 2)`` along the heading ``theta_k + w_k dt / 2`` with
``theta_k = theta_0 + dt sum_{i<k} w_i``. Given per-step bounds ``v_k in [vl_k, vh_k]`` and
``w_k in [wl_k, wh_k]`` (the NLP's simple bounds, which already hold the rate limits' reach
from the previous input, the terminal stop and any derating), interval arithmetic bounds
every position ``p_k``: the chord's interval times the interval of the cosine (sine) of its
heading, summed over the steps. This is done twice, on the world axes (the axes of the
stage boxes) and on the axes of the initial heading (along and across: tight for a robot
moving fast towards the end of a short box, the case that matters). Every plan within the
input bounds has its positions inside these intervals, so when a stage box (widened by the
acceptance tolerance) misses one of them on either pair of axes, no plan the acceptance
test would take exists: the problem is infeasible (proved, not guessed). The converse does
not hold (the intervals are loose: they ignore that the same ``v_k`` enters both
coordinates), so a problem that passes may still be infeasible.
"""

from __future__ import annotations

import numpy as np

from sanav_mj.control.unicycle import sinc_half


def _cos_range(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elementwise (min, max) of ``cos`` over the angle intervals ``[lo, hi]`` [rad] (lo <= hi)."""
    two_pi = 2.0 * np.pi
    c_lo, c_hi = np.cos(lo), np.cos(hi)
    mn, mx = np.minimum(c_lo, c_hi), np.maximum(c_lo, c_hi)
    has_max = np.ceil(lo / two_pi) <= np.floor(hi / two_pi)  # an even multiple of pi inside
    has_min = np.ceil((lo - np.pi) / two_pi) <= np.floor((hi - np.pi) / two_pi)
    return np.where(has_min, -1.0, mn), np.where(has_max, 1.0, mx)


def _product(a_lo, a_hi, b_lo, b_hi) -> tuple[np.ndarray, np.ndarray]:
    """Elementwise interval product ``[a_lo, a_hi] * [b_lo, b_hi]``."""
    p, q, r, t = a_lo * b_lo, a_lo * b_hi, a_hi * b_lo, a_hi * b_hi
    return np.minimum(np.minimum(p, q), np.minimum(r, t)), np.maximum(np.maximum(p, q), np.maximum(r, t))


def position_intervals(x0: np.ndarray, z_lb: np.ndarray, z_ub: np.ndarray, dt: float,
                       frame) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the positions ``p_1..p_N`` reachable from ``x0`` under the input bounds.

    Args:
        x0: (3,) [m, m, rad] initial state.
        z_lb, z_ub: (2N,) [m/s, rad/s] lower and upper input bounds ``(v_0, w_0, v_1, ...)``.
        dt: [s] step length.
        frame: [rad] angle of the axes the positions are expressed on (0: world axes; the
            initial yaw: along and across the heading), origin at ``x0``'s position; a float
            or an (F,) array of angles.

    Returns:
        lo, hi: (N, 2) [m] (or (F, N, 2) for an array ``frame``): each position
        ``p_k - p_0`` rotated by ``-frame`` lies in ``[lo[k-1], hi[k-1]]`` (componentwise)
        for every input sequence within the bounds.
    """
    lb = np.asarray(z_lb, dtype=float).reshape(-1, 2)
    ub = np.asarray(z_ub, dtype=float).reshape(-1, 2)
    wl, wh = lb[:, 1] * dt, ub[:, 1] * dt
    # heading of each chord relative to the frame: theta_k + w_k dt / 2
    cl, ch = np.cumsum(wl), np.cumsum(wh)
    rel_lo, rel_hi = cl - 0.5 * wl, ch - 0.5 * wh
    frames = np.asarray(frame, dtype=float)
    base = (float(x0[2]) - frames.reshape(-1, 1))
    # chord length factor sinc(w dt / 2) in [sinc(max |w| dt / 2), 1] (decreasing in |w|)
    w_abs = np.maximum(np.abs(lb[:, 1]), np.abs(ub[:, 1]))
    w_small = np.where((lb[:, 1] <= 0.0) & (ub[:, 1] >= 0.0), 0.0,
                       np.minimum(np.abs(lb[:, 1]), np.abs(ub[:, 1])))
    s_lo, s_hi = sinc_half(w_abs, dt), sinc_half(w_small, dt)
    ds_lo, ds_hi = _product(lb[:, 0] * dt, ub[:, 0] * dt, s_lo, s_hi)
    # cos on the first axis, sin(a) = cos(a - pi/2) on the second: (F, 2, N)
    shift = np.array([0.0, 0.5 * np.pi]).reshape(1, 2, 1)
    m_lo = (base + rel_lo)[:, None, :] - shift
    m_hi = (base + rel_hi)[:, None, :] - shift
    c_lo, c_hi = _cos_range(m_lo, m_hi)
    p_lo, p_hi = _product(ds_lo, ds_hi, c_lo, c_hi)
    lo = np.cumsum(p_lo, axis=2).transpose(0, 2, 1)
    hi = np.cumsum(p_hi, axis=2).transpose(0, 2, 1)
    if frames.ndim == 0:
        return lo[0], hi[0]
    return lo, hi


def unreachable_stage(x0: np.ndarray, z_lb: np.ndarray, z_ub: np.ndarray, box_lb: np.ndarray,
                      box_ub: np.ndarray, dt: float, tol: float) -> int | None:
    """First stage whose position box no input sequence within the bounds can reach, or None.

    Args:
        x0: (3,) [m, m, rad] initial state.
        z_lb, z_ub: (2N,) [m/s, rad/s] input bounds, as the NLP's (widened by ``tol`` here).
        box_lb, box_ub: (2N,) [m] bounds of the positions ``p_1..p_N`` (the position rows,
            ``(x_1, y_1, x_2, ...)``), widened by ``tol`` here.
        dt: [s] step length.
        tol: [m, m/s] the tolerance the acceptance test allows on every constraint.

    Returns:
        k in 1..N: ``p_k`` cannot lie in its box for any inputs within ``tol`` of their
        bounds (the problem is infeasible); None: no such stage found.

    Raises:
        ValueError: the arrays are not 2N long with the same N.
    """
    z_lb, z_ub = np.asarray(z_lb, dtype=float) - tol, np.asarray(z_ub, dtype=float) + tol
    b_lo = np.asarray(box_lb, dtype=float).reshape(-1, 2) - tol
    b_hi = np.asarray(box_ub, dtype=float).reshape(-1, 2) + tol
    n = len(b_lo)
    if z_lb.shape != (2 * n,) or z_ub.shape != (2 * n,) or b_hi.shape != (n, 2):
        raise ValueError(f"expected input and box bounds of length 2N, got z {z_lb.shape}/{z_ub.shape}, "
                         f"boxes {np.shape(box_lb)}/{np.shape(box_ub)}")
    x0 = np.asarray(x0, dtype=float).reshape(3)
    # rounding of the sums: a few ulps of the largest coordinate per step
    eps = 1e-9 * (1.0 + float(np.max(np.abs(np.concatenate((b_lo.ravel(), b_hi.ravel(), x0[:2]))))))
    p0 = x0[:2]
    th = float(x0[2])
    (lo, lo_h), (hi, hi_h) = position_intervals(x0, z_lb, z_ub, dt, np.array([0.0, th]))
    bad = np.any((lo + p0 > b_hi + eps) | (hi + p0 < b_lo - eps), axis=1)
    # the same on the heading's axes: project the boxes' corners
    c, s = np.cos(th), np.sin(th)
    dx_lo, dx_hi = b_lo[:, 0] - p0[0], b_hi[:, 0] - p0[0]
    dy_lo, dy_hi = b_lo[:, 1] - p0[1], b_hi[:, 1] - p0[1]
    # a linear function's range over a box: its ends at the corners picked by the signs
    ax, ay = (c * dx_lo, c * dx_hi), (s * dy_lo, s * dy_hi)
    bx, by = (-s * dx_lo, -s * dx_hi), (c * dy_lo, c * dy_hi)
    proj_lo = np.stack((np.minimum(*ax) + np.minimum(*ay), np.minimum(*bx) + np.minimum(*by)), axis=1)
    proj_hi = np.stack((np.maximum(*ax) + np.maximum(*ay), np.maximum(*bx) + np.maximum(*by)), axis=1)
    bad |= np.any((lo_h > proj_hi + eps) | (hi_h < proj_lo - eps), axis=1)
    k = np.flatnonzero(bad)
    return int(k[0]) + 1 if k.size else None
