"""PNG figures of maps, runs, benchmarks and robustness sweeps (matplotlib, Agg).

Figures are built on :class:`matplotlib.figure.Figure` objects rendered by the Agg canvas,
never through ``pyplot``: no global figure state, no GUI backend, safe in worker processes.
Every function writes one figure of a fixed pixel size (``figsize * dpi``) in the format of
the file's extension (PNG for ``.png``; also ``.pdf``, ``.svg``, ...: :func:`figure_formats`),
whole or not at all (:mod:`sanav_mj.outputs`), and returns its path.

- :func:`plot_areas`: the paper's Fig. 2 (scene -> inflated grid -> quadtree -> merged safe
  areas and graph) and Fig. 4 (corridor, waypoints, interpolated path, smoothed reference).
- :func:`plot_run`: the paper's Fig. 3 for one run (safe areas, the reference the run's
  controller tracked (:func:`run_reference`), executed path coloured by speed, footprints,
  collisions) with v / w over time.
- :func:`plot_success_bars`: the paper's Fig. 6, success rate per scenario and method.
- :func:`plot_heatmap`: robustness heat map over one or two swept keys (1-D: a line plot).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon, Rectangle

# Colours follow the paper's figures where it names them.
_OBSTACLE = "#c0392b"  # red blocks
_SAFE = "#27ae60"  # green safe regions
_GRID = "#7f8c8d"
_LEAF_FREE = "#2ecc71"
_LEAF_OCC = "#e74c3c"
_GRAPH = "#16a085"
_CORRIDOR = "#f1c40f"
_WAYPOINT = "#8e44ad"  # purple waypoints
_POLYLINE = "#f39c12"  # yellow/orange reference polyline
_SMOOTH = "#2471a3"  # blue B-spline
_START = "#1e8449"
_GOAL = "#c0392b"
_ROBOT = "#34495e"


def figure_formats() -> dict[str, str]:
    """The file formats figures can be written in: extension (no dot) -> description
    (matplotlib's: png, pdf, svg, eps, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return dict(FigureCanvasBase.get_supported_filetypes())


def figure_format(path: str | Path) -> str:
    """The format of a figure file from its extension (``a.pdf`` -> ``pdf``; none -> ``png``,
    e.g. ``/dev/stdout``).

    Raises:
        ValueError: the extension is not a format of :func:`figure_formats` (``r.txt``).
    """
    ext = Path(path).suffix.lower().lstrip(".")
    if not ext:
        return "png"
    formats = figure_formats()
    if ext not in formats:
        raise ValueError(f"{path}: expected a figure file ending in one of .{', .'.join(sorted(formats))} "
                         f"(none: PNG), got '.{ext}'")
    return ext


def _save(fig: Figure, path: str | Path) -> Path:
    """Write ``fig`` in the format of ``path``'s extension (PNG for ``.png``), whole or not at all."""
    from sanav_mj.outputs import atomic_path

    path = Path(path)
    fmt = figure_format(path)
    FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=fig.dpi)
    return path


def _rects(arr: Any, name: str) -> np.ndarray:
    r = np.asarray(arr, dtype=float)
    if r.size == 0:
        return np.zeros((0, 4))
    if r.ndim != 2 or r.shape[1] != 4:
        raise ValueError(f"{name}: expected an (R, 4) array xmin, ymin, xmax, ymax [m], got shape {r.shape}")
    if np.any(r[:, 2] < r[:, 0]) or np.any(r[:, 3] < r[:, 1]):
        raise ValueError(f"{name}: every rectangle needs xmin <= xmax and ymin <= ymax")
    return r


def _xy(arr: Any, name: str) -> np.ndarray:
    a = np.asarray(arr, dtype=float)
    if a.size == 0:
        return np.zeros((0, 2))
    if a.ndim != 2 or a.shape[1] < 2:
        raise ValueError(f"{name}: expected a (K, 2) or (K, 3) array of positions [m], got shape {a.shape}")
    return a[:, :2]


