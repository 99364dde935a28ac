"""Time-parametrisation of a planar path at the MPC step: speed profile and resampling.

The geometric curve comes as dense samples ``q_i`` (N, 2) at curve parameters ``u_i``. From
them (all vectorised, no Python loop over samples):

* arc length ``sigma_i`` (cumulative chord length), chord headings ``phi`` (unwrapped), node
  headings (mean of the adjacent chords) and signed curvature ``kappa_i`` = turning angle /
  mean adjacent chord length (exact for circular arcs, O(ds^2) for smooth curves, and large
  but finite at a polyline corner so the profile slows to turn there);
* a speed limit per node ``v_lim = min(v_cap, w_cap / |kappa|, sqrt(a_lat / |kappa|))``,
  using the largest ``|kappa|`` of the node and its two neighbours so the limits hold on the
  whole intervals between nodes (the speed between nodes is between the two node speeds and
  the interpolated curvature between the two node curvatures), with 0 at both ends;
* the forward-backward acceleration pass in squared speed ``V = v^2``:
  ``V_{i+1} = min(L_{i+1}, V_i + 2 a ds_i)`` forward and the same backward. The recursion
  ``V_i = min_k (L_k + C_i - C_k)`` (``C`` the cumulative ``2 a ds``) is evaluated with
  ``np.minimum.accumulate``. Constant acceleration between nodes gives the node times
  ``dt_i = 2 ds_i / (v_i + v_{i+1})`` and exact positions at any time.

Resampling at ``t_k = k dt`` gives ``sigma(t_k)`` and ``v(t_k)``; the state is the curve
point at the matching parameter ``u`` (so positions lie exactly on the curve), the yaw is the
path tangent (interpolated node heading, unwrapped) and ``w = v kappa``. After the arrival
time T the reference stays at the goal with ``(v, w) = (0, 0)``; the last sample is at
``ceil(T / dt) dt``.

Guarantees for the returned samples (tested): ``0 <= v <= v_cap``, ``|w| <= w_cap``,
``|v_{k+1} - v_k| <= a dt``, ``v^2 |kappa| <= a_lat``; the yaw
acceleration limit ``alpha_max`` is not imposed (the controller's input-rate bounds handle it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PathProfile:
    """Geometry and speed profile on the dense nodes of a curve.

    Attributes:
        u: (N,) [m] curve parameter of each node.
        sigma: (N,) [m] arc length.
        heading: (N,) [rad] tangent direction, unwrapped.
        kappa: (N,) [1/m] signed curvature.
        v: (N,) [m/s] speed (0 at both ends).
        t: (N,) [s] time at each node.
    """

    u: np.ndarray
    sigma: np.ndarray
    heading: np.ndarray
    kappa: np.ndarray
    v: np.ndarray
    t: np.ndarray

    @property
    def duration(self) -> float:
        """[s] arrival time T."""
        return float(self.t[-1])


def discrete_geometry(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Arc length, heading and curvature of dense curve samples.

    Args:
        points: (N, 2) [m], N >= 2, consecutive points distinct.

    Returns:
        ``(sigma, heading, kappa, ds)``: (N,) [m], (N,) [rad] unwrapped, (N,) [1/m] signed,
        (N-1,) [m] chord lengths.
    """
    d = points[1:] - points[:-1]
    ds = np.hypot(d[:, 0], d[:, 1])
    raw = np.arctan2(d[:, 1], d[:, 0])
    phi = np.empty_like(raw)  # unwrapped: consecutive chord headings differ by less than pi
    phi[0] = raw[0]
    if raw.size > 1:
        turn = raw[1:] - raw[:-1]
        np.cumsum((turn + np.pi) % (2.0 * np.pi) - np.pi, out=phi[1:])
        phi[1:] += raw[0]
    n = points.shape[0]
    sigma = np.zeros(n)
    np.cumsum(ds, out=sigma[1:])
    heading = np.empty(n)
    heading[0] = phi[0]
    heading[-1] = phi[-1]
    kappa = np.zeros(n)
    if n > 2:
        heading[1:-1] = 0.5 * (phi[:-1] + phi[1:])
        kappa[1:-1] = (phi[1:] - phi[:-1]) / (0.5 * (ds[:-1] + ds[1:]))
        kappa[0] = kappa[1]
        kappa[-1] = kappa[-2]
    return sigma, heading, kappa, ds


