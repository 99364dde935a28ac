"""SA-MPC's geometry: the corridor chain, stage assignment and stage boxes, and the J_SA penalty.

These are the constraint and cost pieces SA-MPC plugs into the tracking-MPC core
(:mod:`sanav_mj.control.tracking`): the hard stage boxes ``A_k p_k <= b_k`` (bounds of the
position rows of ``g``) and the soft safe-area penalty (a
:class:`~sanav_mj.control.problem.PositionCost`). See :class:`~sanav_mj.control.sa_mpc.SAMPC`
for how they are used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as cs
import numpy as np

from sanav_mj.mapping.safe_areas import SafeAreas


@dataclass(frozen=True)
class SafeAreaPenalty:
    """The paper's soft safe-area penalty as a :class:`~sanav_mj.control.problem.PositionCost`.

    ``J_SA(p) = prod_n (a_n sum_m [q_n h_nm(p)]_-^2 + (1 - a_n))`` over ``n_slots`` rectangle
    slots, with ``h_n = (px - xmin, py - ymin, xmax - px, ymax - py)`` [m], ``[h]_- = min(0, h)``,
    priority ``q_n`` [1/m] and activity flag ``a_n`` in {0, 1}. An active slot is the paper's
    factor; an inactive slot is the neutral factor 1 (padding: repeating a rectangle instead
    would raise its factor to a power and flatten the penalty near its boundary). Zero
    whenever ``p`` is inside any active rectangle. Parameters per slot: ``xmin, ymin, xmax,
    ymax, q, a`` (6,), slots concatenated.
    """

    n_slots: int

    @property
    def key(self) -> str:
        return f"jsa{self.n_slots}"

    @property
    def n_params(self) -> int:
        return 6 * self.n_slots

    def expr(self, p, theta):
        out = 1
        for n in range(self.n_slots):
            r = theta[6 * n : 6 * n + 6]
            h = cs.vertcat(p[0] - r[0], p[1] - r[1], r[2] - p[0], r[3] - p[1])
            neg = cs.fmin(0, r[4] * h)
            out = out * (r[5] * cs.sumsqr(neg) + (1 - r[5]))
        return out

    @staticmethod
    def value_np(p: np.ndarray, rects: np.ndarray, q: np.ndarray) -> float:
        """NumPy value of the penalty at ``p`` (2,) for active ``rects`` (n, 4) [m], priorities ``q`` (n,)."""
        h = np.stack((p[0] - rects[:, 0], p[1] - rects[:, 1], rects[:, 2] - p[0], rects[:, 3] - p[1]), axis=1)
        neg = np.minimum(0.0, q[:, None] * h)
        return float(np.prod(np.sum(neg * neg, axis=1)))


# --------------------------------------------------------------------------------------
# Corridor chain: safe areas and the bridge boxes between consecutive ones


def box_intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection of boxes ``xmin, ymin, xmax, ymax`` (..., 4); empty when min > max."""
    return np.concatenate((np.maximum(a[..., :2], b[..., :2]), np.minimum(a[..., 2:], b[..., 2:])), axis=-1)


def shrink_box(box: np.ndarray, margin: float) -> np.ndarray:
    """Shrink boxes (..., 4) by ``margin`` [m] per side, at most a quarter of each width."""
    box = np.asarray(box, dtype=float)
    w = box[..., 2:] - box[..., :2]
    m = np.minimum(margin, 0.25 * np.maximum(w, 0.0))
    return np.concatenate((box[..., :2] + m, box[..., 2:] - m), axis=-1)