def _draw_rects(ax, rects: np.ndarray, *, face: str | None, edge: str, alpha: float = 1.0, lw: float = 0.8,
                zorder: float = 1.0) -> None:
    if not len(rects):
        return
    patches = [Rectangle((r[0], r[1]), r[2] - r[0], r[3] - r[1]) for r in rects]
    ax.add_collection(PatchCollection(patches, facecolor=face if face else "none", edgecolor=edge, alpha=alpha,
                                      linewidth=lw, zorder=zorder))


def _draw_obstacles(ax, scenario: Any, *, filled: bool = True, zorder: float = 3.0) -> None:
    patches = []
    for o in scenario.obstacles:
        if o.kind == "box":
            patches.append(Polygon(o.corners(), closed=True))
        else:
            patches.append(Circle(tuple(np.asarray(o.center, dtype=float)), float(o.half_size[0])))
    if patches:
        ax.add_collection(PatchCollection(patches, facecolor=_OBSTACLE if filled else "none", edgecolor=_OBSTACLE,
                                          alpha=0.85 if filled else 1.0, linewidth=1.2, zorder=zorder))


def _frame(ax, bounds: np.ndarray, title: str) -> None:
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, edgecolor="black", linewidth=1.2,
                           zorder=0.5))
    pad = 0.03 * max(xmax - xmin, ymax - ymin)
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)


def _start_goal(ax, start: np.ndarray, goal: np.ndarray, used_goal: np.ndarray | None = None) -> None:
    ax.plot(start[0], start[1], "o", color=_START, markersize=9, markeredgecolor="white", zorder=8, label="start")
    if start.size >= 3:
        ax.annotate("", xy=(start[0] + 0.4 * np.cos(start[2]), start[1] + 0.4 * np.sin(start[2])),
                    xytext=(start[0], start[1]), arrowprops={"arrowstyle": "->", "color": _START, "lw": 1.5},
                    zorder=8)
    ax.plot(goal[0], goal[1], "*", color=_GOAL, markersize=14, markeredgecolor="white", zorder=8, label="goal")
    if used_goal is not None and used_goal.size == 2 and np.hypot(*(used_goal - goal[:2])) > 1e-6:
        ax.plot(used_goal[0], used_goal[1], "*", color="none", markersize=14, markeredgecolor=_GOAL, zorder=8,
                label="goal (projected)")


def _check_leaves(leaves: Any) -> tuple[np.ndarray, np.ndarray]:
    boxes = np.asarray(leaves.boxes)
    free = np.asarray(leaves.free, dtype=bool).reshape(-1)
    if boxes.ndim != 2 or boxes.shape[1] != 4 or boxes.shape[0] != free.shape[0]:
        raise ValueError(f"leaves: boxes (n, 4) and free (n,) must agree, got {boxes.shape} and {free.shape}")
    return boxes, free


