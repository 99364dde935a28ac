"""Benchmark the mapping stage (rasterise, quadtree, merge, graph) on seeded random-clutter maps.

Maps are square workspaces of N x N cells at 0.05 m (N = 128, 256, 512, 1024) filled with
boxes at random yaws and cylinders at a fixed density, inflated by 0.35 m. For each size the
script prints the median wall time of each stage over several repeats, the fastest total and
the median CPU time of the whole call, the leaf and
rectangle counts, and the time of the straightforward recursive quadtree
(``quadtree_recursive``: one Python call per node, node state by scanning its cells) beside
the vectorised one.

    python scripts/bench_areas.py [--sizes 128 256 512 1024] [--repeats 15] [--seed 0]
    python scripts/bench_areas.py --merge-study    # paper merge vs a row-run alternative
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from sanav_mj.mapping import MapConfig, build_map
from sanav_mj.mapping.quadtree import quadtree_recursive, sort_leaves
from sanav_mj.mapping.safe_areas import merge_rects
from sanav_mj.scene import Obstacle

RESOLUTION = 0.05  # [m]
INFLATION = 0.35  # [m] about the robot footprint radius plus a margin
DENSITY = 1.0 / 8.0  # [obstacles / m^2]


def clutter(n_cells: int, rng: np.random.Generator, count: int | None = None) -> tuple[list[Obstacle], np.ndarray]:
    """A square workspace of ``n_cells`` x ``n_cells`` cells with random boxes and cylinders.

    ``count`` obstacles (default: DENSITY per m^2). Returns the obstacles and the (4,) [m] bounds.
    """
    side = n_cells * RESOLUTION
    if count is None:
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


def timed_runs(obstacles, bounds, config, repeats):
    """``repeats`` calls of build_map; returns the results and the CPU time of each [ms]
    (``time.process_time``: the cost of the code itself, without time spent preempted)."""
    runs, cpu = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        runs.append(build_map(obstacles, bounds, INFLATION, config))
        cpu.append(1e3 * (time.process_time() - c0))
    return runs, cpu


def row_run_merge(occupied: np.ndarray) -> np.ndarray:
    """Candidate alternative merge (not shipped): maximal free runs of each grid row, then the
    paper's full-edge merging of those runs. Returns (R, 4) cell boxes."""
    ny, nx = occupied.shape
    free = np.zeros((ny, nx + 2), dtype=np.int8)
    free[:, 1:-1] = ~occupied
    step = np.diff(free, axis=1)
    si, sj = np.nonzero(step == 1)
    _, ej = np.nonzero(step == -1)
    return merge_rects(np.stack([si, sj, si + 1, ej], axis=1))


def rect_stats(boxes: np.ndarray) -> str:
    """Count, median area, largest area, area-weighted mean area and share of free cells in
    rectangles one cell thin."""
    h = boxes[:, 2] - boxes[:, 0]
    w = boxes[:, 3] - boxes[:, 1]
    area = h * w
    thin = area[np.minimum(h, w) == 1].sum() / area.sum()
    weighted = (area * area).sum() / area.sum()
    return f"{len(boxes)} | {np.median(area):.0f} | {area.max()} | {weighted:.0f} | {100 * thin:.0f}%"


def merge_study(sizes: list[int], seed: int) -> None:
    """Print the paper merge beside the row-run alternative on the benchmark maps."""
    print("| cells | merge | rects | median area [cells] | largest | area-weighted mean area | free cells in 1-cell-thin rects |")
    print("|---|---|---|---|---|---|---|")
    for n in sizes:
        obstacles, bounds = clutter(n, np.random.default_rng([seed, n]))
        result = build_map(obstacles, bounds, INFLATION, MapConfig(resolution=RESOLUTION))
        print(f"| {n}x{n} | paper | {rect_stats(result.boxes)} |")
        print(f"| {n}x{n} | row runs | {rect_stats(row_run_merge(result.grid.occupied))} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512, 1024])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scaling-size", type=int, default=1024,
                        help="cells per side of the fixed workspace for the clutter-scaling table")
    parser.add_argument("--merge-study", action="store_true",
                        help="only compare the paper merge with a row-run alternative (counts, no timing)")
    args = parser.parse_args()
    if args.merge_study:
        merge_study(args.sizes, args.seed)
        return

    stages = ("rasterise", "quadtree", "merge", "graph", "total")
    header = ("cells", "obst", "occ%", *stages, "total min", "CPU total", "leaves free/occ", "rects", "edges",
              "recursive qt", "ratio")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for n in args.sizes:
        rng = np.random.default_rng([args.seed, n])
        obstacles, bounds = clutter(n, rng)
        config = MapConfig(resolution=RESOLUTION)
        build_map(obstacles, bounds, INFLATION, config)  # warm-up
        runs, cpu = timed_runs(obstacles, bounds, config, args.repeats)
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
            f"{min(r.timing_ms['total'] for r in runs):.2f}", f"{statistics.median(cpu):.2f}",
            f"{result.leaves.n_free}/{result.leaves.n_occupied}",
            str(len(result.areas.rects)), str(len(result.areas.edges)),
            f"{ref_med:.1f}", f"{ref_med / med['quadtree']:.0f}x",
        )
        print("| " + " | ".join(row) + " |", flush=True)

    # Same workspace, more and more clutter: time should follow the leaves, not the cells.
    n = args.scaling_size
    full = round(DENSITY * (n * RESOLUTION) ** 2)
    print(f"\n{n}x{n} cells, varying clutter")
    header = ("obst", "leaves", "rects", *stages, "total min", "CPU total")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for count in sorted({0, max(1, full // 64), max(1, full // 16), max(1, full // 4), full}):
        obstacles, bounds = clutter(n, np.random.default_rng([args.seed, n, count]), count)
        config = MapConfig(resolution=RESOLUTION)
        build_map(obstacles, bounds, INFLATION, config)
        runs, cpu = timed_runs(obstacles, bounds, config, args.repeats)
        med = {s: statistics.median(r.timing_ms[s] for r in runs) for s in stages}
        row = (str(count), str(len(runs[-1].leaves)), str(len(runs[-1].areas.rects)),
               *(f"{med[s]:.2f}" for s in stages), f"{min(r.timing_ms['total'] for r in runs):.2f}",
               f"{statistics.median(cpu):.2f}")
        print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
