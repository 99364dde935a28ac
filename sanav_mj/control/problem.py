"""The unicycle tracking optimal-control problem: its NLP, parameter layout and warm-start shifts.

One builder, :func:`build_tracking_ocp`, writes the nonlinear program shared by the MPC
controllers (SA-MPC and the obstacle-penalty MPC baseline): single shooting over the
inputs of the exact unicycle (:mod:`sanav_mj.control.unicycle`), the paper's tracking cost
and an optional extra position cost term supplied by the controller
(:class:`PositionCost`: the safe-area penalty J_SA for SA-MPC, obstacle polygons for the
baseline). Everything that changes between control steps is a *parameter* or a *bound*, so
the problem is built (and, for the compiled back-ends, compiled) once:

- decision variables ``z = (u_0, ..., u_{N-1})`` (2N,) [m/s, rad/s]; their box bounds
  (input bounds, the rate bound of ``u_0`` against the previously applied input, a terminal
  stop) are passed at every solve;
- parameters ``p`` (see :class:`ParamLayout`): measured state, previous input, reference
  states and inputs over the horizon, the diagonal weights and the position-cost data;
- general constraints ``g(z, p)`` with bounds passed at every solve:
  ``g = (p_1, ..., p_N, [position_constraints]; u_1 - u_0, ..., u_{N-1} - u_{N-2})``, i.e.
  the predicted positions (2N,) [m] (for the stage boxes) and the input increments
  (2(N-1),) [m/s, rad/s] (for the rate bounds).

Objective (paper eq. 10-11 plus the position term)::

    sum_{k=0}^{N-1} |x_k - xr_k|^2_Qx + |u_k - ur_k|^2_Qu + |u_k - u_{k-1}|^2_Qa
      + |x_N - xr_N|^2_QN + sum_{k=1}^{N} c(p_k)

with ``u_{-1}`` the previously applied input. The position term is summed over k = 1..N: at
k = 0 the position is the measured one, a constant.

Solvers of this problem live in their own modules (:mod:`sanav_mj.control.backend_alpaqa`,
:mod:`sanav_mj.control.backend_ipopt`, :mod:`sanav_mj.control.sqp`), reached through the one
registry :mod:`sanav_mj.control.backends`; C code generation and its on-disk cache are
:mod:`sanav_mj.control.codegen`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import casadi as cs
import numpy as np

from sanav_mj.control.unicycle import rollout_cs


class PositionCost(Protocol):
    """An extra cost on each predicted position, with its own parameters.

    Attributes:
        key: short string identifying the structure of the expression (goes into the cache
            key of compiled code: change it whenever ``expr`` changes).
        n_params: number of parameters the term reads.
    """

    key: str
    n_params: int

    def expr(self, p, theta):
        """CasADi scalar cost of position ``p`` (2,) [m] given parameters ``theta`` (n_params,)."""


@dataclass(frozen=True)
class ParamLayout:
    """Where each block lives in the parameter vector (all slices into ``p``).

    Blocks, in order: ``x0`` (3,) [m, m, rad]; ``u_prev`` (2,) [m/s, rad/s]; ``x_ref``
    ((N+1)*3,) row-major (N+1, 3); ``u_ref`` (N*2,) row-major (N, 2); ``q_x`` (3,);
    ``q_u`` (2,); ``q_a`` (2,); ``q_n`` (3,); ``extra`` (n_extra,) position-cost data.
    """

    horizon: int
    n_extra: int

    @property
    def sizes(self) -> tuple[tuple[str, int], ...]:
        n = self.horizon
        return (
            ("x0", 3),
            ("u_prev", 2),
            ("x_ref", 3 * (n + 1)),
            ("u_ref", 2 * n),
            ("q_x", 3),
            ("q_u", 2),
            ("q_a", 2),
            ("q_n", 3),
            ("extra", self.n_extra),
        )

    @property
    def size(self) -> int:
        return sum(s for _, s in self.sizes)

    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for name, s in self.sizes:
            out[name] = slice(i, i + s)
            i += s
        return out

    def pack(
        self,
        x0: np.ndarray,
        u_prev: np.ndarray,
        x_ref: np.ndarray,
        u_ref: np.ndarray,
        q_x: np.ndarray,
        q_u: np.ndarray,
        q_a: np.ndarray,
        q_n: np.ndarray,
        extra: np.ndarray | None = None,
    ) -> np.ndarray:
        """Concatenate the blocks (shapes as in the class docstring) into ``p`` (size,)."""
        parts = [x0, u_prev, x_ref, u_ref, q_x, q_u, q_a, q_n]
        if self.n_extra:
            parts.append(extra)
        return np.concatenate([np.asarray(a, dtype=float).ravel() for a in parts])


@dataclass
class TrackingOCP:
    """The symbolic single-shooting NLP ``min f(z, p) s.t. z in [zl, zu], g(z, p) in [gl, gu]``.

    Attributes:
        horizon: N, number of control intervals.
        dt: [s] step length.
        z: (2N,) SX decision variables (inputs, row-major (N, 2)).
        p: (P,) SX parameters laid out as ``layout``.
        f: scalar SX objective.
        g: (m,) SX constraints: positions (2N,) when ``position_constraints``, then input
            increments (2(N-1),).
        layout: parameter layout.
        position_constraints: whether ``g`` starts with the predicted positions.
        key: string that identifies the structure (used for caching compiled code).
        points: (D, 2) [m] body-frame points whose world positions form the position rows
            (default one point, the base origin: the rows are the predicted positions).
    """

    horizon: int
    dt: float
    z: cs.SX
    p: cs.SX
    f: cs.SX
    g: cs.SX
    layout: ParamLayout
    position_constraints: bool
    key: str
    points: np.ndarray = field(default_factory=lambda: np.zeros((1, 2)))

    @property
    def n_points(self) -> int:
        """D, number of body points per stage in the position rows."""
        return int(self.points.shape[0])

    @property
    def n_z(self) -> int:
        return 2 * self.horizon

    @property
    def n_g(self) -> int:
        return int(self.g.numel())

    @property
    def n_pos(self) -> int:
        """Number of position-constraint rows at the start of ``g`` (2DN or 0)."""
        return 2 * self.n_points * self.horizon if self.position_constraints else 0

    def functions(self) -> tuple[cs.Function, cs.Function]:
        """``f(z, p)`` and ``g(z, p)`` as CasADi functions (names ``f`` and ``g``)."""
        f = cs.Function("f", [self.z, self.p], [self.f], ["x", "p"], ["f"])
        g = cs.Function("g", [self.z, self.p], [self.g], ["x", "p"], ["g"])
        return f, g


def build_tracking_ocp(
    horizon: int,
    dt: float,
    position_cost: PositionCost | None = None,
    position_constraints: bool = True,
    points=None,
    cost_points=None,
) -> TrackingOCP:
    """Build the tracking NLP described in the module docstring.

    Args:
        horizon: N >= 1, number of control intervals.
        dt: [s] > 0, step length (baked into the model).
        position_cost: optional extra cost on each predicted position p_1..p_N.
        position_constraints: include the predicted positions in ``g`` (for stage boxes).
        points: (D, 2) [m] body-frame points (footprint disc centres, see
            :mod:`sanav_mj.control.footprint`) whose world positions at stages 1..N form the
            position rows, stage-major ``(c_1^1, .., c_1^D, c_2^1, ...)`` (2DN,); None: the
            base origin only (the predicted positions, the paper's rows).
        cost_points: (E, 2) [m] body-frame points each charged ``position_cost`` at stages
            1..N; None: ``points`` (or the base origin).

    Returns:
        The symbolic problem.
    """
    if int(horizon) != horizon or horizon < 1:
        raise ValueError(f"horizon must be an integer >= 1, got {horizon!r}")
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    n = int(horizon)
    default = points is None
    pts = np.zeros((1, 2)) if points is None else np.asarray(points, dtype=float)
    cpts = pts if cost_points is None else np.asarray(cost_points, dtype=float)
    for name, a in (("points", pts), ("cost_points", cpts)):
        if a.ndim != 2 or a.shape[1] != 2 or a.shape[0] < 1 or not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: expected a (D, 2) array of finite body offsets [m], got shape {a.shape}")
    n_extra = position_cost.n_params if position_cost is not None else 0
    layout = ParamLayout(n, n_extra)
    z = cs.SX.sym("z", 2 * n)
    p = cs.SX.sym("p", layout.size)
    sl = layout.slices()
    x0 = p[sl["x0"]]
    u_prev = p[sl["u_prev"]]
    x_ref = cs.reshape(p[sl["x_ref"]], 3, n + 1)  # column k = reference state k
    u_ref = cs.reshape(p[sl["u_ref"]], 2, n)
    q_x, q_u, q_a, q_n = (p[sl[k]] for k in ("q_x", "q_u", "q_a", "q_n"))
    extra = p[sl["extra"]]

    us = [z[2 * k : 2 * k + 2] for k in range(n)]
    xs = rollout_cs(x0, us, dt)

    def wsq(e, q):
        return cs.dot(q, e * e)

    cost = 0
    u_last = u_prev
    for k in range(n):
        cost += wsq(xs[k] - x_ref[:, k], q_x)
        cost += wsq(us[k] - u_ref[:, k], q_u)
        cost += wsq(us[k] - u_last, q_a)
        u_last = us[k]
    cost += wsq(xs[n] - x_ref[:, n], q_n)
    from sanav_mj.control.footprint import disc_centres_cs

    def centres(x, offsets):
        if not np.any(offsets) and offsets.shape[0] == 1:
            return [x[:2]]
        return disc_centres_cs(x, offsets)

    if position_cost is not None:
        for k in range(1, n + 1):
            for c in centres(xs[k], cpts):
                cost += position_cost.expr(c, extra)

    rows = []
    if position_constraints:
        for k in range(1, n + 1):
            rows += centres(xs[k], pts)
    rows += [us[k] - us[k - 1] for k in range(1, n)]
    g = cs.vertcat(*rows) if rows else cs.SX(0, 1)
    key = f"track-N{n}-dt{dt!r}-pc{int(position_constraints)}-{position_cost.key if position_cost else 'none'}"
    if not default or cost_points is not None:
        # footprint points change the structure: name them exactly (repr of the floats)
        key += "-pts" + "_".join(f"{v!r}" for v in pts.ravel().tolist())
        key += "-cpts" + "_".join(f"{v!r}" for v in cpts.ravel().tolist())
    return TrackingOCP(n, float(dt), z, p, cost, g, layout, position_constraints, key, pts)


def shift_inputs(u: np.ndarray, start: int, horizon: int, rate_step: np.ndarray, u_last: np.ndarray) -> np.ndarray:
    """Warm start from a plan: ``u[start:]`` then braking towards (0, 0) at the rate limits.

    Args:
        u: (M, 2) [m/s, rad/s] plan.
        start: first input of ``u`` still to apply.
        horizon: N, rows of the result.
        rate_step: (2,) [m/s, rad/s] largest change of each input per step.
        u_last: (2,) input to brake from when nothing of ``u`` is left.

    Returns:
        (N, 2) inputs; every increment respects ``rate_step`` if ``u`` does.
    """
    rest = u[start:]
    out = np.empty((horizon, 2))
    m = min(len(rest), horizon)
    out[:m] = rest[:m]
    last = rest[m - 1] if m else np.asarray(u_last, dtype=float)
    for k in range(m, horizon):
        last = np.sign(last) * np.maximum(np.abs(last) - rate_step, 0.0)
        out[k] = last
    return out


def shift_multipliers(ocp: TrackingOCP, y: np.ndarray, shift_rates: bool = True) -> np.ndarray:
    """Multipliers of ``g`` (m,) shifted by one stage for the next problem's warm start.

    Positions move one stage earlier and repeat the last. Rates move likewise and end with 0
    when ``shift_rates``; otherwise they stay where they are: under a terminal stop the rate
    bounds that bind are mostly those of the braking at the end of every plan, which stays
    at the same stages of the horizon while the robot cruises (measured on the recorded
    SA-MPC sequence: 20 % fewer PANOC iterations than shifting them).
    """
    n = ocp.horizon
    parts = []
    if ocp.position_constraints:
        pos = y[: ocp.n_pos].reshape(n, 2 * ocp.n_points)
        parts.append(np.concatenate((pos[1:], pos[-1:])).ravel())
    rate = y[ocp.n_pos :].reshape(n - 1, 2)
    if shift_rates:
        parts.append(np.concatenate((rate[1:], np.zeros((1, 2)))).ravel())
    else:
        parts.append(rate.ravel())
    return np.concatenate(parts)


def shift_bound_multipliers(y_z: np.ndarray | None) -> np.ndarray | None:
    """Multipliers of the variable bounds (2N,) shifted by one stage (last stage 0), or None."""
    if y_z is None:
        return None
    return np.concatenate((y_z[2:], np.zeros(2)))
