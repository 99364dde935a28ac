"""``sanav-mj bench``: the paper's comparison (Table I and Fig. 6) in our simulator.

Every (scenario, controller, seed) is one episode through the same runner; seeds randomise
the initial yaw. Outputs in ``--out``: ``results.csv`` (one row per run), ``table.md`` (per
scenario and method: solve and full-pipeline ms mean/max/std pooled over all steps of all
runs, mean steps of the successful runs, success %, runs with a collision),
``success.png`` (grouped bars) and ``meta.json`` (what was run, where and on which commit).

What the timing columns hold (see :mod:`sanav_mj.eval.metrics` and
:mod:`sanav_mj.eval.episode`): ``solve`` is the controller's own report per step
(``Command.solve_ms``); ``pipeline`` is the wall time of the controller's whole ``step``
call, with the one-off preparation of the run (the re-plan from the seed's start pose; the
map is built once per scenario and worker, see :mod:`sanav_mj.eval.campaign`) added to the
first step.
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

from sanav_mj.eval.campaign import Job, run_jobs

CSV_COLUMNS = (
    "scenario", "controller", "seed", "success", "reason", "steps", "sim_time_s", "path_length_m",
    "min_clearance_m", "collisions", "safe_area_violations", "solver_failures",
    "solve_mean_ms", "solve_max_ms", "solve_std_ms", "solve_p99_ms",
    "pipeline_mean_ms", "pipeline_max_ms", "pipeline_std_ms",
)


def flatten(doc: dict[str, Any]) -> dict[str, Any]:
    """One CSV row from a run JSON document (without trace)."""
    row = {k: doc.get(k) for k in CSV_COLUMNS if k in doc}
    row["solve_mean_ms"] = doc["solve_ms"]["mean"]
    row["solve_max_ms"] = doc["solve_ms"]["max"]
    row["solve_std_ms"] = doc["solve_ms"]["std"]
    row["solve_p99_ms"] = doc["solve_ms"]["p99"]
    row["pipeline_mean_ms"] = doc["pipeline_ms"]["mean"]
    row["pipeline_max_ms"] = doc["pipeline_ms"]["max"]
    row["pipeline_std_ms"] = doc["pipeline_ms"]["std"]
    return row


def pooled(rows: Sequence[dict[str, Any]], prefix: str) -> tuple[float, float, float]:
    """Mean, max and (population) std [ms] over all steps of all runs.

    Exact from the per-run ``{prefix}_mean_ms``, ``{prefix}_std_ms`` (population std, as
    :func:`sanav_mj.eval.metrics.timing_stats`), ``{prefix}_max_ms`` and ``steps`` (the
    number of samples): the pooled second moment is the step-weighted mean of
    ``std^2 + mean^2``. Runs without steps carry no samples and are left out (all zeros
    when no run has one).
    """
    rows = [r for r in rows if int(r["steps"]) > 0]
    n = sum(int(r["steps"]) for r in rows)
    if n == 0:
        return 0.0, 0.0, 0.0
    mean = sum(r[f"{prefix}_mean_ms"] * int(r["steps"]) for r in rows) / n
    second = sum((r[f"{prefix}_std_ms"] ** 2 + r[f"{prefix}_mean_ms"] ** 2) * int(r["steps"]) for r in rows) / n
    return mean, max(r[f"{prefix}_max_ms"] for r in rows), math.sqrt(max(second - mean**2, 0.0))


def summarise(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (scenario, controller) summary rows, in first-seen order.

    Keys: ``scenario``, ``controller``, ``runs``; ``solve_{mean,max,std}_ms`` and
    ``pipeline_{mean,max,std}_ms`` [ms] pooled over all steps (:func:`pooled`); ``steps``
    mean steps of the successful runs (None when none succeeded); ``success_rate`` [%];
    ``collision_runs`` runs with at least one robot-obstacle contact and
    ``collision_rate`` [%] of them; ``reasons`` the outcome counts, e.g. ``"goal 9, stuck 1"``.
    """
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["scenario"], r["controller"]), []).append(r)
    out = []
    for (scenario, controller), rs in groups.items():
        sm, sx, ss = pooled(rs, "solve")
        pm, px, ps = pooled(rs, "pipeline")
        ok = [r for r in rs if r["success"]]
        out.append({
            "scenario": scenario,
            "controller": controller,
            "runs": len(rs),
            "solve_mean_ms": sm, "solve_max_ms": sx, "solve_std_ms": ss,
            "pipeline_mean_ms": pm, "pipeline_max_ms": px, "pipeline_std_ms": ps,
            "steps": (sum(r["steps"] for r in ok) / len(ok)) if ok else None,
            "success_rate": 100.0 * len(ok) / len(rs),
            "collision_runs": sum(int(r["collisions"]) > 0 for r in rs),
            "collision_rate": 100.0 * sum(int(r["collisions"]) > 0 for r in rs) / len(rs),
            "reasons": _reasons(rs),
        })
    return out


def _reasons(rows: list[dict[str, Any]]) -> str:
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["reason"]] = counts.get(r["reason"], 0) + 1
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))


#: Header cells of :func:`markdown_table`.
TABLE_HEADER = (
    "scenario", "method", "runs", "solve mean / max / std (ms)", "full pipeline mean / max / std (ms)",
    "steps", "success %", "runs with collision", "outcomes",
)


