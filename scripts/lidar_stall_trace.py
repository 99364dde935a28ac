"""Where and why a lidar run stops: a timeline of one ``--sensing lidar`` run.

Usage::

    PYTHONPATH=$PWD python scripts/lidar_stall_trace.py SCENARIO [--footprint discs] [--seed 0]
        [--every 0.5] [--time-limit 60] [--png map.png]

Prints, every ``--every`` seconds of simulated time: the true pose, the command, the
clearance, the number of corridor rectangles the MPC used, the controller statuses and the
replans (by reason) of the interval. Then every replan that found no plan, grouped by second
and reason, and for the last ones why: whether the route (free and unknown space) reached
the goal, the local plan's failure reason and whether the robot's own points stood in safe
cells; and the last plan's corridor rectangles [m]. ``--png``: the final sensed map
(unknown grey, occupied black, safe green, not route-safe tinted red), the true obstacles
and the path. Exit codes: 0 done, 2 bad argument or unwritable output.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np


def _diagnose(ctrl, pose, reason, areas, have_route):
    """Why a replan at ``pose`` found no plan: (reason, route plan reason or None, local
    target missing, local plan reason or None, own points safe)."""
    from sanav_mj.planning import plan as make_plan

    route_areas = ctrl.map.route_areas()[1] if have_route else None
    rp = make_plan(ctrl.body.planning_areas(route_areas), pose, ctrl.goal, ctrl.robot, ctrl.planner) \
        if route_areas is not None else None
    route = rp.reference.states[:, :2] if rp is not None and rp.ok and rp.reference is not None else None
    target = ctrl._local_goal(route)
    lp = make_plan(ctrl.body.planning_areas(areas), pose, target, ctrl.robot, ctrl.planner) \
        if target is not None else None
    return (reason, None if rp is None else ("ok" if rp.ok else rp.reason), target is None,
            None if lp is None else ("ok" if lp.ok else lp.reason), ctrl._own_safe(pose))


def trace(scenario, footprint: str = "discs", seed: int = 0, every: float = 0.5, time_limit: float = 60.0):
    """Run ``scenario`` with the lidar; returns (outcome, timeline lines, failed replans)."""
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.lidar import lidar_controller
    from sanav_mj.scene import load_scenario

    sc = load_scenario(scenario)
    spec = ControllerSpec("sa-mpc", replace(ControllerSpec().sa_mpc, footprint=footprint)) \
        if footprint == "discs" else ControllerSpec("sa-mpc")
    ctrl = lidar_controller(sc, spec)
    failed = []
    compute = ctrl._compute

    def logged(pose, speed, reason, areas, boxes, have_route, moving, kept=None):
        out = compute(pose, speed, reason, areas, boxes, have_route, moving, kept)
        if out is None:
            failed.append((len(ctrl.records), _diagnose(ctrl, pose, reason, areas, have_route)))
        return out

    ctrl._compute = logged  # this instance only: the run is otherwise the plain lidar run
    out = run_scenario(sc, seed=seed, controller_spec=spec, sensing="lidar", controller_obj=ctrl,
                       time_limit_s=time_limit)
    tr, recs = out.episode.trace, ctrl.records
    dt = ctrl.dt
    k_every = max(1, int(round(every / dt)))
    lines = []
    for k in range(0, len(tr.t), k_every):
        p = tr.pose[k]
        win = range(max(0, k - k_every + 1), k + 1)
        st = dict(Counter(tr.status[j] for j in win))
        rp = dict(Counter(recs[j].replan for j in win if recs[j].replan))
        lines.append(f"t={tr.t[k]:6.2f} x={p[0]:6.2f} y={p[1]:6.2f} yaw={p[2]:5.2f} v={tr.cmd[k][0]:5.2f} "
                     f"w={tr.cmd[k][1]:5.2f} clr={tr.clearance[k]:.3f} rects={len(recs[k].corridor_rects)} "
                     f"status={st} replans={rp}")
    return out, lines, failed


def _png(path: Path, out, ctrl) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    from sanav_mj.mapping.live_grid import FREE, OCCUPIED, UNKNOWN

    g = ctrl.map.grid
    st, safe, rs = g.states(), g.safe(), g.route_safe()
    img = np.ones(st.shape + (3,))
    img[st == UNKNOWN] = (0.6, 0.6, 0.6)
    img[st == OCCUPIED] = (0.0, 0.0, 0.0)
    img[(st == FREE) & safe] = (0.7, 1.0, 0.7)
    tint = ~rs & (st != OCCUPIED)
    img[tint] *= np.array([1.0, 0.7, 0.7])
    ny, nx = st.shape
    h = g.resolution
    fig, ax = plt.subplots(figsize=(16, 6))
    ax.imshow(img, origin="lower", extent=(g.origin[0], g.origin[0] + nx * h, g.origin[1], g.origin[1] + ny * h),
              interpolation="nearest")
    for ob in out.prepared.scenario.obstacles:
        if ob.kind == "cylinder":
            ax.add_patch(Circle(ob.center, ob.half_size[0], fill=False, ec="r", lw=0.8))
        else:  # the axis-aligned extent of a box (yaw ignored: a sketch)
            ax.add_patch(Rectangle(ob.center - ob.half_size, *(2 * ob.half_size), fill=False, ec="r", lw=0.8))
    p = out.episode.trace.poses()
    ax.plot(p[:, 0], p[:, 1], "b-", lw=1)
    ax.plot(p[-1, 0], p[-1, 1], "ro")
    fig.savefig(path, dpi=80, bbox_inches="tight")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", help="scenario name or MJCF path")
    ap.add_argument("--footprint", choices=("disc", "discs"), default="discs")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=float, default=0.5, help="[s] timeline interval, > 0")
    ap.add_argument("--time-limit", type=float, default=60.0, help="[s] episode limit, > 0")
    ap.add_argument("--png", type=Path, help="write the final sensed map here")
    args = ap.parse_args(argv)
    if not (math.isfinite(args.every) and args.every > 0 and math.isfinite(args.time_limit) and args.time_limit > 0):
        print(f"lidar_stall_trace: --every and --time-limit: expected numbers > 0 [s], got {args.every!r}, "
              f"{args.time_limit!r}", file=sys.stderr)
        return 2
    if args.png is not None and not args.png.parent.is_dir():
        print(f"lidar_stall_trace: --png {args.png}: directory does not exist", file=sys.stderr)
        return 2
    try:
        out, lines, failed = trace(args.scenario, args.footprint, args.seed, args.every, args.time_limit)
    except (FileNotFoundError, ValueError) as e:
        print(f"lidar_stall_trace: {args.scenario}: {e}", file=sys.stderr)
        return 2
    d = out.document
    print(f"{d['scenario']} seed {args.seed}: {d['reason']} at {d['sim_time_s']:.1f} s, {d['replans']} replans")
    print("\n".join(lines))
    dt = out.sensed.dt
    by = sorted(Counter((int(k * dt), why[0]) for k, why in failed).items())
    print("replans without a plan (second, reason): count:", by)
    for k, why in failed[-5:]:
        print(f"  t={k * dt:.1f} reason={why[0]} route={why[1]} no_local_goal={why[2]} local={why[3]} "
              f"own_safe={why[4]}")
    mpc = out.sensed.mpc
    if mpc is not None:
        rects = np.asarray(mpc.areas.rects)[np.asarray(mpc.plan.corridor, int)]
        print("last corridor rectangles [m] (xmin, ymin, xmax, ymax):")
        print(np.array2string(np.round(rects, 3)))
    if args.png is not None:
        _png(args.png, out, out.sensed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
