"""Discrete unicycle model: a CasADi version for the optimiser and a NumPy twin.

State ``x = (px, py, theta)`` [m, m, rad], input ``u = (v, w)`` [m/s, rad/s] held constant
over one step of length ``dt`` [s] (zero-order hold, as the controller applies it).

The paper writes the explicit Euler step ``x+ = x + v cos(theta) dt`` (its eq. 9). We use the
*exact* discretisation of the same continuous unicycle under a zero-order-hold input::

    px+ = px + v dt sinc(w dt / 2) cos(theta + w dt / 2)
    py+ = py + v dt sinc(w dt / 2) sin(theta + w dt / 2)
    theta+ = theta + w dt,                          sinc(a) = sin(a) / a

Why: the robot drives circular arcs between control instants, so each predicted sample lies
exactly on the nominal path (Euler is off by about ``v |w| dt^2 / 2`` per step, 1 cm at
1 m/s, 2 rad/s, 0.1 s), and the arc between two samples stays within ``v |w| dt^2 / 8`` of
the chord joining them, which is the bound the safe-area argument in
:mod:`sanav_mj.control.sa_mpc` uses. Same cost as Euler (one extra sin/cos pair), and it
reduces to Euler's form when ``w = 0``.

``sinc`` is evaluated by its Taylor polynomial up to ``a^12`` (both twins) so the CasADi
expression is smooth and NaN-free at ``a = 0``; for ``|a| <= 1`` (i.e. ``|w| dt <= 2`` rad
per step, far beyond any controller setting) the truncation error is below ``8e-13``.
"""

from __future__ import annotations

import math

import casadi as cs
import numpy as np

#: Largest ``|w| dt / 2`` [rad] for which the polynomial sinc is accurate to 1e-12.
SINC_HALF_ANGLE_MAX = 1.0

# sin(a)/a = sum_n (-1)^n a^(2n) / (2n+1)!, n = 0..6, in Horner form over s = a^2.
_SINC_COEFFS = tuple((-1) ** n / math.factorial(2 * n + 1) for n in range(7))


def _sinc_poly(a2):
    """Polynomial ``sin(a)/a`` from ``a2 = a^2`` (works on floats, arrays and CasADi)."""
    acc = _SINC_COEFFS[-1]
    for c in reversed(_SINC_COEFFS[:-1]):
        acc = acc * a2 + c
    return acc


def sinc_half(w, dt):
    """``sin(w dt / 2) / (w dt / 2)`` (dimensionless) for NumPy arrays or floats."""
    a = np.asarray(w, dtype=float) * (0.5 * dt)
    return _sinc_poly(a * a)


def step_np(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """One exact unicycle step, vectorised over leading dimensions.

    Args:
        x: (..., 3) [m, m, rad] states.
        u: (..., 2) [m/s, rad/s] inputs held over the step.
        dt: [s] step length.

    Returns:
        (..., 3) [m, m, rad] next states (yaw not wrapped).
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    th = x[..., 2]
    v = u[..., 0]
    w = u[..., 1]
    half = 0.5 * w * dt
    ds = v * dt * _sinc_poly(half * half)
    mid = th + half
    return np.stack((x[..., 0] + ds * np.cos(mid), x[..., 1] + ds * np.sin(mid), th + w * dt), axis=-1)


def rollout_np(x0: np.ndarray, us: np.ndarray, dt: float) -> np.ndarray:
    """Simulate the model from ``x0`` under an input sequence.

    Args:
        x0: (3,) [m, m, rad] initial state.
        us: (N, 2) [m/s, rad/s] inputs, one per step.
        dt: [s] step length.

    Returns:
        (N+1, 3) [m, m, rad] states, the first being ``x0``.
    """
    us = np.asarray(us, dtype=float).reshape(-1, 2)
    px, py, th = (float(c) for c in np.asarray(x0, dtype=float).reshape(3))
    rows = [(px, py, th)]
    # Plain floats: for N ~ 20 this is several times faster than per-step NumPy calls; the
    # polynomial is _sinc_poly's Horner scheme written out (the same operations in the same order).
    cos, sin = math.cos, math.sin
    c0, c1, c2, c3, c4, c5, c6 = _SINC_COEFFS
    for v, w in us.tolist():
        half = 0.5 * w * dt
        a2 = half * half
        ds = v * dt * ((((((c6 * a2 + c5) * a2 + c4) * a2 + c3) * a2 + c2) * a2 + c1) * a2 + c0)
        mid = th + half
        px += ds * cos(mid)
        py += ds * sin(mid)
        th += w * dt
        rows.append((px, py, th))
    return np.array(rows, dtype=float).reshape(-1, 3)


def step_cs(x, u, dt: float):
    """One exact unicycle step as a CasADi expression (SX or MX).

    Args:
        x: (3,) [m, m, rad] state expression.
        u: (2,) [m/s, rad/s] input expression.
        dt: [s] step length (a number, baked into the expression).

    Returns:
        (3,) [m, m, rad] next-state expression, equal to :func:`step_np` to rounding.
    """
    th = x[2]
    v = u[0]
    w = u[1]
    half = 0.5 * dt * w
    ds = v * dt * _sinc_poly(half * half)
    mid = th + half
    return cs.vertcat(x[0] + ds * cs.cos(mid), x[1] + ds * cs.sin(mid), th + dt * w)


def step_function(dt: float) -> cs.Function:
    """The step as a ``casadi.Function`` ``F(x (3,), u (2,)) -> x+ (3,)`` for step ``dt`` [s]."""
    x = cs.SX.sym("x", 3)
    u = cs.SX.sym("u", 2)
    return cs.Function("unicycle_step", [x, u], [step_cs(x, u, dt)], ["x", "u"], ["x_next"])


def rollout_cs(x0, us: list, dt: float) -> list:
    """Symbolic rollout: ``x0`` (3,) expression and ``N`` input expressions (2,) -> ``N+1`` states."""
    xs = [x0]
    for u in us:
        xs.append(step_cs(xs[-1], u, dt))
    return xs


def arc_chord_deviation(v: float, w: float, dt: float) -> float:
    """[m] Largest distance between the arc driven in one step and its chord.

    The robot drives an arc of length ``s = |v| dt`` turning by ``phi = |w| dt``; its sagitta
    is ``(2 s / phi) sin^2(phi / 4) <= s phi / 8 = |v w| dt^2 / 8``. Returns the exact value.
    """
    s = abs(v) * dt
    phi = abs(w) * dt
    if phi < 1e-12:
        return 0.0
    return float(2.0 * s / phi * math.sin(phi / 4.0) ** 2)
