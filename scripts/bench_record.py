"""Measure what recording a run to a rerun ``.rrd`` file adds to its wall time.

The same scenario, controller and seed run back to back with and without ``--rrd``, in
alternating order (A B, B A, ...) so that drift in machine load hits both sides alike,
after one untimed warm-up run of each. Each timed run is the whole ``run_scenario`` call
(mapping, planning, the closed loop, metrics and, when recording, the Recorder's static
scene, per-step logging and closing the file).

It also replays the trace of the last run into a fresh Recorder on its own ("offline"),
which isolates the recording cost from the solver's run-to-run noise, and (``--cli-repeats``)
times whole ``sanav-mj run`` processes with and without ``--rrd``, which adds the one-off
``import rerun`` of a fresh process.

Both wall time and process CPU time are reported: on a shared machine the wall ratio of a
pair swings with other processes' load, the CPU ratio much less.

    python scripts/bench_record.py [--scenario u_shape] [--controller sa-mpc] [--seed 0]
                                   [--repeats 5] [--time-limit 60] [--cli-repeats 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from sanav_mj.eval.episode import run_scenario
from sanav_mj.record import RecordConfig, Recorder
from sanav_mj.sim.runner import EpisodeTrace


def timed_run(args, rrd: Path | None):
    """Wall time [s], process CPU time [s] (all threads, so rerun's writer thread counts) and
    the outcome of one run."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = run_scenario(args.scenario, controller=args.controller, seed=args.seed, time_limit_s=args.time_limit,
                       rrd=rrd)
    return time.perf_counter() - t0, time.process_time() - c0, out


def offline_cost(out, path: Path, flush_every: int = RecordConfig().flush_every) -> dict[str, float]:
    """[s] Recorder construction, all log_step calls, finish, for a recorded trace."""
    full = out.episode.trace
    t0 = time.perf_counter()
    rec = Recorder(path, out.prepared, out.controller, RecordConfig(flush_every=flush_every))
    t1 = time.perf_counter()
    part = EpisodeTrace()
    names = [f.name for f in dataclasses.fields(EpisodeTrace)]
    steps_s = 0.0
    for k in range(len(full)):
        for name in names:  # growing the trace is the runner's work, not timed
            getattr(part, name).append(getattr(full, name)[k])
        s0 = time.perf_counter()
        rec.log_step(k, part)
        steps_s += time.perf_counter() - s0
    t2 = time.perf_counter()
    rec.finish(out.episode, out.document)
    t3 = time.perf_counter()
    return {"init": t1 - t0, "steps": steps_s, "finish": t3 - t2, "total": (t1 - t0) + steps_s + (t3 - t2)}