def plot_areas(prep: Any, path: str | Path, dpi: int = 100) -> Path:
    """The map and plan of a prepared scenario, in five panels.

    (a) the scene (obstacles' true footprints), (b) the inflated occupancy grid, (c) the
    quadtree leaves (free green, occupied red), (d) merged safe areas and their connectivity
    graph (the paper's Fig. 2), (e) trajectory generation (the paper's Fig. 4): safe areas,
    obstacles, the straight start-goal line (dashed), corridor, waypoints (large purple),
    the interpolated path (small purple, yellow polyline) and the smoothed reference (blue).

    Args:
        prep: a :class:`~sanav_mj.eval.prepare.Prepared` (scenario, grid, leaves, areas, plan).
        path: output PNG.
        dpi: [pixel/inch]; the image is 1500 x 900 px at 100 dpi.

    Returns:
        ``path``.

    Raises:
        ValueError: inconsistent inputs (leaf boxes vs states, rectangle arrays, indices).
    """
    from sanav_mj.record import leaf_rects

    sc, grid, areas, plan = prep.scenario, prep.grid, prep.areas, prep.plan
    bounds = np.asarray(sc.bounds, dtype=float)
    rects = _rects(areas.rects, "areas.rects")
    occ = np.asarray(grid.occupied, dtype=bool)
    if occ.ndim != 2:
        raise ValueError(f"grid.occupied: expected a 2-D (ny, nx) array, got shape {occ.shape}")
    res = float(grid.resolution)
    x0, y0 = (float(v) for v in grid.origin)
    extent = (x0, x0 + occ.shape[1] * res, y0, y0 + occ.shape[0] * res)
    edges = np.asarray(areas.edges, dtype=int).reshape(-1, 2)
    if edges.size and (edges.min() < 0 or edges.max() >= len(rects)):
        raise ValueError(f"areas.edges: indices must lie in [0, {len(rects)}), got {edges.min()}..{edges.max()}")
    corridor = np.asarray(plan.corridor, dtype=int).reshape(-1)
    if corridor.size and (corridor.min() < 0 or corridor.max() >= len(rects)):
        raise ValueError(f"plan.corridor: indices must lie in [0, {len(rects)}), got {corridor.tolist()}")

    fig = Figure(figsize=(15, 9), dpi=dpi, layout="constrained")
    gs = fig.add_gridspec(2, 3)
    ax_a, ax_b, ax_c = (fig.add_subplot(gs[0, i]) for i in range(3))
    ax_d = fig.add_subplot(gs[1, 0])
    ax_e = fig.add_subplot(gs[1, 1:])

    _draw_obstacles(ax_a, sc)
    _frame(ax_a, bounds, f"(a) scene {sc.name}: {len(sc.obstacles)} obstacles")

    ax_b.imshow(np.where(occ, 1.0, np.nan), origin="lower", extent=extent, cmap="Greys", vmin=0.0, vmax=1.6,
                interpolation="nearest", zorder=1)
    _draw_obstacles(ax_b, sc, filled=False)
    _frame(ax_b, bounds, f"(b) occupancy {occ.shape[1]} x {occ.shape[0]} @ {res:g} m, inflated {grid.inflation:.3g} m")

    if prep.leaves is not None:
        _, free = _check_leaves(prep.leaves)
        lr = leaf_rects(prep.leaves, grid.origin, res)
        _draw_rects(ax_c, lr[~free], face=_LEAF_OCC, edge="#922b21", alpha=0.55, lw=0.3)
        _draw_rects(ax_c, lr[free], face=None, edge=_LEAF_FREE, lw=0.5)
        title_c = f"(c) quadtree: {int(free.sum())} free / {int((~free).sum())} occupied leaves"
    else:
        title_c = "(c) quadtree: no leaves"
    _frame(ax_c, bounds, title_c)

    _draw_rects(ax_d, rects, face=_SAFE, edge="#145a32", alpha=0.35, lw=0.8)
    centers = (rects[:, :2] + rects[:, 2:]) / 2.0 if len(rects) else np.zeros((0, 2))
    if len(edges):
        ax_d.add_collection(LineCollection(np.stack((centers[edges[:, 0]], centers[edges[:, 1]]), axis=1),
                                           colors=_GRAPH, linewidths=0.8, zorder=4))
    if len(centers):
        ax_d.plot(centers[:, 0], centers[:, 1], ".", color=_GRAPH, markersize=3, zorder=5)
    _draw_obstacles(ax_d, sc, filled=False)
    _frame(ax_d, bounds, f"(d) {len(rects)} safe areas, {len(edges)} graph edges")

    _draw_rects(ax_e, rects, face=_SAFE, edge="#145a32", alpha=0.25, lw=0.6)
    _draw_obstacles(ax_e, sc)
    if corridor.size:
        _draw_rects(ax_e, rects[corridor], face=None, edge=_CORRIDOR, lw=2.0, zorder=4)
    start = np.asarray(sc.start, dtype=float)
    goal = np.asarray(sc.goal, dtype=float)
    ax_e.plot([start[0], goal[0]], [start[1], goal[1]], "--", color="#2c3e50", lw=1.2, zorder=5,
              label="straight line")
    wp = _xy(plan.waypoints, "plan.waypoints")
    pth = _xy(plan.path, "plan.path")
    sm = _xy(plan.smoothed, "plan.smoothed")
    if len(pth):
        ax_e.plot(pth[:, 0], pth[:, 1], "-", color=_POLYLINE, lw=2.0, zorder=6, label="interpolated path")
        ax_e.plot(pth[:, 0], pth[:, 1], ".", color=_WAYPOINT, markersize=3, zorder=7)
    if len(wp):
        ax_e.plot(wp[:, 0], wp[:, 1], "o", color=_WAYPOINT, markersize=7, zorder=7, label="waypoints")
    if len(sm):
        ax_e.plot(sm[:, 0], sm[:, 1], "-", color=_SMOOTH, lw=2.0, zorder=6, label="smoothed (B-spline)")
    _start_goal(ax_e, start, goal, np.asarray(plan.goal, dtype=float).reshape(-1))
    status = "" if plan.ok else f" - {plan.reason}"
    _frame(ax_e, bounds, f"(e) corridor of {corridor.size} areas, {len(wp)} waypoints{status}")
    ax_e.legend(loc="upper left", fontsize=8, framealpha=0.85)
    return _save(fig, path)


