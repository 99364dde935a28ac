"""Safe-area MPC (SA-MPC, paper Sec. III-D/E): track the reference inside the safe rectangles.

The optimisation problem is the shared tracking NLP of :mod:`sanav_mj.control.problem` with

- hard stage boxes ``A_k p_k <= b_k`` (k = 1..N) built from the safe areas of the corridor
  (see "Stage boxes" in :class:`SAMPC`), passed as bounds of the position rows of ``g``;
- the paper's soft penalty ``J_SA(p) = prod_n sum_m [q_SA(n) h_nm(p)]_-^2`` over the safe areas
  around the horizon (:class:`SafeAreaPenalty`), added for k = 1..N;
- input bounds, input-rate bounds against the previously applied input, and (by default) a
  terminal stop ``v_{N-1} = 0``.
"""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sanav_mj.control.adaptation import PlantAdaptation
from sanav_mj.control.assign_kernel import assign_discs, relax_discs
from sanav_mj.control.config import MPCConfig
from sanav_mj.control.disc_stages import (
    DiscCover,
    StallEscape,
    footprint_reference,
    member_chain_of,
    next_stop,
    sa_params_of_ids,
)
from sanav_mj.control.prediction import PredictionMonitor
from sanav_mj.control.problem import build_tracking_ocp
from sanav_mj.control.stages import (
    CorridorChain,
    SafeAreaPenalty,
    _outside_sq,
    assign_stages,
    box_slack,
    chain_slack,
    exit_targets,
    feasible_from_bits,
    first_candidates,
    relax_boxes,
    safe_area_params,
    shrink_box,
    stage_boxes,
    stage_rect_ids,
)
from sanav_mj.control.tracking import Constraints, TrackingMPC
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.scene import RobotParams

__all__ = ["SAMPC", "MPCConfig", "StepInfo", "SafeAreaPenalty"]

#: [m/s], [rad/s]: a previous input below both is "at rest" (the capped relaxation then
#: follows the measured disc centres, :func:`_tightening`).
REST_V, REST_W = 0.02, 0.05

#: [m] :func:`assign_stages`' ``reanchor_distance`` (its default, which SA-MPC uses).
REANCHOR_M = float(inspect.signature(assign_stages).parameters["reanchor_distance"].default)

#: [m] disc-centre distance (position and sweep x yaw) within which the robot has reached a
#: stop of a pose route's reference (see :meth:`SAMPC.reference`).
STOP_REACHED_M = 0.02


