"""The footprint as discs in the MPC: disc centres of a predicted state and their box rows.

The robot's footprint rectangle is covered by ``n`` discs of radius ``r`` with centres on its
long axis (:meth:`sanav_mj.footprint.Footprint.discs`). If every disc centre lies in a safe
rectangle of a map whose obstacles are inflated by ``r`` (plus a margin), the whole footprint
is clear of the obstacles. The centres are collinear, so for one (convex) rectangle it is
enough that the two *extreme* centres lie in it (:func:`extreme_offsets`): every centre in
between is a convex combination of them.

For a state ``x = (px, py, theta)`` the centre of the disc at body offset ``o = (ox, oy)`` is
``c = (px + ox cos(theta) - oy sin(theta), py + ox sin(theta) + oy cos(theta))``. Those
expressions replace the predicted position in the MPC's position rows (``g``) and in J_SA:
with the rows of both extreme centres bounded by the stage's rectangle the footprint of every
predicted state is inside the inflated-by-``r`` free space. Between two samples a centre at
distance ``d`` from the reference point leaves the chord of its two samples by at most
``v |w| dt^2 / 8 + d (|w| dt)^2 / 8`` (the unicycle's arc plus the rotation's), below 1 mm at
1 m/s, 2 rad/s, dt = 0.1 s and d = 0.17 m; the margin covers it.

A CasADi function and its NumPy twin, like :mod:`sanav_mj.control.unicycle`.
"""

from __future__ import annotations

import casadi as cs
import numpy as np


def extreme_offsets(offsets) -> np.ndarray:
    """The (1 or 2, 2) [m] offsets whose centres bound the collinear disc centres.

    Args:
        offsets: (n, 2) [m] disc centres in the body frame, collinear (as
            :meth:`sanav_mj.footprint.Footprint.discs` gives).

    Raises:
        ValueError: not an (n, 2) array of finite numbers, or the centres are not collinear.
    """
    o = np.asarray(offsets, dtype=float)
    if o.ndim != 2 or o.shape[1] != 2 or o.shape[0] < 1 or not np.all(np.isfinite(o)):
        raise ValueError(f"offsets: expected an (n, 2) array of finite numbers [m], got shape {o.shape}")
    if o.shape[0] == 1:
        return o.copy()
    d = o[-1] - o[0]
    span = float(np.hypot(*d))
    if span == 0.0:
        return o[:1].copy()
    rel = o - o[0]
    cross = rel[:, 0] * d[1] - rel[:, 1] * d[0]
    if np.max(np.abs(cross)) > 1e-9 * max(span, 1.0) * max(span, 1.0):
        raise ValueError(f"offsets: expected collinear disc centres, got {o.tolist()}")
    t = rel @ d / span**2
    return o[[int(np.argmin(t)), int(np.argmax(t))]]


def disc_centres(x, offsets) -> np.ndarray:
    """NumPy: world disc centres of states ``x``.

    Args:
        x: (..., 3) [m, m, rad] states.
        offsets: (n, 2) [m] disc centres in the body frame.

    Returns:
        (..., n, 2) [m].
    """
    x = np.asarray(x, dtype=float)
    o = np.asarray(offsets, dtype=float)
    c, s = np.cos(x[..., 2])[..., None], np.sin(x[..., 2])[..., None]
    px = x[..., 0][..., None] + o[:, 0] * c - o[:, 1] * s
    py = x[..., 1][..., None] + o[:, 0] * s + o[:, 1] * c
    return np.stack([px, py], axis=-1)


def disc_centres_cs(x, offsets) -> list:
    """CasADi twin of :func:`disc_centres` for one symbolic state ``x`` (3,): a list of n (2,) expressions."""
    c, s = cs.cos(x[2]), cs.sin(x[2])
    out = []
    for ox, oy in np.asarray(offsets, dtype=float):
        out.append(cs.vertcat(x[0] + ox * c - oy * s, x[1] + ox * s + oy * c))
    return out


def footprint_in_rect(x, rect, offsets, tol: float = 0.0) -> np.ndarray:
    """Whether every disc centre of each state lies in the rectangle (the MPC row bounds).

    Args:
        x: (..., 3) states.
        rect: (4,) or (..., 4) [m] xmin, ymin, xmax, ymax (broadcast against the states).
        offsets: (n, 2) [m] disc centres.
        tol: [m] allowed excursion.

    Returns:
        (...) bool.
    """
    c = disc_centres(x, offsets)
    r = np.asarray(rect, dtype=float)[..., None, :]
    inside = ((c[..., 0] >= r[..., 0] - tol) & (c[..., 0] <= r[..., 2] + tol)
              & (c[..., 1] >= r[..., 1] - tol) & (c[..., 1] <= r[..., 3] + tol))
    return inside.all(axis=-1)


def footprint_rect_margin(x, rect, offsets) -> np.ndarray:
    """Smallest slack [m] of the disc-centre rows of each state in the rectangle (< 0 outside).

    Args, shapes: as :func:`footprint_in_rect`; returns (...) [m].
    """
    c = disc_centres(x, offsets)
    r = np.asarray(rect, dtype=float)[..., None, :]
    slack = np.stack([c[..., 0] - r[..., 0], c[..., 1] - r[..., 1], r[..., 2] - c[..., 0], r[..., 3] - c[..., 1]], axis=-1)
    return slack.min(axis=(-1, -2))
