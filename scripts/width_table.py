"""Planner-level width table for the discs footprint mode (issue 14): does a corridor exist?

    PYTHONPATH=$PWD python scripts/width_table.py /work/data/h14b_runs/barn100/*.xml \
        --worlds /work/data/h14b_runs/barn100_worlds.csv --out runs/width_table.csv

For every world, disc count n (the n-disc cover of the footprint rectangle, radius r_n),
margin m and cell mode, whether the safe-area planner finds a corridor on the map inflated by
r_n + m (no closed loop). Cell modes: ``0.05`` / ``0.025`` / ``0.0125`` (one grid), ``r2`` /
``r4`` (0.05 m cells refined locally to 0.025 / 0.0125 m where the free run is at most
--refine-width, :func:`sanav_mj.mapping.refine.refine_narrow`). Also per mode: the corridor's
safe areas narrower than 3 cm on their short side (slivers) summed over the worlds with a
path. ``exact``: the widest disc that travels start -> goal (the worlds CSV) >= r_n + m.

One process; prints a markdown table, writes CSV (one row per world and setting).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from sanav_mj.eval.prepare import planner_config
from sanav_mj.footprint import robot_footprint
from sanav_mj.mapping import MapConfig, build_map
from sanav_mj.planning import plan
from sanav_mj.scene import load_scenario

MODES = {"0.05": MapConfig(resolution=0.05), "0.025": MapConfig(resolution=0.025),
         "0.0125": MapConfig(resolution=0.0125)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="+", type=Path)
    ap.add_argument("--worlds", type=Path, required=True, help="worlds CSV with widest_disc_m")
    ap.add_argument("--discs", type=int, nargs="+", default=[3, 4, 5])
    ap.add_argument("--margins", type=float, nargs="+", default=[0.0, 0.02, 0.03, 0.05])
    ap.add_argument("--refine-width", type=float, default=0.25)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    modes = dict(MODES)
    modes["r2"] = MapConfig(resolution=0.05, refine=2, refine_width=args.refine_width)
    modes["r4"] = MapConfig(resolution=0.05, refine=4, refine_width=args.refine_width)
    widest = {r["scenario"]: float(r["widest_disc_m"]) for r in csv.DictReader(open(args.worlds))}
    rows = []
    for path in args.scenarios:
        s = load_scenario(path)
        fp = robot_footprint(s.model)
        for n in args.discs:
            r = fp.discs(n)[1]
            for m in args.margins:
                for name, cfg in modes.items():
                    mp = build_map(s.obstacles, s.bounds, r + m, cfg)
                    p = plan(mp.areas, s.start, s.goal, s.robot, planner_config(s.robot))
                    slivers = 0
                    if p.ok:
                        c = mp.rects[np.asarray(p.corridor, dtype=int)]
                        slivers = int(np.sum(np.minimum(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1]) < 0.03 - 1e-9))
                    rows.append({"scenario": s.name, "discs": n, "radius_m": r, "margin_m": m, "mode": name,
                                 "path": int(p.ok), "rects": len(mp.rects), "corridor_slivers": slivers,
                                 "exact": int(widest[s.name] >= r + m)})
        print(s.name, file=sys.stderr, flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    names = list(modes)
    print("| discs (radius) | margin | exact | " + " | ".join(f"{k} m cells" if k[0] != "r" else f"{k}" for k in names) + " |")
    print("|---" * (3 + len(names)) + "|")
    for n in args.discs:
        for m in args.margins:
            sel = [x for x in rows if x["discs"] == n and x["margin_m"] == m]
            cells = []
            for k in names:
                sk = [x for x in sel if x["mode"] == k]
                cells.append(f"{sum(x['path'] for x in sk)} ({sum(x['corridor_slivers'] for x in sk)})")
            print(f"| {n} ({sel[0]['radius_m']:.3f} m) | {m:.2f} | {sum(x['exact'] for x in sel if x['mode'] == names[0])} | "
                  + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
