"""Benchmark: the lidar pipeline per scan in the built-in scenarios, and how safe its map is.

For each scenario the robot is placed every 0.05 m along the straight line from start to goal
(poses inside the known-map obstacles skipped, heading along the line), the robot's lidar
(``models/diff_drive.xml``) scans, and :class:`sanav_mj.mapping.sensed_map.SensedMap`
integrates the scan at that pose. Printed per scenario, mean / median / p99 [ms]: ray cast,
map update, safe-area update (with its snapshot), route-area update, total; and the safety
check: the smallest reduction of the inflation for which every safe cell of the lidar map is
free in the known-map grid (0 = the lidar map's safe cells are inside the known map's).

    PYTHONPATH=$PWD python scripts/bench_sensing.py [SCENARIO ...] [--seed N]

``--loop``: the closed loop instead (``run SCENARIO --sensing lidar``, seed ``--seed``), as
mean / p99 [ms]: the pipeline per step (scan + map update + replan check and plan + SA-MPC
step), the map update per scan, the SA-MPC step (the run JSON's ``solve_ms``: preparation,
solve, acceptance) and the pipeline without it per step, the control thread's planning time
per step that planned, handed a background plan over or requested one, and the computing
time of each plan after the first wherever it ran; then plans per run, plans adopted from
the background worker, the first plan's time and the controller's construction time
(``prepare_ms``) as means. ``--components`` adds the per-step split (map update, planning,
SA-MPC step, rest), the fallback steps per run (and how many of them the reach check
answered without a solve) and the steps over 10 ms per run; ``--realtime`` paces each run at the
control period, as on a robot (a background plan then has a real period's idle time);
``--new-config KEY=VALUE`` / ``--old-config`` set :class:`SensingConfig` fields of each
version's controller (e.g. ``background_replan=true``). With ``--against TREE`` (a source
tree of another version of the package, e.g. ``git archive <commit> | tar -x -C /tmp/base``),
both versions run alternately, ``--repeat`` times each, in fresh processes under the same
machine load, and the run JSONs (wall-clock fields ``*_ms`` aside) are compared (exit 1 when
runs of one version differ from each other):

    PYTHONPATH=$PWD python scripts/bench_sensing.py --loop u_shape v_shape complex --against /tmp/base --repeat 3
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

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


_WORKER = """
import dataclasses, json, sys
from sanav_mj.eval.episode import run_scenario
from sanav_mj.eval.lidar import lidar_controller
from sanav_mj.scene import load_scenario
from sanav_mj.eval.prepare import footprint_spec
sc = load_scenario(sys.argv[1])
spec = footprint_spec("sa-mpc", sys.argv[5])
ctrl = lidar_controller(sc, spec)
over = json.loads(sys.argv[3])
if over:
    ctrl.config = dataclasses.replace(ctrl.config, **over)
hook = None
if sys.argv[4] == "1":  # paced: each control step starts dt after the last, as on a robot
    import time
    t_next = [None]

    def hook(step, trace):
        if t_next[0] is None:
            t_next[0] = time.perf_counter()
        t_next[0] += ctrl.dt
        time.sleep(max(0.0, t_next[0] - time.perf_counter()))
out = run_scenario(sc, seed=int(sys.argv[2]), sensing="lidar", controller_obj=ctrl, controller_spec=spec,
                   on_step=hook)
rec = out.sensed.records
tr = out.episode.trace
first = next((k for k, r in enumerate(rec) if r.replan is not None), len(rec))
later = [r for r in rec[first + 1:] if r.replan is not None]
print(json.dumps({"pipeline": list(tr.pipeline_ms), "map": out.sensed.map_update_ms, "solve": list(tr.solve_ms),
                  "nosolve": [p - s for p, s in zip(tr.pipeline_ms, tr.solve_ms)],
                  # the control thread's planning time per step that planned, handed a background
                  # plan over or started one (after the first plan)
                  "replan": [r.replan_ms for r in rec[first + 1:] if r.replan_ms > 0],
                  # computing time of each plan after the first, wherever it ran
                  "plan": [getattr(r, "plan_ms", 0.0) or r.replan_ms for r in later],
                  "plans": [len(later)],
                  "deferred": [sum(bool(getattr(r, "deferred", False)) for r in later)],
                  "first": [rec[first].replan_ms] if first < len(rec) else [],
                  "prepare": [getattr(out.sensed, "prepare_ms", 0.0)],
                  # per step: map update (0 without a scan), planning on the control thread,
                  # and the rest outside them and the SA-MPC step (lidar cast, replan check)
                  "map_step": [r.map_ms or 0.0 for r in rec], "replan_step": [r.replan_ms for r in rec],
                  "rest_step": [p - (r.map_ms or 0.0) - r.replan_ms - s
                                for p, s, r in zip(tr.pipeline_ms, tr.solve_ms, rec)],
                  "limit": [sum(s.startswith("fallback") for s in tr.status)],
                  # solves the reach check skipped (proved infeasible; 0 in trees without it)
                  "skipped": [getattr(ctrl.mpc, "unreachable", 0) if ctrl.mpc is not None else 0],
                  "doc": out.document}))