def bridge_box(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """A convex box inside ``a ∪ b`` whose intersections with ``a`` and with ``b`` have positive area.

    If the rectangles overlap with positive area the bridge is their intersection. If they
    only share a boundary segment (a portal), e.g. the vertical segment ``x = c``,
    ``y in [y0, y1]``, the bridge is ``[min(xmin), max(xmax)] x [y0, y1]``: every point of it
    lies in ``a`` (left of c) or ``b`` (right of c) because both contain the band
    ``y in [y0, y1]`` over their whole x extent.

    Args:
        a, b: (4,) [m] rectangles ``xmin, ymin, xmax, ymax``.
        tol: [m] tolerance for touching edges.

    Raises:
        ValueError: when the rectangles do not share a boundary segment of positive length.
    """
    inter = box_intersection(a, b)
    w = inter[2:] - inter[:2]
    if np.all(w > tol):
        return inter
    if abs(w[0]) <= tol and w[1] > tol:  # vertical portal
        return np.array([min(a[0], b[0]), inter[1], max(a[2], b[2]), inter[3]])
    if abs(w[1]) <= tol and w[0] > tol:  # horizontal portal
        return np.array([inter[0], min(a[1], b[1]), inter[2], max(a[3], b[3])])
    raise ValueError(f"safe areas {a.tolist()} and {b.tolist()} share no boundary segment of positive length")


@dataclass(frozen=True)
class CorridorChain:
    """The chain ``R_0, B_01, R_1, B_12, ..., R_{C-1}`` of convex boxes along a corridor.

    Consecutive members intersect with positive area and every member lies inside the union
    of the corridor's safe areas.

    Attributes:
        boxes: (L,) x 4 [m] member boxes, L = 2C - 1.
        rect_pair: (L, 2) int safe-area indices of each member: ``(r, r)`` for a safe area,
            ``(r_i, r_{i+1})`` for a bridge.
        stay: (L, 4) [m] stage box when staying on member j: ``shrink(C_j)``.
        advance: (L, 4) [m] stage box when advancing onto member j: ``shrink(C_{j-1} ∩ C_j)``
            (row 0 unused).
        area_rects: (R, 4) [m] the rectangle J_SA uses for each safe area: ``areas.rects``,
            or, when the chain was grown, the corridor's areas grown as their members.
    """

    boxes: np.ndarray
    rect_pair: np.ndarray
    stay: np.ndarray
    advance: np.ndarray
    area_rects: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.boxes.shape[0])

    @staticmethod
    def build(areas: SafeAreas, corridor: np.ndarray, margin: float = 0.0) -> CorridorChain:
        """Chain of the corridor ``(C,)`` int indices into ``areas.rects``; boxes shrunk by ``margin`` [m].

        When ``areas.free`` is set (:class:`~sanav_mj.mapping.grow.FreeCells` of the grid the
        areas were cut from), every member is grown to a maximal free rectangle of that grid
        (:func:`~sanav_mj.mapping.grow.grow_rect`, at most ``areas.free.limit`` per side). A
        grown member holds only free cells of the grid (as safe as a safe area) and contains
        the member it grew from, so consecutive members still overlap with positive area, by
        more than before where the partition is a staircase of thin areas. Its stage boxes are
        the grown box (or intersection) shrunk by ``margin + areas.free.tighten``, per side
        never tighter than the plain member's (shrunk by ``margin``): the room growth adds is
        tightened by the tracking error ``tighten``, the plain chain's room is kept.
        """
        rects = np.asarray(areas.rects, dtype=float)
        corridor = np.asarray(corridor, dtype=int).ravel()
        if corridor.size == 0:
            raise ValueError("plan.corridor must hold at least one safe-area index, got an empty array")
        if corridor.min() < 0 or corridor.max() >= len(rects):
            raise ValueError(f"plan.corridor indices must be in [0, {len(rects)}), got {corridor.tolist()}")
        free = getattr(areas, "free", None)
        if free is not None:
            from sanav_mj.mapping.grow import grow_rect

            area_rects = rects.copy()
        boxes, pairs = [rects[corridor[0]]], [(corridor[0], corridor[0])]
        for i, j in zip(corridor[:-1], corridor[1:]):
            boxes.append(bridge_box(rects[i], rects[j]))
            pairs.append((i, j))
            boxes.append(rects[j])
            pairs.append((j, j))
        boxes = np.array(boxes)
        stay = shrink_box(boxes, margin)
        adv = np.empty_like(boxes)
        adv[0] = stay[0]
        adv[1:] = shrink_box(box_intersection(boxes[:-1], boxes[1:]), margin)
        if free is None:
            return CorridorChain(boxes, np.array(pairs, dtype=int), stay, adv)
        grown = np.array([grow_rect(free, b) for b in boxes])
        roomier = _roomier_bridges(free, grown)
        # the grown boxes shrunk by margin + tighten, but per side never tighter than the plain ones
        # (uncapped: where that inverts a box, the plain side is the looser one)
        inset = np.array([1.0, 1.0, -1.0, -1.0])
        g_stay = _looser(stay, grown + (margin + free.tighten) * inset)
        g_adv = np.empty_like(grown)
        g_adv[0] = g_stay[0]
        g_adv[1:] = _looser(adv[1:], box_intersection(grown[:-1], grown[1:]) + (margin + free.tighten) * inset)
        for j in roomier:  # no plain room to keep: the plain bridge need not lie in the new one
            g_stay[j] = shrink_box(grown[j], margin + free.tighten)
            g_adv[j:j + 2] = shrink_box(box_intersection(grown[j - 1:j + 1], grown[j:j + 2]), margin + free.tighten)
        for k in range(len(corridor)):  # J_SA's area rectangles: as their members
            area_rects[corridor[k]] = _looser(rects[corridor[k]], grown[2 * k] + free.tighten * inset)
        return CorridorChain(grown, np.array(pairs, dtype=int), g_stay, g_adv, area_rects)