def markdown_table(summary: Sequence[dict[str, Any]]) -> str:
    """The timing/success table in Markdown (the paper's Table I layout), one row per summary row."""
    lines = ["| " + " | ".join(TABLE_HEADER) + " |", "|" + "---|" * len(TABLE_HEADER)]
    for s in summary:
        steps = "-" if s["steps"] is None else f"{s['steps']:.0f}"
        lines.append(
            f"| {s['scenario']} | {s['controller']} | {s['runs']} | {s['solve_mean_ms']:.2f} / {s['solve_max_ms']:.2f} / "
            f"{s['solve_std_ms']:.2f} | {s['pipeline_mean_ms']:.2f} / {s['pipeline_max_ms']:.2f} / "
            f"{s['pipeline_std_ms']:.2f} | {steps} | {s['success_rate']:.0f} | {s['collision_runs']} "
            f"| {s['reasons']} |"
        )
    return "\n".join(lines) + "\n"


def write_csv(rows: list[dict[str, Any]], path: Path, columns: tuple[str, ...] = CSV_COLUMNS) -> None:
    """Write result rows (dicts) to CSV with the given leading columns (extra keys appended)."""
    extra = sorted({k for r in rows for k in r} - set(columns))
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=[*columns, *extra], extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)


def _load_average() -> list[float] | None:
    """1, 5 and 15 minute load averages of the machine (None where unavailable)."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def run_metadata(scenarios: Sequence[str], controllers: Sequence[str], runs: int, workers: int,
                 time_limit_s: float) -> dict[str, Any]:
    """What a bench run measured and where: arguments, git commit of the package (and whether
    ``sanav_mj/``, ``models/`` or ``scenarios/`` had uncommitted changes), machine, load, versions."""
    import casadi
    import mujoco
    import numpy

    pkg = Path(__file__).resolve().parents[2]

    def git(*args: str) -> str | None:
        try:
            out = subprocess.run(["git", "-C", str(pkg), *args], capture_output=True, text=True, timeout=10, check=False)
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.rstrip() if out.returncode == 0 else None

    status = git("status", "--porcelain", "--untracked-files=no", "--", "sanav_mj", "models", "scenarios")
    cpu = platform.processor() or None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = {"python": platform.python_version(), "mujoco": mujoco.__version__, "casadi": casadi.__version__,
                "numpy": numpy.__version__}
    try:
        import alpaqa

        versions["alpaqa"] = alpaqa.__version__
    except ImportError:
        pass
    return {
        "scenarios": list(scenarios),
        "controllers": list(controllers),
        "runs": int(runs),
        "seeds": list(range(int(runs))),
        "workers": int(workers),
        "time_limit_s": float(time_limit_s),
        "commit": git("rev-parse", "HEAD"),
        "dirty": None if status is None else bool(status),  # uncommitted changes in the package / models / scenarios
        "dirty_files": None if status is None else [line[3:] for line in status.splitlines()],
        "date_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {"cpu": cpu, "logical_cpus": os.cpu_count(), "platform": platform.platform()},
        "load_average_start": _load_average(),
        "versions": versions,
        "argv": list(sys.argv),
    }


def run_bench(
    scenarios: list[str],
    controllers: list[str],
    runs: int,
    workers: int,
    out: Path,
    record: bool = False,
    time_limit_s: float = 60.0,
) -> list[dict[str, Any]]:
    """Run the comparison and write ``results.csv``, ``table.md`` and ``success.png`` in ``out``.

    Args:
        scenarios: scenario paths/names; empty means all built-in scenarios.
        controllers: controller names.
        runs: seeds 0..runs-1 per (scenario, controller).
        workers: worker processes.
        out: output folder (created).
        record: also write one ``.rrd`` per run to ``out/rrd``.
        time_limit_s: [s] simulated time limit of each run.

    Returns:
        The per (scenario, controller) summary rows (also written to ``table.md``).

    Also writes ``meta.json`` (:func:`run_metadata` plus the wall time of the campaign and
    the load average at its end: the timings are wall times on a possibly shared machine).
    """
    from sanav_mj.eval.plots import plot_success_bars
    from sanav_mj.resources import builtin_scenarios
    from sanav_mj.scene import load_scenario

    names = list(scenarios) or builtin_scenarios()
    for name in names:  # fail fast on bad input, before any worker starts
        load_scenario(name)
    out.mkdir(parents=True, exist_ok=True)
    if record:
        (out / "rrd").mkdir(exist_ok=True)
    jobs = [
        Job(
            scenario=s, controller=c, seed=k, time_limit_s=time_limit_s,
            rrd=str(out / "rrd" / f"{Path(s).stem}_{c}_{k}.rrd") if record else None,
        )
        for s in names for c in controllers for k in range(runs)
    ]
    meta = run_metadata(names, controllers, runs, workers, time_limit_s)
    t0 = time.perf_counter()
    rows = [flatten(d) for d in run_jobs(jobs, workers, desc="bench")]
    meta["wall_time_s"] = time.perf_counter() - t0
    meta["load_average_end"] = _load_average()
    write_csv(rows, out / "results.csv")
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    summary = summarise(rows)
    (out / "table.md").write_text(markdown_table(summary))
    plot_success_bars(
        [{"scenario": s["scenario"], "controller": s["controller"], "success_rate": s["success_rate"]} for s in summary],
        out / "success.png",
    )
    return summary
