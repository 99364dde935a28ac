"""The paper's comparison (Table I, Fig. 6) in one command: bench, figure and the table of docs/results.md.

Runs ``sanav-mj bench`` on the paper's five scenarios with the four methods (seeds 0..RUNS-1,
random initial yaw), then copies ``success.png`` to ``docs/img/results/`` and rewrites the
generated block of ``docs/results.md`` (between the ``reproduced:begin`` / ``reproduced:end``
markers) with the table and the commit, date and machine of the run, read from the bench's
``meta.json``. ``--report-only`` rebuilds the doc block and the figure from an existing
``--out`` folder without running the bench; ``--figures`` also draws one run of the
baseline MPC per scenario (seed 0) to ``docs/img/results/mpc_<scenario>.png``.

    python scripts/reproduce_paper.py --out out/paper --runs 10 --workers 2
    python scripts/reproduce_paper.py --out out/paper --report-only --figures
    python scripts/reproduce_paper.py --ablation single_rect --runs 10

``--ablation SCENARIO`` instead runs the penalty-MPC baseline with each of its choices
undone in turn (:data:`ABLATION`, one process, same seeds) and prints a Markdown table.

About 200 runs; one to a few minutes on two shared cores (the failing baseline runs last
until the runner declares them stuck, 8 s of simulated time without progress).
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
#: the paper's Fig. 6, success % (it plots 2 for 0 %; no complex map in the figure)
PAPER_FIG6 = {
    "single_rect": {"mpc": 100, "dqn": 84, "dwa": 100, "sa-mpc": 100},
    "double_rect": {"mpc": 2, "dqn": 100, "dwa": 100, "sa-mpc": 100},
    "u_shape": {"mpc": 2, "dqn": 94, "dwa": 2, "sa-mpc": 100},
    "v_shape": {"mpc": 2, "dqn": 2, "dwa": 2, "sa-mpc": 100},
}
#: the paper's Table I: (MPC computation mean, max [ms], steps or None, success %); SA-MPC's
#: "full pipeline" mean and max in the last two places (None for the baseline)
PAPER_TABLE1 = {
    ("single_rect", "mpc"): (23.7, 273.5, 66, 100, None, None),
    ("single_rect", "sa-mpc"): (20.34, 39.56, 58, 100, 29.18, 52.67),
    ("double_rect", "mpc"): (24.5, 75.0, 71, 100, None, None),
    ("double_rect", "sa-mpc"): (22.6, 87.04, 83, 100, 46.83, 108.4),
    ("u_shape", "mpc"): (126.2, 949.4, None, 0, None, None),
    ("u_shape", "sa-mpc"): (23.79, 59.77, 62, 100, 38.4, 88.76),
    ("v_shape", "mpc"): (97.8, 694.5, None, 0, None, None),
    ("v_shape", "sa-mpc"): (22.8, 55.41, 64, 100, 38.4, 85.83),
    ("complex", "mpc"): (19.6, 58.1, None, 0, None, None),
    ("complex", "sa-mpc"): (25.71, 48.0, 122, 100, 35.02, 57.3),
}
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


def _fmt_load(values) -> str:
    return "?" if not values else "/".join(f"{v:.2f}" for v in values)


def _read_rows(path: Path) -> list[dict]:
    """results.csv back into typed rows (the columns :func:`sanav_mj.eval.bench.summarise` reads)."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            row = dict(r)
            row["success"] = r["success"] == "True"
            for k in ("steps", "collisions", "seed"):
                row[k] = int(r[k]) if r[k] != "" else None  # empty in the row of a run that raised
            for k in r:
                if k.endswith("_ms"):
                    row[k] = float(r[k]) if r[k] != "" else None
            rows.append(row)
    return rows


