"""Rerun recordings of episodes: the map and plan once, then the run step by step.

A :class:`Recorder` owns an explicit :class:`rerun.RecordingStream` (never the global one)
that encodes into memory; :meth:`Recorder.close` writes the ``.rrd`` file whole or not at
all (a write error such as a full disk is raised naming the file; Ctrl-C leaves no partial
file). It is driven from the edge of the pipeline: either step by step
(:func:`sanav_mj.eval.episode.run_scenario`: the constructor logs the static scene, the
runner's ``on_step(step, trace)`` hook feeds :meth:`Recorder.log_step`, and
:meth:`Recorder.finish` logs the summary and closes the file) or, for a finished run, in one
call (:func:`record_episode`, what ``sanav-mj run --rrd`` uses). Algorithms never log.

Open a recording with ``rerun FILE.rrd``; the file carries a default blueprint (a 2D map
beside time-series panels), see ``docs/recordings.md``.

Timelines
    ``step`` (sequence, control step index) and ``sim_time`` (duration, simulated seconds).
    Step ``k`` is stamped with the time at the *start* of the step (``trace.t[k]``); the
    final pose after the last step is stamped ``step = S``, ``sim_time = episode.sim_time_s``.

Entity paths (world frame, metres; all 2D entities live under ``world``)
    Static (logged once):

    ==========================  =====================================================
    ``world``                   Transform3D ``scale = (1, -1, 1)``: display only, so the
                                2D view (y down on screen) shows the map y-up. Every
                                entity below holds true world coordinates.
    ``world/workspace``         LineStrips2D, the floor rectangle.
    ``world/obstacles/boxes``   LineStrips2D, closed box footprints (label = geom name).
    ``world/obstacles/round``   Ellipses2D, cylinder / capsule footprints (label = name).
    ``world/grid``              Image (RGBA, occupied cells grey) under a Transform3D
                                that places pixel (row i, col j) at the cell's world box.
    ``world/quadtree/free``     Boxes2D, free quadtree leaves (hidden by default).
    ``world/quadtree/occupied`` Boxes2D, occupied quadtree leaves (hidden by default).
    ``world/safe_areas``        Boxes2D, merged safe rectangles; instance index = area id.
    ``world/graph/edges``       LineStrips2D, one segment per graph edge between centres
                                (hidden by default).
    ``world/graph/nodes``       Points2D, area centres; instance index = area id (hidden
                                by default).
    ``world/plan/corridor``     Boxes2D, the corridor's areas (label = area id).
    ``world/plan/waypoints``    Points2D, start, portal crossings, goal.
    ``world/plan/path``         LineStrips2D, arc-length-interpolated waypoint polyline.
    ``world/plan/reference``    LineStrips2D + ``world/plan/reference/samples`` Points2D:
                                the smoothed reference at the MPC step.
    ``world/start``             Points2D, the scenario's start position.
    ``world/goal``              Points2D, the goal (and the projected goal when it differs).
    ``world/robot/footprint``   LineStrips2D, chassis rectangle in the robot frame.
    ``world/robot/heading``     Arrows2D, x axis of the robot frame.
    ==========================  =====================================================

    Per step (timelines ``step`` and ``sim_time``):

    ===============================  ==================================================
    ``world/robot``                  Transform3D: true pose (translation x, y; yaw).
    ``world/trail``                  LineStrips2D, the segment driven during the step
                                     (the blueprint shows the whole history: the path).
    ``world/measured``               Points2D, the pose the controller saw.
    ``world/collisions``             Points2D, robot position at steps with contacts.
    ``world/horizon/predicted``      LineStrips2D, MPC predicted positions (N+1).
    ``world/horizon/points``         Points2D, the same, red where the margin < 0.
    ``world/horizon/rects``          Boxes2D, safe areas assigned to the horizon
                                     (label = area id).
    ``plots/velocity/{v,w}_{cmd,meas}``   Scalars [m/s], [rad/s]: commanded (controller
                                     output) and measured base velocity.
    ``plots/wheels/{left,right}_{cmd,meas}``  Scalars [rad/s].
    ``plots/slip/{v,w}``             Scalars: applied (v, w) (what reached the wheels)
                                     minus measured (v, w) [m/s], [rad/s].
    ``plots/timing/{solve_ms,pipeline_ms}``   Scalars [ms].
    ``plots/safety/clearance``       Scalars [m], robot-obstacle distance.
    ``plots/safety/margin_min``      Scalars [m], smallest horizon constraint slack.
    ``plots/safety/contacts``        Scalars, robot-obstacle contacts after the step.
    ``plots/solver/ok``              Scalars, 1 when the solver succeeded, 0 on fallback.
    ``solver/status``                TextLog, at step 0 and whenever the status changes.
    ===============================  ==================================================

    At the end: ``summary`` (static TextDocument, markdown with the ``run --json``
    document without its trace).

Sensing (``--sensing lidar`` runs, :meth:`Recorder.log_sensing`)
    ``world/sensing/scan`` (Points2D per step: the scan's returns at the measured pose),
    ``world/sensing/map`` (Image: unknown / free / occupied, only when it changed, at most
    every 5 steps and at replans), ``world/sensing/safe_areas`` (Boxes2D, same schedule),
    ``world/sensing/corridor`` (Boxes2D per step), ``plots/timing/map_update_ms``
    (Scalars [ms]) and ``sensing/replans`` (TextLog).

Cost: per-step data is not converted on every step; :meth:`Recorder.log_step` only notes
how far the trace has grown and every ``flush_every`` steps the new rows are sent as
columns (``send_columns``), one call per entity. Nothing static is ever re-logged.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

import mujoco
import numpy as np

from sanav_mj.outputs import write_bytes
from sanav_mj.scene import Scenario

if TYPE_CHECKING:
    import rerun.blueprint as rrb

# rerun is imported inside the functions that log (about 0.3 s on first import): importing
# this module for its geometry helpers (the plots do) must not pay for it.

APP_ID = "sanav_mj"
TIMELINE_STEP = "step"
TIMELINE_TIME = "sim_time"

# Colours (RGBA) for a dark viewer background.
_C_WORKSPACE = (200, 200, 200, 255)
_C_OBSTACLE = (255, 140, 40, 255)
_C_GRID = (130, 130, 130, 150)
_C_LEAF_FREE = (60, 180, 90, 255)
_C_LEAF_OCC = (200, 70, 70, 255)
_C_AREA = (80, 150, 255, 255)
_C_GRAPH = (90, 200, 220, 255)
_C_CORRIDOR = (255, 220, 60, 255)
_C_WAYPOINT = (255, 255, 255, 255)
_C_PATH = (170, 170, 170, 255)
_C_REFERENCE = (230, 80, 230, 255)
_C_START = (80, 230, 80, 255)
_C_GOAL = (255, 60, 60, 255)
_C_ROBOT = (255, 200, 0, 255)
_C_TRAIL = (255, 150, 0, 255)
_C_MEASURED = (120, 220, 255, 255)
_C_HORIZON = (60, 255, 120, 255)
_C_HORIZON_BAD = (255, 40, 40, 255)
_C_COLLISION = (255, 0, 0, 255)
_C_SCAN = (255, 60, 200, 255)
_C_UNKNOWN = (40, 40, 60, 120)
_C_FREE = (235, 235, 235, 70)
_C_OCCUPIED = (20, 20, 20, 230)

# Draw order of 2D layers (higher is drawn on top).
_Z_GRID, _Z_LEAVES, _Z_AREAS, _Z_GRAPH, _Z_CORRIDOR, _Z_PLAN, _Z_OBST = -20.0, -15.0, -10.0, -8.0, -6.0, -4.0, -2.0
_Z_TRAIL, _Z_HORIZON, _Z_ROBOT, _Z_MARK = 5.0, 6.0, 10.0, 12.0

#: Scalar plot entities, their legend names and colours (logged once as SeriesLines).
_SERIES: dict[str, tuple[str, tuple[int, int, int, int]]] = {
    "plots/velocity/v_cmd": ("v commanded [m/s]", (255, 180, 0, 255)),
    "plots/velocity/v_meas": ("v measured [m/s]", (255, 230, 140, 255)),
    "plots/velocity/w_cmd": ("w commanded [rad/s]", (0, 160, 255, 255)),
    "plots/velocity/w_meas": ("w measured [rad/s]", (150, 210, 255, 255)),
    "plots/wheels/left_cmd": ("left commanded [rad/s]", (255, 120, 0, 255)),
    "plots/wheels/left_meas": ("left measured [rad/s]", (255, 200, 140, 255)),
    "plots/wheels/right_cmd": ("right commanded [rad/s]", (0, 200, 120, 255)),
    "plots/wheels/right_meas": ("right measured [rad/s]", (150, 240, 190, 255)),
    "plots/slip/v": ("v applied - measured [m/s]", (255, 180, 0, 255)),
    "plots/slip/w": ("w applied - measured [rad/s]", (0, 160, 255, 255)),
    "plots/timing/solve_ms": ("solve [ms]", (230, 80, 230, 255)),
    "plots/timing/pipeline_ms": ("pipeline [ms]", (170, 170, 170, 255)),
    "plots/safety/clearance": ("clearance [m]", (80, 230, 80, 255)),
    "plots/safety/margin_min": ("min horizon margin [m]", (80, 150, 255, 255)),
    "plots/safety/contacts": ("contacts", (255, 40, 40, 255)),
    "plots/solver/ok": ("solver ok (1) / fallback (0)", (200, 200, 200, 255)),
}


@dataclass(frozen=True)
class RecordConfig:
    """Recording settings.

    Attributes:
        flush_every: [steps] per-step data is sent in columns every this many steps
            (1 = every step, as it happens); the rest is sent by :meth:`Recorder.finish`.
        show_quadtree: show the quadtree leaves in the default layout (they are always
            recorded; hidden by default because the safe areas cover the same ground).
        show_graph: show the connectivity graph in the default layout (always recorded;
            hidden by default: on real maps its many edges hide the run).
    """

    flush_every: int = 50
    show_quadtree: bool = False
    show_graph: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.flush_every, bool) or not isinstance(self.flush_every, int) or self.flush_every < 1:
            raise ValueError(f"RecordConfig.flush_every: expected an integer >= 1 [steps], got {self.flush_every!r}")
        for name in ("show_quadtree", "show_graph"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"RecordConfig.{name}: expected a bool, got {getattr(self, name)!r}")


def robot_footprint(model: mujoco.MjModel, base: str = "base") -> np.ndarray:
    """Planar footprint rectangle of the robot in its own frame.

    The axis-aligned (in the robot frame) bounding rectangle of every collision geom of the
    robot (the bodies whose root is ``base``), read from the model by name.

    Args:
        model: compiled MuJoCo model holding the robot.
        base: name of the robot's root body.

    Returns:
        (4, 2) [m] corners x forward, y left, counter-clockwise from front-left.
    """
    bid = model.body(base).id
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    rot = data.xmat[bid].reshape(3, 3)
    origin = data.xpos[bid]
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    pts = []
    for g in range(model.ngeom):
        if model.body_rootid[model.geom_bodyid[g]] != bid:
            continue
        if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
            continue
        aabb = model.geom_aabb[g]
        corners = aabb[:3] + aabb[3:] * signs
        world = data.geom_xpos[g] + corners @ data.geom_xmat[g].reshape(3, 3).T
        pts.append(((world - origin) @ rot)[:, :2])
    if not pts:
        raise ValueError(f"robot_footprint: body {base!r} has no collision geoms")
    p = np.concatenate(pts)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return np.array([[hi[0], hi[1]], [lo[0], hi[1]], [lo[0], lo[1]], [hi[0], lo[1]]])


def leaf_rects(leaves: Any, origin: np.ndarray, resolution: float) -> np.ndarray:
    """World rectangles of quadtree leaves.

    Args:
        leaves: :class:`~sanav_mj.mapping.quadtree.QuadtreeLeaves` (``boxes`` (n, 4) int
            cell boxes ``[i0, j0, i1, j1)``).
        origin: (2,) [m] grid lower-left corner.
        resolution: [m] cell size.

    Returns:
        (n, 4) [m] ``xmin, ymin, xmax, ymax``.
    """
    b = np.asarray(leaves.boxes, dtype=float).reshape(-1, 4)
    x0, y0 = float(origin[0]), float(origin[1])
    return np.column_stack(
        (x0 + b[:, 1] * resolution, y0 + b[:, 0] * resolution, x0 + b[:, 3] * resolution, y0 + b[:, 2] * resolution)
    )


def _centers_half(rects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.asarray(rects, dtype=float).reshape(-1, 4)
    return (r[:, :2] + r[:, 2:]) / 2.0, (r[:, 2:] - r[:, :2]) / 2.0


def _closed(poly: np.ndarray) -> np.ndarray:
    return np.vstack((poly, poly[:1]))


def default_blueprint(show_quadtree: bool = False, show_graph: bool = False) -> rrb.Blueprint:
    """The layout sent with every recording: the 2D map beside the time-series panels.

    The quadtree leaves and the graph are recorded but hidden unless asked for (toggle them
    with the eye icon in the viewer's blueprint panel)."""
    import rerun.blueprint as rrb

    history = rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(TIMELINE_STEP, start=rrb.TimeRangeBoundary.infinite(),
                                 end=rrb.TimeRangeBoundary.cursor_relative(seq=0)),
            rrb.VisibleTimeRange(TIMELINE_TIME, start=rrb.TimeRangeBoundary.infinite(),
                                 end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0)),
        ]
    )
    overrides: dict[str, Any] = {"/world/trail": history, "/world/collisions": history}
    if not show_quadtree:
        overrides["/world/quadtree/free"] = rrb.EntityBehavior(visible=False)
        overrides["/world/quadtree/occupied"] = rrb.EntityBehavior(visible=False)
    if not show_graph:
        overrides["/world/graph/edges"] = rrb.EntityBehavior(visible=False)
        overrides["/world/graph/nodes"] = rrb.EntityBehavior(visible=False)
    world = rrb.Spatial2DView(name="map (world frame, m)", origin="/", contents="/world/**", overrides=overrides)
    plots = rrb.Vertical(
        rrb.TimeSeriesView(name="velocity: commanded vs measured", origin="/plots/velocity"),
        rrb.TimeSeriesView(name="wheel speeds [rad/s]", origin="/plots/wheels"),
        rrb.TimeSeriesView(name="slip: applied - measured", origin="/plots/slip"),
        rrb.TimeSeriesView(name="solve time [ms]", origin="/plots/timing"),
        rrb.TimeSeriesView(name="clearance and margins [m]", origin="/plots/safety"),
        rrb.Tabs(
            rrb.TextLogView(name="solver status", origin="/solver"),
            rrb.TimeSeriesView(name="solver ok", origin="/plots/solver"),
            rrb.TextDocumentView(name="summary", origin="/summary"),
        ),
    )
    return rrb.Blueprint(
        rrb.Horizontal(world, plots, column_shares=[3, 2]),
        # "following" opens on the last step (the whole executed path); scrub to replay.
        rrb.TimePanel(timeline=TIMELINE_TIME, play_state="following"),
        rrb.SelectionPanel(state="collapsed"),
        collapse_panels=False,
    )