def _roomier_bridges(free, grown: np.ndarray) -> list[int]:
    """Replace in place each bridge of the grown chain ``grown`` (L, 4) [m] (odd rows) by the
    maximal free rectangle grown from the overlap of its grown neighbours when that one is
    roomier: its shorter side longer than the bridge's.

    The bridge grown from the portal strip between two areas is maximal, but where a passage
    turns into a narrow one it is the narrow passage's strip (a grown safe area reaching along
    it), which leaves a footprint no room to swing round the corner (barn_0014: a 0.1 m wide
    bridge beside 0.35 m of free cells). The rectangle grown from the neighbours' overlap
    holds only free cells and contains that overlap, so consecutive members still overlap
    with positive area and the chain's contract holds. Returns the rows replaced."""
    from sanav_mj.mapping.grow import grow_rect

    out = []
    for j in range(1, len(grown) - 1, 2):
        seed = box_intersection(grown[j - 1], grown[j + 1])
        w = seed[2:] - seed[:2]
        if np.any(w < 0.5 * free.resolution):
            continue
        o = np.tile(free.origin, 2)
        seed = o + np.rint((seed - o) / free.resolution) * free.resolution
        try:
            cand = grow_rect(free, seed)
        except ValueError:
            continue
        if np.min(cand[2:] - cand[:2]) > np.min(grown[j, 2:] - grown[j, :2]) + 1e-9:
            grown[j] = cand
            out.append(j)
    return out


