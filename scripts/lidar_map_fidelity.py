"""How faithful is the lidar's sensed grid to the true obstacles? Offline, no controller.

The robot is placed at poses along a shortest path (8-connected, on the known map
inflated as the run inflates it) from the scenario's start to its goal, one pose every
``--step`` metres, heading along the path; at each pose the simulated lidar
(:class:`sanav_mj.sim.lidar.Lidar`, the robot file's noise) scans and the scan is integrated
into a :class:`~sanav_mj.mapping.live_grid.LiveGrid` of each configuration compared. The
sensed grid is then compared with the true occupancy rasterised from the geoms
(:func:`sanav_mj.mapping.occupancy.rasterise`, exact), over the cells the scans observed:

* ``fat_k`` (k = 1, 2, 3): observed cells whose square is >= k cells from every obstacle
  and that the sensed grid calls non-free (the fattening by the range noise);
* ``mat_free``: cells holding obstacle material that the sensed grid calls free;
  ``mat_free_far``: those of them with no non-free 8-neighbour (not covered by one cell of
  extra inflation);
* ``unsafe``: cells the sensed grid calls safe whose square is within the inflation of an
  obstacle (the known-map rule; must be 0: the guarantee); ``short_mm``: by how much the
  inflation would have to shrink for none to be (0.5 mm steps);
* ``safe``: safe cells (the known map's free cells on the observed region for comparison:
  ``known``); ``flips``: safe-state changes per scan over the second half of the path
  (the flicker: safe cells lost per scan).

Usage: PYTHONPATH=$PWD python scripts/lidar_map_fidelity.py WORLD.xml [...] [--step 0.04]
Prints one line per world and configuration.
"""

from __future__ import annotations

import argparse
import heapq
import math
import sys
from dataclasses import replace

import numpy as np
from scipy import ndimage

from sanav_mj.control.config import MPCConfig
from sanav_mj.eval.lidar import lidar_cell, lidar_spec
from sanav_mj.control.spec import ControllerSpec
from sanav_mj.eval.prepare import map_inflation
from sanav_mj.mapping.live_grid import FREE, LiveGrid, LiveGridConfig
from sanav_mj.mapping.occupancy import rasterise
from sanav_mj.mapping.subcell_grid import SubcellGrid
from sanav_mj.scene import load_scenario
from sanav_mj.sim.lidar import Lidar, lidar_config
from sanav_mj.sim.plant import Plant

#: the grids compared: before floor_at (every return locks its cell non-free), the default,
#: the default with one cell of extra inflation, a higher hit-fraction threshold, and the
#: default with the sub-cell evidence of return cells (SubcellGrid, the discs mode's lidar runs),
#: and that with a sub-cell free at free_thresh (-0.35, one crossing) and at -2.
CONFIGS = {
    "before": LiveGridConfig(l_min=-1.0, floor_at=None),
    "default": LiveGridConfig(),
    "noise1": LiveGridConfig(noise_cells=1),
    "l_occ0.7": LiveGridConfig(l_occ=0.7),
    "subcell": LiveGridConfig(sub_cells=2),
    "subcell_f-0.35": LiveGridConfig(sub_cells=2, sub_free_thresh=-0.35),
    "subcell_f-2": LiveGridConfig(sub_cells=2, sub_free_thresh=-2.0),
    "subcell_whole": LiveGridConfig(sub_cells=2, sub_tail=None),
    "subcell_tail0.3": LiveGridConfig(sub_cells=2, sub_tail=0.3),
}


def shortest_path(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]]:
    """8-connected Dijkstra on ``free`` cells; [] when unreachable."""
    ny, nx = free.shape
    dist = np.full(free.shape, np.inf)
    prev = {}
    dist[start] = 0.0
    q = [(0.0, start)]
    moves = [(di, dj, math.hypot(di, dj)) for di in (-1, 0, 1) for dj in (-1, 0, 1) if di or dj]
    while q:
        d, (i, j) = heapq.heappop(q)
        if (i, j) == goal:
            break
        if d > dist[i, j]:
            continue
        for di, dj, w in moves:
            a, b = i + di, j + dj
            if 0 <= a < ny and 0 <= b < nx and free[a, b] and d + w < dist[a, b]:
                dist[a, b] = d + w
                prev[(a, b)] = (i, j)
                heapq.heappush(q, (d + w, (a, b)))
    if goal not in prev and goal != start:
        return []
    path = [goal]
    while path[-1] != start:
        path.append(prev[path[-1]])
    return path[::-1]


