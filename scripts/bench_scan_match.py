"""Scan matching in the lidar closed loop: time per scan and pose-estimate error.

Runs ``--sensing lidar`` episodes (SA-MPC) on the given scenarios and seeds, with an optional
mismatch, and reports per scenario: the wall time of the localisation of each scan (odometry
prediction + :meth:`SensedMap.match`: normals, correlative search, Gauss-Newton, consistency
test), the match statuses, and the error of the pose estimate against the true pose (the
trace's pose at the same step) beside the error of the measured pose.

    PYTHONPATH=$PWD python scripts/bench_scan_match.py u_shape complex --seeds 0 1 --mismatch yaw_noise=0.035
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

import numpy as np

from sanav_mj.eval.episode import run_scenario
from sanav_mj.eval.lidar import lidar_controller
from sanav_mj.scene import load_scenario
from sanav_mj.sim.mismatch import Mismatch, parse_mismatch


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="+")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--mismatch", nargs="*", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    mm = parse_mismatch(args.mismatch) if args.mismatch else Mismatch()
    print(f"# mismatch {mm.changed()}")
    print(f"{'scenario':12s} {'seed':>4s} {'reason':8s} {'scans':>5s}  match ms mean / p50 / p99 / max   "
          f"est err xy rms/max [m]  yaw rms/max [rad]   meas err xy rms  yaw rms   statuses")
    for name in args.scenarios:
        sc = load_scenario(name)
        for seed in args.seeds:
            ctrl = lidar_controller(sc, mismatch=mm)
            times: list[float] = []
            inner = ctrl._localise

            def timed(obs, inner=inner, times=times):
                t0 = time.perf_counter()
                out = inner(obs)
                if obs.scan is not None:
                    times.append((time.perf_counter() - t0) * 1e3)
                return out

            ctrl._localise = timed
            out = run_scenario(sc, seed=seed, sensing="lidar", controller_obj=ctrl, mismatch=mm)
            tr = out.episode.trace
            est = np.array([e for _, e in ctrl.match_log])
            true = np.array(tr.pose)[: len(est)]
            meas = np.array(tr.measured)[: len(est)]
            e = est - true
            e[:, 2] = _wrap(e[:, 2])
            em = meas - true
            em[:, 2] = _wrap(em[:, 2])
            exy, emxy = np.hypot(e[:, 0], e[:, 1]), np.hypot(em[:, 0], em[:, 1])
            t = np.array(times)
            st = dict(Counter(s for s, _ in ctrl.match_log))
            print(f"{name:12s} {seed:4d} {out.document['reason']:8s} {len(t):5d}  "
                  f"{t.mean():6.3f} / {np.median(t):6.3f} / {np.percentile(t, 99):6.3f} / {t.max():6.3f}   "
                  f"{np.sqrt((exy ** 2).mean()):.4f} / {exy.max():.4f}   "
                  f"{np.sqrt((e[:, 2] ** 2).mean()):.4f} / {np.abs(e[:, 2]).max():.4f}   "
                  f"{np.sqrt((emxy ** 2).mean()):.4f}  {np.sqrt((em[:, 2] ** 2).mean()):.4f}   {st}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
