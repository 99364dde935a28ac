"""The paper's comparison (Table I, Fig. 6) in one command: bench, figure and the table of docs/results.md.

Runs ``sanav-mj bench`` on the paper's five scenarios with the four methods (seeds 0..RUNS-1,
random initial yaw), then copies ``success.png`` to ``docs/img/results/`` and rewrites the
generated block of ``docs/results.md`` (between the ``reproduced:begin`` / ``reproduced:end``
markers) with the table and the commit, date and machine of the run, read from the bench's
``meta.json``. ``--report-only`` rebuilds the doc block and the figure from an existing
``--out`` folder without running anything.

    python scripts/reproduce_paper.py --out out/paper --runs 10 --workers 2
    python scripts/reproduce_paper.py --out out/paper --report-only
    python scripts/reproduce_paper.py --ablation single_rect --runs 10

``--ablation SCENARIO`` instead runs the penalty-MPC baseline with each of its choices
undone in turn (:data:`ABLATION`, one process, same seeds) and prints a Markdown table.

About 200 runs; 20-40 minutes on two shared cores (the failing baseline runs last until the
runner declares them stuck, 8 s of simulated time without progress).
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import shutil
import sys
from pathlib import Path

#: the paper's five scenarios (built-in names), in its order
SCENARIOS = ("single_rect", "double_rect", "u_shape", "v_shape", "complex")
#: the four methods, in the order of the paper's Fig. 6 legend
CONTROLLERS = ("mpc", "dqn", "dwa", "sa-mpc")
ROOT = Path(__file__).resolve().parents[1]
BEGIN, END = "<!-- reproduced:begin -->", "<!-- reproduced:end -->"
#: the baseline's choices undone one at a time (``PenaltyConfig`` keywords); the first row is the default
ABLATION: tuple[tuple[str, dict], ...] = (
    ("default (lookahead 3 m, escape starts, depth penalty)", {}),
    ("reference from the robot (lookahead 0)", {"lookahead": 0.0}),
    ("lookahead 2 m", {"lookahead": 2.0}),
    ("no escape starts", {"escape_yaw_rates": ()}),
    ("forward only (v >= 0)", {"forward_only": True}),
    ("product penalty (q_obs 300)", {"form": "product", "q_obs": 300.0}),
    ("first version: lookahead 0, no escapes, product penalty",
     {"lookahead": 0.0, "escape_yaw_rates": (), "form": "product", "q_obs": 300.0}),
)


def _read_rows(path: Path) -> list[dict]:
    """results.csv back into typed rows (the columns :func:`sanav_mj.eval.bench.summarise` reads)."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            row = dict(r)
            row["success"] = r["success"] == "True"
            for k in ("steps", "collisions", "seed"):
                row[k] = int(r[k])
            for k in r:
                if k.endswith("_ms"):
                    row[k] = float(r[k])
            rows.append(row)
    return rows


def report(out: Path, doc: Path, img: Path) -> str:
    """Write the figure and the doc block from ``out``; returns the block."""
    from sanav_mj.eval.bench import markdown_table, summarise

    meta = json.loads((out / "meta.json").read_text())
    summary = summarise(_read_rows(out / "results.csv"))
    img.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / "success.png", img / "success.png")
    commit = meta.get("commit") or "unknown"
    dirty = " (with uncommitted changes)" if meta.get("dirty") else ""
    machine = meta.get("machine", {})
    block = (
        f"{BEGIN}\n"
        f"Measured at commit `{commit[:12]}`{dirty} on {meta.get('date_utc', '?')}, "
        f"{machine.get('cpu', '?')} ({machine.get('logical_cpus', '?')} logical CPUs, shared), "
        f"{meta.get('workers', '?')} worker processes, {meta.get('runs', '?')} runs per cell "
        f"(seeds {meta.get('seeds', ['?'])[0]}..{meta.get('seeds', ['?'])[-1]}), "
        f"{meta.get('wall_time_s', float('nan')) / 60:.0f} min wall time.\n\n"
        + markdown_table(summary)
        + f"{END}"
    )
    text = doc.read_text()
    if BEGIN in text and END in text:
        text = re.sub(re.escape(BEGIN) + r".*?" + re.escape(END), lambda _: block, text, flags=re.DOTALL)
        doc.write_text(text)
    else:
        print(f"{doc}: no {BEGIN} ... {END} block; the table is in {out}/table.md", file=sys.stderr)
    return block


def ablation(scenario: str, runs: int) -> str:
    """Run the penalty-MPC variants of :data:`ABLATION` on ``scenario`` (seeds 0..runs-1); Markdown table."""
    import numpy as np

    from sanav_mj.control.penalty_mpc import PenaltyConfig, PenaltyMPC
    from sanav_mj.eval.episode import prepare, run_scenario

    prep = prepare(scenario)
    sc = prep.scenario
    lines = ["| variant | success | outcomes | min clearance (m) | solve mean / max (ms) |", "|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for label, kwargs in ABLATION:
        docs = []
        for seed in range(runs):
            ctl = PenaltyMPC(sc.robot, sc.obstacles, prep.grid.inflation, sc.goal, penalty=PenaltyConfig(**kwargs))
            docs.append(run_scenario(prep, controller="mpc", seed=seed, controller_obj=ctl).document)
        reasons: dict[str, int] = {}
        for d in docs:
            reasons[d["reason"]] = reasons.get(d["reason"], 0) + 1
        steps = np.array([d["steps"] for d in docs], float)
        mean = float(np.sum([d["solve_ms"]["mean"] * d["steps"] for d in docs]) / max(steps.sum(), 1))
        lines.append(
            f"| {label} | {sum(d['success'] for d in docs)}/{runs} | "
            f"{', '.join(f'{k} {v}' for k, v in sorted(reasons.items()))} | "
            f"{min(d['min_clearance_m'] for d in docs):.3f} | {mean:.1f} / {max(d['solve_ms']['max'] for d in docs):.0f} |"
        )
        print(lines[-1], flush=True)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/paper"), help="bench output folder")
    ap.add_argument("--runs", type=int, default=10, help="seeds per scenario and method")
    ap.add_argument("--workers", type=int, default=2, help="worker processes")
    ap.add_argument("--doc", type=Path, default=ROOT / "docs" / "results.md", help="doc with the generated block")
    ap.add_argument("--img", type=Path, default=ROOT / "docs" / "img" / "results", help="folder of the figure")
    ap.add_argument("--report-only", action="store_true", help="only rebuild the figure and doc block from --out")
    ap.add_argument("--ablation", metavar="SCENARIO", help="run the penalty-MPC ablation on SCENARIO instead")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.workers < 1:
        ap.error("--runs and --workers must be >= 1")
    if args.ablation:
        ablation(args.ablation, args.runs)
        return 0
    if not args.report_only:
        from sanav_mj.eval.bench import run_bench

        run_bench(list(SCENARIOS), list(CONTROLLERS), args.runs, args.workers, args.out)
    print(report(args.out, args.doc, args.img))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
