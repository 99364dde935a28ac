"""``sanav-mj demo``: every built-in scenario with SA-MPC, with recordings, plots and a summary."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm


@dataclass
class DemoResult:
    """What :func:`run_demo` ran and wrote.

    Attributes:
        rows: one summary row per scenario (the run JSON without its trace).
        written: the files written completely, in order.
        failed: the outputs that could not be written (``OSError`` with ``filename`` the
            output's path); the other outputs were still written.
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    written: list[Path] = field(default_factory=list)
    failed: list[OSError] = field(default_factory=list)


def run_demo(out: Path, record: bool = True, seed: int = 0, sensing: str = "map",
             footprint: str = "disc") -> DemoResult:
    """Run SA-MPC once on each built-in scenario.

    Writes, per scenario NAME, into ``out``: ``NAME.json`` (the run JSON), ``NAME.png`` (run
    plot), ``NAME_areas.png`` (map and reference) and, when ``record``, ``NAME.rrd``; and
    ``summary.md`` with one line per scenario. Each file is written whole or not at all
    (:mod:`sanav_mj.outputs`); one that cannot be written (a full disk) is noted in
    :attr:`DemoResult.failed` and the others are still written.

    Args:
        out: output folder (created).
        record: also write the rerun recordings.
        seed: the seed of every run.
        sensing: ``"map"`` or ``"lidar"`` (see :func:`sanav_mj.eval.episode.run_scenario`).
        footprint: SA-MPC's ``"disc"`` or ``"discs"`` (:func:`sanav_mj.eval.prepare.footprint_spec`).
    """
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.prepare import footprint_spec
    from sanav_mj.eval.plots import plot_areas, plot_run
    from sanav_mj.outputs import write_text
    from sanav_mj.record import record_episode
    from sanav_mj.resources import builtin_scenarios

    result = DemoResult()

    def write(path: Path, fn) -> None:
        try:
            fn()
        except OSError as exc:
            result.failed.append(exc if exc.filename else OSError(exc.errno, exc.strerror, str(path)))
        else:
            result.written.append(path)

    out.mkdir(parents=True, exist_ok=True)
    for name in tqdm(builtin_scenarios(), desc="demo", unit="scenario", dynamic_ncols=True):
        outcome = run_scenario(name, seed=seed, sensing=sensing, record_sensing=record,
                               controller_spec=footprint_spec("sa-mpc", footprint))
        doc = outcome.document
        js, png, areas, rrd = (out / f"{name}.json", out / f"{name}.png", out / f"{name}_areas.png",
                               out / f"{name}.rrd")
        write(js, lambda: write_text(js, json.dumps(doc, indent=1, allow_nan=False)))
        write(png, lambda: plot_run(outcome, png))
        write(areas, lambda: plot_areas(outcome.prepared, areas))
        if record:
            write(rrd, lambda: record_episode(rrd, outcome))
        result.rows.append({k: v for k, v in doc.items() if k != "trace"})
    summary = out / "summary.md"
    write(summary, lambda: write_text(summary, summary_table(result.rows)))
    return result


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