def side_by_side(summary: list[dict]) -> str:
    """Markdown tables: success % (paper / ours: Table I for the two MPCs, else Fig. 6) and the two
    MPCs' timing and steps (Table I / ours)."""
    by = {(r["scenario"], r["controller"]): r for r in summary}
    scen = [sc for sc in SCENARIOS if any((sc, c) in by for c in CONTROLLERS)]
    out = ["| scenario | " + " | ".join(f"{c} paper / ours" for c in CONTROLLERS) + " |",
           "|---|" + "---|" * len(CONTROLLERS)]
    for sc in scen:
        cells = []
        for c in CONTROLLERS:
            paper = PAPER_TABLE1[(sc, c)][3] if (sc, c) in PAPER_TABLE1 else PAPER_FIG6.get(sc, {}).get(c)
            rate = by[(sc, c)]["success_rate"] if (sc, c) in by else None  # None: every run raised
            ours = "-" if rate is None else f"{rate:.0f}"
            cells.append(f"{'-' if paper is None else paper} / {ours}")
        out.append(f"| {sc} | " + " | ".join(cells) + " |")
    out += ["", "| scenario | method | mean (ms) paper / ours | max (ms) paper / ours | steps paper / ours |",
            "|---|---|---|---|---|"]
    for sc in scen:
        for c in ("mpc", "sa-mpc"):
            if (sc, c) not in PAPER_TABLE1 or (sc, c) not in by:
                continue
            mean, mx, steps, _, pmean, pmax = PAPER_TABLE1[(sc, c)]
            r = by[(sc, c)]
            pm = f"{mean:g}" + (f" ({pmean:g})" if pmean is not None else "")
            px = f"{mx:g}" + (f" ({pmax:g})" if pmax is not None else "")
            om = f"{r['solve_mean_ms']:.1f} ({r['pipeline_mean_ms']:.1f})"
            ox = f"{r['solve_max_ms']:.0f} ({r['pipeline_max_ms']:.0f})"
            st = f"{'-' if steps is None else steps} / {'-' if r['steps'] is None else round(r['steps'])}"
            out.append(f"| {sc} | {c} | {pm} / {om} | {px} / {ox} | {st} |")
    return "\n".join(out) + "\n"


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
        f"{meta.get('wall_time_s', float('nan')) / 60:.1f} min wall time, load average (1/5/15 min) "
        f"{_fmt_load(meta.get('load_average_start'))} at the start and {_fmt_load(meta.get('load_average_end'))} "
        f"at the end.\n\n"
        + markdown_table(summary)
        + "\nNext to the paper (success %: Table I for the two MPCs, Fig. 6 for DQN and DWA, where 2 "
        "stands for 0; timing: Table I, in brackets the full pipeline):\n\n"
        + side_by_side(summary)
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
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.prepare import prepare

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


def baseline_figures(img: Path, seed: int = 0, dpi: int = 50) -> list[Path]:
    """One run of the baseline MPC per scenario (``seed``), drawn to ``img/mpc_<scenario>.png``."""
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.plots import plot_run

    img.mkdir(parents=True, exist_ok=True)
    paths = []
    for sc in SCENARIOS:
        out = run_scenario(sc, controller="mpc", seed=seed)
        paths.append(plot_run(out, img / f"mpc_{sc}.png", dpi=dpi))
        d = out.document
        print(f"{sc}: {d['reason']} after {d['steps']} steps, end ({d['trace']['x'][-1]:.2f}, "
              f"{d['trace']['y'][-1]:.2f}) -> {paths[-1]}", flush=True)
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/paper"), help="bench output folder")
    ap.add_argument("--runs", type=int, default=10, help="seeds per scenario and method")
    ap.add_argument("--workers", type=int, default=2, help="worker processes")
    ap.add_argument("--doc", type=Path, default=ROOT / "docs" / "results.md", help="doc with the generated block")
    ap.add_argument("--img", type=Path, default=ROOT / "docs" / "img" / "results", help="folder of the figure")
    ap.add_argument("--report-only", action="store_true", help="only rebuild the figure and doc block from --out")
    ap.add_argument("--ablation", metavar="SCENARIO", help="run the penalty-MPC ablation on SCENARIO instead")
    ap.add_argument("--figures", action="store_true", help="also draw one baseline-MPC run per scenario into --img")
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
    if args.figures:
        baseline_figures(args.img)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
