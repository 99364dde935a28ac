"""BARN-style evaluation of generated worlds (see :mod:`sanav_mj.generate`, :mod:`sanav_mj.eval.barn`).

    python scripts/barn_eval.py worlds runs/barn40/*.xml --out runs/barn40_worlds.csv
        per world: shortest path L [m] for the BARN metric (inscribed clearance), t_opt [s],
        widest disc radius that passes [m], and whether the safe-area planner finds a path at
        each (inflation, resolution) of --configs (default: today's 0.33 + 0.05 m at 0.05 m,
        without the margin, at 0.025 m, both, and at 0.0125 m).
    python scripts/barn_eval.py score runs/bench_dir --worlds runs/barn40_worlds.csv
        BARN score per run of a ``sanav-mj bench`` output folder (results.csv) and the mean.
    python scripts/barn_eval.py closed-loop runs/barn40/*.xml [--worlds runs/barn40_worlds.csv] \
            --margin 0.05 --resolution 0.05 [--footprint disc|discs] [--discs 3] [--seeds 0 1] \
            [--mismatch KEY=VALUE ...] [--sensing map|lidar] --out runs/cl.json
        SA-MPC on each world and seed with the map inflated by circumscribed radius + MARGIN
        (--footprint disc) or by the N-disc cover's radius + MARGIN with the disc centres in the
        MPC (--footprint discs) at RESOLUTION; per run also the largest distance of the true
        position (disc mode) or of every true disc centre (discs mode) outside every safe area
        (the tracking excursion the margin has to absorb) and the solve times. With
        ``--sensing lidar`` the robot maps with its own lidar (docs/sensing.md); per run also
        the replans, the map update and pipeline times and the safe-area violation steps
        (the excursion is then not computed: the safe areas change from step to step), and
        the braking fallback's choices (``fallback_*``, ``brake_*`` step counts of the
        controller's stats). Every run: ``solver_failures``.

One process; prints a markdown summary, writes CSV.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np

from sanav_mj.eval.barn import BARN_SPEED, barn_score, optimal_path_length, widest_disc
from sanav_mj.footprint import robot_footprint
from sanav_mj.mapping import MapConfig, build_map
from sanav_mj.planning import plan
from sanav_mj.eval.prepare import planner_config
from sanav_mj.scene import load_scenario

MARGIN = 0.05


def _configs(text: str, radius: float) -> list[tuple[str, float, float]]:
    out = []
    for item in text.split(","):
        margin, res = item.split("@")
        out.append((f"m{margin}@{res}", radius + float(margin), float(res)))
    return out


def cmd_worlds(args) -> int:
    rows = []
    for path in args.scenarios:
        s = load_scenario(path)
        fp = robot_footprint(s.model)
        length = optimal_path_length(s.obstacles, s.bounds, s.start, s.goal, fp.inradius)
        row = {"scenario": s.name, "path": str(path), "L_m": length, "t_opt_s": length / BARN_SPEED,
               "widest_disc_m": widest_disc(s.obstacles, s.bounds, s.start, s.goal)}
        for name, infl, res in _configs(args.configs, s.robot.footprint_radius):
            m = build_map(s.obstacles, s.bounds, infl, MapConfig(resolution=res))
            p = plan(m.areas, s.start, s.goal, s.robot, planner_config(s.robot))
            row[f"path_{name}"] = int(p.ok)
        rows.append(row)
        print(f"{s.name}: " + ", ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                                       for k, v in row.items() if k not in ("scenario", "path")), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    n = len(rows)
    wd = np.array([r["widest_disc_m"] for r in rows])
    radius = load_scenario(args.scenarios[0]).robot.footprint_radius
    print(f"\n{n} worlds; widest passing disc radius [m]: min {wd.min():.3f}, median {np.median(wd):.3f}")
    print(f"exact disc {radius:.3f} m passes in {int((wd >= radius).sum())}, disc + {MARGIN} m in "
          f"{int((wd >= radius + MARGIN).sum())}")
    for k in rows[0]:
        if k.startswith("path_"):
            print(f"planner finds a path with {k[5:]}: {sum(r[k] for r in rows)} of {n}")
    return 0


def cmd_score(args) -> int:
    worlds = {}
    with open(args.worlds) as f:
        for r in csv.DictReader(f):
            worlds[r["scenario"]] = float(r["t_opt_s"])
    rows = list(csv.DictReader(open(args.bench / "results.csv")))
    scores, out = [], []
    for r in rows:
        t_opt = worlds.get(r["scenario"])
        if t_opt is None:
            print(f"barn_eval: scenario {r['scenario']!r} of {args.bench / 'results.csv'} is not in {args.worlds}",
                  file=sys.stderr)
            return 2
        ok = r["success"] == "True"
        sc = barn_score(ok, float(r["sim_time_s"] or "nan") if ok else math.nan, t_opt)
        scores.append(sc)
        out.append({**{k: r[k] for k in ("scenario", "controller", "seed", "success", "reason", "sim_time_s", "collisions")},
                    "t_opt_s": t_opt, "barn_score": sc})
    with open(args.bench / "barn_scores.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(out[0]))
        w.writeheader()
        w.writerows(out)
    by = {}
    for r in out:
        by.setdefault(r["controller"], []).append(r)
    for ctl, rs in by.items():
        succ = [r for r in rs if r["success"] == "True"]
        reasons = {}
        for r in rs:
            reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
        t = [float(r["sim_time_s"]) for r in succ]
        print(f"{ctl}: {len(rs)} runs, success {len(succ)} ({100 * len(succ) / len(rs):.1f} %), "
              f"collisions {sum(int(r['collisions'] or 0) > 0 for r in rs)}, outcomes {reasons}, "
              f"mean time (successful) {np.mean(t) if t else float('nan'):.2f} s, "
              f"mean BARN score {np.mean([r['barn_score'] for r in rs]):.3f}, "
              f"successful only {np.mean([r['barn_score'] for r in succ]) if succ else float('nan'):.3f}")
    return 0


def _excursion(xy: np.ndarray, rects: np.ndarray) -> float:
    """Largest distance [m] of the points (K, 2) outside the union of rects (R, 4); 0 if all inside."""
    dx = np.maximum(np.maximum(rects[None, :, 0] - xy[:, None, 0], xy[:, None, 0] - rects[None, :, 2]), 0.0)
    dy = np.maximum(np.maximum(rects[None, :, 1] - xy[:, None, 1], xy[:, None, 1] - rects[None, :, 3]), 0.0)
    return float(np.hypot(dx, dy).min(axis=1).max()) if len(xy) else 0.0


def cmd_closed_loop(args) -> int:
    import json
    from collections import Counter

    import sanav_mj.eval.prepare as prepare_mod
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.lidar import lidar_spec
    from sanav_mj.sim.mismatch import Mismatch

    from dataclasses import replace

    from sanav_mj.control.footprint import disc_centres
    from sanav_mj.control.spec import ControllerSpec

    if args.footprint == "discs":  # the options given replace MPCConfig's discs-mode defaults
        given = {k: v for k, v in (("footprint_discs", args.discs), ("footprint_margin", args.margin),
                                   ("footprint_narrow_penalty", args.narrow_penalty),
                                   ("footprint_refine", args.refine), ("footprint_refine_width", args.refine_width),
                                   ("footprint_grow", args.grow), ("footprint_grow_tighten", args.grow_tighten),
                                   ("footprint_route", args.route), ("footprint_box_margin", args.box_margin))
                 if v is not None}
        if args.refine_fallback is not None:
            given["footprint_refine_fallback"] = args.refine_fallback
        if args.no_manoeuvre:  # no manoeuvres where the corridor reference leaves the safe areas
            given["footprint_manoeuvre"] = None
        if args.no_tighten:  # the prediction derating without the tightening of the disc rows
            from sanav_mj.control.prediction import PredictionDerating

            given["footprint_prediction"] = PredictionDerating(tighten=False)
        spec = ControllerSpec("sa-mpc", replace(ControllerSpec().sa_mpc, footprint="discs", **given))
        mpc = spec.sa_mpc
        args.discs, args.margin, args.refine, args.grow = (mpc.footprint_discs, mpc.footprint_margin,
                                                           mpc.footprint_refine, mpc.footprint_grow)
        args.refine_fallback = mpc.footprint_refine_fallback
        args.no_manoeuvre = mpc.footprint_manoeuvre is None
        if args.sensing == "lidar":  # the sensed map is one grid (lidar_spec)
            args.refine = lidar_spec(spec).sa_mpc.footprint_refine
    else:
        # Measurement knob: the run path has no margin argument for the circumscribed disc,
        # so the module default is set for this process only (prepare() reads it).
        args.margin = MARGIN if args.margin is None else args.margin
        prepare_mod.DEFAULT_MARGIN_M = args.margin
        spec = ControllerSpec("sa-mpc")
    mm = {}
    for item in args.mismatch:
        key, value = item.split("=", 1)
        mm[key] = int(value) if key == "delay" else float(value)
    mismatch = Mismatch(**mm)
    t_opt = {r["scenario"]: float(r["t_opt_s"]) for r in csv.DictReader(open(args.worlds))} if args.worlds else {}
    rows = []
    for path, seed in ((p, s) for p in args.scenarios for s in args.seeds):
        out = run_scenario(path, seed=seed, resolution=args.resolution, mismatch=mismatch,
                           controller_spec=spec, sensing=args.sensing)
        d = out.document
        lidar = args.sensing == "lidar"
        exc = math.nan if lidar else 0.0
        if d["trace"]["x"] and not lidar:
            rects = np.asarray(out.prepared.areas.rects)
            xy = np.column_stack([d["trace"]["x"], d["trace"]["y"]])
            if args.footprint == "discs":  # every disc centre of the cover, true pose
                offsets = robot_footprint(out.prepared.scenario.model).discs(args.discs)[0]
                c = disc_centres(np.column_stack([xy, d["trace"]["yaw"]]), offsets)
                xy = c.reshape(-1, 2)
            exc = _excursion(xy, rects)
        to = t_opt.get(d["scenario"], math.nan)
        rows.append({"scenario": d["scenario"], "seed": seed, "success": d["success"], "reason": d["reason"],
                     "sim_time_s": d["sim_time_s"], "collisions": d["collisions"],
                     "min_clearance_m": d["min_clearance_m"], "excursion_m": exc,
                     "solve_mean_ms": d["solve_ms"]["mean"], "solve_p99_ms": d["solve_ms"]["p99"],
                     "steps": d["steps"], "safe_area_violations": d["safe_area_violations"],
                     "barn_score": barn_score(d["success"], d["sim_time_s"], to) if math.isfinite(to) else math.nan})
        rows[-1]["solver_failures"] = d["solver_failures"]
        mpc = getattr(out.sensed, "mpc", None)
        if mpc is not None:  # the braking fallback's choices (sensed_footprint.StraightBrakeSAMPC)
            rows[-1].update({k: mpc.stats.counts.get(k, 0) for k in (
                "fallback_shift", "fallback_stop", "brake_straight", "brake_kept", "brake_steer", "brake_outside")})
        if lidar:
            rows[-1].update(replans=d["replans"], map_update_mean_ms=d["map_update_ms"]["mean"],
                            map_update_p99_ms=d["map_update_ms"]["p99"], pipeline_mean_ms=d["pipeline_ms"]["mean"],
                            pipeline_p99_ms=d["pipeline_ms"].get("p99"))
        extra = (f", {d['replans']} replans, map update {d['map_update_ms']['mean']:.2f} ms, "
                 f"SA viol. {d['safe_area_violations']}") if lidar else ""
        print(f"{d['scenario']}/{seed}: {d['reason']} {d['sim_time_s']:.1f} s, excursion {exc:.4f} m, "
              f"solve mean {d['solve_ms']['mean']:.2f} p99 {d['solve_ms']['p99']:.2f} ms{extra}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    ok = [r for r in rows if r["success"]]
    clr = [r["min_clearance_m"] for r in rows if r["min_clearance_m"] is not None]
    print(f"sensing {args.sensing}, footprint {args.footprint}, discs {args.discs}, refine {args.refine}{f' (fallback {args.refine_fallback}' + (', no manoeuvres)' if args.no_manoeuvre else ', manoeuvres)') if args.footprint == 'discs' and args.sensing == 'map' and args.refine_fallback else ''}, grow {args.grow}/{args.grow_tighten}, margin {args.margin} m, cells {args.resolution} m, mismatch {mm}: success {len(ok)}/{len(rows)}, "
          f"runs with collision {sum(r['collisions'] > 0 for r in rows)}, {dict(Counter(r['reason'] for r in rows))}, "
          f"mean time (successful) {np.mean([r['sim_time_s'] for r in ok]) if ok else float('nan'):.2f} s, "
          f"mean BARN score {np.mean([r['barn_score'] for r in rows]):.3f}, "
          f"min clearance {min(clr) if clr else float('nan'):.3f} m, max excursion {max(r['excursion_m'] for r in rows):.4f} m")
    if args.sensing == "lidar":
        print(f"lidar: replans mean {np.mean([r['replans'] for r in rows]):.1f} (successful "
              f"{np.mean([r['replans'] for r in ok]) if ok else float('nan'):.1f}), map update mean of run means "
              f"{np.nanmean([r['map_update_mean_ms'] for r in rows]):.2f} ms, median run p99 "
              f"{np.nanmedian([r['map_update_p99_ms'] for r in rows]):.2f} ms, pipeline mean of run means "
              f"{np.nanmean([r['pipeline_mean_ms'] for r in rows]):.2f} ms, safe-area violation steps "
              f"{sum(r['safe_area_violations'] for r in rows)} in {sum(r['safe_area_violations'] > 0 for r in rows)} runs")
        if all("fallback_stop" in r for r in rows):
            print("fallback steps: " + ", ".join(f"{k} {sum(r[k] for r in rows)}" for k in (
                "fallback_shift", "fallback_stop", "brake_straight", "brake_kept", "brake_steer", "brake_outside")))
    ran = [r for r in rows if r["steps"] > 0]
    if ran:
        w = np.array([r["steps"] for r in ran], float)
        print(f"solve ms: pooled mean {np.average([r['solve_mean_ms'] for r in ran], weights=w):.2f}, "
              f"per-run p99 median {np.median([r['solve_p99_ms'] for r in ran]):.2f}, "
              f"max p99 {max(r['solve_p99_ms'] for r in ran):.2f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("worlds")
    w.add_argument("scenarios", nargs="+", type=Path)
    w.add_argument("--out", type=Path, required=True)
    w.add_argument("--configs", default="0.05@0.05,0@0.05,0.05@0.025,0@0.025,0@0.0125",
                   help="comma list MARGIN@RESOLUTION [m]; inflation = circumscribed radius + MARGIN")
    s = sub.add_parser("score")
    s.add_argument("bench", type=Path)
    s.add_argument("--worlds", type=Path, required=True)
    c = sub.add_parser("closed-loop")
    c.add_argument("scenarios", nargs="+", type=Path)
    c.add_argument("--worlds", type=Path, default=None, help="worlds CSV (t_opt for the BARN score; optional)")
    c.add_argument("--margin", type=float, default=None,
                   help=f"[m] disc: beyond the circumscribed radius (default {MARGIN}); discs: MPCConfig.footprint_margin")
    c.add_argument("--footprint", choices=("disc", "discs"), default="disc",
                   help="disc: circumscribed radius + MARGIN; discs: the N-disc cover's radius + MARGIN "
                        "and the disc centres in the MPC (MPCConfig.footprint)")
    c.add_argument("--discs", type=int, default=None, help="discs of the cover (--footprint discs; default MPCConfig's)")
    c.add_argument("--seeds", type=int, nargs="+", default=[0])
    c.add_argument("--route", choices=("pose", "corridor"), default=None,
                   help="discs mode: corridor and reference from the pose search or the corridor planner "
                        "(MPCConfig.footprint_route; default: the config's)")
    c.add_argument("--box-margin", type=float, default=None,
                   help="[m] discs mode: MPCConfig.footprint_box_margin (default: the config's)")
    c.add_argument("--narrow-penalty", type=float, default=None,
                   help="[m] discs mode: corridor weight added per edge through a place too narrow to turn")
    c.add_argument("--no-tighten", action="store_true",
                   help="discs mode: PredictionDerating(tighten=False) (derating only, no tightening by the error)")
    c.add_argument("--resolution", type=float, default=0.05)
    c.add_argument("--refine", type=int, default=None,
                   help="discs mode: refine the cells by this factor where the free space is narrow")
    c.add_argument("--refine-fallback", type=int, default=None,
                   help="discs mode: refine the map by this factor where the plan finds no path "
                        "(MPCConfig.footprint_refine_fallback)")
    c.add_argument("--no-manoeuvre", action="store_true",
                   help="discs mode: no manoeuvres where the fallback map's corridor reference leaves the "
                        "safe areas (MPCConfig.footprint_manoeuvre None)")
    c.add_argument("--refine-width", type=float, default=None, help="[m] discs mode, --refine > 1: narrow below this")
    c.add_argument("--grow", type=float, default=None,
                   help="[m] discs mode: grow the corridor chain's boxes to maximal free rectangles, at most this per side")
    c.add_argument("--grow-tighten", type=float, default=None,
                   help="[m] discs mode, --grow > 0: tighten the added room by this much more than the box margin")
    c.add_argument("--mismatch", nargs="*", default=[])
    c.add_argument("--sensing", choices=("map", "lidar"), default="map",
                   help="map: the grid from the true geoms; lidar: the robot maps with its own lidar")
    c.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:
        return {"worlds": cmd_worlds, "score": cmd_score, "closed-loop": cmd_closed_loop}[args.cmd](args)
    except (OSError, ValueError, KeyError) as err:  # ScenarioError is a ValueError
        print(f"barn_eval: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