def _trace_arrays(tr: Any) -> dict[str, np.ndarray]:
    """The trace's per-step arrays, checked for equal lengths."""
    fields = ("t", "pose", "cmd", "velocity", "contacts")
    lengths = {f: len(getattr(tr, f)) for f in fields}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"trace: per-step lists must have equal lengths, got {lengths}")
    n = lengths["t"]
    return {
        "t": np.asarray(tr.t, dtype=float).reshape(n),
        "pose": np.asarray(tr.pose, dtype=float).reshape(n, 3),
        "cmd": np.asarray(tr.cmd, dtype=float).reshape(n, 2),
        "velocity": np.asarray(tr.velocity, dtype=float).reshape(n, 2),
        "contacts": np.asarray(tr.contacts, dtype=float).reshape(n),
    }


@dataclass
class RunReference:
    """What a run's controller tracked, to draw on the map.

    Attributes:
        label: legend text; when ``paths`` is empty it says that there is no reference path
            and what the controller was given instead.
        paths: polylines (K_i, 2) [m] of the reference (empty: none).
        origins: (len(paths), 2) [m] the measured robot position each path was computed
            from, or (0, 2) when the path does not depend on the robot's position.
    """

    label: str
    paths: list[np.ndarray] = field(default_factory=list)
    origins: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def run_reference(outcome: Any, steps: Sequence[int] = (0,)) -> RunReference:
    """The reference that the run's controller (``outcome.controller``) tracked.

    - ``"sa-mpc"``: the planned reference (smoothed, time-parametrised path through the
      safe-area corridor), one polyline; none when planning found no path.
    - ``"mpc"``: the penalty MPC re-aims its reference at every step: the straight line to
      the goal from the *measured* pose, from ``lookahead`` ahead over the horizon
      (:func:`sanav_mj.control.penalty_mpc.straight_reference` with the settings of the
      run's controller spec, ``outcome.spec``), one segment per step in ``steps``.
    - ``"dwa"``, ``"dqn"`` and any other name: no reference path (DWA scores arcs by their
      heading to the goal; the DQN policy sees the goal's distance and bearing).

    Args:
        outcome: a :class:`~sanav_mj.eval.outcome.RunOutcome`.
        steps: control-step indices at which the ``"mpc"`` reference is drawn (indices
            outside the trace are ignored).
    """
    prep, tr = outcome.prepared, outcome.episode.trace
    name = str(outcome.controller)
    if name == "sa-mpc":
        ref = prep.plan.reference
        if ref is None or not len(ref):
            return RunReference(f"no reference path (planning: {prep.plan.reason})")
        return RunReference("reference (safe-area corridor)", [np.asarray(ref.states, dtype=float)[:, :2]])
    if name == "mpc":
        from sanav_mj.control.penalty_mpc import resolved_reference_speed, straight_reference
        from sanav_mj.control.spec import ControllerSpec

        spec = getattr(outcome, "spec", None) or ControllerSpec("mpc")
        cfg, pen = spec.mpc, spec.penalty
        speed = resolved_reference_speed(prep.scenario.robot, cfg, pen)
        seen = tr.measured if len(tr.measured) == len(tr.t) else tr.pose
        if not len(seen):  # no step was run: the reference of the first step, from the start
            seen = [np.asarray(outcome.start, dtype=float).reshape(3)]
        idx = sorted({int(k) for k in steps if 0 <= int(k) < len(seen)})
        poses = [np.asarray(seen[k], dtype=float).reshape(3) for k in idx]
        poses = [p for p in poses if np.all(np.isfinite(p))]
        paths = [straight_reference(p, prep.scenario.goal, pen.lookahead, speed, cfg.horizon, cfg.dt)[0][:, :2]
                 for p in poses]
        origins = np.array([p[:2] for p in poses]).reshape(-1, 2)
        return RunReference(f"reference: straight to the goal from {pen.lookahead:g} m ahead, re-aimed "
                            "every step (drawn at the footprints)", paths, origins)
    given = {"dwa": "DWA scores arcs by heading to the goal", "dqn": "DQN sees the goal's distance and bearing"}
    return RunReference(f"no reference path ({given.get(name, f'controller {name!r}')})")