def speed_profile(
    ds: np.ndarray, kappa: np.ndarray, v_cap: float | np.ndarray, w_cap: float, a_lat: float, a_max: float,
    v_start: float = 0.0,
) -> np.ndarray:
    """Speed at each node from rest to rest under speed, yaw-rate, lateral and longitudinal
    acceleration limits (forward-backward pass, see the module docstring).

    Args:
        ds: (N-1,) [m] distances between nodes (> 0).
        kappa: (N,) [1/m] curvature at the nodes.
        v_cap: [m/s] speed limit, one for all nodes or (N,) one per node.
        w_cap: [rad/s] yaw-rate limit.
        a_lat: [m/s^2] lateral acceleration limit.
        a_max: [m/s^2] longitudinal acceleration / deceleration limit.
        v_start: [m/s] speed at the first node (>= 0; a robot replanning in motion), capped
            by the first node's limit; 0: from rest.

    Returns:
        (N,) [m/s] speeds, ``min(v_start, limit)`` at the first node (0 from rest), 0 at the end.
    """
    k = np.abs(kappa)
    env = k.copy()
    if k.size > 1:
        env[1:] = np.maximum(env[1:], k[:-1])
        env[:-1] = np.maximum(env[:-1], k[1:])
    with np.errstate(divide="ignore"):
        lim = np.minimum(v_cap, np.minimum(w_cap / env, np.sqrt(a_lat / env)))
    V_lim = lim * lim
    V_lim[0] = min(float(V_lim[0]), float(v_start) ** 2) if v_start > 0 else 0.0
    V_lim[-1] = 0.0
    c = np.zeros(k.size)
    np.cumsum(2.0 * a_max * ds, out=c[1:])
    fwd = c + np.minimum.accumulate(V_lim - c)
    cr = c[-1] - c  # cumulative from the end
    bwd = (cr[::-1] + np.minimum.accumulate((V_lim - cr)[::-1]))[::-1]
    V = np.maximum(np.minimum(fwd, bwd), 0.0)
    return np.sqrt(V)


def profile_curve(
    u: np.ndarray, points: np.ndarray, v_cap: float | np.ndarray, w_cap: float, a_lat: float, a_max: float,
    v_start: float = 0.0,
) -> PathProfile:
    """Geometry, speed and timing on the dense samples of a curve.

    Args:
        u: (N,) [m] curve parameters of the samples (increasing).
        points: (N, 2) [m] curve samples; repeated points are dropped.
        v_cap, w_cap, a_lat, a_max, v_start: limits and start speed as in :func:`speed_profile`.

    Returns:
        The :class:`PathProfile` (at least 3 nodes unless the curve has length 0).
    """
    d = points[1:] - points[:-1]
    keep = np.ones(points.shape[0], dtype=bool)
    keep[1:] = np.hypot(d[:, 0], d[:, 1]) > 1e-12
    if not keep[-1] and keep.sum() > 1:  # keep the end point, drop its duplicate before it
        last = np.flatnonzero(keep)[-1]
        keep[last] = False
        keep[-1] = True
    u = u[keep]
    points = points[keep]
    if points.shape[0] == 2:  # give the profile an interior node to accelerate through
        u = np.array([u[0], 0.5 * (u[0] + u[1]), u[1]])
        points = np.array([points[0], 0.5 * (points[0] + points[1]), points[1]])
    sigma, heading, kappa, ds = discrete_geometry(points)
    v = speed_profile(ds, kappa, v_cap, w_cap, a_lat, a_max, v_start)
    vs = v[:-1] + v[1:]
    t = np.zeros(points.shape[0])
    np.cumsum(2.0 * ds / np.maximum(vs, 1e-12), out=t[1:])
    return PathProfile(u=u, sigma=sigma, heading=heading, kappa=kappa, v=v, t=t)