"""


def _strip_ms(x):
    """A run document without its wall-clock fields (keys ending in ``_ms``)."""
    if isinstance(x, dict):
        return {k: _strip_ms(v) for k, v in x.items() if not k.endswith("_ms")}
    if isinstance(x, list):
        return [_strip_ms(v) for v in x]
    return x


_KEYS = ("pipeline", "map", "solve", "nosolve", "replan", "plan", "plans", "deferred", "first", "prepare",
         "map_step", "replan_step", "rest_step", "limit", "skipped")


def loop(names: list[str], seed: int, against: str | None, repeat: int, new_config: dict | None = None,
         old_config: dict | None = None, realtime: bool = False, components: bool = False,
         footprint: str = "disc") -> int:
    """The closed-loop per-step times of this tree (and of ``against``), printed as a table;
    ``new_config`` / ``old_config``: :class:`SensingConfig` fields replaced in each version's
    controller (e.g. ``{"background_replan": False}``); ``realtime``: pace the loop at the
    control period (each step starts ``dt`` after the last, as on a robot), so a background
    plan has the idle time of a real control period; ``components``: also the per-step split
    (map update, control-thread planning, SA-MPC step, rest) and the fallbacks per run;
    ``footprint``: the SA-MPC's footprint mode (``"disc"`` or ``"discs"``).

    With ``repeat`` > 1 each version's runs are the same steps (the run JSON is checked
    repeatable), so it also prints the mean and p99 of each step's *minimum* ``pipeline_ms``
    over the runs (``min/step``): on a shared machine that drops most of the time a step
    waited for a core, which a single run cannot separate."""
    trees = {"new": (str(Path(__file__).resolve().parents[1]), new_config or {})}
    if against:
        trees = {"old": (str(Path(against).resolve()), old_config or {}), **trees}
    print(f"footprint {footprint}; load average {os.getloadavg()[0]:.2f} (start); {repeat} run(s) per version, alternating; "
          f"ms as mean / p99 over all steps, scans or plans of the runs{'; paced at real time' if realtime else ''}")
    for ver, (tree, over) in trees.items():
        print(f"  {ver}: {tree} {over or ''}")
    print(f"{'scenario':10s} {'ver':3s}  {'pipeline':^15s}  {'map update':^15s}  {'solve':^15s}  {'w/o solve':^15s}  "
          f"{'replan (ctl)':^15s}  {'plan':^15s}  plans  defer  first  prep  load  {'min/step':^15s}")
    sys.stdout.flush()
    status = 0
    for name in names:
        acc: dict[str, dict[str, list]] = {v: {k: [] for k in (*_KEYS, "load")} for v in trees}
        docs: dict[str, list] = {v: [] for v in trees}
        runs: dict[str, list] = {v: [] for v in trees}  # per run, its steps' pipeline_ms
        for _ in range(repeat):
            for ver, (tree, over) in trees.items():
                env = {**os.environ, "PYTHONPATH": tree}
                proc = subprocess.run([sys.executable, "-c", _WORKER, name, str(seed), json.dumps(over),
                                       "1" if realtime else "0", footprint], env=env,
                                      cwd=tree, capture_output=True, text=True, check=False)
                if proc.returncode != 0:
                    print(f"bench_sensing: {ver} run of {name} failed: {proc.stderr.strip()[-500:]}", file=sys.stderr)
                    return 3
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                for k in _KEYS:
                    acc[ver][k].extend(r[k])
                runs[ver].append(r["pipeline"])
                acc[ver]["load"].append(os.getloadavg()[0])
                docs[ver].append(_strip_ms(r["doc"]))
        for ver in trees:
            a = acc[ver]

            def f(v):
                return f"{np.mean(v):6.2f} / {np.percentile(v, 99):6.2f}" if len(v) else f"{'-':^15s}"

            print(f"{name:10s} {ver:3s}  {f(a['pipeline'])}  {f(a['map'])}  {f(a['solve'])}  {f(a['nosolve'])}  "
                  f"{f(a['replan'])}  {f(a['plan'])}  {np.mean(a['plans']):5.1f}  {np.mean(a['deferred']):5.1f}  "
                  f"{np.mean(a['first']):5.1f}  {np.mean(a['prepare']):4.1f}  {np.mean(a['load']):4.2f}  "
                  f"{f(_step_minima(runs[ver]))}")
        if components:
            for ver in trees:
                a = acc[ver]

                def g(v):
                    return f"{np.mean(v):5.2f} / {np.percentile(v, 99):6.2f}"

                print(f"{'':10s} {ver:3s}  per step:  map update {g(a['map_step'])}  replan {g(a['replan_step'])}  "
                      f"SA-MPC step {g(a['solve'])}  rest {g(a['rest_step'])}  fallbacks/run "
                      f"{np.mean(a['limit']):.1f} (solve skipped {np.mean(a['skipped']):.1f})  "
                      f"steps > 10 ms/run {sum(v > 10.0 for v in a['pipeline']) / repeat:.1f}")
        repeatable = all(d == docs[v][0] for v in trees for d in docs[v])
        same = repeatable and all(docs[v][0] == docs["new"][0] for v in trees)
        print(f"{name:10s} run JSON (without *_ms): {'repeatable' if repeatable else 'NOT REPEATABLE'} within each "
              f"version; {'identical' if same else 'different'} across versions")
        status = status or (0 if repeatable else 1)
    return status


def _step_minima(runs: list[list[float]]) -> list[float]:
    """Each step's smallest time over runs of the same steps (runs of different lengths, which
    a repeatable run JSON rules out: the steps all runs have)."""
    n = min((len(r) for r in runs), default=0)
    return list(np.min(np.array([r[:n] for r in runs]), axis=0)) if n else []


def _overrides(items: list[str] | None) -> dict:
    """``KEY=VALUE`` strings -> {key: bool | int | float} for :class:`SensingConfig`."""
    out = {}
    for item in items or []:
        key, _, value = item.partition("=")
        out[key] = {"true": True, "false": False}.get(value.lower(), None)
        if out[key] is None:
            out[key] = float(value) if "." in value else int(value)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenarios", nargs="*", help="scenario paths or built-in names (default: all built-in)")
    p.add_argument("--seed", type=int, default=0, help="range-noise seed (default 0)")
    p.add_argument("--loop", action="store_true", help="time the closed loop (run --sensing lidar) per step")
    p.add_argument("--against", metavar="TREE", help="with --loop: also run this source tree, alternately")
    p.add_argument("--repeat", type=int, default=1, help="with --loop: runs per version (default 1)")
    p.add_argument("--new-config", nargs="*", metavar="KEY=VALUE",
                   help="with --loop: SensingConfig fields for this tree's runs, e.g. background_replan=false")
    p.add_argument("--old-config", nargs="*", metavar="KEY=VALUE", help="with --loop: the same for --against")
    p.add_argument("--components", action="store_true",
                   help="with --loop: also print the per-step split (map update, replan, SA-MPC step, rest)")
    p.add_argument("--realtime", action="store_true",
                   help="with --loop: pace each run at the control period (10 Hz), as on a robot")
    p.add_argument("--footprint", choices=("disc", "discs"), default="disc",
                   help="with --loop: the SA-MPC's footprint mode (default disc)")
    a = p.parse_args(argv)
    names = a.scenarios or list(builtin_scenarios())
    if a.loop:
        return loop(names, a.seed, a.against, max(1, a.repeat), _overrides(a.new_config), _overrides(a.old_config),
                    a.realtime, a.components, a.footprint)
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
