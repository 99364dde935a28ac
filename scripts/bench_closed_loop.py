"""Closed-loop real-time factor of SA-MPC in MuJoCo, without recording.

For every built-in scenario and seed: simulated time / wall time of the episode loop
(controller + physics + measurements), and the share of wall time spent in the controller.
Mapping and planning are done once per scenario before the loop and reported separately.

    python scripts/bench_closed_loop.py --seeds 5
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.prepare import prepare
    from sanav_mj.resources import builtin_scenarios

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=5, help="seeds per scenario (random initial yaw)")
    p.add_argument("--controller", default="sa-mpc")
    args = p.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f}; controller {args.controller}; {args.seeds} seeds per scenario")
    print(f"{'scenario':12s} {'steps':>6s} {'sim s':>7s} {'wall s':>7s} {'RTF':>6s} {'ctrl %':>7s} {'map+plan ms':>12s}")
    all_sim = all_wall = 0.0
    rtfs = []
    for name in builtin_scenarios():
        prep = prepare(name)
        steps = sim = wall = ctrl = 0.0
        for seed in range(args.seeds):
            out = run_scenario(prep, controller=args.controller, seed=seed)
            ep = out.episode
            steps += ep.steps
            sim += ep.sim_time_s
            wall += ep.wall_time_s
            ctrl += sum(ep.trace.pipeline_ms) / 1e3
        rtfs.append(sim / wall)
        all_sim += sim
        all_wall += wall
        print(f"{name:12s} {steps:6.0f} {sim:7.1f} {wall:7.2f} {sim / wall:6.1f} {100 * ctrl / wall:7.1f} "
              f"{prep.timing_ms['total']:12.2f}")
    print(f"overall real-time factor {all_sim / all_wall:.1f}x (min over scenarios {min(rtfs):.1f}x)")
    return 0 if np.isfinite(all_sim / all_wall) else 1


if __name__ == "__main__":
    sys.exit(main())
