"""``sanav-mj bench``: the paper's comparison (Table I and Fig. 6) in our simulator.

Every (scenario, controller, seed) is one episode through the same runner; seeds randomise
the initial yaw. Outputs in ``--out``: ``results.csv`` (one row per run), ``table.md`` (per
scenario and method: solve and full-pipeline ms mean/max/std pooled over all steps of all
runs, mean steps of the successful runs, success %) and ``success.png`` (grouped bars).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

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


def pooled(rows: list[dict[str, Any]], prefix: str) -> tuple[float, float, float]:
    """Mean, max, std [ms] over all steps of all runs, exact from per-run mean/std/steps."""
    n = sum(max(int(r["steps"]), 0) for r in rows)
    if n == 0:
        return 0.0, 0.0, 0.0
    mean = sum(r[f"{prefix}_mean_ms"] * r["steps"] for r in rows) / n
    second = sum((r[f"{prefix}_std_ms"] ** 2 + r[f"{prefix}_mean_ms"] ** 2) * r["steps"] for r in rows) / n
    return mean, max(r[f"{prefix}_max_ms"] for r in rows), math.sqrt(max(second - mean**2, 0.0))


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (scenario, controller) summary rows, in first-seen order."""
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
            "collision_rate": 100.0 * sum(r["collisions"] > 0 for r in rs) / len(rs),
            "reasons": _reasons(rs),
        })
    return out


def _reasons(rows: list[dict[str, Any]]) -> str:
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["reason"]] = counts.get(r["reason"], 0) + 1
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))


def markdown_table(summary: list[dict[str, Any]]) -> str:
    """The timing/success table in Markdown (the paper's Table I layout)."""
    lines = [
        "| scenario | method | solve mean / max / std (ms) | full pipeline mean / max / std (ms) "
        "| steps | success % | collisions % | outcomes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        steps = "-" if s["steps"] is None else f"{s['steps']:.0f}"
        lines.append(
            f"| {s['scenario']} | {s['controller']} | {s['solve_mean_ms']:.2f} / {s['solve_max_ms']:.2f} / "
            f"{s['solve_std_ms']:.2f} | {s['pipeline_mean_ms']:.2f} / {s['pipeline_max_ms']:.2f} / "
            f"{s['pipeline_std_ms']:.2f} | {steps} | {s['success_rate']:.0f} | {s['collision_rate']:.0f} "
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
    rows = [flatten(d) for d in run_jobs(jobs, workers, desc="bench")]
    write_csv(rows, out / "results.csv")
    summary = summarise(rows)
    (out / "table.md").write_text(markdown_table(summary))
    plot_success_bars(
        [{"scenario": s["scenario"], "controller": s["controller"], "success_rate": s["success_rate"]} for s in summary],
        out / "success.png",
    )
    return summary
