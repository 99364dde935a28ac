"""Benchmark planning (corridor search + waypoints + smoothing + time-parametrisation).

Maps: the built-in scenarios (mapped at 0.05 m with the robot footprint radius + 0.05 m
inflation, as the pipeline does) and seeded random-clutter maps of N x N cells from
``scripts/bench_areas.py`` (N = 512 by default). On a clutter map the start and goal are the
centres of the safe areas nearest to the lower-left and upper-right corners within the
largest connected component of the graph. Mapping is not timed here (see bench_areas.py).

For each map and search backend the script prints one markdown table row: sizes, the
plan's outcome, the median wall time of each stage (from ``Plan.info["timing_ms"]``), the
median / 90th percentile / maximum wall time of the whole ``plan(...)`` call over the
repeats, the median CPU time of the process during the call (``time.process_time``: on a
machine shared with other jobs the wall time includes waiting for a core, the CPU time does
not), and the first (cold) call's wall time.

    python scripts/bench_planning.py [--scenarios NAME ...] [--sizes 512] [--repeats 50] [--seed 0]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from sanav_mj.mapping import MapConfig, build_map
from sanav_mj.planning import PlannerConfig, plan
from sanav_mj.planning.corridor import build_graph, reachable_from
from sanav_mj.scene import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_areas import INFLATION, RESOLUTION, clutter  # noqa: E402

SCENARIOS = ("single_rect", "double_rect", "u_shape", "v_shape", "complex")
MARGIN = 0.05  # [m] inflation beyond the footprint radius, as the pipeline


def _clutter_task(n: int, seed: int):
    obstacles, bounds = clutter(n, np.random.default_rng([seed, n]))
    m = build_map(obstacles, bounds, INFLATION, MapConfig(resolution=RESOLUTION))
    areas = m.areas
    rects = np.asarray(areas.rects)
    centres = 0.5 * (rects[:, :2] + rects[:, 2:])
    g = build_graph(areas)
    # largest connected component: grow from each unvisited area
    seen = np.zeros(len(rects), bool)
    best = np.zeros(len(rects), bool)
    for i in range(len(rects)):
        if not seen[i]:
            comp = reachable_from(g, i)
            seen |= comp
            if comp.sum() > best.sum():
                best = comp
    cand = np.flatnonzero(best)
    s = cand[np.argmin(np.linalg.norm(centres[cand] - bounds[:2], axis=1))]
    t = cand[np.argmin(np.linalg.norm(centres[cand] - bounds[2:], axis=1))]
    return f"clutter {n}^2", areas, np.r_[centres[s], 0.0], centres[t]


def _robot():
    return load_scenario("single_rect").robot


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    parser.add_argument("--sizes", type=int, nargs="*", default=[512])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--search", nargs="+", default=["dijkstra", "astar"], choices=["dijkstra", "astar"])
    args = parser.parse_args()

    tasks = []
    for name in args.scenarios:
        sc = load_scenario(name)
        m = build_map(sc.obstacles, sc.bounds, sc.robot.footprint_radius + MARGIN, MapConfig(resolution=RESOLUTION))
        tasks.append((name, m.areas, sc.start, sc.goal, sc.robot))
    robot = _robot()
    for n in args.sizes:
        tasks.append((*_clutter_task(n, args.seed), robot))

    stages = ("search", "waypoints", "smoothing", "timing")
    header = ("map", "search", "rects", "edges", "corridor", "ok", "path m", "T s", "lam steps", "fallback m",
              *(f"{s} ms" for s in stages), "wall p50 ms", "p90", "max", "CPU p50 ms", "cold ms")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for name, areas, start, goal, rob in tasks:
        for search in args.search:
            cfg = PlannerConfig(search=search)
            t0 = time.perf_counter()
            p = plan(areas, start, goal, rob, cfg)
            cold = 1e3 * (time.perf_counter() - t0)
            wall, cpu, st = [], [], {s: [] for s in stages}
            for _ in range(args.repeats):
                c0 = time.process_time()
                t0 = time.perf_counter()
                p = plan(areas, start, goal, rob, cfg)
                wall.append(1e3 * (time.perf_counter() - t0))
                cpu.append(1e3 * (time.process_time() - c0))
                for s in stages:
                    st[s].append(p.info.get("timing_ms", {}).get(s, float("nan")))
            info = p.info
            row = (
                name, search, len(areas.rects), len(areas.edges), int(p.corridor.size), p.ok,
                f"{info.get('path_length_m', float('nan')):.2f}", f"{info.get('duration_s', float('nan')):.2f}",
                info.get("lambda_steps", "-"), f"{info.get('fallback_length_m', 0.0):.2f}",
                *(f"{statistics.median(st[s]):.3f}" for s in stages),
                f"{statistics.median(wall):.3f}", f"{np.percentile(wall, 90):.3f}", f"{max(wall):.3f}",
                f"{statistics.median(cpu):.3f}", f"{cold:.3f}",
            )
            print("| " + " | ".join(str(v) for v in row) + " |", flush=True)


if __name__ == "__main__":
    main()
