"""``sanav-mj demo``: every built-in scenario with SA-MPC, with recordings, plots and a summary."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from tqdm import tqdm


def run_demo(out: Path, record: bool = True, seed: int = 0) -> list[dict[str, Any]]:
    """Run SA-MPC once on each built-in scenario.

    Writes, per scenario NAME, into ``out``: ``NAME.json`` (the run JSON), ``NAME.png`` (run
    plot), ``NAME_areas.png`` (map and reference) and, when ``record``, ``NAME.rrd``; and
    ``summary.md`` with one line per scenario.

    Returns:
        One summary row per scenario (the run JSON without its trace).
    """
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.plots import plot_areas, plot_run
    from sanav_mj.resources import builtin_scenarios

    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in tqdm(builtin_scenarios(), desc="demo", unit="scenario", dynamic_ncols=True):
        outcome = run_scenario(name, seed=seed, rrd=out / f"{name}.rrd" if record else None)
        (out / f"{name}.json").write_text(json.dumps(outcome.document, indent=1, allow_nan=False))
        plot_run(outcome, out / f"{name}.png")
        plot_areas(outcome.prepared, out / f"{name}_areas.png")
        rows.append({k: v for k, v in outcome.document.items() if k != "trace"})
    (out / "summary.md").write_text(summary_table(rows))
    return rows


def summary_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of demo runs: outcome, steps, path, clearance, solve times."""
    lines = [
        "| scenario | outcome | steps | time (s) | path (m) | min clearance (m) | collisions | solve mean / p99 / max (ms) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        s = r["solve_ms"]
        clear = "-" if r["min_clearance_m"] is None else f"{r['min_clearance_m']:.3f}"
        lines.append(
            f"| {r['scenario']} | {r['reason']} | {r['steps']} | {r['sim_time_s']:.1f} | {r['path_length_m']:.2f} "
            f"| {clear} | {r['collisions']} | {s['mean']:.2f} / {s['p99']:.2f} / {s['max']:.2f} |"
        )
    return "\n".join(lines) + "\n"
