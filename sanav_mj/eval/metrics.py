"""Episode metrics and the ``run --json`` document (field by field in docs/outputs.md)."""

from __future__ import annotations

from typing import Any

import numpy as np

from sanav_mj.control.footprint import disc_centres
from sanav_mj.sim.runner import Episode


def timing_stats(values_ms: list[float] | np.ndarray, percentiles: bool = True) -> dict[str, float]:
    """Summary of per-step times [ms]: mean, max, std (and p50, p99 when ``percentiles``).

    An empty input gives zeros, so a run that never reached the controller stays valid JSON.
    """
    a = np.asarray(values_ms, dtype=float)
    if a.size == 0:
        a = np.zeros(1)
    out = {"mean": float(a.mean()), "max": float(a.max()), "std": float(a.std())}
    if percentiles:
        out["p50"] = float(np.percentile(a, 50))
        out["p99"] = float(np.percentile(a, 99))
    return out


def path_length(xy: np.ndarray) -> float:
    """Length [m] of a polyline (K, 2) [m]."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) < 2:
        return 0.0
    return float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))


def _outside(xy: np.ndarray, rects: np.ndarray, tol: float) -> np.ndarray:
    """(K,) bool: each position (K, 2) [m] outside every rectangle (R, 4) [m] widened by ``tol``."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    rects = np.asarray(rects, dtype=float).reshape(-1, 4)
    if len(rects) == 0:
        return np.ones(len(xy), dtype=bool)
    x = xy[:, 0:1]
    y = xy[:, 1:2]
    inside = (
        (x >= rects[None, :, 0] - tol)
        & (x <= rects[None, :, 2] + tol)
        & (y >= rects[None, :, 1] - tol)
        & (y <= rects[None, :, 3] + tol)
    )
    return ~inside.any(axis=1)


def safe_area_violations(xy: np.ndarray, rects: np.ndarray, tol: float = 1e-9) -> int:
    """Number of positions (K, 2) [m] that lie outside every rectangle (R, 4) [m]."""
    return int(np.sum(_outside(xy, rects, tol)))


def body_points(poses: np.ndarray, offsets: np.ndarray | None) -> np.ndarray:
    """(K, P, 2) [m] world positions of the body-frame points ``offsets`` (P, 2) [m] (x
    forward, y left) at the poses (K, 3) [m, m, rad]; ``offsets`` None: the positions
    themselves (K, 1, 2)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if offsets is None:
        return poses[:, None, :2]
    return disc_centres(poses, np.asarray(offsets, dtype=float).reshape(-1, 2))


def step_violations(poses: np.ndarray, rects: np.ndarray, offsets: np.ndarray | None = None,
                    tol: float = 1e-9) -> int:
    """Number of poses (K, 3) [m, m, rad] at which some body point lies outside every
    rectangle (R, 4) [m]: each point of ``offsets`` (P, 2) [m] in the body frame (the disc
    centres the hard constraints hold in the safe areas), or the position itself when
    ``offsets`` is None (:func:`safe_area_violations` of the positions). A pose counts
    once however many of its points are outside."""
    pts = body_points(poses, offsets)
    k, p = pts.shape[:2]
    return int(np.sum(_outside(pts.reshape(-1, 2), rects, tol).reshape(k, p).any(axis=1)))


def episode_json(
    episode: Episode,
    *,
    scenario: str,
    controller: str,
    seed: int,
    start: np.ndarray,
    goal: np.ndarray,
    rects: np.ndarray | None,
    mismatch: dict[str, float],
    setup_ms: float = 0.0,
    points: np.ndarray | None = None,
) -> dict[str, Any]:
    """The ``run --json`` document of one episode (keys, types and units: docs/outputs.md).

    Args:
        episode: the finished episode.
        scenario: scenario name.
        controller: controller name as given on the command line.
        seed: run seed.
        start: (3,) [m, m, rad] start pose actually used.
        goal: (2,) [m] goal.
        rects: (R, 4) [m] safe areas for ``safe_area_violations`` (None: not applicable, 0).
        points: (P, 2) [m] body-frame points every one of which must lie in ``rects`` at a
            step for it not to count in ``safe_area_violations`` (:func:`step_violations`;
            the disc centres of SA-MPC's ``"discs"`` mode); None: the position alone.
        mismatch: the changed mismatch keys.
        setup_ms: [ms] one-off planning work (mapping + planning) charged to the first
            step's ``pipeline_ms`` so the pipeline figures include it.
    """
    tr = episode.trace
    poses = tr.poses()
    pipeline = list(tr.pipeline_ms)
    if pipeline:
        pipeline[0] += setup_ms
    clear = np.asarray(tr.clearance, dtype=float)
    cmd = np.asarray(tr.cmd, dtype=float).reshape(-1, 2)
    return {
        "scenario": scenario,
        "controller": controller,
        "seed": int(seed),
        "start": [float(v) for v in np.asarray(start).reshape(3)],
        "goal": [float(v) for v in np.asarray(goal).reshape(2)],
        "success": bool(episode.success),
        "reason": episode.reason,
        "steps": int(episode.steps),
        "sim_time_s": float(episode.sim_time_s),
        "path_length_m": path_length(np.vstack([poses[:, :2], episode.final_pose[None, :2]])) if len(poses) else 0.0,
        "min_clearance_m": float(clear.min()) if clear.size else None,
        "collisions": int(episode.collisions),
        "safe_area_violations": step_violations(poses, rects, points) if rects is not None else 0,
        "solver_failures": int(episode.solver_failures),
        "solve_ms": timing_stats(tr.solve_ms),
        "pipeline_ms": timing_stats(pipeline, percentiles=False),
        "mismatch": dict(mismatch),
        "trace": {
            "t": [float(v) for v in tr.t],
            "x": [float(v) for v in poses[:, 0]],
            "y": [float(v) for v in poses[:, 1]],
            "yaw": [float(v) for v in poses[:, 2]],
            "v": [float(v) for v in cmd[:, 0]],
            "w": [float(v) for v in cmd[:, 1]],
        },
    }
