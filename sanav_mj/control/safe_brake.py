"""Choosing a braking manoeuvre whose predicted disc centres stay inside the safe areas.

A rejected solve leaves the robot without a plan checked against this step's constraints.
The braking fallback of the lidar ``"discs"`` mode
(:class:`~sanav_mj.control.sensed_footprint.StraightBrakeSAMPC`) then rolls a few candidate
input sequences out from the current state (each within the input and rate bounds and
ending at rest) and takes the first, in a fixed order of preference, whose every predicted
disc centre (stages 1..N) lies in the current safe areas; when none does, a fixed one (the
straight stop there: choosing the candidate whose worst centre lies least far outside turned
the robot hard at speed, and its corners came within 6 mm of a cylinder, barn_0060 seed 3,
2026-11-25). :func:`choose_brake` is that choice, :func:`rect_slack` its measure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sanav_mj.control.footprint import disc_centres
from sanav_mj.control.unicycle import rollout_np

__all__ = ["BrakeChoice", "choose_brake", "rect_slack"]


def rect_slack(points: np.ndarray, rects: np.ndarray) -> np.ndarray:
    """(P,) [m] the largest slack of each point (P, 2) [m] over the rectangles (R, 4) [m]
    ``xmin, ymin, xmax, ymax``: the distance to the nearest edge of the rectangle holding the
    point most deeply (>= 0 inside a closed rectangle), negative outside every rectangle (its
    magnitude then between 1 / sqrt(2) and 1 times the distance to the nearest rectangle).
    ``-inf`` for every point when there is no rectangle."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    r = np.asarray(rects, dtype=float).reshape(-1, 4)
    if len(r) == 0:
        return np.full(len(p), -np.inf)
    sl = np.minimum(
        np.minimum(p[:, None, 0] - r[None, :, 0], r[None, :, 2] - p[:, None, 0]),
        np.minimum(p[:, None, 1] - r[None, :, 1], r[None, :, 3] - p[:, None, 1]),
    )
    return sl.max(axis=1)


@dataclass(frozen=True)
class BrakeChoice:
    """The braking manoeuvre chosen by :func:`choose_brake`.

    Attributes:
        name: the candidate's name (as given).
        u: (N, 2) [m/s, rad/s] its inputs.
        slack: [m] the smallest :func:`rect_slack` of its predicted points over stages 1..N
            (negative: some point predicted outside every rectangle).
        inside: ``slack >= -tol``: every predicted point within ``tol`` of a rectangle.
        scores: [m] the ``slack`` of every candidate, in the order given.
    """

    name: str
    u: np.ndarray
    slack: float
    inside: bool
    scores: tuple[float, ...]


def choose_brake(x0: np.ndarray, candidates: list[tuple[str, np.ndarray]], offsets: np.ndarray,
                 rects: np.ndarray, dt: float, tol: float, gains: np.ndarray | None = None,
                 otherwise: int | None = 0) -> BrakeChoice:
    """The first candidate whose predicted points stay inside ``rects``, else ``otherwise``.

    Args:
        x0: (3,) [m, m, rad] the current state (finite).
        candidates: (name, inputs (N, 2) [m/s, rad/s]) in order of preference (at least one).
        offsets: (P, 2) [m] body-frame points that must stay inside (the disc centres; x
            forward, y left).
        rects: (R, 4) [m] the safe areas.
        dt: [s] the model's period.
        tol: [m] >= 0, how far outside a point may lie and still count as inside (the
            acceptance tolerance of a solve).
        gains: (2,) input gains the candidates are rolled out with (what the plant does with
            a command), or None (the model's).
        otherwise: index of the candidate taken when none is inside; None: the one whose
            worst point lies least far outside (ties to the earlier one).

    Returns:
        the :class:`BrakeChoice`.
    """
    if not candidates:
        raise ValueError("candidates: expected at least one (name, inputs) pair, got none")
    x0 = np.asarray(x0, dtype=float).reshape(3)
    o = np.asarray(offsets, dtype=float).reshape(-1, 2)
    scores = []
    for _, u in candidates:
        xs = rollout_np(x0, u if gains is None else u * gains, dt)[1:]
        scores.append(float(rect_slack(disc_centres(xs, o).reshape(-1, 2), rects).min()))
    inside = [i for i, v in enumerate(scores) if v >= -tol]
    if inside:
        best = inside[0]
    elif otherwise is None:
        best = int(np.argmax(scores))
    else:
        if not 0 <= otherwise < len(candidates):
            raise ValueError(f"otherwise: expected a candidate index in [0, {len(candidates)}), got {otherwise!r}")
        best = int(otherwise)
    name, u = candidates[best]
    return BrakeChoice(name, u, scores[best], bool(inside), tuple(scores))