@dataclass(frozen=True)
class TimedSamples:
    """Samples of a profile at a fixed step.

    Attributes:
        t: (K,) [s] ``k * dt``.
        u: (K,) [m] curve parameter of each sample.
        sigma: (K,) [m] arc length.
        yaw: (K,) [rad] path tangent, unwrapped.
        v: (K,) [m/s] speed.
        w: (K,) [rad/s] yaw rate ``v * kappa``.
    """

    t: np.ndarray
    u: np.ndarray
    sigma: np.ndarray
    yaw: np.ndarray
    v: np.ndarray
    w: np.ndarray


def sample_profile(profile: PathProfile, dt: float) -> TimedSamples:
    """Sample a profile at ``t_k = k dt`` up to the first step at or after arrival.

    Between nodes the acceleration is constant: ``sigma = sigma_i + v_i tau + a_i tau^2 / 2``.

    Args:
        profile: from :func:`profile_curve`.
        dt: [s] step (> 0).

    Returns:
        :class:`TimedSamples` with ``K = ceil(T / dt) + 1`` samples; the last is at the end
        of the curve with ``v = w = 0``.
    """
    T = profile.duration
    K = int(np.ceil(T / dt - 1e-9)) + 1
    t = np.arange(K) * dt
    tn, vn, sn = profile.t, profile.v, profile.sigma
    n = tn.size
    i = np.minimum(np.maximum(np.searchsorted(tn, t, side="right") - 1, 0), n - 2)
    tau = np.maximum(t - tn[i], 0.0)
    dsn = sn[i + 1] - sn[i]
    acc = (vn[i + 1] ** 2 - vn[i] ** 2) / (2.0 * np.maximum(dsn, 1e-15))
    span = tn[i + 1] - tn[i]
    tau = np.minimum(tau, span)
    v = np.maximum(vn[i] + acc * tau, 0.0)
    sigma = np.minimum(sn[i] + vn[i] * tau + 0.5 * acc * tau * tau, sn[i + 1])
    done = t >= T
    v[done] = 0.0
    sigma[done] = sn[-1]
    v[-1] = 0.0
    sigma[-1] = sn[-1]
    u = np.interp(sigma, sn, profile.u)
    yaw = np.interp(sigma, sn, profile.heading)
    kap = np.interp(sigma, sn, profile.kappa)
    w = v * kap
    return TimedSamples(t=t, u=u, sigma=sigma, yaw=yaw, v=v, w=w)


def time_parametrise(
    curve: Callable[[np.ndarray], np.ndarray],
    u_nodes: np.ndarray,
    dt: float,
    v_cap: float | np.ndarray,
    w_cap: float,
    a_lat: float,
    a_max: float,
    points: np.ndarray | None = None,
    v_start: float = 0.0,
) -> tuple[PathProfile, TimedSamples, np.ndarray]:
    """Profile a curve on dense nodes and sample it at ``dt``.

    Args:
        curve: maps (K,) parameters [m] to (K, 2) [m] points.
        u_nodes: (N,) [m] dense node parameters (increasing).
        dt: [s] sampling step.
        v_cap, w_cap, a_lat, a_max: limits as in :func:`speed_profile`.
        points: (N, 2) [m] ``curve(u_nodes)`` when already computed.
        v_start: [m/s] speed at the start (see :func:`speed_profile`).

    Returns:
        ``(profile, samples, positions)``: positions (K, 2) [m] are ``curve(samples.u)``.
    """
    q = curve(u_nodes) if points is None else points
    prof = profile_curve(np.asarray(u_nodes, dtype=float), q, v_cap, w_cap, a_lat, a_max, v_start)
    smp = sample_profile(prof, dt)
    return prof, smp, curve(smp.u)
