"""The tracking-MPC core shared by SA-MPC and the penalty MPC.

:class:`TrackingMPC` owns what every tracking MPC of the package does the same way: the step
skeleton, the input and rate bounds (with the plant adaptation's derating and traction
limit), the warm start (shifted previous plan and its multipliers), the acceptance of a
solution, the fallback policy (follow the shifted plan if it still fits the current
problem, else brake steering to the clearest side), the opening turn on the spot, the
per-episode statistics and the command sent through the plant adaptation
(:class:`~sanav_mj.control.adaptation.PlantAdaptation`).

A controller subclasses it and adds only its constraints and cost (the plug-in points):

- the NLP: :func:`~sanav_mj.control.problem.build_tracking_ocp` with its
  :class:`~sanav_mj.control.problem.PositionCost` (J_SA, obstacle polygons) and whether the
  predicted positions are constraint rows, passed to ``__init__``;
- :meth:`TrackingMPC.reference`: reference states and inputs over the horizon;
- :meth:`TrackingMPC.constrain`: per step, the bounds of the position rows of ``g`` (the
  hard constraints ``A_k p_k <= b_k``), the position-cost parameters, the (possibly
  adjusted) reference and the excursion of the measured position from its constraint set.
  Footprint-true constraints (several discs along the body, each inside a safe rectangle)
  go here: more position rows in the OCP's ``g`` (``build_tracking_ocp``) and their bounds
  returned by ``constrain``; the acceptance (:meth:`TrackingMPC.violation`) and the
  fallback check (:meth:`TrackingMPC.shift_fits`) evaluate the same rows through
  :meth:`TrackingMPC.position_rows`, which a controller with other rows overrides;
- optionally :meth:`TrackingMPC.solve` (multi-start), :meth:`TrackingMPC.describe`
  (rectangle ids and margins of a command), :meth:`TrackingMPC.clearance` (how the braking
  fallback chooses its side), :meth:`TrackingMPC.turn_context` and
  :meth:`TrackingMPC.commit` (controller state that follows the applied plan).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sanav_mj.control.adaptation import PlantAdaptation
from sanav_mj.control.backends import get_backend
from sanav_mj.control.base import Command, Observation
from sanav_mj.control.config import InputLimits, TrackingConfig
from sanav_mj.control.problem import TrackingOCP, shift_bound_multipliers, shift_inputs, shift_multipliers
from sanav_mj.control.solver import SolveResult
from sanav_mj.control.reach import unreachable_stage
from sanav_mj.control.unicycle import rollout_np


@dataclass
class ActivePlan:
    """The active input plan: inputs (N, 2), the next index to apply, multipliers to reuse, braking or not."""

    u: np.ndarray
    next: int
    y: np.ndarray | None = None
    y_z: np.ndarray | None = None
    brake: bool = False


@dataclass
class Constraints:
    """A controller's part of one step's problem (returned by :meth:`TrackingMPC.constrain`).

    Attributes:
        pos_lb, pos_ub: (n_pos,) bounds of the position rows of ``g`` (empty without them).
        extra: (n_extra,) parameters of the position cost.
        x_ref: (N+1, 3) [m, m, rad] reference states (possibly adjusted to the constraints).
        u_ref: (N, 2) [m/s, rad/s] reference inputs.
        excursion: [m] how far the measured position lies outside its constraint set
            (derates the speed, see :meth:`PlantAdaptation.speed_cap`); 0 inside.
        context: controller data that follows the plan (e.g. SA-MPC's stage assignment).
        shift_bounds: (pos_lb, pos_ub) the fallback's shift check reads instead of
            ``pos_lb``/``pos_ub`` (SA-MPC's untightened boxes), or None.
    """

    pos_lb: np.ndarray
    pos_ub: np.ndarray
    extra: np.ndarray
    x_ref: np.ndarray
    u_ref: np.ndarray
    excursion: float = 0.0
    context: Any = None
    shift_bounds: tuple[np.ndarray, np.ndarray] | None = None


@dataclass
class Problem:
    """One step's NLP data as posed to the back-end, and what the fallback checks it against.

    Attributes:
        p: (P,) parameters; z_lb, z_ub: (2N,) input bounds as solved (derated);
        g_lb, g_ub: (m,) constraint bounds; z0: (2N,) initial guess;
        u_guess: (N, 2) the shifted previous plan; guess: (N+1, 3) its rollout;
        fb_lb, fb_ub: (2N,) input bounds the shifted plan must meet in the fallback.
        y0, y_z0: warm-start multipliers (or None).
        shift_bounds: (n_pos,) x 2 position-row bounds of the shift check instead of the
            problem's (:attr:`Constraints.shift_bounds`), or None.
    """

    p: np.ndarray
    z_lb: np.ndarray
    z_ub: np.ndarray
    g_lb: np.ndarray
    g_ub: np.ndarray
    z0: np.ndarray
    u_guess: np.ndarray
    guess: np.ndarray
    fb_lb: np.ndarray
    fb_ub: np.ndarray
    y0: np.ndarray | None = None
    y_z0: np.ndarray | None = None
    shift_bounds: tuple[np.ndarray, np.ndarray] | None = None


@dataclass
class MPCStats:
    """Counters of one episode: steps per status (plus controller-specific keys) and failures."""

    counts: dict[str, int] = field(default_factory=dict)

    @property
    def failures(self) -> int:
        """Steps whose command came from a fallback."""
        return sum(v for k, v in self.counts.items() if k.startswith("fallback"))

    def count(self, key: str) -> None:
        """Add one to ``key``."""
        self.counts[key] = self.counts.get(key, 0) + 1


def turn_profile(err: float, w0: float, a: float, w_max: float, n: int, dt: float) -> np.ndarray:
    """(n, 2) inputs turning on the spot by ``err`` [rad] as fast as the bounds allow.

    ``v = 0`` throughout; the yaw rate starts from ``w0`` [rad/s] and, stage by stage, takes
    the largest value within the rate bound ``a`` [rad/s per step] and ``|w| <= w_max``
    [rad/s] from which braking at the rate bound does not turn past ``err`` (time-optimal
    rest-to-rest profile of the discrete double integrator, period ``dt`` [s]); it brakes at
    the rate bound when even that overshoots.
    """
    sgn = 1.0 if err >= 0 else -1.0
    rem = abs(err)
    w = sgn * w0  # yaw rate towards the target
    out = np.zeros((n, 2))
    for k in range(n):
        # Largest w' >= 0 whose braking run turns at most rem: in units of dt the run
        # turns S(w') = (m + 1) w' - a m (m + 1) / 2 with m = floor(w' / a), continuous
        # and increasing; solve piece by piece.
        budget = rem / dt
        best = 0.0
        m = 0
        while budget > 0:
            cand = (budget + a * m * (m + 1) / 2) / (m + 1)
            if cand < (m + 1) * a:
                best = cand
                break
            m += 1
        w = min(max(best, w - a, -w_max), w + a, w_max)
        out[k, 1] = sgn * w
        rem -= w * dt
    return out


def brake_inputs(u_prev: np.ndarray, rate_step: np.ndarray, n: int, target: float) -> np.ndarray:
    """(n, 2) [m/s, rad/s] one braking candidate of :meth:`TrackingMPC.brake_plan`.

    The speed goes from ``u_prev[0]`` to zero at the rate bound ``rate_step[0]`` [m/s per
    step]; the yaw rate ramps from ``u_prev[1]`` at its rate bound ``rate_step[1]`` [rad/s
    per step] towards ``target`` [rad/s] and, from the first stage at rest, back to zero at
    that bound. Every increment respects the rate bounds.
    """
    a, al = float(rate_step[0]), float(rate_step[1])
    v0, w0 = float(u_prev[0]), float(u_prev[1])
    k = np.arange(1, n + 1)
    v = np.sign(v0) * np.maximum(abs(v0) - k * a, 0.0)
    w = w0 + np.clip(target - w0, -k * al, k * al)
    # once stopped, bring the yaw rate back to rest as well
    stopped = np.flatnonzero(v == 0.0)
    if stopped.size:
        j = stopped[0]
        w[j:] = np.sign(w[j - 1] if j > 0 else w0) * np.maximum(
            abs(w[j - 1] if j > 0 else w0) - np.arange(1, n - j + 1) * al, 0.0
        )
    return np.stack((v, w), axis=1)


def _unreachable(ctl, x0: np.ndarray, con: Constraints, prob: Problem) -> int | None:
    """The ``reach_check`` of a :class:`TrackingMPC` step: the first stage (1..N) whose box
    no plan within the input bounds reaches (:func:`unreachable_stage`; the solve could not
    be accepted, ``ctl.unreachable`` counts it), or None. Only when the position rows are
    the positions ``p_1..p_N`` (2N rows); else None."""
    if len(con.pos_lb) != 2 * ctl.N:
        return None
    if _guess_fits(x0, con, prob, 0.5 * ctl._check_tol):
        return None  # the warm start reaches every box: no stage is unreachable
    k = unreachable_stage(x0, prob.z_lb, prob.z_ub, con.pos_lb, con.pos_ub, ctl.dt, ctl._check_tol)
    ctl.unreachable += k is not None
    return k


def _guess_fits(x0: np.ndarray, con: Constraints, prob: Problem, tol: float) -> bool:
    """Whether the warm start ``prob.u_guess`` (N, 2), rolled out from ``x0`` (3,) as
    ``prob.guess`` (N+1, 3), is within ``tol`` of the input bounds and of the position boxes
    (the 2N position rows ``con.pos_lb``/``pos_ub``).

    A shortcut of the reach check, not a change of it: with ``tol`` below the check's own
    tolerance, such a plan proves every stage box reachable, so
    :func:`~sanav_mj.control.reach.unreachable_stage` (whose intervals hold every plan within
    its tolerance of the input bounds, widened boxes, rounding covered by a margin many
    orders of magnitude below ``tol``) would return None. False when anything is not finite.
    """
    guess = prob.guess
    if not np.array_equal(guess[0], x0):
        return False
    z = prob.u_guess.ravel()
    pos = guess[1:, :2].ravel()
    return bool(np.all(z >= prob.z_lb - tol) and np.all(z <= prob.z_ub + tol)
                and np.all(pos >= con.pos_lb - tol) and np.all(pos <= con.pos_ub + tol))


def _rollout_of(ctl, z: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """(N+1, 3) rollout of the solution ``z`` (2N,) from ``x0`` (3,): the one the acceptance
    test made of this very ``z`` from this ``x0`` (``ctl._rolled``, kept by
    :meth:`TrackingMPC.acceptance`), else computed. The kept tuple holds its ``z`` alive, so
    a later solution can never be that same object."""
    rolled = getattr(ctl, "_rolled", None)
    if rolled is not None and rolled[0] is z and rolled[1] is x0:
        return rolled[2]
    return rollout_np(x0, z.reshape(ctl.N, 2), ctl.dt)


def _with_rows(rows: tuple[np.ndarray, np.ndarray], prob: Problem, n_pos: int) -> tuple[np.ndarray, np.ndarray]:
    """``prob``'s constraint bounds with the first ``n_pos`` (the position rows) replaced by ``rows``."""
    return np.concatenate((rows[0], prob.g_lb[n_pos:])), np.concatenate((rows[1], prob.g_ub[n_pos:]))


class TrackingMPC:
    """The shared tracking-MPC core (see the module docstring); implements the Controller protocol.

    Args:
        robot: nominal robot parameters.
        config: the core's settings.
        limits: resolved input and rate bounds.
        ocp: the controller's NLP (built once).
        adaptation: the plant adaptation (its bounds, effective state and sent command).
        failure_injector: test hook called with the step index; True fails that solve.

    Attributes:
        dt: [s] control period. N: horizon. limits: input limits. ocp, backend: the NLP and
        its solver. adaptation: the plant adaptation. accel: [m/s^2] current speed rate
        bound (the traction limit lowers it). stats: :class:`MPCStats` of the episode.
        last_failure_reason: why the last fallback was taken, or None.
    """

    name = "tracking-mpc"
    needs_ranges = False
    #: shift the multipliers of the rate rows with the plan (else they stay at their stages).
    shift_rate_multipliers = True
    #: [m] extra tolerance of the position rows when the fallback checks the shifted plan.
    position_slack = 0.0

    def __init__(self, robot, config: TrackingConfig, limits: InputLimits, ocp: TrackingOCP,
                 adaptation: PlantAdaptation, *, failure_injector: Callable[[int], bool] | None = None):
        self.config = config
        self.robot = robot
        self.dt = float(config.dt)
        self.N = int(config.horizon)
        self.limits = limits
        self.ocp = ocp
        self.adaptation = adaptation
        self.failure_injector = failure_injector
        cache = Path(config.cache_dir) if config.cache_dir else None
        self.backend = get_backend(ocp, config.solver, config.solver_settings(), cache)
        self._check_tol = 10.0 * config.constraint_tol + 1e-9
        sl = ocp.layout.slices()
        self._p_buf = np.zeros(ocp.layout.size)
        for name, w in zip(("q_x", "q_u", "q_a", "q_n"), (config.q_x, config.q_u, config.q_a, config.q_n)):
            self._p_buf[sl[name]] = np.asarray(w, float)
        self._p_slices = sl
        self._set_accel(limits.a_max)

    # ------------------------------------------------------------ plug-in points

    def reference(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference states (N+1, 3) and inputs (N, 2) for the horizon from the state ``x0`` (3,)."""
        raise NotImplementedError

    def constrain(self, x0: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray, guess: np.ndarray) -> Constraints:
        """The controller's constraints and cost data for this step (see :class:`Constraints`).

        ``guess`` (N+1, 3) is the shifted previous plan rolled out from ``x0``.
        """
        return Constraints(np.zeros(0), np.zeros(0), np.zeros(0), x_ref, u_ref)

    def solve(self, prob: Problem, x0: np.ndarray) -> tuple[SolveResult, str | None, str]:
        """Solve the posed problem: (result, ``"ok"``/``"inexact"`` or None when rejected, reason)."""
        res = self.backend.solve(prob.p, prob.z_lb, prob.z_ub, prob.g_lb, prob.g_ub, prob.z0, prob.y0, prob.y_z0)
        status, reason = self.acceptance(res, x0, prob)
        return res, status, reason

    def describe(self, xs: np.ndarray, x0: np.ndarray, context: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Rectangle ids (N+1,) and constraint margins (N+1,) [m] of an applied plan (None: not applicable)."""
        return None, None

    def clearance(self, points: np.ndarray) -> np.ndarray | None:
        """(P,) [m] slack of points (P, 2) in the free space the controller knows (None: unknown,
        the braking fallback then brakes straight)."""
        return None

    def turn_context(self, x0: np.ndarray, xs: np.ndarray) -> Any:
        """Controller context of an opening-turn plan rolled out as ``xs`` (N+1, 3)."""
        return None

    def turn_allowed(self, x0: np.ndarray) -> bool:
        """Whether the robot at ``x0`` (3,) may turn on the spot (the opening turn); when not,
        the MPC takes over at once (its constraints then decide how it turns)."""
        return True

    def state_clearance(self, xs: np.ndarray) -> np.ndarray | None:
        """(P,) [m] slack of the states ``xs`` (P, 3) in the known free space (the braking
        fallback's score): :meth:`clearance` of their positions unless overridden."""
        return self.clearance(xs[:, :2])

    def commit(self, context: Any) -> None:
        """Keep the controller context of the plan just applied (called on accept and fallback)."""

    def position_rows(self, xs: np.ndarray) -> np.ndarray:
        """The position rows of ``g`` for the rollout ``xs`` (N+1, 3): ``p_1..p_N`` (2N,), or empty."""
        return xs[1:, :2].ravel() if self.ocp.position_constraints else np.zeros(0)

    # ------------------------------------------------------------ bounds

    def _set_accel(self, a_max: float) -> None:
        """Set the rate bound of the speed to ``a_max`` [m/s^2] and everything derived from it
        (input bounds implied by the terminal stop, reach from the previous input, rate
        constraints); the yaw-rate bound stays ``limits.alpha_max``."""
        n = self.N
        self.accel = float(a_max)
        self._z_lb = np.tile(self.limits.lower(), n)
        self._z_ub = np.tile(self.limits.upper(), n)
        self._rate_step = np.array([self.accel, self.limits.alpha_max]) * self.dt
        if self.config.terminal_stop:
            # v_{N-1} = 0 and the rate bound imply |v_k| <= (N-1-k) a dt
            stop = (n - 1 - np.arange(n)) * self._rate_step[0]
            self._z_lb[0::2] = np.maximum(self._z_lb[0::2], -stop)
            self._z_ub[0::2] = np.minimum(self._z_ub[0::2], stop)
        # |u_k - u_prev| <= (k + 1) * rate step, implied by the rate bounds from u_prev
        self._reach = np.outer(np.arange(1, n + 1), self._rate_step).ravel()
        self._rate_lb = np.tile(-self._rate_step, n - 1)
        self._rate_ub = np.tile(self._rate_step, n - 1)

    @property
    def rate_step(self) -> np.ndarray:
        """(2,) [m/s, rad/s] largest change of each input per step (the current rate bounds x dt)."""
        return self._rate_step

    def input_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(2N,) lower and upper input bounds of this step: the input bounds, the terminal stop
        and the reach from the previous input (all implied by the rate bounds)."""
        u_prev = np.tile(self._u_prev, self.N)
        z_ub = np.minimum(self._z_ub, u_prev + self._reach)
        z_lb = np.minimum(np.maximum(self._z_lb, u_prev - self._reach), z_ub)
        return z_lb, z_ub

    def derate(self, z_lb: np.ndarray, z_ub: np.ndarray, col: int, cap: float) -> np.ndarray:
        """Lower the bound of input ``col`` (0: v [m/s], 1: w [rad/s]) to ``|u| <= cap``, reached at
        the rate bound from the previous input (never asks for more than the rate allows).

        Updates ``z_ub`` (2N,) in place and returns the new ``z_lb`` (2N,), kept <= ``z_ub``.
        """
        u_prev = np.tile(self._u_prev, self.N)
        sl = slice(col, None, 2)
        z_ub[sl] = np.minimum(z_ub[sl], np.maximum(cap, u_prev[sl] - self._reach[sl]))
        z_lb[sl] = np.maximum(z_lb[sl], np.minimum(-cap, u_prev[sl] + self._reach[sl]))
        return np.minimum(z_lb, z_ub)

    # ------------------------------------------------------------ episode

    def reset(self, pose: np.ndarray, *, u_prev: np.ndarray | None = None, opening_turn: bool = True) -> None:
        """Start a new episode at ``pose`` (3,) [m, m, rad].

        Args:
            pose: (3,) [m, m, rad] start pose.
            u_prev: (2,) [m/s, rad/s] the input the robot is moving with (resuming in
                motion); None: at rest.
            opening_turn: allow the opening turn on the spot (``turn_in_place``) at the
                first step.
        """
        self._u_prev = np.zeros(2) if u_prev is None else np.asarray(u_prev, dtype=float).reshape(2).copy()
        self.adaptation.reset()
        if self.accel != self.limits.a_max:
            self._set_accel(self.limits.a_max)
        self._active: ActivePlan | None = None
        self._step_index = 0
        self._turning = opening_turn and self.config.turn_in_place is not None
        self.stats = MPCStats()
        self.unreachable = 0  # solves skipped: proved infeasible (_unreachable)
        self.last_failure_reason: str | None = None

    @property
    def failures(self) -> int:
        """Fallback steps of this episode."""
        return self.stats.failures

    @property
    def plan_inputs(self) -> np.ndarray | None:
        """(N, 2) [m/s, rad/s] the active plan's inputs (its first row was applied first), or None."""
        return None if self._active is None else self._active.u

    @property
    def u_prev(self) -> np.ndarray:
        """(2,) [m/s, rad/s] the input applied at the last step (zeros after ``reset``)."""
        return self._u_prev.copy()

    # ------------------------------------------------------------ the step

    def step(self, obs: Observation) -> Command:
        """Compute the command for the next period from the measured pose (wall time in ``solve_ms``)."""
        t0 = time.perf_counter()
        k_step = self._step_index
        self._step_index += 1
        x_meas = np.asarray(obs.pose, dtype=float).reshape(3)
        if obs.velocity is not None:
            self.adaptation.update(obs.velocity)
            a = self.adaptation.traction_accel(self.accel)
            if a != self.accel:
                self._set_accel(a)
        if not np.all(np.isfinite(x_meas)):
            return self._fallback(x_meas, t0, None, "bad_measurement")
        x_meas = self.adaptation.filter(x_meas, obs.velocity)
        x0 = self.adaptation.effective_state(x_meas)

        xr, ur = self.reference(x0)
        if self._turning:
            err = float(xr[0, 2] - x0[2])  # wrapped: the reference yaw is shifted to the measured branch
            limit = self.config.turn_in_place if k_step == 0 else self.config.turn_exit
            if abs(err) > limit and self.turn_allowed(x0):
                return self._turn_step(x0, t0, err)
            self._turning = False
        u_guess = self._guess_inputs()
        guess = rollout_np(x0, u_guess, self.dt)
        con = self.constrain(x0, xr, ur, guess)
        prob = self._pose(x0, con, u_guess, guess)
        if self.failure_injector is not None and self.failure_injector(k_step):
            return self._fallback(x0, t0, con.context, "injected", prob)
        if self.config.reach_check and (k := _unreachable(self, x0, con, prob)) is not None:
            return self._fallback(x0, t0, con.context, f"unreachable:stage={k}", prob)
        res, status, reason = self.solve(prob, x0)
        if status is None:
            return self._fallback(x0, t0, con.context, reason, prob)
        n = self.N
        xs = _rollout_of(self, res.z, x0)
        plan = ActivePlan(res.z.reshape(n, 2).copy(), 1, np.asarray(res.y, float), res.y_z)
        return self._accept(plan, xs, x0, t0, status, con.context)

    def _pose(self, x0: np.ndarray, con: Constraints, u_guess: np.ndarray, guess: np.ndarray) -> Problem:
        """Bounds (derated), parameters, initial guess and warm-start multipliers of this step."""
        z_lb, z_ub = self.input_bounds()
        fb_lb, fb_ub = z_lb.copy(), z_ub.copy()
        ad = self.adaptation
        cap = min(ad.speed_cap(con.excursion), ad.residual_cap(), ad.prediction_cap())
        if cap < self.limits.v_max:
            z_lb = self.derate(z_lb, z_ub, 0, cap)
        wcap = min(ad.residual_yaw_cap(), ad.prediction_yaw_cap())
        if wcap < self.limits.w_max:
            z_lb = self.derate(z_lb, z_ub, 1, wcap)
        if ad.config.fallback_derated:
            fb_lb, fb_ub = z_lb, z_ub
        g_lb = np.concatenate((con.pos_lb, self._rate_lb))
        g_ub = np.concatenate((con.pos_ub, self._rate_ub))
        p = self._p_buf.copy()
        sl = self._p_slices
        p[sl["x0"]] = x0
        p[sl["u_prev"]] = self._u_prev
        p[sl["x_ref"]] = con.x_ref.ravel()
        p[sl["u_ref"]] = con.u_ref.ravel()
        if sl["extra"].stop > sl["extra"].start:
            p[sl["extra"]] = con.extra
        z0 = np.clip(u_guess.ravel(), z_lb, z_ub)
        y0 = y_z0 = None
        if self._active is not None and self._active.next == 1 and self._active.y is not None:
            y0 = shift_multipliers(self.ocp, self._active.y, shift_rates=self.shift_rate_multipliers)
            y_z0 = shift_bound_multipliers(self._active.y_z)
        return Problem(p, z_lb, z_ub, g_lb, g_ub, z0, u_guess, guess, fb_lb, fb_ub, y0, y_z0, con.shift_bounds)

    def _guess_inputs(self) -> np.ndarray:
        """(N, 2) warm start: the rest of the active plan, then braking towards (0, 0)."""
        if self._active is None:
            return np.zeros((self.N, 2))
        return shift_inputs(self._active.u, self._active.next, self.N, self._rate_step, self._u_prev)

    # ------------------------------------------------------------ acceptance

    def violation(self, z: np.ndarray, xs: np.ndarray, prob: Problem) -> float:
        """Largest violation of any constraint of ``prob`` by the plan ``z`` (2N,) rolled out as ``xs``."""
        u = z.reshape(-1, 2)
        g = np.concatenate((self.position_rows(xs), np.diff(u, axis=0).ravel()))
        return max(
            float(np.max(prob.g_lb - g, initial=0.0)),
            float(np.max(g - prob.g_ub, initial=0.0)),
            float(np.max(prob.z_lb - z, initial=0.0)),
            float(np.max(z - prob.z_ub, initial=0.0)),
        )

    def acceptance(self, res: SolveResult, x0: np.ndarray, prob: Problem) -> tuple[str | None, str]:
        """``("ok" | "inexact" | None, reason)``: a solution is accepted when finite and within
        10x ``constraint_tol`` of every constraint, and converged (or ``accept_inexact``)."""
        z = res.z
        if not np.all(np.isfinite(z)):
            return None, f"nonfinite:{res.status}"
        self._rolled = (z, x0, xs := rollout_np(x0, z.reshape(self.N, 2), self.dt))  # see _rollout_of
        viol = self.violation(z, xs, prob)
        feasible = viol <= self._check_tol
        if res.converged and feasible:
            return "ok", ""
        if self.config.accept_inexact and feasible:
            return "inexact", ""
        return None, f"rejected:{res.status}:viol={viol:.2e}"

    def _accept(self, plan: ActivePlan, xs: np.ndarray, x0: np.ndarray, t0: float, status: str, context: Any) -> Command:
        """Make ``plan`` the active plan and send its first input (``xs`` (N+1, 3) its rollout from ``x0``)."""
        self._active = plan
        self.commit(context)
        self._u_prev = plan.u[0].copy()
        self.stats.count(status)
        rect_ids, margins = self.describe(xs, x0, context)
        v, w = self.adaptation.send(plan.u[0])
        return Command(v=v, w=w, solve_ms=(time.perf_counter() - t0) * 1e3, status=status, ok=True,
                       predicted=xs, rect_ids=rect_ids, margins=margins)

    # ------------------------------------------------------------ opening turn

    def turn_plan(self, err: float) -> np.ndarray:
        """(N, 2) inputs turning on the spot by ``err`` [rad] as fast as the bounds allow
        (:func:`turn_profile` from the previous yaw rate at the current rate bound)."""
        return turn_profile(err, float(self._u_prev[1]), float(self._rate_step[1]), self.limits.w_max, self.N, self.dt)

    def _turn_step(self, x0: np.ndarray, t0: float, err: float) -> Command:
        """One step of the opening turn on the spot (status ``"turn"``)."""
        u = self.turn_plan(err)
        xs = rollout_np(x0, u, self.dt)
        return self._accept(ActivePlan(u, 1), xs, x0, t0, "turn", self.turn_context(x0, xs))

    # ------------------------------------------------------------ fallback

    def shift_fits(self, prob: Problem) -> bool:
        """Whether the shifted previous plan ``prob.u_guess`` (N, 2), rolled out from the current
        state as ``prob.guess`` (N+1, 3), may still be followed: input and rate bounds
        (``prob.fb_lb``/``fb_ub``) within the acceptance tolerance, the position rows within
        it plus :attr:`position_slack`."""
        z = prob.u_guess.ravel()
        g = np.concatenate((self.position_rows(prob.guess), np.diff(prob.u_guess, axis=0).ravel()))
        tol = np.full(g.shape, self._check_tol)
        n_pos = len(g) - 2 * (self.N - 1)
        tol[:n_pos] += self.position_slack
        lb, ub = (prob.g_lb, prob.g_ub) if prob.shift_bounds is None else _with_rows(prob.shift_bounds, prob, n_pos)
        return bool(
            np.all(g >= lb - tol) and np.all(g <= ub + tol)
            and np.all(z >= prob.fb_lb - self._check_tol) and np.all(z <= prob.fb_ub + self._check_tol)
        )

    def brake_plan(self, x0: np.ndarray, prob: Problem | None = None) -> np.ndarray:
        """(N, 2) inputs braking at the rate limits, steering to the clearest side.

        The speed goes to zero at the rate bound from the previous input. The yaw rate ramps
        at its rate bound from the previous one towards each of 0, +-w_max / 2 and +-w_max
        (five candidates, :func:`brake_inputs`); each candidate is rolled out from ``x0``
        (3,) and scored by the smallest :meth:`clearance` of its positions (saturated at 5
        cm, so any candidate that stays 5 cm clear counts as good); the best wins, ties going
        to the first (yaw rate towards 0). Without a clearance the first candidate is taken.
        ``prob``: the step's problem when one was posed (unused here; a subclass may read
        it, see :class:`~sanav_mj.control.sensed_footprint.StraightBrakeSAMPC`).
        """
        n = self.N
        wm, gains = self.adaptation.brake_response(self.limits.w_max)
        best, best_score = None, -np.inf
        for target in (0.0, 0.5 * wm, -0.5 * wm, wm, -wm):
            u = brake_inputs(self._u_prev, self._rate_step, n, target)
            if not np.all(np.isfinite(x0)):
                return u
            xs = rollout_np(x0, u if gains is None else u * gains, self.dt)
            slack = self.state_clearance(xs[1:])
            if slack is None:
                return u
            score = min(float(slack.min()), 0.05)
            if score > best_score + 1e-9:
                best, best_score = u, score
        return best

    def _fallback(self, x0: np.ndarray, t0: float, context: Any, reason: str, prob: Problem | None = None) -> Command:
        """Apply the next input of the active plan if it still fits the current problem, else
        brake (``fallback_brake``); ``fallback_brake=False`` replays the old plan open loop."""
        a = self._active
        rest = None
        if a is not None and not a.brake and a.next < len(a.u):
            shift_ok = not self.config.fallback_brake
            if not shift_ok and prob is not None:
                shift_ok = self.shift_fits(prob)
            if shift_ok:
                u = a.u[a.next].copy()
                a.next += 1
                a.y = None
                a.y_z = None
                status = "fallback_shift"
                rest = a.u[a.next - 1 :]
        if rest is None:
            if self.config.fallback_brake:
                plan = self.brake_plan(x0, prob)
                u = plan[0].copy()
                self._active = ActivePlan(plan, 1, brake=True)
                rest = plan
            else:
                u = np.sign(self._u_prev) * np.maximum(np.abs(self._u_prev) - self._rate_step, 0.0)
                self._active = None
                rest = u[None, :]
            status = "fallback_stop"
        u = np.clip(np.nan_to_num(u), self.limits.lower(), self.limits.upper())
        self._u_prev = u
        if context is not None:
            self.commit(context)
        self.stats.count(status)
        self.last_failure_reason = reason
        predicted = rollout_np(x0, rest, self.dt) if np.all(np.isfinite(x0)) else None
        v, w = self.adaptation.send(u)
        return Command(v=v, w=w, solve_ms=(time.perf_counter() - t0) * 1e3, status=status, ok=False,
                       predicted=predicted, rect_ids=None, margins=None)
