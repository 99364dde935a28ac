"""BARN-style evaluation of generated worlds (see :mod:`sanav_mj.generate`, :mod:`sanav_mj.eval.barn`).

    python scripts/barn_eval.py worlds runs/barn40/*.xml --out runs/barn40_worlds.csv
        per world: shortest path L [m] for the BARN metric (inscribed clearance), t_opt [s],
        widest disc radius that passes [m], and whether the safe-area planner finds a path at
        each (inflation, resolution) of --configs (default: today's 0.33 + 0.05 m at 0.05 m,
        without the margin, at 0.025 m, both, and at 0.0125 m).
    python scripts/barn_eval.py score runs/bench_dir --worlds runs/barn40_worlds.csv
        BARN score per run of a ``sanav-mj bench`` output folder (results.csv) and the mean.

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
from sanav_mj.eval.episode import planner_config
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
    args = parser.parse_args(argv)
    try:
        return cmd_worlds(args) if args.cmd == "worlds" else cmd_score(args)
    except (OSError, ValueError, KeyError) as err:  # ScenarioError is a ValueError
        print(f"barn_eval: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