def cli_run(args, rrd: Path | None) -> tuple[float, float]:
    """Wall time [s] and CPU time [s] (user + system) of one ``sanav-mj run`` process."""
    exe = shutil.which("sanav-mj")
    cmd = [exe] if exe else [sys.executable, "-m", "sanav_mj.cli"]
    cmd += ["run", args.scenario, "--controller", args.controller, "--seed", str(args.seed),
            "--time-limit", str(args.time_limit)]
    if rrd is not None:
        cmd += ["--rrd", str(rrd)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ))
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="u_shape")
    p.add_argument("--controller", default="sa-mpc")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeats", type=int, default=5, help="timed pairs (default 5)")
    p.add_argument("--time-limit", type=float, default=60.0, help="[s] simulated")
    p.add_argument("--cli-repeats", type=int, default=3, help="timed pairs of whole CLI processes (0: skip)")
    args = p.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        rrd = Path(tmp) / "run.rrd"
        timed_run(args, None)  # warm-up: solver build / caches, imports
        timed_run(args, rrd)
        plain, recorded, ratios, cpu_ratios, steps_seen = [], [], [], [], set()
        cpu_plain, cpu_rec = [], []
        out = None
        for r in range(args.repeats):
            order = (False, True) if r % 2 == 0 else (True, False)
            wall, cpu = {}, {}
            for rec in order:
                wall[rec], cpu[rec], res = timed_run(args, rrd if rec else None)
                steps_seen.add(res.document["steps"])
                if rec:
                    out = res
            plain.append(wall[False])
            recorded.append(wall[True])
            ratios.append(wall[True] / wall[False])
            cpu_plain.append(cpu[False])
            cpu_rec.append(cpu[True])
            cpu_ratios.append(cpu[True] / cpu[False])
            print(f"pair {r + 1}: wall without {wall[False]:.3f} s, with {wall[True]:.3f} s, ratio {ratios[-1]:.3f}; "
                  f"CPU without {cpu[False]:.3f} s, with {cpu[True]:.3f} s, ratio {cpu_ratios[-1]:.3f}")
        size_kb = rrd.stat().st_size / 1024
        off = [offline_cost(out, Path(tmp) / f"offline{k}.rrd") for k in range(args.repeats)]
        off1 = [offline_cost(out, Path(tmp) / f"offline1_{k}.rrd", flush_every=1) for k in range(3)]
        cli = []
        for r in range(args.cli_repeats):
            order = (False, True) if r % 2 == 0 else (True, False)
            pair = {rec: cli_run(args, rrd if rec else None) for rec in order}
            cli.append(pair)

    doc = out.document
    steps = doc["steps"]
    print()
    print(f"{args.scenario} / {args.controller} seed {args.seed}: {doc['reason']} after {steps} steps "
          f"({doc['sim_time_s']:.1f} s simulated), recording {size_kb:.0f} KiB")
    print(f"wall time without recording: median {statistics.median(plain):.3f} s "
          f"(min {min(plain):.3f}, max {max(plain):.3f})")
    print(f"wall time with recording:    median {statistics.median(recorded):.3f} s "
          f"(min {min(recorded):.3f}, max {max(recorded):.3f})")
    print(f"CPU time without / with recording: median {statistics.median(cpu_plain):.3f} s / "
          f"{statistics.median(cpu_rec):.3f} s")
    print(f"wall ratio with/without (paired): median {statistics.median(ratios):.3f}, "
          f"min {min(ratios):.3f}, max {max(ratios):.3f}")
    print(f"CPU ratio with/without (paired):  median {statistics.median(cpu_ratios):.3f}, "
          f"min {min(cpu_ratios):.3f}, max {max(cpu_ratios):.3f}")
    if len(steps_seen) > 1:
        print(f"note: the episode length varied between runs: {sorted(steps_seen)} steps")
    med = {k: statistics.median(o[k] for o in off) for k in ("init", "steps", "finish", "total")}
    print(f"recorder alone (offline replay, median of {len(off)}): init {1e3 * med['init']:.1f} ms, "
          f"log_step total {1e3 * med['steps']:.1f} ms ({1e6 * med['steps'] / max(steps, 1):.0f} us/step), "
          f"finish {1e3 * med['finish']:.1f} ms, total {1e3 * med['total']:.1f} ms = "
          f"{100 * med['total'] / statistics.median(plain):.1f} % of the median run")
    print(f"same, logging every step as it happens (flush_every=1, median of {len(off1)}): "
          f"total {1e3 * statistics.median(o['total'] for o in off1):.1f} ms")
    if cli:
        w0 = statistics.median(c[False][0] for c in cli)
        w1 = statistics.median(c[True][0] for c in cli)
        c0 = statistics.median(c[False][1] for c in cli)
        c1 = statistics.median(c[True][1] for c in cli)
        print(f"whole `sanav-mj run` process (median of {len(cli)} pairs): wall {w0:.2f} s -> {w1:.2f} s "
              f"(ratio {statistics.median(c[True][0] / c[False][0] for c in cli):.3f}), CPU {c0:.2f} s -> {c1:.2f} s "
              f"(ratio {statistics.median(c[True][1] / c[False][1] for c in cli):.3f}); includes `import rerun`")


if __name__ == "__main__":
    main()