def _looser(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per side the looser of boxes ``a`` and ``b`` (..., 4): the smaller min, the larger max."""
    return np.concatenate((np.minimum(a[..., :2], b[..., :2]), np.maximum(a[..., 2:], b[..., 2:])), axis=-1)


def _outside_sq(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Squared Euclidean distance (P, L) [m^2] from points (P, 2) to boxes (L, 4) (0 inside)."""
    dx = np.maximum(np.maximum(boxes[None, :, 0] - points[:, :1], points[:, :1] - boxes[None, :, 2]), 0.0)
    dy = np.maximum(np.maximum(boxes[None, :, 1] - points[:, 1:], points[:, 1:] - boxes[None, :, 3]), 0.0)
    return dx * dx + dy * dy


def assign_stages(
    chain: CorridorChain,
    guess: np.ndarray,
    first_candidates: np.ndarray | None = None,
    tol: float = 1e-6,
    reanchor_distance: float = 0.3,
) -> np.ndarray:
    """Monotone assignment of chain members to the stages 0..N of a guessed trajectory.

    Finds ``s`` (N+1,) with ``s(k) - s(k-1)`` in {0, 1} minimising the summed distance of
    each guessed position ``g_k`` outside its stage box (``stay[s(k)]`` if ``s(k) = s(k-1)``,
    else ``advance[s(k)]``; k = 0 uses ``stay[s(0)]``), distances below ``tol`` counting as
    zero; between assignments whose violations differ by less than about 1e-4 m it takes
    the larger ``sum_k s(k)`` (advance as early as the guess allows), so an assignment
    under which the guess is feasible always beats one under which it is not. Dynamic
    programming over (stage, member) restricted to the reachable band, O(N L).

    Args:
        chain: the corridor chain.
        guess: (N+1, 2) [m] guessed positions, ``guess[0]`` the measured one; or
            (N+1, D, 2) [m] D points per stage (footprint disc centres), a stage's distance
            being the largest of its points'.
        first_candidates: (L,) bool, members allowed for ``s(0)`` (None: all). Ignored when
            ``guess[0]`` is farther than ``reanchor_distance`` [m] from all of them.
        tol: [m] distances below this count as zero.
        reanchor_distance: [m] see ``first_candidates``.

    Returns:
        (N+1,) int chain member per stage.
    """
    n1 = guess.shape[0]
    L = len(chain)
    both = np.concatenate((chain.stay, chain.advance))
    if guess.ndim == 3:  # several points per stage (footprint disc centres): the worst one counts
        d2 = np.max([_outside_sq(guess[:, d], both) for d in range(guess.shape[1])], axis=0)
    else:
        d2 = _outside_sq(guess, both)
    d2[d2 < tol * tol] = 0.0
    if L <= 62:
        s = assign_feasible(d2, L, first_candidates, reanchor_distance)
        if s is not None:
            return s
    v = np.sqrt(d2)
    big = 1e7  # [1/m]: violation weight against the progress count (<= (N+1) L)
    idx = np.arange(L, dtype=float)
    c_stay = (v[:, :L] * big - idx).tolist()
    c_adv = (v[:, L:] * big - idx).tolist()
    inf = math.inf
    key = list(c_stay[0])
    if first_candidates is not None and np.min(v[0, :L][first_candidates]) <= reanchor_distance:
        key = [c if ok else inf for c, ok in zip(key, first_candidates.tolist())]
    finite = [j for j in range(L) if key[j] < inf]
    lo, hi = finite[0], finite[-1]
    back = [[False] * L for _ in range(n1)]
    for k in range(1, n1):
        hi_new = min(L - 1, hi + 1)
        row_s, row_a, bk = c_stay[k], c_adv[k], back[k]
        new = [inf] * L
        prev = inf
        for j in range(lo, hi_new + 1):
            cur = key[j]
            st = cur + row_s[j]
            ad = prev + row_a[j]
            if ad < st:
                new[j] = ad
                bk[j] = True
            else:
                new[j] = st
            prev = cur
        key = new
        hi = hi_new
    j = min(range(lo, hi + 1), key=key.__getitem__)
    s = np.empty(n1, dtype=int)
    for k in range(n1 - 1, 0, -1):
        s[k] = j
        if back[k][j]:
            j -= 1
    s[0] = j
    return s


def assign_feasible(v: np.ndarray, L: int, first_candidates, reanchor_distance: float) -> np.ndarray | None:
    """The assignment of :func:`assign_stages` when one with zero violation exists, else None
    (its fast path; ``v`` (N+1, 2L) [m^2] squared distance of each stage's position outside
    the stay boxes (first L columns) and advance boxes (last L) of the ``L`` chain members,
    zero below the tolerance; the other arguments as in :func:`assign_stages`).

    Among zero-violation assignments the one advancing as early as possible is pointwise
    the largest (if another one advanced at a stage where it did not, it could have too),
    hence the unique maximiser of ``sum_k s(k)`` that the dynamic programme returns. With
    the members as bits of an integer, stage k's feasible members ``R_k`` (a zero-violation
    completion to stage N exists) follow backwards in a few integer operations per stage,
    then the assignment forwards: 5-10x faster than the dynamic programme in Python.

    Args:
        v: (N+1, 2L) [m^2] squared distances of the guessed positions outside each
            member's stay box (first L columns) and advance box (last L), zero below the
            tolerance.
        L: number of members (<= 62).
        first_candidates, reanchor_distance: as in :func:`assign_stages`.
    """
    weights = np.left_shift(np.int64(1), np.arange(L, dtype=np.int64))
    zero = v == 0.0
    first_mask = None
    if first_candidates is not None and np.min(v[0, :L][first_candidates]) <= reanchor_distance**2:
        first_mask = int(first_candidates.astype(np.int64) @ weights)
    return feasible_from_bits((zero[:, :L] @ weights).tolist(), (zero[:, L:] @ weights).tolist(), first_mask)


def feasible_from_bits(stay: list[int], adv: list[int], first_mask: int | None) -> np.ndarray | None:
    """:func:`assign_feasible` from its bit sets: ``stay[k]`` / ``adv[k]`` (N+1 ints) have
    bit ``j`` set when stage k's position is (within the tolerance) in member j's stay /
    advance box; ``first_mask`` (bits of the members allowed for stage 0) or None. The
    assignment (N+1,) int, or None when no zero-violation assignment exists."""
    n1 = len(stay)
    reach = [0] * n1
    r = stay[-1]
    reach[-1] = r
    for k in range(n1 - 2, -1, -1):
        # member j at stage k continues by staying on j (stay box of k+1) or advancing to j+1
        r = (stay[k + 1] & r) | ((adv[k + 1] & r) >> 1)
        reach[k] = r
    first = stay[0] & reach[0]
    if first_mask is not None:
        first &= first_mask
    if first == 0:
        return None
    s = np.empty(n1, dtype=int)
    j = first.bit_length() - 1
    s[0] = j
    for k in range(1, n1):
        if (adv[k] >> (j + 1)) & (reach[k] >> (j + 1)) & 1:
            j += 1
        s[k] = j
    return s


def first_candidates(n_members: int, s_prev: np.ndarray | None) -> np.ndarray | None:
    """(L,) bool members allowed for stage 0: within two of the previous assignment
    ``s_prev``'s anchor ``s_prev[1]`` (None at a cold start)."""
    if s_prev is None:
        return None
    anchor = int(s_prev[1])
    cand = np.zeros(n_members, dtype=bool)
    cand[max(0, anchor - 2) : min(n_members, anchor + 3)] = True
    return cand


def stage_boxes(chain: CorridorChain, s: np.ndarray) -> np.ndarray:
    """Stage boxes (N+1, 4) [m] of an assignment ``s`` (N+1,): ``shrink(C_{s(k-1)} ∩ C_{s(k)})``."""
    out = chain.stay[s].copy()
    adv = np.flatnonzero(np.diff(s) > 0) + 1
    out[adv] = chain.advance[s[adv]]
    return out


def box_slack(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Smallest slack ``b - a^T p`` [m] of each point (K, 2) in its box (K, 4); negative outside."""
    return np.min(np.concatenate((points - boxes[:, :2], boxes[:, 2:] - points), axis=1), axis=1)


def chain_slack(chain: CorridorChain, points: np.ndarray) -> np.ndarray:
    """(P,) [m] largest slack of each point (P, 2) over the chain's members (negative: outside all)."""
    b = chain.boxes
    sl = np.minimum(
        np.minimum(points[:, None, 0] - b[None, :, 0], b[None, :, 2] - points[:, None, 0]),
        np.minimum(points[:, None, 1] - b[None, :, 1], b[None, :, 3] - points[:, None, 1]),
    )
    return sl.max(axis=1)


def exit_targets(
    chain: CorridorChain, ref_member: np.ndarray, xr: np.ndarray, ur: np.ndarray, s: np.ndarray,
    p0: np.ndarray, yaw0: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Reference states (N+1, 3) and inputs (N, 2) pulled into reach: see "Targets beyond the
    assigned area" in :class:`~sanav_mj.control.sa_mpc.SAMPC`.

    Args:
        chain: the corridor chain.
        ref_member: (N+1,) chain index of each reference sample's area (-1 off the corridor).
        xr, ur: the horizon's reference states (N+1, 3) and inputs (N, 2).
        s: (N+1,) stage assignment.
        p0: (2,) [m] position at stage 0; yaw0: [rad] its yaw.
    """
    ahead = ref_member > s
    ahead &= s + 1 < len(chain)
    if not ahead.any():
        return xr, ur
    ur = ur.copy()
    ur[ahead[1:]] = 0.0  # a target that stands still: no reference motion into it
    out = xr.copy()
    k = np.flatnonzero(ahead)
    box = chain.advance[s[k] + 1]
    inner = 0.25 * (box[:, 2:] - box[:, :2])  # aim at the central half, not the edge
    tgt = np.clip(out[k, :2], box[:, :2] + inner, box[:, 2:] - inner)
    out[k, :2] = tgt
    d = tgt - p0
    far = np.hypot(d[:, 0], d[:, 1]) > 0.02
    if far.any():
        bearing = np.arctan2(d[far, 1], d[far, 0])
        out[k[far], 2] = yaw0 + (bearing - yaw0 + np.pi) % (2 * np.pi) - np.pi
    return out, ur


def safe_area_params(chain: CorridorChain, rects: np.ndarray, members: tuple[int, int], slots: int,
                     q_sa: np.ndarray, margin: float, all_or_none: bool = False) -> np.ndarray:
    """J_SA slot parameters (6 * slots,) (see :class:`SafeAreaPenalty`): the distinct safe
    areas of chain members ``members[0]..members[1]``, in order, shrunk by ``margin`` [m],
    with priorities ``q_sa`` (slots,); unused slots inactive. When there are more areas than
    slots the first ``slots`` are used, or, with ``all_or_none``, none (every slot inactive,
    J_SA a constant): a partial set penalises a point for being in an area it leaves out,
    which held the front disc of a footprint back from areas its hard rows allow. A grown
    chain (``chain.area_rects``) gives the grown areas instead of ``rects``."""
    ids: list[int] = []
    for pair in chain.rect_pair[members[0] : members[1] + 1]:
        for r in pair:
            if int(r) not in ids:
                ids.append(int(r))
    if all_or_none and len(ids) > slots:
        ids = []
    ids = ids[:slots]
    theta = np.zeros((slots, 6))
    src = rects if chain.area_rects is None else chain.area_rects  # a grown chain: its grown areas
    theta[: len(ids), :4] = shrink_box(src[ids], margin)
    theta[: len(ids), 4] = q_sa[: len(ids)]
    theta[: len(ids), 5] = 1.0
    theta[len(ids) :, 2:4] = 1.0  # inactive slots: any finite rectangle
    return theta.ravel()


def stage_rect_ids(chain: CorridorChain, rects: np.ndarray, s: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """(K,) safe-area index of each stage: of member ``s[k]``'s area(s), the one containing
    ``pos[k]`` (K, 2) [m] best."""
    pair = chain.rect_pair[s]
    slack_a = box_slack(pos, rects[pair[:, 0]])
    slack_b = box_slack(pos, rects[pair[:, 1]])
    return np.where(slack_a >= slack_b, pair[:, 0], pair[:, 1])


def relax_boxes(boxes: np.ndarray, p0: np.ndarray) -> tuple[np.ndarray, float]:
    """Widen each side of the boxes of stages 1..N by how far ``p0`` (2,) [m] lies beyond that
    side of the stage-0 box (see "Measured position outside its box" in
    :class:`~sanav_mj.control.sa_mpc.SAMPC`).

    ``p0`` may also be (D, 2) [m], several points of the measured state (footprint disc
    centres): each side is widened by the farthest point beyond it.

    Returns the boxes (N+1, 4) [m] and the excursion [m]: the distance of ``p0`` outside the
    stage-0 box (0 inside; for several points the largest).
    """
    p0 = np.asarray(p0, dtype=float)
    below_p, above_p = _beyond(boxes[0], p0.reshape(-1, 2))
    below, above = below_p.max(axis=0), above_p.max(axis=0)
    if not (below.any() or above.any()):
        return boxes, 0.0
    out = boxes.copy()
    out[1:, :2] -= below
    out[1:, 2:] += above
    if p0.ndim == 1:
        return out, float(np.hypot(*(below + above)))
    return out, _excursion(below_p, above_p)


def _beyond(box: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far each point of ``pts`` (P, 2) [m] lies below the low sides and above the high
    sides of ``box`` (4,) [m]: two (P, 2) arrays, 0 where inside."""
    return np.maximum(box[:2] - pts, 0.0), np.maximum(pts - box[2:], 0.0)


def _excursion(below: np.ndarray, above: np.ndarray) -> float:
    """[m] the largest distance of a point outside its box, from :func:`_beyond`'s arrays."""
    return float(np.max(np.hypot(*(below + above).T)))


def tighten_relax(boxes: np.ndarray, p0: np.ndarray, delta: float, follow: bool = False) -> tuple[np.ndarray, float]:
    """Stage boxes tightened by the one-step prediction error bound ``delta`` [m], relaxed
    around the measured points but never beyond the untightened boxes (``"discs"`` SA-MPC
    with :attr:`~sanav_mj.control.prediction.PredictionDerating.tighten`; see "Tightening by
    the prediction error" in :mod:`sanav_mj.control.prediction` for why this bounds the
    excursion).

    ``T = shrink_box(boxes, delta)`` (per side at most a quarter of each box's width). Each
    side of the boxes of stages 1..N is widened, like :func:`relax_boxes`, by how far the
    farthest point of ``p0`` lies beyond that side of ``T[0]``, but a widened side never
    passes the same side of ``boxes`` (the relaxation may use the room the tightening took,
    no more). With ``follow`` (a robot at rest, which cannot move sideways in one period)
    the widening is not capped: the plan may stay where the robot is, as with
    :func:`relax_boxes`.

    Args:
        boxes: (N+1, 4) [m] stage boxes ``xmin, ymin, xmax, ymax`` (already shrunk by
            ``box_margin``); row 0 is the box of the measured points.
        p0: (2,) or (D, 2) [m] the measured point(s) (disc centres) of stage 0.
        delta: [m] >= 0 tightening.
        follow: do not cap the widening.

    Returns:
        The boxes (N+1, 4) [m] (row 0: ``T[0]``) and the excursion [m]: the largest distance
        of a point of ``p0`` outside ``boxes[0]`` (the untightened box; 0 inside), which
        the excursion derating reads as before.
    """
    boxes = np.asarray(boxes, dtype=float)
    pts = np.asarray(p0, dtype=float).reshape(-1, 2)
    excursion = _excursion(*_beyond(boxes[0], pts))
    out, _ = relax_boxes(shrink_box(boxes, delta) if delta > 0 else boxes.copy(), pts)
    if not follow:
        out[1:, :2] = np.maximum(out[1:, :2], boxes[1:, :2])
        out[1:, 2:] = np.minimum(out[1:, 2:], boxes[1:, 2:])
    return out, excursion