def measure(xml: str, step: float, seed: int, configs: dict) -> dict:
    sc = load_scenario(xml)
    spec = lidar_spec(ControllerSpec("sa-mpc", replace(MPCConfig(), footprint="discs")))
    h = lidar_cell(0.05, spec)
    infl = map_inflation(sc, spec)
    known = rasterise(sc.obstacles, sc.bounds, h, inflation=infl)
    org = known.origin
    ij = lambda p: (int((p[1] - org[1]) / h), int((p[0] - org[0]) / h))  # noqa: E731
    free = ~known.occupied
    path = shortest_path(free, ij(sc.start), ij(sc.goal))
    if not path:
        # the known map closes the way at this inflation: drive the largest inflation that passes
        free = ~rasterise(sc.obstacles, sc.bounds, h, inflation=0.5 * infl).occupied
        path = shortest_path(free, ij(sc.start), ij(sc.goal))
    pts = np.array([[org[0] + (j + 0.5) * h, org[1] + (i + 0.5) * h] for i, j in path])
    seg = np.hypot(*np.diff(pts, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    ss = np.arange(0.0, s[-1], step)
    xs, ys = np.interp(ss, s, pts[:, 0]), np.interp(ss, s, pts[:, 1])
    look = np.minimum(np.searchsorted(s, ss + 0.3), len(pts) - 1)
    yaw = np.arctan2(pts[look, 1] - ys, pts[look, 0] - xs)
    plant = Plant(sc)
    lidar = Lidar(plant.model, sc.obstacles, lidar_config(plant.model))
    grids = {k: (SubcellGrid if c.sub_cells == 2 else LiveGrid)(sc.bounds, h, infl, c) for k, c in configs.items()}
    rng = np.random.default_rng([seed, 16])
    flips = {k: 0 for k in configs}
    half = len(ss) // 2
    for n, (x, y, th) in enumerate(zip(xs, ys, yaw)):
        plant.reset(np.array([x, y, th]))
        scan = lidar.scan(plant.data, rng)
        _, origin, heading = lidar.true_ranges(plant.data)
        for k, g in grids.items():
            up = g.integrate(origin[:2], heading, scan.ranges, scan.hit, scan.angles)
            if n >= half:  # safe cells lost (safe -> not safe): the flicker
                flips[k] += int((~g.safe_at(up.safe_changed)).sum())
    material = rasterise(sc.obstacles, sc.bounds, h, inflation=0.0).occupied
    fine = 5  # material on cells fine times smaller: how deep it reaches into free cells
    mat_f = rasterise(sc.obstacles, sc.bounds, h / fine, inflation=0.0).occupied
    far = [~rasterise(sc.obstacles, sc.bounds, h, inflation=k * h - 1e-6).occupied for k in (1, 2, 3)]
    out = {}
    for k, g in grids.items():
        seen = g.log_odds != 0
        st = g.states()
        nonfree = st != FREE
        pad = np.pad(nonfree, 1, constant_values=True)
        ny, nx = nonfree.shape
        nb = np.zeros_like(nonfree)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di or dj:
                    nb |= pad[1 + di:1 + di + ny, 1 + dj:1 + dj + nx]
        mf = material & ~nonfree
        safe = g.safe()
        nf = np.kron(nonfree, np.ones((fine, fine), dtype=bool))[:mat_f.shape[0], :mat_f.shape[1]]
        depth = ndimage.distance_transform_edt(~nf) * (h / fine)  # to the nearest non-free fine cell
        inside = mat_f & ~nf
        depth_m = float(depth[inside].max()) if inside.any() else 0.0
        short = 0.0  # [m] how much less inflation the safe cells keep from the obstacles (0.5 mm steps)
        while np.any(safe & rasterise(sc.obstacles, sc.bounds, h, inflation=infl - short).occupied):
            short += 0.0005
        out[k] = {"fat_0": int((~material & seen & nonfree).sum()), "fat_1": int((far[0] & seen & nonfree).sum()), "fat_2": int((far[1] & seen & nonfree).sum()),
                  "fat_3": int((far[2] & seen & nonfree).sum()), "mat_free": int(mf.sum()),
                  "mat_free_far": int((mf & ~nb).sum()), "depth_mm": round(1000 * depth_m, 1), "unsafe": int((safe & known.occupied).sum()), "short_mm": round(1000 * short, 1),
                  "safe": int(safe.sum()), "known": int((free & seen).sum()),
                  "flips": round(flips[k] / max(1, len(ss) - half), 1)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("worlds", nargs="+")
    ap.add_argument("--step", type=float, default=0.04, help="[m] pose spacing along the path")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--configs", default=",".join(CONFIGS), help="comma-separated subset of " + ", ".join(CONFIGS))
    a = ap.parse_args(argv)
    for xml in a.worlds:
        res = measure(xml, a.step, a.seed, {k: CONFIGS[k] for k in a.configs.split(",")})
        for k, v in res.items():
            print(xml.rsplit("/", 1)[-1], k, " ".join(f"{n}={x}" for n, x in v.items()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
