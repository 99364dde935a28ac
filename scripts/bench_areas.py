"""Benchmark the mapping stage (rasterise, quadtree, merge, graph) on seeded random-clutter maps.

Maps are square workspaces of N x N cells at 0.05 m (N = 128, 256, 512, 1024) filled with
boxes at random yaws and cylinders at a fixed density, inflated by 0.35 m. For each size the
script prints the median wall time of each stage over several repeats, the leaf and
rectangle counts, and the time of the straightforward recursive quadtree
(``quadtree_recursive``: one Python call per node, node state by scanning its cells) beside
the vectorised one.

    python scripts/bench_areas.py [--sizes 128 256 512 1024] [--repeats 15] [--seed 0]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from sanav_mj.mapping import MapConfig, build_map
from sanav_mj.mapping.quadtree import quadtree_recursive, sort_leaves
from sanav_mj.scene import Obstacle

RESOLUTION = 0.05  # [m]
INFLATION = 0.35  # [m] about the robot footprint radius plus a margin
DENSITY = 1.0 / 8.0  # [obstacles / m^2]


def clutter(n_cells: int, rng: np.random.Generator) -> tuple[list[Obstacle], np.ndarray]:
    """A square workspace of ``n_cells`` x ``n_cells`` cells with random boxes and cylinders.

    Returns the obstacles and the (4,) [m] bounds.
    """
    side = n_cells * RESOLUTION
    count = max(1, round(DENSITY * side * side))
    obstacles = []
    for k in range(count):
        centre = rng.uniform(0.0, side, 2)
        if rng.random() < 0.7:
            half = rng.uniform(0.1, 0.8, 2)
            obstacles.append(Obstacle(f"box_{k}", "box", centre, float(rng.uniform(-np.pi, np.pi)), half, 0.5, -1))
        else:
            r = float(rng.uniform(0.1, 0.5))
            obstacles.append(Obstacle(f"cyl_{k}", "cylinder", centre, 0.0, np.array([r, r]), 0.5, -1))
    return obstacles, np.array([0.0, 0.0, side, side])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512, 1024])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    stages = ("rasterise", "quadtree", "merge", "graph", "total")
    header = ("cells", "obst", "occ%", *stages, "total min", "leaves free/occ", "rects", "edges",
              "recursive qt", "ratio")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for n in args.sizes:
        rng = np.random.default_rng([args.seed, n])
        obstacles, bounds = clutter(n, rng)
        config = MapConfig(resolution=RESOLUTION)
        build_map(obstacles, bounds, INFLATION, config)  # warm-up
        runs = [build_map(obstacles, bounds, INFLATION, config) for _ in range(args.repeats)]
        med = {s: statistics.median(r.timing_ms[s] for r in runs) for s in stages}
        result = runs[-1]
        occ = result.grid.occupied
        ref_runs = max(1, min(args.repeats, 5))
        ref_ms = []
        for _ in range(ref_runs):
            t0 = time.perf_counter()
            ref = quadtree_recursive(occ)
            ref_ms.append(1e3 * (time.perf_counter() - t0))
        ref, fast = sort_leaves(ref), sort_leaves(result.leaves)
        if not np.array_equal(ref.boxes, fast.boxes) or not np.array_equal(ref.free, fast.free):
            raise SystemExit(f"{n}: recursive and vectorised quadtrees differ")
        ref_med = statistics.median(ref_ms)
        row = (
            f"{n}x{n}", str(len(obstacles)), f"{100 * occ.mean():.0f}",
            *(f"{med[s]:.2f}" for s in stages),
            f"{min(r.timing_ms['total'] for r in runs):.2f}",
            f"{result.leaves.n_free}/{result.leaves.n_occupied}",
            str(len(result.areas.rects)), str(len(result.areas.edges)),
            f"{ref_med:.1f}", f"{ref_med / med['quadtree']:.0f}x",
        )
        print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
