"""Benchmark: the lidar pipeline per scan in the built-in scenarios, and how safe its map is.

For each scenario the robot is placed every 0.05 m along the straight line from start to goal
(poses inside the known-map obstacles skipped, heading along the line), the robot's lidar
(``models/diff_drive.xml``) scans, and :class:`sanav_mj.mapping.sensed_map.SensedMap`
integrates the scan at that pose. Printed per scenario, mean / median / p99 [ms]: ray cast,
map update, safe-area update (with its snapshot), route-area update, total; and the safety
check: the smallest reduction of the inflation for which every safe cell of the lidar map is
free in the known-map grid (0 = the lidar map's safe cells are inside the known map's).

    PYTHONPATH=$PWD python scripts/bench_sensing.py [SCENARIO ...] [--seed N]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import mujoco
import numpy as np

from sanav_mj.mapping.occupancy import rasterise
from sanav_mj.mapping.sensed_map import SensedMap
from sanav_mj.resources import builtin_scenarios
from sanav_mj.scene import ScenarioError, load_scenario, robot_qpos
from sanav_mj.sim.lidar import Lidar, lidar_config

MARGIN = 0.05  # [m] inflation = footprint radius + this, as the known-map pipeline


def run(name: str, seed: int) -> str:
    sc = load_scenario(name)
    m = sc.model
    d = mujoco.MjData(m)
    infl = sc.robot.footprint_radius + MARGIN
    cfg = lidar_config(m)
    lidar = Lidar(m, sc.obstacles, cfg)
    sm = SensedMap(sc.bounds, infl, cfg.offset)
    rng = np.random.default_rng(seed)
    known = rasterise(sc.obstacles, sc.bounds, 0.05, inflation=infl)
    line = sc.goal - sc.start[:2]
    yaw = math.atan2(line[1], line[0])
    t_scan, t = [], {"map": [], "areas": [], "route": [], "total": []}
    for s in np.linspace(0.0, 1.0, max(2, int(np.hypot(*line) / 0.05))):
        p = sc.start[:2] + s * line
        i, j = ((p - known.origin) / known.resolution).astype(int)[::-1]
        if known.occupied[i, j]:
            continue
        d.qpos[:] = robot_qpos(m, np.array([p[0], p[1], yaw]))
        mujoco.mj_forward(m, d)
        t0 = time.perf_counter()
        scan = lidar.scan(d, rng)
        t_scan.append(1e3 * (time.perf_counter() - t0))
        up = sm.integrate((p[0], p[1], yaw), scan.ranges, scan.hit, scan.angles)
        tm = up.timing_ms
        t["map"].append(tm["map"])
        t["areas"].append(tm["areas"] + tm["snapshot"])
        t["route"].append(tm["route"])
        t["total"].append(tm["total"] + t_scan[-1])
    safe = sm.grid.safe()
    delta = math.nan
    for dl in np.arange(0.0, 0.3, 0.005):
        if not np.any(safe & rasterise(sc.obstacles, sc.bounds, 0.05, inflation=max(infl - dl, 0.0)).occupied):
            delta = dl
            break

    def f(v):
        return f"{np.mean(v):5.2f} / {np.median(v):5.2f} / {np.percentile(v, 99):5.2f}"

    return (f"{name:12s} {len(t_scan):4d}  {np.mean(t_scan):5.2f}  {f(t['map'])}  {f(t['areas'])}  "
            f"{f(t['route'])}  {f(t['total'])}  {len(up.boxes):5d}  {delta:.3f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenarios", nargs="*", help="scenario paths or built-in names (default: all built-in)")
    p.add_argument("--seed", type=int, default=0, help="range-noise seed (default 0)")
    a = p.parse_args(argv)
    names = a.scenarios or list(builtin_scenarios())
    print(f"load average {os.getloadavg()[0]:.2f}; ms as mean / median / p99")
    print(f"{'scenario':12s} {'scans':>4s}  {'cast':>5s}  {'map update':^21s}  {'safe areas':^21s}  "
          f"{'route areas':^21s}  {'total':^21s}  {'rects':>5s}  delta_m")
    for name in names:
        try:
            print(run(name, a.seed))
        except ScenarioError as exc:
            print(f"bench_sensing: {exc}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