def plot_run(outcome: Any, path: str | Path, n_footprints: int = 6, dpi: int = 100) -> Path:
    """One run (the paper's Fig. 3): map with the executed path, and v / w over time.

    The map shows the safe areas (green), obstacles (red), the reference the controller
    tracked (blue, :func:`run_reference`: SA-MPC's planned reference; the penalty MPC's
    straight reference at the footprint steps, dotted from the measured position; for DWA
    and DQN none, which the legend says), the executed path coloured by measured speed,
    start / goal, the robot footprint at ``n_footprints`` poses evenly spaced in time plus
    the final one, and a red cross at every step that ended in contact. The right panels
    show commanded and measured v and w.

    Args:
        outcome: a :class:`~sanav_mj.eval.outcome.RunOutcome`.
        path: output PNG.
        n_footprints: footprints drawn along the path (>= 0).
        dpi: [pixel/inch]; the image is 1500 x 750 px at 100 dpi.

    Returns:
        ``path``.

    Raises:
        ValueError: trace lists of unequal lengths, or bad arguments.
    """
    from sanav_mj.record import robot_footprint

    if isinstance(n_footprints, bool) or not isinstance(n_footprints, int) or n_footprints < 0:
        raise ValueError(f"n_footprints: expected an integer >= 0, got {n_footprints!r}")
    prep, ep = outcome.prepared, outcome.episode
    sc = prep.scenario
    tr = _trace_arrays(ep.trace)
    bounds = np.asarray(sc.bounds, dtype=float)
    rects = _rects(prep.areas.rects, "areas.rects")
    doc = outcome.document or {}

    fig = Figure(figsize=(15, 7.5), dpi=dpi, layout="constrained")
    gs = fig.add_gridspec(2, 2, width_ratios=[2.2, 1.0])
    ax = fig.add_subplot(gs[:, 0])
    ax_v = fig.add_subplot(gs[0, 1])
    ax_w = fig.add_subplot(gs[1, 1], sharex=ax_v)

    _draw_rects(ax, rects, face=_SAFE, edge="#145a32", alpha=0.25, lw=0.6)
    _draw_obstacles(ax, sc)
    pose = tr["pose"]
    n = len(pose)
    idx = np.unique(np.linspace(0, n - 1, n_footprints).round().astype(int)) if n and n_footprints else []
    reference = run_reference(outcome, [int(i) for i in idx] or [0])
    for i, line in enumerate(reference.paths):
        ax.plot(line[:, 0], line[:, 1], "-", color=_SMOOTH, lw=1.5, zorder=5,
                label=reference.label if i == 0 else None)
    for origin, line in zip(reference.origins, reference.paths):
        ax.plot([origin[0], line[0, 0]], [origin[1], line[0, 1]], ":", color=_SMOOTH, lw=0.8, zorder=5)
    if not reference.paths:
        ax.plot([], [], " ", label=reference.label)
    if n:
        xy = np.vstack((pose[:, :2], np.asarray(ep.final_pose, dtype=float).reshape(3)[:2]))
        speed = np.abs(tr["velocity"][:, 0])
        segs = np.stack((xy[:-1], xy[1:]), axis=1)
        lc = LineCollection(segs, cmap="plasma", linewidths=2.5, zorder=6)
        lc.set_array(speed)
        lc.set_clim(0.0, max(float(sc.robot.v_max), float(speed.max()) if speed.size else 0.0, 1e-6))
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label="measured speed [m/s]", shrink=0.8)
        fp = robot_footprint(sc.model)
        poses = [pose[i] for i in idx] + [np.asarray(ep.final_pose, dtype=float).reshape(3)]
        for p in poses:
            c, s = np.cos(p[2]), np.sin(p[2])
            corners = fp @ np.array([[c, s], [-s, c]]) + p[:2]
            ax.add_patch(Polygon(corners, closed=True, fill=False, edgecolor=_ROBOT, linewidth=1.0, zorder=7))
            nose = p[:2] + 0.8 * float(fp[:, 0].max()) * np.array([c, s])
            ax.plot([p[0], nose[0]], [p[1], nose[1]], "-", color=_ROBOT, lw=1.0, zorder=7)
        hit = tr["contacts"] > 0
        if hit.any():
            ax.plot(pose[hit, 0], pose[hit, 1], "x", color="red", markersize=12, mew=2.5, zorder=9,
                    label="collision")
    start = np.asarray(outcome.start, dtype=float).reshape(-1)
    _start_goal(ax, start, np.asarray(sc.goal, dtype=float))
    head = f"{sc.name} / {outcome.controller}"
    if "seed" in doc:
        head += f" (seed {doc['seed']})"
    head += f": {ep.reason}, {ep.steps} steps, {ep.sim_time_s:.1f} s"
    if "path_length_m" in doc:
        head += f", path {doc['path_length_m']:.2f} m"
    if doc.get("min_clearance_m") is not None:
        head += f", min clearance {doc['min_clearance_m']:.3f} m"
    _frame(ax, bounds, head)
    ax.legend(loc="upper left", fontsize=8, framealpha=0.85)

    t = tr["t"]
    ax_v.plot(t, tr["cmd"][:, 0], "-", color="#e67e22", lw=1.2, label="commanded")
    ax_v.plot(t, tr["velocity"][:, 0], "-", color="#2c3e50", lw=1.0, label="measured")
    ax_v.set_ylabel("v [m/s]")
    ax_v.legend(fontsize=8)
    ax_v.grid(alpha=0.3)
    ax_w.plot(t, tr["cmd"][:, 1], "-", color="#e67e22", lw=1.2, label="commanded")
    ax_w.plot(t, tr["velocity"][:, 1], "-", color="#2c3e50", lw=1.0, label="measured")
    ax_w.set_ylabel("w [rad/s]")
    ax_w.set_xlabel("simulated time [s]")
    ax_w.grid(alpha=0.3)
    return _save(fig, path)


