"""Campaign machinery figures: memory of a huge lazy sweep, and pool vs Ray throughput.

    python scripts/bench_campaign.py memory [--runs N] [--complete]
        A robustness sweep of 200 x 200 grid points x 10 000 seeds on one scenario
        (400 million jobs) with a trivial job function (no simulation) in this process,
        stopped after N finished runs: the resident memory before the campaign, after the
        first run, after 1 000, N/2 and N runs. With --complete: a 2 x 2 sweep of N runs
        run to its end, the outputs written (RSS after them too).

    python scripts/bench_campaign.py throughput [--scenarios ...] [--runs N] [--workers W]
        The same bench campaign (sa-mpc, time limit 30 s) on the process pool and on a local
        Ray with W CPUs: runs per minute for each and Ray's overhead per run, with a
        trivial job function too (the pure overhead of dispatching a run).

Prints the figures; the machine's load average is printed with them (timings are wall
times on a possibly shared machine).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path


def _rss_mb() -> tuple[float, float]:
    """(resident, peak resident) memory of this process [MB] from /proc/self/status."""
    fields = {}
    with open("/proc/self/status") as fh:
        for line in fh:
            key, _, value = line.partition(":")
            fields[key] = value
    return int(fields["VmRSS"].split()[0]) / 1024, int(fields["VmHWM"].split()[0]) / 1024


def _load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def trivial_run(job):
    """A valid run row that is a function of the job, without simulating anything."""
    from sanav_mj.sim.mismatch import parse_mismatch

    stats = {"mean": 1.0, "max": 2.0, "std": 0.5, "p50": 1.0, "p99": 2.0}
    return {"scenario": job.scenario, "controller": job.controller, "seed": job.seed, "success": True,
            "reason": "goal", "steps": 10, "sim_time_s": 1.0, "path_length_m": 2.0, "min_clearance_m": 0.1,
            "collisions": 0, "safe_area_violations": 0, "solver_failures": 0, "solve_ms": stats,
            "pipeline_ms": stats, "mismatch": parse_mismatch(list(job.mismatch)).changed(), **dict(job.tags)}


def memory(runs: int, complete: bool = False) -> None:
    """RSS of a robustness campaign with a trivial job function, in this process, at a few
    points of the campaign: the huge lazy sweep stopped after ``runs`` runs, or (``complete``)
    a whole 2 x 2 sweep of ``runs`` runs with its outputs written."""
    from sanav_mj.eval import campaign
    from sanav_mj.eval.campaign import CampaignInterrupted
    from sanav_mj.eval.robustness import parse_sweep, run_robustness

    if complete:
        seeds = max(runs // 4, 1)
        sweep = parse_sweep(["mass=1,1.2", "track=1,1.2"])
        what = f"sweep 2 x 2 x {seeds} seeds = {4 * seeds:,} jobs, run to the end (outputs written)"
    else:
        values = ",".join(f"{0.5 + 0.005 * i:.3f}" for i in range(200))
        sweep = parse_sweep([f"mass={values}", f"track={values}"])
        seeds = 10_000
        what = f"sweep 200 x 200 x 10000 seeds = {200 * 200 * 10_000:,} jobs, stopped after {runs:,} runs"
    marks: dict[str, tuple[float, float]] = {}
    count = {"n": 0}
    checkpoints = {2, 1_000, runs // 2, runs}

    def run(job):
        count["n"] += 1
        if count["n"] in checkpoints:
            marks["after the first run" if count["n"] == 2 else f"after {count['n'] - 1:,} runs"] = _rss_mb()
        if count["n"] > runs:
            raise KeyboardInterrupt
        return trivial_run(job)

    campaign.run_job = run
    marks["before the campaign"] = _rss_mb()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        try:
            run_robustness(["single_rect"], sweep, seeds, "dwa", 1, Path(tmp))
            marks[f"after {count['n']:,} runs + outputs"] = _rss_mb()
        except CampaignInterrupted as exc:
            marks[f"after {exc.saved:,} runs (Ctrl-C)"] = _rss_mb()
        wall = time.perf_counter() - t0
    print(f"{what}, trivial job function, in this process ({wall:.1f} s, load {_load()})")
    for name, (rss, peak) in sorted(marks.items(), key=lambda kv: kv[1][1]):
        print(f"  {name:32s} RSS {rss:7.1f} MB   peak {peak:7.1f} MB")


def throughput(scenarios: list[str], runs: int, workers: int, controller: str, repeats: int) -> None:
    from sanav_mj.eval import campaign
    from sanav_mj.eval.bench import run_bench
    from sanav_mj.eval.ray_runner import RayExecutor, ray_session

    n = len(scenarios) * runs
    print(f"bench {' '.join(scenarios)} x {controller} x {runs} runs = {n} runs, {workers} workers, "
          f"load {_load()}")
    walls: dict[str, list[float]] = {"pool": [], "ray": [], "pool trivial": [], "ray trivial": []}
    jobs = [campaign.Job(s, controller, k) for s in scenarios for k in range(runs * 10)]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        with ray_session(None, num_cpus=workers) as session:
            start = time.perf_counter() - t0
            for rep in range(repeats):  # alternate, so a change of the machine's load hits both alike
                for name in ("pool", "ray"):
                    t0 = time.perf_counter()
                    run_bench(scenarios, [controller], runs, workers, Path(tmp) / f"{name}{rep}", time_limit_s=30.0,
                              ray=session if name == "ray" else None)
                    walls[name].append(time.perf_counter() - t0)
                # the pure dispatch cost: trivial jobs through each executor
                t0 = time.perf_counter()
                campaign.run_jobs(jobs, workers, runner=trivial_run)
                walls["pool trivial"].append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                campaign.run_jobs(jobs, executor=RayExecutor(session, runner=trivial_run))
                walls["ray trivial"].append(time.perf_counter() - t0)
    for name in ("pool", "ray"):
        print(f"  {name:4s}: " + ", ".join(f"{w:.1f} s = {60 * n / w:.0f} runs/min" for w in walls[name]))
    print(f"  local Ray start-up: {start:.1f} s (once per session)")
    diff = [(r - p) / n for p, r in zip(walls["pool"], walls["ray"])]
    print("  (ray - pool) wall per run: " + ", ".join(f"{1e3 * d:+.0f} ms" for d in diff))
    m = len(jobs)
    print(f"  trivial job x {m} (no simulation): pool " + ", ".join(f"{1e3 * w / m:.2f}" for w in walls["pool trivial"])
          + " ms/run; ray " + ", ".join(f"{1e3 * w / m:.2f}" for w in walls["ray trivial"]) + " ms/run (wall)")
    print(f"  load at the end {_load()}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="what", required=True)
    m = sub.add_parser("memory")
    m.add_argument("--runs", type=int, default=20_000)
    m.add_argument("--complete", action="store_true", help="a whole 2 x 2 sweep of --runs runs, outputs written")
    t = sub.add_parser("throughput")
    t.add_argument("--scenarios", nargs="+", default=["single_rect", "double_rect", "u_shape"])
    t.add_argument("--runs", type=int, default=4)
    t.add_argument("--workers", type=int, default=2)
    t.add_argument("--controller", default="sa-mpc")
    t.add_argument("--repeats", type=int, default=2)
    args = p.parse_args(argv)
    if args.what == "memory":
        memory(args.runs, args.complete)
    else:
        throughput(args.scenarios, args.runs, args.workers, args.controller, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
