"""Endurance: a long simulated SA-MPC run, printing the process memory as it goes.

The robot drives to the goal of a scenario and then keeps station there (goal tolerance 0,
no stuck detection) until the simulated time limit, so the solver, the plant and the runner
run every control step for the whole duration. Per-step trace entries are dropped as they
are produced (as a streaming consumer would), so what remains is the memory of the
pipeline itself: it must not grow.

    python scripts/endurance.py --scenario u_shape --minutes 10
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np


def rss_mb() -> float:
    """Resident set size of this process [MiB] (Linux /proc)."""
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def endurance(scenario: str = "u_shape", minutes: float = 10.0, every_s: float = 60.0):
    """Run the long episode; returns a list of (sim_time_s, rss_mb) samples."""
    from sanav_mj.control.factory import make_controller
    from sanav_mj.eval.prepare import prepare
    from sanav_mj.sim.plant import Plant
    from sanav_mj.sim.runner import RunConfig, run_episode

    prep = prepare(scenario)
    s = prep.scenario
    ctrl = make_controller("sa-mpc", s, prep.grid, prep.areas, prep.plan)
    cfg = RunConfig(time_limit_s=minutes * 60.0, goal_tolerance_m=1e-9, stuck_window_s=1e9,
                    max_solver_failures=10**9)
    samples: list[tuple[float, float]] = []
    every = max(1, int(round(every_s / ctrl.dt)))

    def on_step(step, trace):
        if step % every == 0:
            samples.append((step * ctrl.dt, rss_mb()))
        for name in vars(trace):
            getattr(trace, name).clear()

    ep = run_episode(Plant(s), ctrl, s.start, s.goal, cfg, on_step=on_step)
    samples.append((ep.sim_time_s, rss_mb()))
    return samples, ep


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="u_shape")
    p.add_argument("--minutes", type=float, default=10.0, help="simulated minutes")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    samples, ep = endurance(args.scenario, args.minutes)
    wall = time.perf_counter() - t0
    for t, mb in samples:
        print(f"sim {t:7.1f} s  rss {mb:8.2f} MiB")
    after_warmup = [mb for t, mb in samples if t >= 120.0]
    growth = (after_warmup[-1] - after_warmup[0]) if len(after_warmup) > 1 else float("nan")
    print(f"{args.scenario}: {ep.sim_time_s:.0f} s simulated in {wall:.1f} s wall "
          f"(real-time factor {ep.sim_time_s / wall:.0f}x), reason {ep.reason}, collisions {ep.collisions}, "
          f"rss growth after 2 min {growth:+.2f} MiB, min/max rss {min(m for _, m in samples):.1f}/"
          f"{max(m for _, m in samples):.1f} MiB")
    return 0 if np.isfinite(growth) else 1


if __name__ == "__main__":
    sys.exit(main())