def plot_success_bars(rows: Sequence[dict[str, Any]], path: str | Path, dpi: int = 100) -> Path:
    """Grouped bars of success rate per scenario and method (the paper's Fig. 6).

    Args:
        rows: one dict per (scenario, controller) with keys ``scenario`` (str),
            ``controller`` (str) and ``success_rate`` [%] in [0, 100]. Groups and bars keep
            the order of first appearance; a missing pair leaves a gap.
        path: output PNG.
        dpi: [pixel/inch]; the image is 1200 x 600 px at 100 dpi.

    Returns:
        ``path``.

    Raises:
        ValueError: no rows, a missing key, a rate outside [0, 100], or a duplicate pair.
    """
    if not rows:
        raise ValueError("rows: expected at least one {scenario, controller, success_rate} row, got none")
    scenarios: list[str] = []
    controllers: list[str] = []
    rate: dict[tuple[str, str], float] = {}
    for i, r in enumerate(rows):
        for key in ("scenario", "controller", "success_rate"):
            if key not in r:
                raise ValueError(f"rows[{i}]: missing key {key!r} (has {sorted(r)})")
        s, c = str(r["scenario"]), str(r["controller"])
        v = float(r["success_rate"])
        if not (np.isfinite(v) and 0.0 <= v <= 100.0):
            raise ValueError(f"rows[{i}].success_rate: expected a percentage in [0, 100], got {r['success_rate']!r}")
        if (s, c) in rate:
            raise ValueError(f"rows[{i}]: duplicate pair scenario={s!r} controller={c!r}")
        rate[(s, c)] = v
        if s not in scenarios:
            scenarios.append(s)
        if c not in controllers:
            controllers.append(c)

    fig = Figure(figsize=(12, 6), dpi=dpi, layout="constrained")
    ax = fig.add_subplot()
    width = 0.8 / len(controllers)
    x = np.arange(len(scenarios))
    colors = ["#2471a3", "#c0392b", "#27ae60", "#8e44ad", "#f39c12", "#16a085", "#7f8c8d"]
    for k, c in enumerate(controllers):
        xs = [x[i] + (k - (len(controllers) - 1) / 2) * width for i, s in enumerate(scenarios) if (s, c) in rate]
        vs = [rate[(s, c)] for s in scenarios if (s, c) in rate]
        bars = ax.bar(xs, vs, width=width * 0.95, label=c, color=colors[k % len(colors)])
        ax.bar_label(bars, labels=[f"{v:.0f}" for v in vs], fontsize=8, padding=2)
    ax.set_xticks(x, scenarios)
    ax.set_ylim(0, 112)
    ax.set_ylabel("success rate [%]")
    ax.set_title("Success rate per scenario and method")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(ncols=len(controllers), loc="upper center", fontsize=9)
    return _save(fig, path)