class Recorder:
    """Records one episode to an ``.rrd`` file (see the module docstring for the layout).

    Args:
        path: output ``.rrd`` file (its folder is created when missing).
        prep: the prepared scenario (:class:`~sanav_mj.eval.prepare.Prepared`: scenario,
            grid, leaves, areas, plan).
        controller: controller name, shown in the recording name and summary.
        config: recording settings.

    Usage: ``rec = Recorder(path, prep, "sa-mpc")``; pass ``rec.log_step`` as the runner's
    ``on_step``; call ``rec.finish(episode, document)`` once at the end, or
    :func:`record_episode` to record a finished run in one call. Also a context manager:
    leaving the block without ``finish`` closes the file (data so far is kept), Ctrl-C
    discards it.

    The file is written whole or not at all, by :meth:`close`: the recording is held in
    memory until then (a few MB for a minute of driving), written to a temporary file
    beside ``path`` and renamed onto it. A write error (a full disk) is raised by
    :meth:`finish` / :meth:`close` as :class:`OSError` naming ``path``, with no file left
    behind; nothing is written before, so Ctrl-C leaves no partial file.
    """

    def __init__(self, path: str | Path, prep: Any, controller: str, config: RecordConfig = RecordConfig()) -> None:
        if not isinstance(config, RecordConfig):
            raise TypeError(f"Recorder: config must be a RecordConfig, got {type(config).__name__}")
        for attr in ("scenario", "grid", "leaves", "areas", "plan"):
            if not hasattr(prep, attr):
                raise ValueError(f"Recorder: prep must be a Prepared with .{attr}, got {type(prep).__name__}")
        self.path = Path(path)
        self.config = config
        self.controller = str(controller)
        self._prep = prep
        self._n_areas = int(np.asarray(prep.areas.rects).reshape(-1, 4).shape[0])
        self._rects = np.asarray(prep.areas.rects, dtype=float).reshape(-1, 4)
        self._sent = 0  # trace rows already sent
        self._times: list[float] | None = None  # step start times for log_sensing
        self._last_status: str | None = None
        self._closed = False
        import rerun as rr

        self.rec = rr.RecordingStream(APP_ID, make_default=False, make_thread_default=False)
        # The SDK encodes into memory and close() writes the file: the SDK's own file sink
        # writes from a thread that only logs a write error (a full disk gave a cut file and
        # exit 0) and leaves a partial file behind on Ctrl-C. The stream is read once, at the
        # end: each flushing read would start a new stream segment in the file.
        self._stream = self.rec.binary_stream()
        self.rec.send_blueprint(default_blueprint(config.show_quadtree, config.show_graph), make_active=True,
                                make_default=True)
        self.rec.send_recording_name(f"{prep.scenario.name} / {self.controller}")
        self._log_static()

    # ------------------------------------------------------------------ static scene
    def _log_static(self) -> None:
        import rerun as rr

        rec, prep = self.rec, self._prep
        sc: Scenario = prep.scenario
        rec.log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        xmin, ymin, xmax, ymax = (float(v) for v in np.asarray(sc.bounds, dtype=float))
        ws = np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]])
        rec.log("world/workspace", rr.LineStrips2D([_closed(ws)], colors=_C_WORKSPACE, radii=0.02,
                                                  draw_order=_Z_OBST), static=True)
        boxes = [o for o in sc.obstacles if o.kind == "box"]
        rounds = [o for o in sc.obstacles if o.kind != "box"]
        if boxes:
            rec.log("world/obstacles/boxes", rr.LineStrips2D([_closed(o.corners()) for o in boxes],
                                                            colors=_C_OBSTACLE, radii=0.02, labels=[o.name for o in boxes],
                                                            show_labels=False, draw_order=_Z_OBST), static=True)
        if rounds:
            rec.log("world/obstacles/round", rr.Ellipses2D(
                centers=np.array([o.center for o in rounds], dtype=float),
                half_sizes=np.array([o.half_size for o in rounds], dtype=float),
                colors=_C_OBSTACLE, line_radii=0.02, labels=[o.name for o in rounds], show_labels=False,
                draw_order=_Z_OBST), static=True)

        g = prep.grid
        occ = np.asarray(g.occupied, dtype=bool)
        rgba = np.zeros(occ.shape + (4,), dtype=np.uint8)
        rgba[occ] = _C_GRID
        res = float(g.resolution)
        rec.log("world/grid", rr.Transform3D(translation=[float(g.origin[0]), float(g.origin[1]), 0.0],
                                             scale=[res, res, 1.0]), static=True)
        rec.log("world/grid", rr.Image(rgba, color_model="RGBA", draw_order=_Z_GRID), static=True)

        if prep.leaves is not None and len(prep.leaves):
            lr = leaf_rects(prep.leaves, g.origin, res)
            free = np.asarray(prep.leaves.free, dtype=bool)
            for name, mask, color in (("free", free, _C_LEAF_FREE), ("occupied", ~free, _C_LEAF_OCC)):
                c, h = _centers_half(lr[mask])
                rec.log(f"world/quadtree/{name}", rr.Boxes2D(centers=c, half_sizes=h, colors=color,
                                                            radii=0.1 * res, draw_order=_Z_LEAVES), static=True)

        areas = prep.areas
        if self._n_areas:
            c, h = _centers_half(self._rects)
            rec.log("world/safe_areas", rr.Boxes2D(centers=c, half_sizes=h, colors=_C_AREA, radii=0.012,
                                                   draw_order=_Z_AREAS), static=True)
            rec.log("world/graph/nodes", rr.Points2D(c, colors=_C_GRAPH, radii=0.03, draw_order=_Z_GRAPH), static=True)
            edges = np.asarray(areas.edges, dtype=int).reshape(-1, 2)
            if len(edges):
                segs = np.stack((c[edges[:, 0]], c[edges[:, 1]]), axis=1)
                rec.log("world/graph/edges", rr.LineStrips2D(segs, colors=_C_GRAPH, radii=0.008,
                                                             draw_order=_Z_GRAPH), static=True)

        plan = prep.plan
        corridor = np.asarray(plan.corridor, dtype=int).reshape(-1)
        corridor = corridor[(corridor >= 0) & (corridor < self._n_areas)]
        if corridor.size:
            c, h = _centers_half(self._rects[corridor])
            rec.log("world/plan/corridor", rr.Boxes2D(centers=c, half_sizes=h, colors=_C_CORRIDOR, radii=0.025,
                                                      labels=[str(i) for i in corridor], show_labels=False,
                                                      draw_order=_Z_CORRIDOR), static=True)
        wp = np.asarray(plan.waypoints, dtype=float).reshape(-1, 2)
        if len(wp):
            rec.log("world/plan/waypoints", rr.Points2D(wp, colors=_C_WAYPOINT, radii=0.05, draw_order=_Z_PLAN),
                    static=True)
        path = np.asarray(plan.path, dtype=float).reshape(-1, 2)
        if len(path) >= 2:
            rec.log("world/plan/path", rr.LineStrips2D([path], colors=_C_PATH, radii=0.01, draw_order=_Z_PLAN),
                    static=True)
        if plan.reference is not None and len(plan.reference):
            ref = np.asarray(plan.reference.states, dtype=float)[:, :2]
            rec.log("world/plan/reference", rr.LineStrips2D([ref], colors=_C_REFERENCE, radii=0.012,
                                                            draw_order=_Z_PLAN + 0.5), static=True)
            rec.log("world/plan/reference/samples", rr.Points2D(ref, colors=_C_REFERENCE, radii=0.02,
                                                                draw_order=_Z_PLAN + 0.5), static=True)

        start = np.asarray(sc.start, dtype=float)
        rec.log("world/start", rr.Points2D(start[:2], colors=_C_START, radii=0.08, labels="start",
                                           draw_order=_Z_MARK), static=True)
        goals, labels = [np.asarray(sc.goal, dtype=float)[:2]], ["goal"]
        pg = np.asarray(plan.goal, dtype=float).reshape(-1)
        if pg.size == 2 and np.hypot(*(pg - goals[0])) > 1e-6:
            goals.append(pg)
            labels.append("goal (projected)")
        rec.log("world/goal", rr.Points2D(np.array(goals), colors=_C_GOAL, radii=0.08, labels=labels,
                                          draw_order=_Z_MARK), static=True)

        fp = robot_footprint(sc.model)
        rec.log("world/robot/footprint", rr.LineStrips2D([_closed(fp)], colors=_C_ROBOT, radii=0.015,
                                                         draw_order=_Z_ROBOT), static=True)
        length = 0.8 * float(fp[:, 0].max())
        rec.log("world/robot/heading", rr.Arrows2D(origins=[[0.0, 0.0]], vectors=[[length, 0.0]], colors=_C_ROBOT,
                                                   radii=0.015, draw_order=_Z_ROBOT), static=True)
        for entity, (name, color) in _SERIES.items():
            rec.log(entity, rr.SeriesLines(names=name, colors=color), static=True)
        # Style of the per-step entities, once (only components that are not logged per step:
        # a static component would shadow the per-step values of the same component).
        rec.log("world/trail", rr.LineStrips2D.from_fields(colors=_C_TRAIL, radii=0.035, draw_order=_Z_TRAIL),
                static=True)
        rec.log("world/measured", rr.Points2D.from_fields(colors=_C_MEASURED, radii=0.025, draw_order=_Z_ROBOT),
                static=True)
        rec.log("world/collisions", rr.Points2D.from_fields(colors=_C_COLLISION, radii=0.09, draw_order=_Z_MARK),
                static=True)
        rec.log("world/horizon/predicted", rr.LineStrips2D.from_fields(colors=_C_HORIZON, radii=0.012,
                                                                       draw_order=_Z_HORIZON), static=True)
        rec.log("world/horizon/points", rr.Points2D.from_fields(radii=0.03, draw_order=_Z_HORIZON), static=True)
        rec.log("world/horizon/rects", rr.Boxes2D.from_fields(colors=_C_HORIZON, radii=0.02, draw_order=_Z_HORIZON),
                static=True)

    # ------------------------------------------------------------------ per step
    def log_step(self, step: int, trace: Any) -> None:
        """Record step ``step``: the last entry of ``trace`` (an :class:`EpisodeTrace`).

        This is the runner's ``on_step`` hook. The row is sent at once when
        ``config.flush_every == 1``, otherwise with the next batch.

        Raises:
            ValueError: ``step`` is not the index of the trace's last entry, or the
                recorder is closed.
        """
        if self._closed:
            raise ValueError("Recorder.log_step: the recording is already finished")
        n = len(trace)
        if step != n - 1:
            raise ValueError(f"Recorder.log_step: step must be the trace's last index {n - 1}, got {step}")
        if n - self._sent >= self.config.flush_every:
            self._send(trace, n)

    def _send(self, tr: Any, end: int) -> None:
        """Send trace rows ``[self._sent, end)`` as columns (one call per entity)."""
        import rerun as rr

        a = self._sent
        if end <= a:
            return
        rec = self.rec
        idx = np.arange(a, end, dtype=np.int64)
        t = np.asarray(tr.t[a:end], dtype=float)

        def times(mask: np.ndarray | None = None) -> list[rr.TimeColumn]:
            i, s = (idx, t) if mask is None else (idx[mask], t[mask])
            return [rr.TimeColumn(TIMELINE_STEP, sequence=i), rr.TimeColumn(TIMELINE_TIME, duration=s)]

        tall = times()
        pose = np.asarray(tr.pose[a:end], dtype=float).reshape(-1, 3)
        k = len(pose)
        half = pose[:, 2] / 2.0
        quat = np.column_stack((np.zeros(k), np.zeros(k), np.sin(half), np.cos(half)))
        rec.send_columns("world/robot", tall, rr.Transform3D.columns(
            translation=np.column_stack((pose[:, :2], np.zeros(k))), quaternion=quat))
        prev = np.asarray(tr.pose[a - 1], dtype=float)[:2] if a > 0 else pose[0, :2]
        starts = np.vstack((prev, pose[:-1, :2]))
        segs = np.stack((starts, pose[:, :2]), axis=1)
        rec.send_columns("world/trail", tall, rr.LineStrips2D.columns(strips=segs))
        meas = np.asarray(tr.measured[a:end], dtype=float).reshape(-1, 3)
        rec.send_columns("world/measured", tall, rr.Points2D.columns(positions=meas[:, :2]))

        contacts = np.asarray(tr.contacts[a:end], dtype=float)
        hit = contacts > 0
        if hit.any():
            rec.send_columns("world/collisions", times(hit), rr.Points2D.columns(positions=pose[hit, :2]))

        self._send_horizon(tr, a, end, idx, t)

        cmd = np.asarray(tr.cmd[a:end], dtype=float).reshape(-1, 2)
        applied = np.asarray(tr.applied[a:end], dtype=float).reshape(-1, 2)
        vel = np.asarray(tr.velocity[a:end], dtype=float).reshape(-1, 2)
        wcmd = np.asarray(tr.wheel_cmd[a:end], dtype=float).reshape(-1, 2)
        wmeas = np.asarray(tr.wheel_speed[a:end], dtype=float).reshape(-1, 2)
        scalars = {
            "plots/velocity/v_cmd": cmd[:, 0],
            "plots/velocity/v_meas": vel[:, 0],
            "plots/velocity/w_cmd": cmd[:, 1],
            "plots/velocity/w_meas": vel[:, 1],
            "plots/wheels/left_cmd": wcmd[:, 0],
            "plots/wheels/left_meas": wmeas[:, 0],
            "plots/wheels/right_cmd": wcmd[:, 1],
            "plots/wheels/right_meas": wmeas[:, 1],
            "plots/slip/v": applied[:, 0] - vel[:, 0],
            "plots/slip/w": applied[:, 1] - vel[:, 1],
            "plots/timing/solve_ms": np.asarray(tr.solve_ms[a:end], dtype=float),
            "plots/timing/pipeline_ms": np.asarray(tr.pipeline_ms[a:end], dtype=float),
            "plots/safety/clearance": np.asarray(tr.clearance[a:end], dtype=float),
            "plots/safety/contacts": contacts,
            "plots/solver/ok": np.asarray(tr.ok[a:end], dtype=float),
        }
        for entity, values in scalars.items():
            rec.send_columns(entity, tall, rr.Scalars.columns(scalars=values))

        status = [str(s) for s in tr.status[a:end]]
        ok = tr.ok[a:end]
        change = np.zeros(k, dtype=bool)
        last = self._last_status
        for i, s in enumerate(status):
            if s != last:
                change[i] = True
                last = s
        self._last_status = last
        if change.any():
            sel = np.flatnonzero(change)
            rec.send_columns("solver/status", times(change), rr.TextLog.columns(
                text=[status[i] for i in sel],
                level=[rr.TextLogLevel.INFO if ok[i] else rr.TextLogLevel.WARN for i in sel]))
        self._sent = end

    def _send_horizon(self, tr: Any, a: int, end: int, idx: np.ndarray, t: np.ndarray) -> None:
        import rerun as rr

        rec = self.rec
        rows, strips, colors, margin_min, mrows = [], [], [], [], []
        for i in range(a, end):
            pred = tr.predicted[i]
            marg = tr.margins[i]
            if marg is not None:
                m = np.asarray(marg, dtype=float).reshape(-1)
                if m.size and np.isfinite(m).any():
                    margin_min.append(float(np.nanmin(m)))
                    mrows.append(i - a)
            if pred is None:
                continue
            p = np.asarray(pred, dtype=float)
            if p.ndim != 2 or p.shape[1] < 2 or not len(p):
                continue  # (K, 3) states expected; (K, 2) positions also accepted
            p = p[:, :2]
            rows.append(i - a)
            strips.append(p)
            col = np.tile(np.array(_C_HORIZON, dtype=np.uint8), (len(p), 1))
            if marg is not None:
                m = np.asarray(marg, dtype=float).reshape(-1)
                if m.size == len(p):
                    col[m < 0] = _C_HORIZON_BAD
            colors.append(col)
        if mrows:
            sel = np.asarray(mrows)
            rec.send_columns("plots/safety/margin_min",
                             [rr.TimeColumn(TIMELINE_STEP, sequence=idx[sel]), rr.TimeColumn(TIMELINE_TIME, duration=t[sel])],
                             rr.Scalars.columns(scalars=np.asarray(margin_min)))
        if rows:
            sel = np.asarray(rows)
            tcols = [rr.TimeColumn(TIMELINE_STEP, sequence=idx[sel]), rr.TimeColumn(TIMELINE_TIME, duration=t[sel])]
            lengths = [len(p) for p in strips]
            rec.send_columns("world/horizon/predicted", tcols, rr.LineStrips2D.columns(strips=strips))
            rec.send_columns("world/horizon/points", tcols, rr.Points2D.columns(
                positions=np.concatenate(strips), colors=np.concatenate(colors)).partition(lengths))
        # Safe areas assigned to the horizon: one box per distinct area id.
        rows, centers, halfs, labels, counts = [], [], [], [], []
        for i in range(a, end):
            ids = tr.rect_ids[i]
            if ids is None:
                continue
            u = np.unique(np.asarray(ids, dtype=int).reshape(-1))
            u = u[(u >= 0) & (u < self._n_areas)]
            rows.append(i - a)
            counts.append(len(u))
            if len(u):
                c, h = _centers_half(self._rects[u])
                centers.append(c)
                halfs.append(h)
                labels.extend(str(v) for v in u)
        if rows:
            sel = np.asarray(rows)
            tcols = [rr.TimeColumn(TIMELINE_STEP, sequence=idx[sel]), rr.TimeColumn(TIMELINE_TIME, duration=t[sel])]
            c = np.concatenate(centers) if centers else np.zeros((0, 2))
            h = np.concatenate(halfs) if halfs else np.zeros((0, 2))
            rec.send_columns("world/horizon/rects", tcols, rr.Boxes2D.columns(
                centers=c, half_sizes=h, labels=labels).partition(counts))

    # ------------------------------------------------------------------ sensing
    def log_sensing(self, log: Any, records: Any) -> None:
        """Record what a lidar run saw (see "Sensing" in the module docstring).

        Args:
            log: the run's :class:`~sanav_mj.eval.outcome.SensingLog` (scans, map frames,
                safe-area frames).
            records: the controller's per-step
                :class:`~sanav_mj.control.sensing.StepRecord` list (corridor, replans,
                map update time).
        """
        import rerun as rr

        rec = self.rec

        def tcols(steps: list[int]) -> list[rr.TimeColumn]:
            steps = [int(k) for k in steps]
            return [rr.TimeColumn(TIMELINE_STEP, sequence=steps),
                    rr.TimeColumn(TIMELINE_TIME, duration=[self._step_time(k) for k in steps])]

        steps = [k for k, p in enumerate(log.scan_points) if p is not None]
        if steps:
            pts = [log.scan_points[k] for k in steps]
            rec.log("world/sensing/scan", rr.Points2D.from_fields(colors=_C_SCAN, radii=0.02, draw_order=_Z_HORIZON),
                    static=True)
            rec.send_columns("world/sensing/scan", tcols(steps), rr.Points2D.columns(
                positions=np.concatenate(pts) if pts else np.zeros((0, 2))).partition([len(p) for p in pts]))
        res = float(log.resolution)
        rec.log("world/sensing/map", rr.Transform3D(translation=[float(log.origin[0]), float(log.origin[1]), 0.0],
                                                    scale=[res, res, 1.0]), static=True)
        for k, states in log.map_frames:
            rgba = np.zeros(states.shape + (4,), dtype=np.uint8)
            rgba[states == 0] = _C_UNKNOWN
            rgba[states == 1] = _C_FREE
            rgba[states == 2] = _C_OCCUPIED
            rec.set_time(TIMELINE_STEP, sequence=int(k))
            rec.set_time(TIMELINE_TIME, duration=self._step_time(k))
            rec.log("world/sensing/map", rr.Image(rgba, color_model="RGBA", draw_order=_Z_GRID + 1))
        for k, rects in log.area_frames:
            c, h = _centers_half(rects)
            rec.set_time(TIMELINE_STEP, sequence=int(k))
            rec.set_time(TIMELINE_TIME, duration=self._step_time(k))
            rec.log("world/sensing/safe_areas", rr.Boxes2D(centers=c, half_sizes=h, colors=_C_AREA, radii=0.01,
                                                           draw_order=_Z_AREAS + 1))
        rec.reset_time()
        n = len(records)
        if n:
            corr = [np.asarray(r.corridor_rects, float).reshape(-1, 4) for r in records]
            ch = [(_centers_half(c) if len(c) else (np.zeros((0, 2)), np.zeros((0, 2)))) for c in corr]
            rec.log("world/sensing/corridor", rr.Boxes2D.from_fields(colors=_C_CORRIDOR, radii=0.02,
                                                                     draw_order=_Z_CORRIDOR), static=True)
            rec.send_columns("world/sensing/corridor", tcols(list(range(n))), rr.Boxes2D.columns(
                centers=np.concatenate([c for c, _ in ch]), half_sizes=np.concatenate([h for _, h in ch])
            ).partition([len(c) for c in corr]))
            mu = [k for k, r in enumerate(records) if r.map_ms is not None]
            if mu:
                rec.send_columns("plots/timing/map_update_ms", tcols(mu), rr.Scalars.columns(
                    scalars=[records[k].map_ms for k in mu]))
            rp = [k for k, r in enumerate(records) if r.replan is not None]
            if rp:
                rec.send_columns("sensing/replans", tcols(rp), rr.TextLog.columns(
                    text=[f"replan: {records[k].replan} ({records[k].replan_ms:.1f} ms)" for k in rp],
                    level=[rr.TextLogLevel.INFO] * len(rp)))

    def _step_time(self, k: int) -> float:
        """[s] simulated time of step ``k`` (``k dt`` of the recorded trace when known)."""
        t = self._times
        return float(t[k]) if t is not None and 0 <= k < len(t) else float(k) * 0.1

    # ------------------------------------------------------------------ end
    def finish(self, episode: Any, document: dict[str, Any]) -> None:
        """Send the remaining steps, the final pose and the summary; close the file.

        Args:
            episode: the finished :class:`~sanav_mj.sim.runner.Episode` (its trace is the
                one that was passed to :meth:`log_step`).
            document: the ``run --json`` document (logged without its ``trace``).

        Raises:
            ValueError: called twice.
        """
        import rerun as rr

        if self._closed:
            raise ValueError("Recorder.finish: the recording is already finished")
        tr = episode.trace
        n = len(tr)
        self._send(tr, n)
        final = np.asarray(episode.final_pose, dtype=float).reshape(3)
        if n and np.all(np.isfinite(final)):
            tcols = [rr.TimeColumn(TIMELINE_STEP, sequence=[n]),
                     rr.TimeColumn(TIMELINE_TIME, duration=[float(episode.sim_time_s)])]
            half = final[2] / 2.0
            self.rec.send_columns("world/robot", tcols, rr.Transform3D.columns(
                translation=[[final[0], final[1], 0.0]], quaternion=[[0.0, 0.0, math.sin(half), math.cos(half)]]))
            last = np.asarray(tr.pose[n - 1], dtype=float)[:2]
            self.rec.send_columns("world/trail", tcols, rr.LineStrips2D.columns(strips=[[last, final[:2]]]))
        self.rec.log("summary", rr.TextDocument(summary_markdown(document), media_type=rr.MediaType.MARKDOWN),
                     static=True)
        self.close()

    def close(self) -> None:
        """End the recording and write the complete file at ``path`` (idempotent).

        :meth:`finish` calls it. The file is written to a temporary file beside ``path`` and
        renamed onto it (:func:`sanav_mj.outputs.write_bytes`).

        Raises:
            OSError: the file could not be written completely (e.g. ``ENOSPC``, a full
                disk); ``filename`` is ``path``, and nothing (not even a partial file) is
                left at ``path``.
        """
        if self._closed:
            return
        self._closed = True
        self.rec.disconnect()  # ends the stream (its footer); the bytes are read after it
        data = self._stream.read(flush=False) or b""
        write_bytes(self.path, data)

    def discard(self) -> None:
        """End the recording without writing ``path`` (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.rec.disconnect()
        self._stream.read(flush=False)  # the SDK warns on stderr about bytes dropped unread

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        """Leaving the block closes the file (data so far is a valid recording of what ran
        before an error); Ctrl-C (or any non-``Exception``) discards it: no partial file."""
        if exc_type is not None and not issubclass(exc_type, Exception):
            self.discard()
        else:
            self.close()


def record_episode(path: str | Path, outcome: Any, config: RecordConfig = RecordConfig()) -> Path:
    """Record a finished run to ``path`` in one call (the same file as streaming it step by step).

    Args:
        path: output ``.rrd`` file.
        outcome: :class:`~sanav_mj.eval.outcome.RunOutcome` (``prepared``, ``controller``,
            ``episode``, ``document``).
        config: recording settings.

    Returns:
        ``path``.

    Raises:
        OSError: the file could not be written completely (``filename`` is ``path``; no file
            is left at ``path``).
    """
    rec = Recorder(path, outcome.prepared, outcome.controller, config)
    try:
        log = getattr(outcome, "sensing_log", None)
        if log is not None:
            rec._times = list(outcome.episode.trace.t)
            rec.log_sensing(log, outcome.sensed.records)
        rec.finish(outcome.episode, outcome.document)
    except BaseException:
        rec.discard()
        raise
    return Path(path)


def summary_markdown(document: dict[str, Any]) -> str:
    """Markdown summary of a ``run --json`` document: headline, key figures, JSON (no trace)."""
    doc = {k: v for k, v in document.items() if k != "trace"}
    head = (f"# {doc.get('scenario', '?')} / {doc.get('controller', '?')} (seed {doc.get('seed', '?')}): "
            f"{doc.get('reason', '?')}")
    rows = [
        ("success", doc.get("success")),
        ("steps", doc.get("steps")),
        ("sim time [s]", doc.get("sim_time_s")),
        ("path length [m]", doc.get("path_length_m")),
        ("min clearance [m]", doc.get("min_clearance_m")),
        ("collisions", doc.get("collisions")),
        ("safe-area violations", doc.get("safe_area_violations")),
        ("solve mean / p99 [ms]", _pair(doc.get("solve_ms"), "mean", "p99")),
    ]
    table = "| quantity | value |\n|---|---|\n" + "\n".join(f"| {k} | {_fmt(v)} |" for k, v in rows)
    body = json.dumps(doc, indent=1, default=_json_default)
    return f"{head}\n\n{table}\n\n```json\n{body}\n```\n"


def _pair(d: Any, a: str, b: str) -> str:
    if not isinstance(d, dict):
        return "-"
    return f"{_fmt(d.get(a))} / {_fmt(d.get(b))}"


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "-" if v is None else str(v)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)