def _resample(ref: Reference, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference states (K', 3), inputs (K', 2) and areas (K',) resampled to period ``dt`` [s].

    States and inputs are interpolated linearly in time; each new sample takes the area of
    the nearest original sample.
    """
    k = len(ref)
    if abs(ref.dt - dt) <= 1e-9 * dt:
        return np.asarray(ref.states, float), np.asarray(ref.inputs, float), np.asarray(ref.area, int)
    t = np.arange(k) * ref.dt
    tn = np.arange(0.0, t[-1] + 1e-9, dt)
    states = np.stack([np.interp(tn, t, ref.states[:, i]) for i in range(3)], axis=1)
    inputs = np.stack([np.interp(tn, t, ref.inputs[:, i]) for i in range(2)], axis=1)
    area = np.asarray(ref.area, int)[np.minimum(np.rint(tn / ref.dt).astype(int), k - 1)]
    return states, inputs, area


def _plan_tables(areas: SafeAreas, plan: Plan, box_margin: float, dt: float):
    """The corridor chain, reference states (K', 3) and inputs (K', 2) at period ``dt`` [s],
    and the chain index (2 x corridor position, -1 off the corridor) of each sample's area."""
    chain = CorridorChain.build(areas, plan.corridor, box_margin)
    states, inputs, ref_area = _resample(plan.reference, dt)
    corridor = np.asarray(plan.corridor, int)
    if len(set(corridor.tolist())) == corridor.size:
        pos = {int(a): 2 * i for i, a in enumerate(corridor)}
        return chain, states, inputs, np.array([pos.get(int(a), -1) for a in ref_area], dtype=int)
    # an area repeats (a pose route that backs up): each sample takes the first occurrence
    # of its area at or after the previous sample's position
    out, j = np.full(len(ref_area), -1, dtype=int), 0
    for k, a in enumerate(np.asarray(ref_area, int)):
        hit = np.flatnonzero(corridor[j:] == a)
        if hit.size:
            j += int(hit[0])
            out[k] = 2 * j
    return chain, states, inputs, out


def _disc_constraints(ctl: SAMPC, x0: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray, guess: np.ndarray) -> Constraints:
    """:meth:`SAMPC.constrain` in ``"discs"`` mode: per-disc stages; exit targets and J_SA
    slots of the chain (the corridor reference itself moved to poses whose disc centres fit
    the chain, :func:`~sanav_mj.control.disc_stages.footprint_reference`; keeping the
    targets as planned instead, without exit targets, collided at the envelope corner:
    barn_0061, 5.8 cm excursion), or for a pose route (one chain per disc) the planned
    targets and the areas every disc's assignment spans (:mod:`sanav_mj.control.disc_stages`). With
    ``PredictionDerating.tighten`` the disc rows' boxes are shrunk by the measured one-step
    prediction error and their widening is capped at the untightened boxes while the robot
    moves (:func:`~sanav_mj.control.stages.tighten_relax`; the argument and its assumptions
    in :mod:`sanav_mj.control.prediction`); the shift check reads :func:`_shift_bounds`."""
    tight = _tightening(ctl)
    if ctl.disc_chains is None:  # one chain for every disc: the vectorised twins (exact)
        pts = ctl.discs.centres(guess)
        ss, plain = _assign_shared(ctl.chain, ctl._both, pts, ctl._s_prev_d, ctl._check_tol)
        bs, excursion = _relax_all(plain, pts[0], tight)
    else:
        ss, plain, pts = ctl.discs.assign(ctl._chains(), guess, ctl._s_prev_d, ctl._check_tol)
        bs, excursion = ctl.discs.relax(plain, pts[0], tight)
    c = ctl.discs.centre
    if ctl.disc_chains is None:
        xr, ur = exit_targets(ctl.chain, ctl._ref_chain[ctl._horizon_idx], x_ref, u_ref, ss[c], x0[:2], float(x0[2]))
        theta = ctl._sa_params(np.array([ss[:, 0].min(), ss[:, -1].max()]))
    else:  # a pose route: its reference walks every disc's chain; targets stay as planned
        xr, ur = x_ref, u_ref
        theta = sa_params_of_ids(ctl._rects, DiscCover.area_ids(ctl.disc_chains, ss), ctl.penalty.n_slots,
                                 ctl._q_sa, ctl.config.stage_box_margin)
    shift = None if tight is None else _shift_bounds(plain, pts[0], tight[1])
    return Constraints(*DiscCover.bounds(bs), theta, xr, ur, excursion, (ss[c], bs[c], ss, bs), shift)


def _tightening(ctl: SAMPC) -> tuple[float, bool] | None:
    """``"discs"`` mode: ``(delta, follow)`` for :func:`~sanav_mj.control.stages.tighten_relax`
    (``delta`` [m] the prediction monitor's
    :meth:`~sanav_mj.control.prediction.PredictionMonitor.tightening`, ``follow`` while the
    previous input is at rest), or None (no monitor or ``tighten`` off)."""
    mon = ctl.adaptation.prediction
    if mon is None or not mon.config.tighten:
        return None
    u = ctl._u_prev
    return mon.tightening(), bool(abs(u[0]) < REST_V and abs(u[1]) < REST_W)


def _shift_bounds(plain: np.ndarray, pts0: np.ndarray, follow: bool) -> tuple[np.ndarray, np.ndarray]:
    """``"discs"`` mode with the tightening: the row bounds the fallback's shift check reads
    (:attr:`~sanav_mj.control.tracking.Constraints.shift_bounds`): the stage boxes ``plain``
    (D, N+1, 4) [m] of this step's assignments (:meth:`DiscCover.assign`) *without* the
    tightening and without relaxation (relaxed towards the stage-0 centres ``pts0`` (D, 2)
    [m] only at rest, ``follow``), grown by ``box_margin`` in the check as always. The
    shifted plan is so followed while its disc centres stay in the chain members (the safe
    areas), whatever the tightening: a jump of the error bound does not turn a plan that
    still fits the safe areas into a braking manoeuvre (the braking steps were where the
    corner runs left their safe areas), and the shift cannot follow the robot out (an
    uncapped relaxation here let a nominal run creep 3 cm out over 17 shifted steps,
    barn_0026)."""
    if follow:
        plain = _relax_all(plain, pts0, None)[0]
    return DiscCover.bounds(plain)


def _disc_rows(ctl: SAMPC, xs: np.ndarray) -> np.ndarray:
    """:meth:`SAMPC.position_rows` in ``"discs"`` mode: the disc centres of stages 1..N of
    the rollout ``xs`` (N+1, 3) as rows (2DN,) [m]; the centres of all of ``xs`` are kept
    for :func:`_plan_centres` (the acceptance's rollout is the plan ``describe`` reports)."""
    pts = ctl.discs.centres(xs)
    ctl._centres_of = (xs, pts)
    return pts[1:].ravel()


def _plan_centres(ctl: SAMPC, xs: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """(N+1, D, 2) [m] disc centres of ``x0`` (3,) and the states ``xs[1:]`` (N, 3): those
    :func:`_disc_rows` computed for this very ``xs`` when its first state is ``x0`` bit for
    bit (the acceptance's rollout from ``x0``), else computed."""
    kept = ctl._centres_of
    if kept is not None and kept[0] is xs and xs[0].tobytes() == np.asarray(x0, dtype=float).tobytes():
        return kept[1]
    return ctl.discs.centres(np.vstack((x0[None], xs[1:])))


def _disc_margins(pts: np.ndarray, bs: np.ndarray) -> np.ndarray:
    """:meth:`DiscCover.margins` from the disc centres ``pts`` (K, D, 2) [m] and the boxes
    ``bs`` (D, K, 4) [m], vectorised over the discs (the same minima in the same order):
    (K,) [m] the smallest slack of any centre in its own box."""
    p = pts.transpose(1, 0, 2)
    return np.concatenate((p - bs[..., :2], bs[..., 2:] - p), axis=2).min(axis=2).min(axis=0)


def _assign_shared(chain: CorridorChain, both: np.ndarray, pts: np.ndarray, s_prev: np.ndarray | None,
                   tol: float) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`DiscCover.assign` when every disc walks the same ``chain`` (not a pose route),
    vectorised over the discs with the same arithmetic: assignments (D, N+1) and their stage
    boxes (D, N+1, 4) [m] of the disc centres ``pts`` (N+1, D, 2) [m]. ``both`` (2L, 4) is
    ``chain.stay`` and ``chain.advance`` stacked (:func:`assign_stages`' table, built once per
    plan); ``s_prev`` (D, N+1) or None the previous assignments; ``tol`` [m] as in
    :func:`assign_stages`. The distances of all centres to all members come from one call;
    each disc's assignment from the bit sets of :func:`~sanav_mj.control.stages.assign_feasible`
    (the fast path of :func:`assign_stages`; :func:`feasible_from_bits`), or from
    :func:`assign_stages` itself when no assignment fits."""
    n1, n_d = pts.shape[:2]
    n_m = len(chain)
    fast = assign_discs(both, n_m, pts, s_prev, tol, REANCHOR_M)
    if fast is not None:  # the same in one C call (sanav_mj.control.assign_kernel)
        ss, plain, ok, _ = fast
        if ok.all():
            return ss, plain
        for d in np.flatnonzero(~ok):  # no zero-violation assignment: the dynamic programme
            ss[d] = assign_stages(chain, pts[:, d], first_candidates(n_m, None if s_prev is None else s_prev[d]),
                                  tol=tol)
        return ss, _stage_boxes_of(chain, ss)
    d2 = _outside_sq(pts.transpose(1, 0, 2).reshape(-1, 2), both).reshape(n_d, n1, 2 * n_m)
    d2[d2 < tol * tol] = 0.0
    ss = np.empty((n_d, n1), dtype=int)
    if n_m <= 62:  # assign_feasible's bit sets of all discs at once
        weights = np.left_shift(np.int64(1), np.arange(n_m, dtype=np.int64))
        zero = d2 == 0.0
        stay, adv = (zero[..., :n_m] @ weights).tolist(), (zero[..., n_m:] @ weights).tolist()
    last = None  # (bit sets, mask, assignment) of the previous disc
    for d in range(n_d):
        cand = first_candidates(n_m, None if s_prev is None else s_prev[d])
        s = None
        if n_m <= 62:
            mask = None
            if cand is not None and np.min(d2[d, 0, :n_m][cand]) <= REANCHOR_M**2:
                mask = int(cand.astype(np.int64) @ weights)
            if last is not None and last[0] == stay[d] and last[1] == adv[d] and last[2] == mask:
                s = last[3]  # the same bit sets (discs in the same members): the same answer
            else:
                s = feasible_from_bits(stay[d], adv[d], mask)
                last = (stay[d], adv[d], mask, s)
        ss[d] = assign_stages(chain, pts[:, d], cand, tol=tol) if s is None else s
    return ss, _stage_boxes_of(chain, ss)


def _assign_point(chain: CorridorChain, both: np.ndarray, guess: np.ndarray, s_prev: np.ndarray | None,
                  tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``"disc"`` mode: :func:`assign_stages` of the guessed positions ``guess[:, :2]`` (N+1, 2)
    [m] from the candidates around ``s_prev`` (N+1,) (or None) and the stage boxes (N+1, 4)
    [m] (:func:`stage_boxes`): the assignment (N+1,) int and its boxes. A zero-violation
    assignment comes from the compiled kernel (:func:`assign_discs` with one point per
    stage: the same distances, tests and bit sets as :func:`assign_stages`' fast path);
    otherwise, or without the kernel, :func:`assign_stages` itself."""
    fast = assign_discs(both, len(chain), guess[:, None, :2], None if s_prev is None else s_prev[None], tol,
                        REANCHOR_M)
    if fast is not None and fast[2][0]:
        return fast[0][0], fast[1][0]
    s = assign_stages(chain, guess[:, :2], first_candidates(len(chain), s_prev), tol=tol)
    return s, stage_boxes(chain, s)


def _stage_boxes_of(chain: CorridorChain, ss: np.ndarray) -> np.ndarray:
    """(D, N+1, 4) [m] the unrelaxed stage boxes of assignments ``ss`` (D, N+1): the stay box
    of each stage's member, its advance box where the assignment advances."""
    plain = chain.stay[ss]
    adv = np.diff(ss, axis=1) > 0
    plain[:, 1:][adv] = chain.advance[ss[:, 1:][adv]]
    return plain


def _relax_all(plain: np.ndarray, pts0: np.ndarray, tighten: tuple[float, bool] | None) -> tuple[np.ndarray, float]:
    """:meth:`DiscCover.relax` vectorised over the discs with the same arithmetic: the stage
    boxes (D, N+1, 4) [m] from ``plain`` (D, N+1, 4) [m] relaxed around each disc's stage-0
    centre ``pts0`` (D, 2) [m] (:func:`relax_boxes`), or with ``tighten`` ``(delta, follow)``
    tightened with a capped relaxation (:func:`~sanav_mj.control.stages.tighten_relax`), and
    the largest excursion [m] of a stage-0 centre. In one C call when the kernel is
    available (:func:`~sanav_mj.control.assign_kernel.relax_discs`)."""
    fast = relax_discs(plain, pts0, tighten)
    if fast is not None:
        return fast
    exc0 = plain[:, 0]
    below = np.maximum(exc0[:, :2] - pts0, 0.0)
    above = np.maximum(pts0 - exc0[:, 2:], 0.0)
    e = np.hypot(*(below + above).T)
    excursion = max(0.0, float(np.max(e)))
    if tighten is None:
        t = plain
    else:
        delta, follow = tighten
        t = shrink_box(plain, delta) if delta > 0 else plain.copy()
        below = np.maximum(t[:, 0, :2] - pts0, 0.0)
        above = np.maximum(pts0 - t[:, 0, 2:], 0.0)
    moved = np.flatnonzero(below.any(axis=1) | above.any(axis=1))
    out = t.copy() if tighten is None else t
    if moved.size:  # only the discs whose centre lies beyond its stage-0 box (as relax_boxes)
        out[moved, 1:, :2] -= below[moved, None, :]
        out[moved, 1:, 2:] += above[moved, None, :]
    if tighten is not None and not tighten[1]:
        out[:, 1:, :2] = np.maximum(out[:, 1:, :2], plain[:, 1:, :2])
        out[:, 1:, 2:] = np.minimum(out[:, 1:, 2:], plain[:, 1:, 2:])
    return out, excursion


def _route_tables(ctl: SAMPC, areas: SafeAreas, plan: Plan, box_margin: float, dt: float):
    """:func:`_pose_route_tables` and the reference states and inputs ``ctl`` follows: in
    ``"discs"`` mode with a corridor reference moved to poses whose disc centres stay in the
    chain (:func:`~sanav_mj.control.disc_stages.footprint_reference`), else as tabled."""
    stops, chains = _pose_route_tables(areas, plan, box_margin, dt)
    if ctl.discs is None or chains is not None:
        return stops, chains, ctl.ref_states, ctl.ref_inputs
    return (stops, chains, *footprint_reference(ctl.discs, ctl.chain, ctl.ref_states, ctl.ref_inputs, dt))


def _pose_route_tables(areas: SafeAreas, plan: Plan, box_margin: float, dt: float):
    """A pose route's stops (S,) int at period ``dt`` [s] and one chain per disc; (None,
    None) for other plans (the horizon never holds; one chain for all discs)."""
    st, dc = plan.reference.stops, getattr(plan, "disc_corridors", None)
    stops = None if st is None else np.unique(np.rint(np.asarray(st, float) * plan.reference.dt / dt).astype(int))
    grow = float(plan.info.get("grown_members", 0.0))
    ex, ea = getattr(plan, "extra_members", None), getattr(plan, "extra_areas", None)
    return stops, (None if dc is None else [member_chain_of(areas, c, box_margin, grow, ex, ea) for c in dc])


def _nearest_sample(ref_states: np.ndarray, lo: int, hi: int, pos: np.ndarray, sweep: float | None,
                    stops: np.ndarray | None) -> int:
    """Index of the reference sample in ``[lo, hi)`` nearest ``pos`` (2,) [m]; with ``sweep``
    [m], nearest the pose ``pos`` (3,) in disc-centre distance ``|dp|^2 + (sweep dyaw)^2``;
    with ``stops``, not past the next stop, and the stop itself once within
    :data:`STOP_REACHED_M` of it."""
    stop = next_stop(stops, lo)
    if stop is not None:
        hi = min(hi, stop + 1)
    seg = ref_states[lo:hi, :2] - pos[:2]
    d2 = np.einsum("ij,ij->i", seg, seg)
    if sweep is not None:
        dyaw = (ref_states[lo:hi, 2] - pos[2] + np.pi) % (2 * np.pi) - np.pi
        d2 = d2 + (sweep * dyaw) ** 2
    i = lo + int(np.argmin(d2))
    if stop is not None and i < stop < hi and d2[stop - lo] < STOP_REACHED_M**2:
        i = stop  # arrived at the stop: the motion after it comes into view
    return i


def _horizon_indices(i: int, n: int, k: int, stops: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Reference sample indices (n+1,) of the horizon from sample ``i`` of ``k`` (the last
    held) and which are held at the next stop (n+1,) bool (their inputs are zero)."""
    idx = np.minimum(np.arange(i, i + n + 1), k - 1)
    stop = next_stop(stops, i)
    if stop is None:
        return idx, np.zeros(idx.size, dtype=bool)
    return np.minimum(idx, stop), np.arange(i, i + n + 1) >= stop


@dataclass(frozen=True)
class StepInfo:
    """The problem data of the last step (for inspection, recording and tests).

    Attributes:
        assignment: (N+1,) int chain member of each stage.
        boxes: (N+1, 4) [m] stage boxes as imposed (shrunk, relaxed); row 0 is the box of
            the measured position (not a constraint).
        guess: (N, 2) [m/s, rad/s] warm-start inputs (the shifted previous plan).
        guess_states: (N+1, 3) [m, m, rad] the warm start rolled out from the measured state.
        x_ref: (N+1, 3) [m, m, rad] reference states over the horizon.
        u_ref: (N, 2) [m/s, rad/s] reference inputs.
        u_prev: (2,) [m/s, rad/s] previously applied input.
        input_lower, input_upper: (N, 2) input bounds including the rate bound of u_0 and
            the terminal stop.
        rate_step: (2,) [m/s, rad/s] largest change of each input per step.
    """

    assignment: np.ndarray
    boxes: np.ndarray
    guess: np.ndarray
    guess_states: np.ndarray
    x_ref: np.ndarray
    u_ref: np.ndarray
    u_prev: np.ndarray
    input_lower: np.ndarray
    input_upper: np.ndarray
    rate_step: np.ndarray


class SAMPC(TrackingMPC):
    """Safe-area MPC controller (the paper's Sec. III-D/E) implementing the Controller protocol.

    The step skeleton, bounds, warm start, acceptance, fallback, opening turn and command are
    the core's (:class:`~sanav_mj.control.tracking.TrackingMPC`); the plant adaptation
    (monitor, pose filter, latency compensation, derating, traction limit) is
    :class:`~sanav_mj.control.adaptation.PlantAdaptation`. This class adds the safe-area
    constraints and cost (:meth:`constrain`: stage assignment, stage boxes, J_SA slots, exit
    targets). With ``MPCConfig.footprint="discs"`` the OCP's position rows are the centres of
    the footprint's disc cover (:mod:`sanav_mj.control.footprint`) instead of the position,
    each centre with its own stage assignment and boxes in a map inflated by the disc radius
    (see :meth:`constrain`, :meth:`turn_allowed`); docs/results.md ("Tight spaces") gives
    what it measured.

    **Pose route** (``Plan.disc_corridors`` set): see :mod:`sanav_mj.control.disc_stages`.

    Each step: update the actuation monitor with the measured velocity, filter the measured
    pose with the measured velocity, predict the state
    at which the new command takes effect (latency compensation), find the progress along
    the reference, build the stage boxes, bound the speed by the excursion and the
    tracking residual, solve the NLP (:mod:`sanav_mj.control.problem`) warm-started from the
    shifted previous plan, check the result, apply the first input (or a fallback).

    **Stage boxes.** The corridor ``c_0..c_{C-1}`` gives the chain ``R_0, B_01, R_1, ...``
    (:class:`CorridorChain`) where ``B_ij`` is a bridge box inside ``R_i ∪ R_j`` crossing
    their common portal; consecutive members intersect with positive area. A monotone
    assignment ``s(k)``, ``s(k) - s(k-1) in {0, 1}``, of members to stages gives the stage sets
    ``S_k = C_{s(k-1)} ∩ C_{s(k)}`` (``S_k = C_{s(k)}`` when ``s`` stays); the constraint
    ``A_k p_k <= b_k`` is ``p_k in shrink(S_k)`` for k = 1..N, each box shrunk by
    ``box_margin`` (at most a quarter of its width). ``s`` is chosen by
    :func:`assign_stages` for the guessed trajectory (the shifted previous plan rolled out
    from the measured state): the assignment under which the guess violates the boxes
    least, advancing as early as it allows.

    **Targets beyond the assigned area.** A stage whose reference sample lies in a corridor
    area *ahead* of the stage's chain member cannot reach it; its position target is the
    reference sample projected onto the central half of the exit region of the member,
    ``shrink(C_{s(k)} ∩ C_{s(k)+1})``, and its yaw target the bearing from the robot to that
    point (when it is more than 2 cm away). Without this the far reference pulls the plan
    against the nearest wall of the current area, which in a narrow passage need not touch
    the portal to the next one: the plan stops at the wall, the assignment never advances
    and the robot stalls (seen on ``v_shape``, where the corridor threads 5-15 cm slivers).
    With it the plan heads for the portal, the guess enters the intersection and the
    assignment advances next step. The reference *inputs* of such stages are zero: the
    target stands still, and the reference's own speed there (it belongs to a sample beyond
    the portal) made the optimal plan drive through the target and out of the thin
    intersection, so the guess never fitted the next member and the assignment never
    advanced; the plan then kept postponing its motion and the robot stalled for good
    (4 of 100 generated clutter maps, e.g. a 10 cm portal entered at right angles).

    **Implied input bounds.** The rate bounds and the terminal stop imply simple bounds on
    each input: ``|u_k - u_prev| <= (k + 1) rate_step`` (reachable from the previous input)
    and ``|v_k| <= (N - 1 - k) a_max dt`` (able to stop by the last stage). They are passed
    as variable bounds together with the input bounds. They remove no feasible plan (every
    plan satisfying the rate bounds and the terminal stop satisfies them), so the problem
    and its optimum are unchanged; but PANOC/PANTR handle variable bounds by projection,
    exactly and at no cost, whereas the rate rows go through the augmented Lagrangian. In
    cruise every plan brakes to its terminal stop at the rate bound over its last stages,
    and after a standstill it accelerates at it: with the implied bounds those active rate
    rows no longer need multipliers. Measured on the MuJoCo step time (five scenarios x 10
    seeds, CPU): PANTR mean -16 %, 99th percentile -18 %; PANOC mean -37 %, 99th
    percentile -19 % (docs/benchmarks.md).

    **Safety between samples.** ``p_k in S_k ⊂ C_{s(k)}`` and ``p_{k+1} in S_{k+1} ⊂ C_{s(k)}``,
    so the chord ``[p_k, p_{k+1}]`` lies in the convex member ``C_{s(k)}``, which lies in the
    union of safe areas. The nominal robot drives an arc, not the chord; the arc stays within
    ``|v w| dt^2 / 8`` of it (:func:`~sanav_mj.control.unicycle.arc_chord_deviation`, 1.5 mm
    at 0.6 m/s and 2 rad/s with dt = 0.1 s), which the obstacle inflation margin of the
    safe-area map has to cover. For k = 0 the position is the measurement, a parameter: if
    it lies within ``S_0 = shrink(C_{s(0)})`` the argument holds from the first sample on.

    **Measured position outside its box** (noise, slip, mismatch): p_0 cannot be constrained,
    and requiring ``p_1`` inside a box that a robot at rest cannot reach in one step would
    make the problem infeasible (a unicycle needs time to move sideways). Each side of the
    boxes of stages 1..N is widened by the amount p_0 lies beyond that side of its own box
    ``S_0``: the plan may not go further out than the robot already is, staying put is
    feasible for a robot at rest, and J_SA (zero inside the corridor's areas, which are
    shrunk by the same margin) together with the tracking cost pulls the plan back in. The
    widening is re-measured every step, so it vanishes once the robot is back inside; it
    never exceeds the measured excursion, which lies inside the real safe area as long as
    it is smaller than ``box_margin``. Because an excursion is evidence that the model is
    wrong, the speed bound of every stage is lowered at the same time, to
    ``v_max max(derate_floor, 1 - e / excursion_stop)`` for an excursion ``e`` (reached at
    the rate bound from the previous input, so the bounds stay consistent): the further
    out, the slower, which shortens the stopping distance and the distance driven on a
    wrong model before the next measurement. (``"discs"`` mode: :func:`_disc_constraints`.)

    **Derating by tracking residual, traction limit, pose filter, latency compensation**: the
    plant adaptation's mechanisms, described with their measurements in
    :mod:`sanav_mj.control.adaptation`.

    **Recursive feasibility** (nominal model, no disturbance, converged solves, the default
    ``terminal_stop``): let ``u*`` be the previous plan with positions ``p*_0..p*_N`` and
    assignment ``s*``. The next measured state is ``x*_1``. The shifted plan
    ``(u*_1, ..., u*_{N-1}, (0, w'))``, with ``w'`` the last yaw rate brought towards 0 by one
    rate step, satisfies the input bounds, the rate bounds (same increments; ``u*_1 - u*_0``
    against the new previous input ``u*_0``) and the terminal stop (its last speed is 0). Its
    positions are ``p*_1..p*_N, p*_N`` (``v*_{N-1} = 0``, so the last step only turns), which
    satisfy the boxes of the shifted assignment ``s*(1..N), s*(N)``: that assignment has zero
    violation, so the minimiser chosen by :func:`assign_stages` also has zero violation and
    the shifted plan is feasible for the new problem. Without ``terminal_stop`` the last
    shifted position may leave the last box and feasibility is not guaranteed. With model
    mismatch, noise or an inexact solve none of this is guaranteed; the relaxation above
    and the fallback cover those cases.

    **Fallback.** A solve is rejected when the back-end does not converge (unless
    ``accept_inexact`` and the iterate satisfies every constraint), returns non-finite
    values, or the rolled-out plan violates a constraint by more than 10x
    ``constraint_tol``. With ``fallback_brake`` (default) the rest of the previous plan
    (the warm start, ending at rest) is then rolled out from the *current* state and
    checked against the current problem (:meth:`shift_fits`): input and rate bounds as
    posed (with the speed and yaw-rate derating when ``fallback_derated``), positions
    inside their stage boxes grown back by
    ``box_margin``, i.e. inside the chain members and so inside the safe areas. If it
    passes, its first input is applied (status ``"fallback_shift"``; without mismatch this
    is the recursive-feasibility case). Accepting the shift up to the margin matters in
    slivers a few cm wide: braking there instead (a 5 % geometry error was enough to make
    the shifted plan miss a 1 cm wide stage box) left the robot stopped in a place from
    which the MPC did not restart (7 of 8 ``v_shape`` runs at wheel radius 1.05 / track
    0.9, docs/robustness.md). Otherwise the robot
    brakes (status ``"fallback_stop"``, re-planned every step from the current state): the
    speed goes to zero at the rate bound while the yaw rate ramps at its rate bound towards
    the one of five candidates (0, +-w_max/2, +-w_max) whose braking path stays deepest
    inside the corridor's chain members (:meth:`brake_plan`). It never replays an old plan
    that the current state contradicts: under mismatch that open-loop replay at speed was
    the last step before most collisions (docs/robustness.md). With ``fallback_brake=False``
    the previous plan is replayed open loop until it runs out, then the robot brakes
    straight. Commands are always finite.

    **What the mismatch handling assumes, and what it does not give.** Nothing above is a
    guarantee under mismatch: the stage boxes constrain the *model's* prediction. What the
    mechanisms give is that model error is met by going slower (excursion derating),
    planning from where the robot will be when the command acts (latency compensation) and
    stopping instead of replaying (fallback). A plant that cannot follow the braking the
    model assumes (``a_max``; e.g. at very low friction or a small torque limit) before
    the monitor has seen it slip (see "Traction limit"), or a
    position error larger than ``box_margin`` plus the map's inflation margin within one
    period can still collide; docs/robustness.md gives the measured envelope.

    **Opening turn.** With a random initial yaw the robot often starts facing away from the
    reference. Posed to the MPC, that start is the hardest problem of the episode: the
    optimal plan turns on the spot at the yaw-acceleration bound with most rate constraints
    active, and PANOC needed 1000-1900 iterations (20-57 ms) for it. As is standard practice,
    the controller instead starts the episode with a dedicated turn on the spot when the
    heading error to the reference (at the robot's progress index) exceeds
    ``turn_in_place``, until it is at most ``turn_exit``; then the MPC takes over, warm
    started with the rest of the turn. Each turn step plans ``v = 0`` and the time-optimal
    rest-to-rest yaw-rate profile within the input and rate bounds (:meth:`turn_plan`), so
    every constraint of the MPC problem holds for that plan: the position stays where it
    is, hence inside the stage box of the measured position, the plan ends at rest
    (terminal stop), and it is a feasible shifted plan for the MPC's first problem. The
    commands have status ``"turn"`` and the same prediction, rectangle ids and margins as
    an MPC step.

    Attributes:
        name: ``"sa-mpc"``.
        dt: [s] control period.
        needs_ranges: False.
        config, robot, limits: settings and resolved input limits.
        chain: the corridor chain.
        adaptation: the :class:`~sanav_mj.control.adaptation.PlantAdaptation` (its
            ``monitor``: identified delay, gains and tracking residual of the episode; its
            ``pose_filter``; the derating caps and the traction limit).
        monitor: ``adaptation.monitor``.
        stats: per-episode status counts (``stats.failures`` counts fallback steps).
        last: :class:`StepInfo` of the last step that reached the solver stage, or None.
        last_failure_reason: why the last fallback was taken, or None.
        accel: [m/s^2] the current rate bound of the speed: ``limits.a_max``, lowered while
            the monitor sees slip (see "Traction limit").
        build_s: [s] time spent building this controller (including the solver back-end).
    """

    name = "sa-mpc"
    needs_ranges = False
    #: multipliers of the rate rows stay at their stages (see ``shift_multipliers``).
    shift_rate_multipliers = False

    def __init__(
        self,
        robot: RobotParams,
        areas: SafeAreas,
        plan: Plan,
        config: MPCConfig = MPCConfig(),
        *,
        footprint=None,
        failure_injector: Callable[[int], bool] | None = None,
    ):
        """Build the controller (and its solver, once per process).

        Args:
            robot: nominal robot parameters (input and rate bounds by default, half track).
            areas: the safe areas.
            plan: a successful plan (corridor and reference).
            config: settings.
            footprint: the robot's footprint rectangle
                (:class:`sanav_mj.footprint.Footprint`), required when ``config.footprint``
                is ``"discs"`` (its disc cover gives the constrained points), else unused.
            failure_injector: test hook called with the step index; returning True makes
                that step's solve count as failed.

        Raises:
            ValueError: the plan failed or has no reference, the corridor is not a chain
                of adjacent safe areas, or ``"discs"`` without a footprint.
        """
        t0 = time.perf_counter()
        if not plan.ok or plan.reference is None:
            raise ValueError(f"plan must be successful with a reference, got ok={plan.ok} reason={plan.reason!r}")
        if len(plan.reference) < 1:
            raise ValueError("plan.reference must hold at least one sample")
        limits = config.limits(robot)
        dt = float(config.dt)
        adaptation = PlantAdaptation(robot, dt, limits.v_max, limits.w_max, limits.a_max,
                                     limits.lower(), limits.upper(), config.adaptation)
        self.penalty = SafeAreaPenalty(len(config.q_sa))
        self.discs: DiscCover | None = None
        if config.footprint == "discs":
            if footprint is None:
                raise ValueError("footprint: MPCConfig.footprint='discs' needs the robot's Footprint, got None")
            self.discs = DiscCover.of(footprint, config.footprint_discs)
            self._escape = StallEscape(config.horizon)
        self._set_plan(areas, plan, config.stage_box_margin, dt)
        pts = None if self.discs is None else self.discs.offsets
        ocp = build_tracking_ocp(config.horizon, dt, self.penalty, position_constraints=True, points=pts)
        super().__init__(robot, config, limits, ocp, adaptation, failure_injector=failure_injector)
        self.position_slack = config.stage_box_margin
        if self.discs is not None and config.footprint_prediction is not None:
            self.adaptation.prediction = PredictionMonitor(self.discs.offsets, config.footprint_prediction)
        self._q_sa = np.asarray(config.q_sa, float)
        self.reset(np.array([*self.ref_states[0, :2], self.ref_states[0, 2]]))
        self.build_s = time.perf_counter() - t0

    def _set_plan(self, areas: SafeAreas, plan: Plan, box_margin: float, dt: float) -> None:
        self.areas, self._rects, self.plan = areas, np.asarray(areas.rects, dtype=float), plan
        self.chain, self.ref_states, self.ref_inputs, self._ref_chain = _plan_tables(areas, plan, box_margin, dt)
        self._sa_cache, self._both = {}, np.concatenate((self.chain.stay, self.chain.advance))  # J_SA, _assign_shared
        self._stops, self.disc_chains, self.ref_states, self.ref_inputs = _route_tables(self, areas, plan, box_margin, dt)

    def replace_plan(self, areas: SafeAreas, plan: Plan) -> None:
        """Follow a new corridor and reference (a successful plan on ``areas`` starting at the
        current pose) from now on, keeping the episode state (previous input, warm start,
        adaptation, traction limit); the stage assignment restarts cold, the progress at the
        reference's start. Raises ValueError as the constructor for a bad plan."""
        if not plan.ok or plan.reference is None or len(plan.reference) < 1:
            raise ValueError(f"plan must be successful with a reference, got ok={plan.ok} reason={plan.reason!r}")
        self._set_plan(areas, plan, self.config.stage_box_margin, self.dt)
        self._s_prev, self._s_prev_d, self._ref_index = None, None, 0

    @property
    def monitor(self):
        """The adaptation's :class:`~sanav_mj.control.monitor.ActuationMonitor`."""
        return self.adaptation.monitor

    def reset(self, pose: np.ndarray, *, u_prev: np.ndarray | None = None, opening_turn: bool = True,
              progress: int | None = None) -> None:
        """Start a new episode at ``pose`` (3,) [m, m, rad] (see :meth:`TrackingMPC.reset`).

        ``progress``: index of the reference sample to resume from; None: the sample nearest
        ``pose`` among the first ``2N + 1``.
        """
        pose = np.asarray(pose, dtype=float).reshape(3)
        super().reset(pose, u_prev=u_prev, opening_turn=opening_turn)
        self._s_prev: np.ndarray | None = None
        self._s_prev_d, self._centres_of = None, None  # _centres_of: see _disc_rows
        if self.discs is not None:
            self._escape.reset()
        self.last: StepInfo | None = None
        if progress is not None and not 0 <= progress < len(self.ref_states):
            raise ValueError(f"progress must be a reference index in [0, {len(self.ref_states)}), got {progress!r}")
        w = min(len(self.ref_states), 2 * self.N + 1)
        d = np.hypot(*(self.ref_states[:w, :2] - pose[:2]).T)
        self._ref_index = int(np.argmin(d)) if progress is None else int(progress)

    @property
    def progress_index(self) -> int:
        """Index of the reference sample the robot was last found nearest to."""
        return self._ref_index

    # ---------------------------------------------------------------- plug-in points

    def constrain(self, x0: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray, guess: np.ndarray) -> Constraints:
        """Stage assignment of the guess, stage boxes (relaxed around the measured position),
        J_SA slots and exit targets of this step (see the class docstring); in ``"discs"``
        mode per disc centre (:meth:`DiscCover.stages`)."""
        if self.discs is None:
            s, plain = _assign_point(self.chain, self._both, guess, self._s_prev, self._check_tol)
            boxes_c, excursion = relax_boxes(plain, x0[:2])
            xr, ur = exit_targets(self.chain, self._ref_chain[self._horizon_idx], x_ref, u_ref, s, x0[:2],
                                  float(x0[2]))
            return Constraints(boxes_c[1:, :2].ravel(), boxes_c[1:, 2:].ravel(), self._sa_params(s), xr, ur,
                               excursion, (s, boxes_c))
        return _disc_constraints(self, x0, x_ref, u_ref, guess)

    def _chains(self):
        """The chain(s) of the disc rows: one per disc for a pose route, else the corridor's."""
        return self.chain if self.disc_chains is None else self.disc_chains

    def _guess_inputs(self) -> np.ndarray:
        """The warm start; in ``"discs"`` mode an escape guess once stalled (:class:`StallEscape`)."""
        u = super()._guess_inputs()
        if self.discs is None or self._active is None:
            return u
        g = self._escape.next_guess(self._u_prev, self._ref_index >= len(self.ref_states) - 5)
        if g is None:
            return u
        self._active.y = self._active.y_z = None  # no multipliers of the abandoned plan
        self.stats.count("escape")
        return g

    def position_rows(self, xs: np.ndarray) -> np.ndarray:
        """The position rows of ``g`` for the rollout ``xs`` (N+1, 3): positions or disc centres of stages 1..N."""
        return xs[1:, :2].ravel() if self.discs is None else _disc_rows(self, xs)

    def turn_allowed(self, x0: np.ndarray) -> bool:
        """``"disc"``: always; ``"discs"``: where the centres' sweep fits (:meth:`DiscCover.turn_allowed`)."""
        return self.discs is None or self.discs.turn_allowed(self.chain, x0)

    def state_clearance(self, xs: np.ndarray) -> np.ndarray:
        """(P,) [m] slack of the states (P, 3) over the chain's members (``"discs"``: the worst centre's)."""
        return chain_slack(self.chain, xs[:, :2]) if self.discs is None else self.discs.clearance(self._chains(), xs)

    def _pose(self, x0, con, u_guess, guess):
        prob = super()._pose(x0, con, u_guess, guess)
        s, boxes_c = con.context[:2]
        n = self.N
        self.last = StepInfo(s, boxes_c, u_guess, guess, con.x_ref, con.u_ref, self._u_prev.copy(),
                             prob.z_lb.reshape(n, 2), prob.z_ub.reshape(n, 2), self._rate_step)
        return prob

    def describe(self, xs: np.ndarray, x0: np.ndarray, context) -> tuple[np.ndarray, np.ndarray]:
        """Safe-area ids (N+1,) and box margins (N+1,) [m] of an applied plan."""
        s, boxes = context[:2]
        if self.discs is None:
            margins = np.concatenate(([box_slack(x0[None, :2], boxes[:1])[0]], box_slack(xs[1:, :2], boxes[1:])))
        else:
            margins = _disc_margins(_plan_centres(self, xs, x0), context[3])
        chain = self.chain if self.disc_chains is None else self.disc_chains[self.discs.centre]
        return stage_rect_ids(chain, self._rects, s, xs[:, :2]), margins

    def turn_context(self, x0: np.ndarray, xs: np.ndarray):
        """Stage assignment and boxes of an opening-turn plan."""
        if self.discs is not None:
            ss, bs, _ = self.discs.stages(self._chains(), np.vstack((x0[None], xs[1:])), self._s_prev_d, self._check_tol)
            return ss[self.discs.centre], bs[self.discs.centre], ss, bs
        s = assign_stages(self.chain, xs[:, :2], first_candidates(len(self.chain), self._s_prev), tol=self._check_tol)
        boxes, _ = relax_boxes(stage_boxes(self.chain, s), x0[:2])
        return s, boxes

    def commit(self, context) -> None:
        """Keep the stage assignment of the applied plan (anchors the next assignment)."""
        self._s_prev = context[0]
        if len(context) > 2:
            self._s_prev_d = context[2]

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """(P,) [m] largest slack of each point (P, 2) over the corridor chain's members (negative: outside all)."""
        return chain_slack(self.chain, points)

    # ---------------------------------------------------------------- pieces of a step

    def _progress(self, pos: np.ndarray) -> int:
        """Index of the reference sample nearest ``pos`` (2,) in the window ahead of the last
        one; a pose route: nearest the pose ``pos`` (3,) in disc-centre distance
        ``|dp|^2 + (sweep dyaw)^2`` (a reference that turns on the spot holds its position)."""
        k = len(self.ref_states)
        lo = self._ref_index
        hi = min(k, lo + (self.config.reference_window or self.N) + 1)
        sweep = self.discs.sweep if self.disc_chains is not None and pos.shape[0] > 2 else None
        i = _nearest_sample(self.ref_states, lo, hi, pos, sweep, self._stops)
        self._ref_index = i
        return i

    def reference(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference states (N+1, 3) and inputs (N, 2) for the horizon starting at ``pose``.

        The samples start at the progress index; past the end the last state is held with
        zero inputs. The yaw is shifted by a multiple of 2 pi so that its first sample is
        within pi of the measured yaw (the reference yaw is unwrapped, the measured one is
        not), which makes the yaw error the wrapped one.
        """
        i = self._progress(pose[:2] if self.disc_chains is None else pose[:3])
        k = len(self.ref_states)
        idx, held = _horizon_indices(i, self.N, k, self._stops)
        xr = self.ref_states[idx].copy()
        ur = self.ref_inputs[idx[:-1]].copy()
        ur[(idx[:-1] >= k - 1) | held[:-1]] = 0.0
        xr[:, 2] += 2 * np.pi * np.round((pose[2] - xr[0, 2]) / (2 * np.pi))
        self._horizon_idx = idx
        return xr, ur


    def _sa_params(self, s: np.ndarray) -> np.ndarray:
        """J_SA slot parameters (6 * slots,) of an assignment (cached per first and last member)."""
        key = (int(s[0]), int(s[-1]))
        theta = self._sa_cache.get(key)
        if theta is None:
            theta = safe_area_params(self.chain, self._rects, key, self.penalty.n_slots, self._q_sa,
                                     self.config.stage_box_margin, all_or_none=self.discs is not None)
            self._sa_cache[key] = theta
        return theta
