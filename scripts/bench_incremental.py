"""Benchmark: safe areas updated per lidar scan (incremental) vs rebuilt from the same grid.

Two maps (``--maps``):

* ``barn``: 5 m x 15 m at 0.05 m (100 x 300 cells), 60 random posts and boxes;
* ``big``: 1024 x 1024 cells at 0.05 m (51.2 m square), 900 random obstacles.

A robot drives a fixed path through each world, one scan every 0.05 m (20 Hz at about
1 m/s) from the start of the path; at every pose a scan is cast against the
true occupancy (sampled every quarter cell along each beam; not timed) with the robot's lidar
parameters (270 deg, 541 beams, 10 m, 0.02 m noise). Timed per scan, in one run:

* ``map``: :meth:`LiveGrid.integrate` (log-odds update + incremental inflation);
* ``update``: :meth:`IncrementalSafeAreas.update` (quadtree nodes, merge, graph edges of
  the dirty tiles) -- the number the issue targets (<= 1 ms barn, <= 5 ms big);
* ``snapshot``: :meth:`IncrementalSafeAreas.safe_areas` (compact arrays for the planner);
* ``rebuild``: :func:`build_safe_areas` on the same safe grid (quadtree + merge + graph
  from scratch), as the known-map pipeline would have to do after every scan.

Prints median and p90 [ms] of each, the cells changed per scan, the rectangle counts, the
load average (the machine is shared) and a digest of the final grid, counts, rectangles and
edges (run this script with another version of the package on ``PYTHONPATH`` to compare
timings and check that both compute the same). Run from the repository root:

    PYTHONPATH=$PWD python scripts/bench_incremental.py [--maps barn big] [--scans N] [--warmup N] [--tile T]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time

import numpy as np

from sanav_mj.mapping.incremental import IncrementalSafeAreas
from sanav_mj.mapping.live_grid import LiveGrid
from sanav_mj.mapping.safe_areas import build_safe_areas

RES = 0.05
INFLATION = 0.38  # robot footprint radius 0.33 m + 0.05 m margin
FOV, BEAMS, RANGE, NOISE = np.radians(270.0), 541, 10.0, 0.02


def world(kind: str, rng: np.random.Generator):
    """True occupancy (ny, nx) bool, bounds and a drive path (K, 3) [m, m, rad]."""
    if kind == "barn":
        w, h, n_obs, size = 5.0, 15.0, 60, (0.1, 0.35)
    else:
        w, h, n_obs, size = 1024 * RES, 1024 * RES, 900, (0.1, 1.2)
    nx, ny = int(round(w / RES)), int(round(h / RES))
    occ = np.zeros((ny, nx), dtype=bool)
    yy, xx = (np.mgrid[0:ny, 0:nx] + 0.5) * RES
    for _ in range(n_obs):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        r = rng.uniform(*size)
        if rng.random() < 0.5:
            occ |= (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r
        else:
            occ |= (np.abs(xx - cx) <= r) & (np.abs(yy - cy) <= rng.uniform(*size))
    # keep a lane clear along the path
    if kind == "barn":
        path_y = np.arange(1.0, 14.0, 0.05)  # 0.05 m apart: 20 Hz scans at about 1 m/s
        path_x = 2.5 + 1.0 * np.sin(3 * np.pi * (path_y - 1.0) / 13.0)
    else:
        t = np.linspace(0, 1, 1000)  # about 0.05 m apart
        path_x = 5.0 + 40.0 * t
        path_y = 25.6 + 12.0 * np.sin(2 * np.pi * t)
    for x, y in zip(path_x, path_y):
        occ &= (xx - x) ** 2 + (yy - y) ** 2 > 0.6 ** 2
    yaw = np.arctan2(np.gradient(path_y), np.gradient(path_x))
    return occ, (0.0, 0.0, w, h), np.stack([path_x, path_y, yaw], axis=1)


def true_scan(occ, pose, angles, rng):
    """Ranges by marching every beam at quarter-cell steps through the true grid."""
    ny, nx = occ.shape
    s = np.arange(1, int(RANGE / (RES / 4)) + 1) * (RES / 4)
    a = pose[2] + angles
    px = pose[0] + np.cos(a)[:, None] * s[None, :]
    py = pose[1] + np.sin(a)[:, None] * s[None, :]
    j = np.floor(px / RES).astype(int)
    i = np.floor(py / RES).astype(int)
    outside = (i < 0) | (i >= ny) | (j < 0) | (j >= nx)
    blocked = outside | occ[np.clip(i, 0, ny - 1), np.clip(j, 0, nx - 1)]
    first = np.where(blocked.any(axis=1), blocked.argmax(axis=1), -1)
    hit = first >= 0
    r = np.where(hit, s[np.maximum(first, 0)], RANGE)
    r = np.where(hit, np.clip(r + rng.normal(0, NOISE, len(r)), 0, RANGE), RANGE)
    return r, hit


def stats(v):
    v = np.asarray(v) * 1e3
    return f"{np.median(v):7.3f} {np.percentile(v, 90):7.3f}"


def bench(kind: str, scans: int, tile: int, warmup: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    occ, bounds, path = world(kind, rng)
    angles = -0.5 * FOV + FOV / (BEAMS - 1) * np.arange(BEAMS)
    warmup = min(warmup, len(path) - 2)
    data = [(path[k], *true_scan(occ, path[k], angles, rng)) for k in range(min(warmup + scans, len(path)))]
    g = LiveGrid(bounds, RES, INFLATION)
    inc = IncrementalSafeAreas(g.safe_grid(), tile=tile)
    for pose, r, hit in data[:warmup]:  # the map explored so far (not timed)
        up = g.integrate(pose[:2], pose[2], r, hit, angles)
        inc.update(~g.safe(), up.safe_changed)
    data = data[warmup:]
    t_map, t_upd, t_snap, t_reb, n_changed, n_inc, n_reb, n_tiles = [], [], [], [], [], [], [], []
    load0 = os.getloadavg()
    for pose, r, hit in data:
        t0 = time.perf_counter()
        up = g.integrate(pose[:2], pose[2], r, hit, angles)
        t1 = time.perf_counter()
        occ_safe = ~g.safe()
        t2 = time.perf_counter()
        n_tiles.append(inc.update(occ_safe, up.safe_changed))
        t3 = time.perf_counter()
        boxes, _ = inc.safe_areas()
        t4 = time.perf_counter()
        ref = build_safe_areas(g.safe_grid())
        t5 = time.perf_counter()
        t_map.append(t1 - t0)
        t_upd.append(t3 - t2)
        t_snap.append(t4 - t3)
        t_reb.append(t5 - t4)
        n_changed.append(len(up.safe_changed))
        n_inc.append(len(boxes))
        n_reb.append(len(ref.boxes))
    load1 = os.getloadavg()
    ny, nx = g.shape
    print(f"\n{kind}: {ny} x {nx} cells at {RES} m, {len(data)} timed scans after {warmup} untimed, scans of {BEAMS} beams / {RANGE} m, tile {tile}, "
          f"inflation {INFLATION} m")
    print(f"  load average (1 min) {load0[0]:.2f} before, {load1[0]:.2f} after; {os.cpu_count()} CPUs")
    print(f"  safe cells changed per scan: median {int(np.median(n_changed))}, max {max(n_changed)}; "
          f"dirty tiles median {int(np.median(n_tiles))}, max {max(n_tiles)}")
    print(f"  rectangles at the end: incremental {n_inc[-1]}, rebuild {n_reb[-1]} "
          f"(mean over scans {np.mean(n_inc):.0f} vs {np.mean(n_reb):.0f})")
    print("  [ms]                                   median     p90")
    print(f"  map update (LiveGrid.integrate)       {stats(t_map)}")
    print(f"  safe areas, incremental update        {stats(t_upd)}")
    print(f"  safe areas, compact snapshot          {stats(t_snap)}")
    print(f"  safe areas, rebuild (build_safe_areas) {stats(t_reb)}")
    h = hashlib.sha256()
    for arr in (g.log_odds, g.blocked, boxes, inc.safe_areas()[1].edges):
        h.update(np.ascontiguousarray(arr).tobytes())
    print(f"  digest of the final grid, counts, rectangles and edges: {h.hexdigest()[:16]} "
          "(equal across versions that compute the same)")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--maps", nargs="+", default=["barn", "big"], choices=["barn", "big"])
    p.add_argument("--scans", type=int, default=60, help="scans per map (default 60)")
    p.add_argument("--warmup", type=int, default=0,
                   help="scans integrated before timing starts (the map explored so far; default 0)")
    p.add_argument("--tile", type=int, default=32, help="tile edge [cells], power of two (default 32)")
    a = p.parse_args(argv)
    if a.scans < 2:
        print(f"bench_incremental: --scans must be >= 2, got {a.scans}", file=sys.stderr)
        return 2
    for kind in a.maps:
        bench(kind, a.scans, a.tile, a.warmup)
    return 0


if __name__ == "__main__":
    sys.exit(main())
