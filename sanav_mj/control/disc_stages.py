"""SA-MPC's footprint-discs mode (``MPCConfig.footprint="discs"``): per-disc stages, turns, escapes.

The robot's footprint rectangle is covered by discs along its long axis
(:meth:`sanav_mj.footprint.Footprint.discs`); in a map inflated by the disc radius every disc
centre inside a safe area keeps its disc clear. :class:`DiscCover` gives each centre of the
predicted states its own monotone stage assignment along the corridor chain and its own
stage boxes (the front disc may already be in the next safe area while the rear one is still
in the last: one convex box for all of them could never pass an L-turn of a strip narrower
than the disc spacing), the row bounds in the OCP's order, the margins, the braking
fallback's clearance and where the robot may turn on the spot. :class:`StallEscape` gives
the escape warm starts of a stalled plan (see its docstring).

**Pose route** (a plan from :mod:`sanav_mj.planning.pose_reference`, ``Plan.disc_corridors``
set): each disc centre has its own chain of member boxes (safe areas and portal bridges,
:func:`member_chain_of`) that the reference's disc centre walks; the rows are the same (each
centre in a shrunk box of its chain, consecutive boxes overlapping, every box inside the
safe areas), so SA-MPC's safety argument holds per disc. The reference's yaw is the
route's, so SA-MPC does not retarget it to the exit of the area; the progress is found in
disc-centre distance (a turn on the spot holds the position), and the horizon is held at
the reference's next stop (``Reference.stops``: a cusp or a turn on the spot,
:func:`next_stop`) until the robot is within ``STOP_REACHED_M`` of it, so the plan does not
blend the motions before and after it (the robot turned early at such places and stalled:
barn_0052). J_SA's slots are the areas all discs' assignments span, all or none
(:func:`sa_params_of_ids`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sanav_mj.control.footprint import disc_centres
from sanav_mj.control.repair_kernel import first_acceptable
from sanav_mj.control.stages import (
    CorridorChain,
    assign_stages,
    box_slack,
    chain_slack,
    first_candidates,
    relax_boxes,
    stage_boxes,
    tighten_relax,
)

def member_chain_of(areas, members: np.ndarray, margin: float, grow: float = 0.0, extra: np.ndarray | None = None,
                    extra_areas: np.ndarray | None = None) -> CorridorChain:
    """The :class:`CorridorChain` of a pose route's per-disc member sequence (``Plan.disc_corridors``).

    Args:
        areas: the safe areas (rects, edges).
        members: (L,) int indices into :func:`sanav_mj.planning.pose_search.member_boxes`
            (area ``r`` for ``r < R``, else the bridge across edge ``r - R``).
        margin: [m] each stay / advance box is shrunk by this (``box_margin``).
        grow: [m] > 0: the members grown to maximal free rectangles, at most this per side
            (``member_boxes(..., grow=grow)``, a plan whose ``info["grown_members"]`` is set).
        extra, extra_areas: None, or (X, 4) [m] further boxes indexed after the member boxes
            and (X,) int the safe area of each (``Plan.extra_members``, ``Plan.extra_areas``).

    Raises:
        ValueError: an index out of range, or consecutive members that do not overlap with
            positive area (the chain's contract).
    """
    from sanav_mj.planning.pose_search import member_boxes

    from sanav_mj.control.stages import box_intersection, shrink_box

    allb = member_boxes(areas, 0.0, grow=grow)
    n_base = len(allb)
    if extra is not None and len(extra):
        extra = np.asarray(extra, dtype=float).reshape(-1, 4)
        if extra_areas is None or np.asarray(extra_areas).shape != (len(extra),):
            raise ValueError(f"disc_corridors: expected one safe area per extra box ({len(extra)}), got "
                             f"{None if extra_areas is None else np.asarray(extra_areas).tolist()}")
        allb = np.vstack((allb, extra))
    m = np.asarray(members, dtype=int).ravel()
    if m.size == 0 or m.min() < 0 or m.max() >= len(allb):
        raise ValueError(f"disc_corridors: expected member indices in [0, {len(allb)}), got {m.tolist()}")
    boxes = allb[m]
    inter = box_intersection(boxes[:-1], boxes[1:])
    if np.any(inter[:, 2:] - inter[:, :2] <= 1e-9):
        raise ValueError(f"disc_corridors: consecutive member boxes must overlap, got members {m.tolist()}")
    R = len(areas.rects)
    edges = np.asarray(areas.edges, dtype=int).reshape(-1, 2)
    pairs = np.array([(i, i) if i < R else tuple(edges[i - R]) if i < n_base else (int(extra_areas[i - n_base]),) * 2
                      for i in m], dtype=int).reshape(-1, 2)
    stay = shrink_box(boxes, margin)
    adv = np.empty_like(boxes)
    adv[0] = stay[0]
    adv[1:] = shrink_box(inter, margin)
    return CorridorChain(boxes, pairs, stay, adv)


def next_stop(stops: np.ndarray | None, i: int) -> int | None:
    """The first of the reference's ``stops`` (S,) int (increasing) after sample ``i``; None
    when there is none or ``stops`` is None."""
    if stops is None:
        return None
    j = int(np.searchsorted(stops, i, side="right"))
    return int(stops[j]) if j < len(stops) else None


def sa_params_of_ids(rects: np.ndarray, ids: list[int], slots: int, q_sa: np.ndarray, margin: float) -> np.ndarray:
    """J_SA slot parameters (6 * slots,) for the safe areas ``ids`` (shrunk by ``margin`` [m],
    priorities ``q_sa``), all or none: no slot is active when there are more areas than
    slots (see :func:`~sanav_mj.control.stages.safe_area_params`)."""
    from sanav_mj.control.stages import shrink_box

    if len(ids) > slots:
        ids = []
    theta = np.zeros((slots, 6))
    theta[: len(ids), :4] = shrink_box(np.asarray(rects, float)[ids], margin)
    theta[: len(ids), 4] = q_sa[: len(ids)]
    theta[: len(ids), 5] = 1.0
    theta[len(ids):, 2:4] = 1.0
    return theta.ravel()


#: steps at rest before an escape guess is tried (see :class:`StallEscape`).
STALL_STEPS = 3


def escape_guesses(horizon: int) -> list[np.ndarray]:
    """Escape warm starts (each (N, 2) [m/s, rad/s]) for a stalled ``"discs"`` SA-MPC: forward
    at 0.2 m/s turning left / right at 1 rad/s, the same reversing, and turning on the spot at
    +-1.5 rad/s; each ramps up over 3 steps, is held to step 10 and then rests (the terminal
    stop). They only seed the solver and the stage assignment."""
    k = np.arange(horizon)
    ramp = np.where(k < 10, np.minimum(1.0, (k + 1) / 3.0), 0.0)
    out = []
    for v, w in ((0.2, 1.0), (0.2, -1.0), (-0.2, 1.0), (-0.2, -1.0), (0.0, 1.5), (0.0, -1.5)):
        out.append(np.column_stack((v * ramp, w * ramp)))
    return out


@dataclass(frozen=True)
class DiscCover:
    """The disc cover of the footprint as SA-MPC's constrained points.

    Attributes:
        offsets: (D, 2) [m] disc centres in the body frame.
        radius: [m] disc radius (the map's inflation is this plus the margin).
        sweep: [m] radius of the circle the centres sweep turning on the spot.
        centre: index of the disc nearest the base origin (its assignment gives the exit
            targets and the reported stage data).
    """

    offsets: np.ndarray
    radius: float
    sweep: float
    centre: int

    @staticmethod
    def of(footprint, n: int) -> DiscCover:
        """The ``n``-disc cover of a :class:`sanav_mj.footprint.Footprint`."""
        offsets, radius = footprint.discs(n)
        d = np.hypot(*offsets.T)
        return DiscCover(offsets, float(radius), float(d.max()), int(np.argmin(d)))

    def centres(self, xs: np.ndarray) -> np.ndarray:
        """(K, D, 2) [m] disc centres of the states ``xs`` (K, 3)."""
        return disc_centres(xs, self.offsets)

    def per_disc(self, chain) -> list[CorridorChain]:
        """The chain of each disc: ``chain`` itself when it is a list (one per disc), else the
        one chain D times."""
        if isinstance(chain, (list, tuple)):
            if len(chain) != len(self.offsets):
                raise ValueError(f"chain: expected one corridor chain per disc ({len(self.offsets)}), got {len(chain)}")
            return list(chain)
        return [chain] * len(self.offsets)

    def assign(self, chain, xs: np.ndarray, s_prev: np.ndarray | None,
               tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per disc centre of the states ``xs`` (N+1, 3): assignments (D, N+1) (each anchored
        on its previous one, ``s_prev`` (D, N+1) or None), the stage boxes (D, N+1, 4) [m] of
        those assignments as they are (neither relaxed nor tightened), and the centres
        (N+1, D, 2) [m]. ``chain`` as in :meth:`stages`."""
        pts = self.centres(xs)
        chains = self.per_disc(chain)
        ss, plain = [], []
        for d in range(pts.shape[1]):
            c = chains[d]
            s = assign_stages(c, pts[:, d], first_candidates(len(c), None if s_prev is None else s_prev[d]), tol=tol)
            ss.append(s)
            plain.append(stage_boxes(c, s))
        return np.array(ss), np.array(plain), pts

    @staticmethod
    def relax(plain: np.ndarray, pts0: np.ndarray,
              tighten: tuple[float, bool] | None = None) -> tuple[np.ndarray, float]:
        """The stage boxes (D, N+1, 4) [m] the disc rows use, from :meth:`assign`'s ``plain``
        boxes and the stage-0 centres ``pts0`` (D, 2) [m], and the largest excursion [m] of a
        stage-0 centre: each disc's boxes relaxed around its centre (:func:`relax_boxes`), or
        with ``tighten`` ``(delta, follow)`` tightened by ``delta`` [m] with a capped
        relaxation (:func:`~sanav_mj.control.stages.tighten_relax`)."""
        bs, exc = [], 0.0
        for d in range(plain.shape[0]):
            if tighten is None:
                b, e = relax_boxes(plain[d], pts0[d])
            else:
                b, e = tighten_relax(plain[d], pts0[d], *tighten)
            bs.append(b)
            exc = max(exc, e)
        return np.array(bs), exc

    def stages(self, chain, xs: np.ndarray, s_prev: np.ndarray | None,
               tol: float, tighten: tuple[float, bool] | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """Per disc centre of the states ``xs`` (N+1, 3): assignments (D, N+1) (each anchored
        on its previous one, ``s_prev`` (D, N+1) or None), stage boxes (D, N+1, 4) [m] relaxed
        around its stage-0 centre, and the largest excursion [m] of a stage-0 centre
        (:meth:`assign`, then :meth:`relax`).
        ``chain``: one :class:`CorridorChain` for every disc, or a list of one per disc (a
        pose route's per-disc corridors, ``Plan.disc_corridors``). ``tighten``: ``(delta,
        follow)``, the boxes tightened by ``delta`` [m] with a capped relaxation
        (:func:`~sanav_mj.control.stages.tighten_relax`); None: :func:`relax_boxes`."""
        ss, plain, pts = self.assign(chain, xs, s_prev, tol)
        bs, exc = self.relax(plain, pts[0], tighten)
        return ss, bs, exc

    @staticmethod
    def bounds(bs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds (2DN,) of the OCP's rows (stage-major, disc, x/y) from the
        stage boxes (D, N+1, 4) (row 0, the measured state, is not a row)."""
        return bs[:, 1:, :2].transpose(1, 0, 2).ravel(), bs[:, 1:, 2:].transpose(1, 0, 2).ravel()

    def margins(self, xs: np.ndarray, bs: np.ndarray) -> np.ndarray:
        """(K,) [m] smallest slack of any disc centre of the states (K, 3) in its own box (D, K, 4)."""
        pts = self.centres(xs)
        return np.min([box_slack(pts[:, d], bs[d]) for d in range(pts.shape[1])], axis=0)

    def clearance(self, chain, xs: np.ndarray) -> np.ndarray:
        """(P,) [m] of the states (P, 3): the worst disc centre's largest slack over the
        chain's members (``chain`` as in :meth:`stages`)."""
        pts = self.centres(xs)
        chains = self.per_disc(chain)
        return np.min([chain_slack(chains[d], pts[:, d]) for d in range(pts.shape[1])], axis=0)

    @staticmethod
    def area_ids(chains: list[CorridorChain], ss: np.ndarray) -> list[int]:
        """Distinct safe-area indices of the members each disc's assignment ``ss`` (D, N+1)
        spans on its own chain, in order of first appearance (the J_SA candidates)."""
        ids: list[int] = []
        for chain, s in zip(chains, ss):
            for pair in chain.rect_pair[int(s[0]): int(s[-1]) + 1]:
                for r in pair:
                    if int(r) not in ids:
                        ids.append(int(r))
        return ids

    def turn_allowed(self, chain: CorridorChain, x0: np.ndarray) -> bool:
        """Whether the circle of radius :attr:`sweep` about the position of ``x0`` (3,) fits in
        one stay box of the chain: turning on the spot there keeps every centre in it."""
        st = chain.stay
        sl = np.minimum(np.minimum(x0[0] - st[:, 0], st[:, 2] - x0[0]), np.minimum(x0[1] - st[:, 1], st[:, 3] - x0[1]))
        return bool(sl.max() >= self.sweep)


class StallEscape:
    """Escape warm starts for a plan stuck at rest.

    The stage assignment follows the warm start: from a plan at rest it never advances, and
    with the footprint's discs in slivers the solver's optimum from there can be to stay (a
    local minimum of the non-convex problem; measured on the BARN-like worlds: 27 of 100 runs
    stopped so). Once the applied input has stayed at rest (``|v| < 0.02 m/s``,
    ``|w| < 0.05 rad/s``) for :data:`STALL_STEPS` steps away from the reference's end, the
    next of :func:`escape_guesses` replaces the shifted plan as the warm start (7 of those 27
    runs then reached the goal); the solution is checked against every constraint as usual.
    """

    def __init__(self, horizon: int):
        self.guesses = escape_guesses(horizon)
        self.reset()

    def reset(self) -> None:
        """Forget the stall (new episode)."""
        self.still = 0
        self.index = 0

    def next_guess(self, u_prev: np.ndarray, at_end: bool) -> np.ndarray | None:
        """The escape guess (N, 2) to use this step, or None (``u_prev`` (2,) the applied input)."""
        moving = abs(u_prev[0]) >= 0.02 or abs(u_prev[1]) >= 0.05
        self.still = 0 if (moving or at_end) else self.still + 1
        if self.still < STALL_STEPS:
            return None
        g = self.guesses[self.index % len(self.guesses)]
        self.index += 1
        return g


#: [m] how far :func:`footprint_reference` moves a reference position, at most, per axis.
REPAIR_REACH_M = 0.05
#: [m] its position step; [rad] its yaw span either side of the planned yaw and yaw step.
REPAIR_STEP_M = 0.01
REPAIR_YAW_SPAN = 0.5 * np.pi
REPAIR_YAW_STEP = np.deg2rad(2.0)


#: the repair lattice's sorted candidates per sweep radius (:func:`repair_lattice`).
_LATTICE: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
#: bad samples whose candidates :func:`footprint_reference` tests in one batch (memory bound).
_REPAIR_BATCH = 16


def repair_lattice(sweep: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidate offsets of :func:`footprint_reference` in cost order (cached per ``sweep``).

    Args:
        sweep: [m] the cover's turning radius (weight of the yaw offset in the cost).

    Returns:
        ``(order, dx, dy, da)``: ``order`` (L,) int, the index of each candidate in the
        lattice's ``(x, y, yaw)``-major ravel order (``L = (2n+1)^2 (2m+1)``: 11 x 11 x 89),
        sorted by ``|d|^2 + (sweep da)^2`` (stable); ``dx, dy`` (L,) [m] and ``da`` (L,) [rad]
        the offsets in that order. Read-only arrays.
    """
    key = float(sweep)
    hit = _LATTICE.get(key)
    if hit is None:
        n, m = _lattice_sizes()
        r = REPAIR_STEP_M * np.arange(-n, n + 1)  # integer multiples: the zero offset is exact
        a = REPAIR_YAW_STEP * np.arange(-m, m + 1)
        dx, dy, da = (g.ravel() for g in np.meshgrid(r, r, a, indexing="ij"))
        cost = dx * dx + dy * dy + (key * da) ** 2
        order = np.argsort(cost, kind="stable")
        hit = (order, dx[order], dy[order], da[order])
        for v in hit:
            v.setflags(write=False)
        _LATTICE[key] = hit
    return hit


def _lattice_sizes() -> tuple[int, int]:
    """Half-widths ``(n, m)`` of the repair lattice: positions ``-n..n`` steps, yaws ``-m..m``."""
    return int(round(REPAIR_REACH_M / REPAIR_STEP_M)), int(REPAIR_YAW_SPAN // REPAIR_YAW_STEP)


def _lattice_axes(states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The repair lattice's axes for each state (B, 3): candidate x and y (B, n) [m] (state
    plus offset) and the cosine and sine (B, a) of the candidate yaws, as the candidates'
    ``clearance`` computes them (the same additions; NumPy's cos and sin)."""
    n, m = _lattice_sizes()
    r = REPAIR_STEP_M * np.arange(-n, n + 1)
    a = REPAIR_YAW_STEP * np.arange(-m, m + 1)
    yaw = states[:, 2, None] + a
    return states[:, 0, None] + r, states[:, 1, None] + r, np.cos(yaw), np.sin(yaw)


def _acceptable(cover: DiscCover, chain, states: np.ndarray) -> np.ndarray:
    """(B, L) bool: whether each lattice candidate (ravel order of :func:`repair_lattice`) of
    each state (B, 3) has every disc centre in a member of its chain, i.e.
    ``cover.clearance(chain, candidates) >= 0``, decided with the same floating-point
    operations on the same values (the NumPy path and reference of
    :func:`sanav_mj.control.repair_kernel.first_acceptable`).

    The candidate poses ``(x + dx, y + dy, yaw + da)`` share their 11 positions per axis and
    89 yaws: the disc centres ``(x + dx + ox cos - oy sin, y + dy + ox sin + oy cos)`` are
    computed once per (position, yaw) pair and axis, the member tests per axis (a slack
    ``>= 0`` on both sides), and a disc centre is in a member exactly when both axes pass.
    The x-axis passes of each member are packed into bits over the x offsets, OR-ed over the
    members whose y test passes, and AND-ed over the discs.
    """
    xs, ys, cos, sin = _lattice_axes(states)
    nx, na = xs.shape[1], cos.shape[1]
    c, s = cos[:, None, :], sin[:, None, :]
    bit = np.left_shift(np.int64(1), np.arange(nx, dtype=np.int64))[:, None]  # (nx, 1)
    acc = np.full((len(states), nx, na), (1 << nx) - 1, dtype=np.int64)  # [b, iy, k]: bits over ix
    for (ox, oy), ch in zip(cover.offsets, cover.per_disc(chain)):
        # the same operations as disc_centres: x + ox cos - oy sin, y + ox sin + oy cos
        px = xs[:, :, None] + ox * c - oy * s  # (B, nx, na)
        py = ys[:, :, None] + ox * s + oy * c
        b = np.asarray(ch.boxes, dtype=float)[None, :, None, None, :]  # (1, M, 1, 1, 4)
        pxm, pym = px[:, None], py[:, None]  # (B, 1, n, na)
        okx = (pxm - b[..., 0] >= 0.0) & (b[..., 2] - pxm >= 0.0)  # (B, M, nx, na)
        oky = (pym - b[..., 1] >= 0.0) & (b[..., 3] - pym >= 0.0)
        maskx = (okx * bit).sum(axis=2)  # (B, M, na): bit ix set where the x test passes
        acc &= np.bitwise_or.reduce(np.where(oky, maskx[:, :, None, :], 0), axis=1)  # (B, ny, na)
    ok = (acc[:, None, :, :] >> np.arange(nx, dtype=np.int64)[None, :, None, None]) & 1  # (B, ix, iy, k)
    return ok.reshape(len(states), -1).astype(bool)


def _first_acceptable(cover: DiscCover, chain, states: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(B,) int: per state (B, 3), the position in ``order`` (:func:`repair_lattice`) of its
    first acceptable candidate (:func:`_acceptable`), -1 when there is none; compiled
    (:func:`~sanav_mj.control.repair_kernel.first_acceptable`) or, without the kernel, NumPy."""
    xs, ys, cos, sin = _lattice_axes(states)
    boxes = [ch.boxes for ch in cover.per_disc(chain)]
    first = first_acceptable(xs, ys, cos, sin, cover.offsets, boxes, order)
    if first is not None:
        return first
    out = []
    for lo in range(0, len(states), _REPAIR_BATCH):
        ok = _acceptable(cover, chain, states[lo: lo + _REPAIR_BATCH])[:, order]  # (B, L) in cost order
        j = ok.argmax(axis=1)
        out.append(np.where(ok[np.arange(j.size), j], j, -1))
    return np.concatenate(out)


def footprint_reference(cover: DiscCover, chain: CorridorChain, states: np.ndarray, inputs: np.ndarray,
                        dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The reference with every pose that puts a disc centre outside the corridor chain moved
    to the nearest pose that keeps all of them inside a member.

    The corridor reference's yaw is its path's tangent; where the path turns from one narrow
    passage into another that pose can leave a disc centre outside every chain member
    (barn_0060, barn_0017: by up to 2 and 10 cm where the robot stalled), so SA-MPC tracks a
    target its rows forbid. Each such sample ``i`` is replaced by the pose of a lattice
    (position within :data:`REPAIR_REACH_M` per axis in steps of :data:`REPAIR_STEP_M`, yaw
    within :data:`REPAIR_YAW_SPAN` in steps of :data:`REPAIR_YAW_STEP`) whose disc centres
    all lie in the members (:meth:`DiscCover.clearance` >= 0) nearest in disc-centre
    distance ``|dp|^2 + (sweep dyaw)^2`` (the first in the stable cost order of
    :func:`repair_lattice`); a sample with no such pose is kept. The yaw rate of the inputs
    around a moved sample is the yaw change over ``dt`` [s]. The candidates are tested per
    axis (:func:`_acceptable`, compiled: :mod:`sanav_mj.control.repair_kernel`), with the same
    decisions as evaluating ``clearance`` on all of them.

    Args:
        cover: the disc cover.
        chain: the corridor chain the disc rows use (or one per disc, as in
            :meth:`DiscCover.stages`).
        states: (K, 3) [m, m, rad] reference states; inputs: (K, 2) or (K-1, 2) [m/s, rad/s].
        dt: [s] the reference's period (> 0).

    Returns:
        New (states, inputs) arrays (the given ones untouched).
    """
    states = np.asarray(states, dtype=float)
    bad = np.flatnonzero(cover.clearance(chain, states) < 0.0)
    if bad.size == 0:
        return states, inputs
    order, dx, dy, da = repair_lattice(cover.sweep)
    out = states.copy()
    for i, j in zip(bad, _first_acceptable(cover, chain, states[bad], order)):
        if j >= 0:  # the candidate pose as states[i] + (dx, dy, da)[j]
            out[i] = (states[i, 0] + dx[j], states[i, 1] + dy[j], states[i, 2] + da[j])
    inputs = np.asarray(inputs, dtype=float).copy()
    touched = np.unique(np.concatenate((bad - 1, bad)))
    touched = touched[(touched >= 0) & (touched < min(len(inputs), len(out) - 1))]
    inputs[touched, 1] = (out[touched + 1, 2] - out[touched, 2]) / dt
    return out, inputs