def _heat_style(title: str, values: np.ndarray, cmap: str | None, vmin: float | None, vmax: float | None
                ) -> tuple[str, float, float]:
    t = title.lower()
    if cmap is None:
        cmap = "RdYlGn" if "success" in t else "RdYlGn_r" if "collision" in t else "viridis"
    finite = values[np.isfinite(values)]
    if "%" in title:
        lo, hi = 0.0, 100.0
    elif finite.size:
        lo, hi = float(finite.min()), float(finite.max())
    else:
        lo, hi = 0.0, 1.0
    lo = lo if vmin is None else float(vmin)
    hi = hi if vmax is None else float(vmax)
    if hi <= lo:
        hi = lo + 1.0
    return cmap, lo, hi


def plot_heatmap(
    grid_values: Any,
    x_key: str,
    x_values: Sequence[Any],
    y_key: str | None,
    y_values: Sequence[Any] | None,
    title: str,
    path: str | Path,
    *,
    cmap: str | None = None,
    vmin: float | None = None,
    vmax: float | None = None,
    fmt: str = "{:.3g}",
    dpi: int = 100,
) -> Path:
    """Robustness heat map with annotated cells, or a line plot when one key is swept.

    Args:
        grid_values: (len(y_values), len(x_values)) values; cell [i, j] belongs to
            ``y_values[i]`` and ``x_values[j]``. Non-finite cells are drawn blank ("n/a").
        x_key: name of the swept key on the x axis.
        x_values: its values (numbers or labels).
        y_key: name of the second key, or None / "" for a 1-D sweep.
        y_values: its values; for a 1-D sweep None or a single placeholder, and
            ``grid_values`` is (len(x_values),) or (1, len(x_values)).
        title: figure title (a title containing "%" fixes the colour range to [0, 100];
            "success" / "collision" in it pick a green-is-good / red-is-bad colour map).
        path: output PNG.
        cmap, vmin, vmax: override the colour map and range.
        fmt: format of the cell annotations.
        dpi: [pixel/inch]; the image is 900 x 700 px at 100 dpi (900 x 500 for 1-D).

    Returns:
        ``path``.

    Raises:
        ValueError: ``grid_values`` does not match the value lists, or a list is empty.
    """
    vals = np.asarray(grid_values, dtype=float)
    nx = len(x_values)
    if nx == 0:
        raise ValueError("x_values: expected at least one value, got none")
    one_d = not y_key
    if one_d:
        ny = 1 if y_values is None else len(y_values)
        if ny != 1 or vals.size != nx or vals.ndim > 2 or (vals.ndim == 2 and vals.shape[0] != 1):
            raise ValueError(f"grid_values: a 1-D sweep of {x_key!r} needs shape ({nx},) or (1, {nx}) and at most one "
                             f"y value, got shape {vals.shape} and {ny} y values")
        vals = vals.reshape(nx)
    else:
        if y_values is None or len(y_values) == 0:
            raise ValueError(f"y_values: expected at least one value for y_key {y_key!r}, got none")
        if vals.shape != (len(y_values), nx):
            raise ValueError(f"grid_values: expected shape (len(y_values), len(x_values)) = ({len(y_values)}, {nx}), "
                             f"got {vals.shape}")
    cmap_name, lo, hi = _heat_style(title, vals, cmap, vmin, vmax)
    labels_x = [str(v) for v in x_values]

    if one_d:
        fig = Figure(figsize=(9, 5), dpi=dpi, layout="constrained")
        ax = fig.add_subplot()
        xs = np.arange(nx)
        ax.plot(xs, vals, "o-", color="#2471a3", lw=1.5, markersize=7)
        for xi, v in zip(xs, vals):
            ax.annotate("n/a" if not np.isfinite(v) else fmt.format(v), (xi, v if np.isfinite(v) else lo),
                        textcoords="offset points", xytext=(0, 8), ha="center", fontsize=9)
        ax.set_xticks(xs, labels_x)
        ax.set_xlim(-0.5, nx - 0.5)
        ax.set_xlabel(x_key)
        pad = 0.08 * (hi - lo)
        ax.set_ylim(lo - pad, hi + pad)
        ax.grid(alpha=0.3)
        ax.set_title(title)
        return _save(fig, path)

    fig = Figure(figsize=(9, 7), dpi=dpi, layout="constrained")
    ax = fig.add_subplot()
    masked = np.ma.masked_invalid(vals)
    im = ax.imshow(masked, origin="lower", cmap=cmap_name, vmin=lo, vmax=hi, aspect="auto")
    fig.colorbar(im, ax=ax)
    mid = (lo + hi) / 2.0
    for i in range(vals.shape[0]):
        for j in range(nx):
            v = vals[i, j]
            text = "n/a" if not np.isfinite(v) else fmt.format(v)
            dark = np.isfinite(v) and cmap_name == "viridis" and v < mid
            ax.text(j, i, text, ha="center", va="center", fontsize=10, color="white" if dark else "black")
    ax.set_xticks(np.arange(nx), labels_x)
    ax.set_yticks(np.arange(vals.shape[0]), [str(v) for v in y_values])
    ax.set_xlabel(x_key)
    ax.set_ylabel(str(y_key))
    ax.set_title(title)
    return _save(fig, path)
