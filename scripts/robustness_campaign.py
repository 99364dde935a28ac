"""The robustness campaign of docs/robustness.md in one go: sweeps, heat maps, markdown summary.

Runs SA-MPC on the paper's five scenarios under every sweep of :data:`CAMPAIGN` (the
envelope sweeps with ``--seeds-envelope`` seeds, the beyond-envelope sweeps with
``--seeds-beyond``), each through :func:`sanav_mj.eval.robustness.run_robustness` into its
own folder ``OUT/<sweep>/`` (robustness.csv, summary.csv, three heat maps), then writes
``OUT/summary.md``: the envelope verdict, one table per sweep and the list of failed runs,
all read back from the CSVs on disk (``--report-only`` rebuilds it without running).

    python scripts/robustness_campaign.py --out out/robustness_campaign --workers 2
    python scripts/robustness_campaign.py --out out/robustness_campaign --only envelope
    python scripts/robustness_campaign.py --out out/robustness_campaign --report-only

About 2 700 runs; 4-5 min on two cores with two workers at 5e9dc79 (most of it in the runs beyond
the envelope, which last until they stop or time out).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import math
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

#: the paper's five scenarios (built-in names)
SCENARIOS = ("single_rect", "double_rect", "u_shape", "v_shape", "complex")
#: the envelope verdict: no collision at all and at least this success rate in every cell
MIN_SUCCESS_PCT = 95.0


@dataclass(frozen=True)
class Sweep:
    """One sweep of the campaign.

    Attributes:
        name: folder name under the output folder.
        group: ``"envelope"`` (must keep 0 collisions and >= 95 % success) or ``"beyond"``.
        sweep: one or two ``KEY=V1,V2,...`` items (as ``sanav-mj robustness --sweep``).
        fixed: ``KEY=VALUE`` items applied at every grid point as well.
        what: one line saying what the sweep shows.
    """

    name: str
    group: str
    sweep: tuple[str, ...]
    fixed: tuple[str, ...] = ()
    what: str = ""


CAMPAIGN: tuple[Sweep, ...] = (
    # ---- the envelope: the minimum ranges, alone and all at once
    Sweep("geometry", "envelope", ("wheel_radius=0.9,0.95,1.0,1.05,1.1", "track=0.9,1.0,1.1"),
          what="wheel radius and track width +-10 % (odometry scale and turn-rate errors)"),
    Sweep("traction_delay", "envelope", ("friction=0.3,0.5,1.0", "delay=0,1"),
          what="friction down to 0.3 with and without one step of actuator delay"),
    Sweep("pose_noise", "envelope", ("pos_noise=0,0.01,0.02", "yaw_noise=0,0.0175,0.035"),
          what="Gaussian pose noise up to 2 cm / 2 deg (std)"),
    Sweep("combined", "envelope", ("wheel_radius=0.9,1.1", "track=0.9,1.1"),
          fixed=("friction=0.3", "delay=1", "pos_noise=0.02", "yaw_noise=0.035"),
          what="the four geometry corners with low friction, one step of delay and full noise at once"),
    Sweep("corner_traction", "envelope", ("friction=0.3,1.0", "delay=0,1"),
          fixed=("wheel_radius=1.1", "track=0.9"),
          what="the worst geometry corner (10 % fast, 22 % over-turning) with low friction and delay, "
               "to find which combination breaks the all-at-once corner"),
    # ---- beyond the envelope: how it degrades
    Sweep("wheel_radius_far", "beyond", ("wheel_radius=0.6,0.7,0.8,1.2,1.3,1.4",),
          what="wheel radius -40 % to +40 %"),
    Sweep("track_far", "beyond", ("track=0.6,0.7,0.8,1.2,1.3,1.4",), what="track width -40 % to +40 %"),
    Sweep("friction_far", "beyond", ("friction=0.05,0.1,0.15,0.2", "delay=0,1"),
          what="friction 0.05-0.2 with and without one step of delay"),
    Sweep("delay_far", "beyond", ("delay=2,3,4,5",), what="actuator delay 2-5 control steps (0.2-0.5 s)"),
    Sweep("noise_far", "beyond", ("pos_noise=0.05,0.1,0.2", "yaw_noise=0,0.087,0.175"),
          what="pose noise 5-20 cm and 0/5/10 deg"),
    Sweep("mass_far", "beyond", ("mass=0.5,2,3,4",), what="mass and inertia x0.5 to x4"),
    Sweep("actuator_far", "beyond", ("actuator_gain=0.1,0.3,1.0", "torque_limit=0.1,0.3,1.0"),
          what="wheel servo gain and torque limit down to 10 %"),
    Sweep("jitter_far", "beyond", ("jitter=0.1,0.3,0.5",), what="control period jitter up to +-50 %"),
    Sweep("combined_far", "beyond", ("wheel_radius=0.8,1.2", "track=0.8,1.2"),
          fixed=("friction=0.2", "delay=2", "pos_noise=0.05", "yaw_noise=0.087"),
          what="+-20 % geometry corners with friction 0.2, two steps of delay and 5 cm / 5 deg noise at once"),
    Sweep("solve_budget", "beyond", ("solve_budget_ms=0.5,1,2,3,5,10",),
          what="solver wall-time budget 0.5-10 ms (wall-clock: depends on the machine and its load)"),
)


#: the envelope table by key: (label, sweep, {key: value} the runs are restricted to)
ENVELOPE_ROWS: tuple[tuple[str, str, dict[str, float]], ...] = (
    ("wheel_radius 0.9-1.1 (track nominal)", "geometry", {"track": 1.0}),
    ("track 0.9-1.1 (wheel radius nominal)", "geometry", {"wheel_radius": 1.0}),
    ("wheel_radius 0.9-1.1 x track 0.9-1.1", "geometry", {}),
    ("friction 0.3-1.0 (no delay)", "traction_delay", {"delay": 0}),
    ("delay 1 (friction 1.0)", "traction_delay", {"friction": 1.0, "delay": 1}),
    ("friction 0.3-1.0 x delay 0-1", "traction_delay", {}),
    ("pos_noise 0-2 cm (no yaw noise)", "pose_noise", {"yaw_noise": 0.0}),
    ("yaw_noise 0-2 deg (no position noise)", "pose_noise", {"pos_noise": 0.0}),
    ("pos_noise 0-2 cm x yaw_noise 0-2 deg", "pose_noise", {}),
    ("wheel 1.1, track 0.9, friction 0.3 (no delay)", "corner_traction", {"friction": 0.3, "delay": 0}),
    ("wheel 1.1, track 0.9, delay 1 (friction 1.0)", "corner_traction", {"friction": 1.0, "delay": 1}),
    ("all four geometry corners + friction 0.3 + delay 1 + 2 cm / 2 deg", "combined", {}),
)


def run_campaign(out: Path, sweeps: list[Sweep], seeds_envelope: int, seeds_beyond: int, workers: int,
                 time_limit_s: float, resume: bool) -> dict[str, float]:
    """Run ``sweeps`` into ``out/<name>/``; returns the wall time [s] of each sweep that ran."""
    from sanav_mj.eval.robustness import parse_sweep, run_robustness
    from sanav_mj.sim.mismatch import parse_mismatch

    walls: dict[str, float] = {}
    for sw in sweeps:
        folder = out / sw.name
        if resume and (folder / "summary.csv").exists():
            continue
        seeds = seeds_envelope if sw.group == "envelope" else seeds_beyond
        print(f"[{sw.name}] {' '.join(sw.sweep)} {' '.join(sw.fixed)} x {len(SCENARIOS)} scenarios x {seeds} seeds",
              file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        # A sweep interrupted part-way left its journal (runs.jsonl) and meta.json: resume it.
        partial = resume and (folder / "meta.json").exists()
        run_robustness(list(SCENARIOS), parse_sweep(list(sw.sweep)), seeds, "sa-mpc", workers, folder,
                       time_limit_s=time_limit_s, fixed=parse_mismatch(list(sw.fixed)), resume=partial)
        walls[sw.name] = time.perf_counter() - t0
        info = {"commit": _git("rev-parse", "--short", "HEAD"), "local_changes": _dirty(), "seeds": seeds,
                "wall_s": round(walls[sw.name], 1), "workers": workers, "time_limit_s": time_limit_s,
                "finished": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}
        (folder / "run_info.json").write_text(json.dumps(info, indent=1) + "\n")
    return walls


# ------------------------------------------------------------------------------ report


def _read(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _keys(sw: Sweep) -> list[str]:
    return [item.partition("=")[0] for item in sw.sweep]


def _num(text: str) -> str:
    v = float(text)
    return str(int(v)) if v == int(v) and abs(v) >= 1 else f"{v:g}"


def _clear(text: str) -> str:
    v = float(text)
    return "n/a" if not math.isfinite(v) else f"{v:.3f}"


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).resolve().parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _dirty() -> list[str]:
    """Files of sanav_mj/ that differ from the commit (the campaign measured those too)."""
    text = _git("status", "--porcelain", "--", "sanav_mj")
    return [] if text == "unknown" else [line[3:] for line in text.splitlines()]


def _info(folder: Path) -> dict:
    path = folder / "run_info.json"
    return json.loads(path.read_text()) if path.exists() else {}


def _cell(runs: list[dict[str, str]]):
    """The package's running summary (:class:`sanav_mj.eval.robustness.CellSummary`, as
    ``summary.csv`` is made) of some rows of robustness.csv, read back from their text."""
    from sanav_mj.eval.robustness import CellSummary

    acc = CellSummary()
    for r in runs:
        clear = r["min_clearance_m"]
        acc.add({"reason": r["reason"], "success": r["success"] == "True", "collisions": int(r["collisions"] or 0),
                 "min_clearance_m": None if clear in ("", "None") else float(clear)})
    return acc


def _aggregate(runs: list[dict[str, str]]) -> tuple[int, float, float, float]:
    """(runs, success %, collision %, min clearance [m]) of some rows of robustness.csv (rows of
    runs that raised are left out, as in summary.csv; no run at all: 0 %, NaN clearance)."""
    s = _cell(runs).summary()
    n = s["runs"]
    return n, s["success_rate"] if n else 0.0, s["collision_rate"] if n else 0.0, s["min_clearance_m"]


def write_report(out: Path, sweeps: list[Sweep], walls: dict[str, float], args_line: str) -> Path:
    """Write ``out/summary.md`` from the CSVs of ``sweeps`` found under ``out``; returns its path."""
    import mujoco

    present = [sw for sw in sweeps if (out / sw.name / "robustness.csv").exists()]
    commits: dict[str, list[str]] = {}
    for sw in present:
        info = _info(out / sw.name)
        code = f"`{info['commit']}`" if info else "not recorded"
        if info.get("local_changes"):
            code += f" with local changes in {', '.join(info['local_changes'])}"
        commits.setdefault(code, []).append(sw.name)
    lines = ["# SA-MPC robustness campaign", ""]
    lines += [f"- code measured: commit {code}" + ("" if len(commits) == 1 else f" ({', '.join(names)})")
              for code, names in commits.items()]
    lines += [
        f"- report written: {datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}; "
        f"python {platform.python_version()}, mujoco {mujoco.__version__}",
        f"- command: `{args_line}`",
        f"- scenarios: {' '.join(SCENARIOS)}; seeds 0..n-1 per scenario (seed = random initial yaw, noise, jitter)",
        "",
    ]
    total = 0
    lines += ["## Envelope verdict", "",
              f"Every cell of an envelope sweep must have 0 collisions and >= {MIN_SUCCESS_PCT:g} % success.", "",
              "| sweep | group | swept | fixed | cells | runs | success % (all) | worst cell success % | "
              "collision % | min clearance [m] | verdict |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for sw in present:
        runs = _read(out / sw.name / "robustness.csv")
        cells = _read(out / sw.name / "summary.csv")
        total += len(runs)
        n, succ, coll, clear = _aggregate(runs)
        worst = min(float(c["success_rate"]) for c in cells)
        holds = coll == 0 and worst >= MIN_SUCCESS_PCT
        verdict = ("holds" if holds else "**fails**") if sw.group == "envelope" else \
            ("no collision" if coll == 0 else "**collisions**")
        lines.append(f"| {sw.name} | {sw.group} | {' '.join(sw.sweep)} | {' '.join(sw.fixed) or '-'} | {len(cells)} | "
                     f"{n} | {succ:.1f} | {worst:.1f} | {coll:.1f} | {_clear(str(clear))} | {verdict} |")
    rows = [(label, name, where) for label, name, where in ENVELOPE_ROWS
            if (out / name / "robustness.csv").exists()]
    if rows:
        lines += ["", "## Envelope by key", "",
                  "| mismatch | sweep | runs | success % | collision % | min clearance [m] |", "|---|---|---|---|---|---|"]
        for label, name, where in rows:
            runs = [r for r in _read(out / name / "robustness.csv")
                    if all(float(r[k]) == v for k, v in where.items())]
            n, succ, coll, clear = _aggregate(runs)
            lines.append(f"| {label} | {name} | {n} | {succ:.1f} | {coll:.1f} | {_clear(str(clear))} |")
    beyond = [sw for sw in present if sw.group == "beyond"]
    if beyond:
        lines += ["", "## Beyond the envelope: how the failed runs end", "",
                  "Every run beyond the envelope that did not reach the goal, by reason (a collision is the "
                  "failure to avoid; `stuck`, `timeout`, `solver_failure` and `bad_measurement` end with the "
                  "robot stopped or crawling, without contact).", "",
                  "| sweep | runs | failed | collision | stuck | timeout | solver_failure | bad_measurement | "
                  "collision % of runs | collision % of failures |", "|---|---|---|---|---|---|---|---|---|---|"]
        tot: dict[str, int] = {}
        n_all = 0
        for sw in beyond:
            acc = _cell(_read(out / sw.name / "robustness.csv"))
            failed = acc.all - acc.success  # a run succeeds exactly when its reason is goal
            by = {k: acc.reasons.get(k, 0) for k in ("collision", "stuck", "timeout", "solver_failure", "bad_measurement")}
            n_all += acc.all
            tot["failed"] = tot.get("failed", 0) + failed
            for k, v in by.items():
                tot[k] = tot.get(k, 0) + v
            lines.append(f"| {sw.name} | {acc.all} | {failed} | " + " | ".join(str(v) for v in by.values())
                         + f" | {100.0 * by['collision'] / max(acc.all, 1):.1f} | "
                         f"{100.0 * by['collision'] / max(failed, 1):.1f} |")
        lines.append(f"| **all** | {n_all} | {tot['failed']} | " + " | ".join(
            str(tot[k]) for k in ("collision", "stuck", "timeout", "solver_failure", "bad_measurement"))
            + f" | {100.0 * tot['collision'] / max(n_all, 1):.1f} | "
            f"{100.0 * tot['collision'] / max(tot['failed'], 1):.1f} |")
    wall_s = sum(float(_info(out / sw.name).get("wall_s", 0.0)) for sw in present)
    lines += ["", f"{total} runs in all, {wall_s / 60:.1f} min wall"
              + (f" ({sum(walls.values()) / 60:.1f} min in this invocation)" if walls else "") + ".", ""]

    for sw in present:
        folder = out / sw.name
        runs = _read(folder / "robustness.csv")
        cells = _read(folder / "summary.csv")
        keys = _keys(sw)
        info = _info(folder)
        wall = info.get("wall_s", "?")
        lines += [f"## {sw.name} ({sw.group})", "", sw.what + ".", "",
                  f"`--sweep {' '.join(sw.sweep)}`" + (f", fixed `{' '.join(sw.fixed)}`" if sw.fixed else "")
                  + f"; {len(runs)} runs ({info.get('seeds', '?')} seeds per scenario), {wall} s wall on "
                  f"{info.get('workers', '?')} workers. Heat maps: `{sw.name}/*.png`.", ""]
        lines += ["| " + " | ".join(keys) + " | runs | success % | collision % | min clearance [m] | reasons |",
                  "|" + "---|" * (len(keys) + 5)]
        for c in cells:
            lines.append("| " + " | ".join(_num(c[k]) for k in keys) + f" | {c['runs']} | {float(c['success_rate']):.1f} | "
                         f"{float(c['collision_rate']):.1f} | {_clear(c['min_clearance_m'])} | {c['reasons']} |")
        failed = [r for r in runs if r["success"] != "True"]
        if failed:
            lines += ["", "Failed runs (scenario/seed: reason at sim time):", ""]
            by_cell: dict[str, list[str]] = {}
            for r in failed:
                cell = ", ".join(f"{k}={_num(r[k])}" for k in keys)
                by_cell.setdefault(cell, []).append(
                    f"{r['scenario']}/{r['seed']}: {r['reason']} at {float(r['sim_time_s']):.1f} s")
            for cell, items in by_cell.items():
                lines.append(f"- {cell}: " + "; ".join(items))
        lines.append("")
    path = out / "summary.md"
    path.write_text("\n".join(lines))
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/robustness_campaign"))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seeds-envelope", type=int, default=8, help="seeds per scenario in the envelope sweeps")
    p.add_argument("--seeds-beyond", type=int, default=4, help="seeds per scenario beyond the envelope")
    p.add_argument("--time-limit", type=float, default=60.0, help="[s] simulated time limit of each run")
    p.add_argument("--only", nargs="+", metavar="NAME",
                   help="sweep names, or 'envelope' / 'beyond' for a whole group")
    p.add_argument("--resume", action="store_true",
                   help="skip sweeps whose summary.csv exists and finish interrupted ones from their journal")
    p.add_argument("--report-only", action="store_true", help="only rebuild summary.md from the CSVs")
    args = p.parse_args(argv)
    if args.workers < 1 or args.seeds_envelope < 1 or args.seeds_beyond < 1 or args.time_limit <= 0:
        p.error("--workers, --seeds-envelope, --seeds-beyond and --time-limit must be positive")
    names = {sw.name for sw in CAMPAIGN}
    wanted = set(args.only or [])
    unknown = wanted - names - {"envelope", "beyond"}
    if unknown:
        p.error(f"--only: unknown sweep(s) {', '.join(sorted(unknown))}; expected envelope, beyond or one of "
                f"{', '.join(sorted(names))}")
    sweeps = [sw for sw in CAMPAIGN if not wanted or sw.name in wanted or sw.group in wanted]
    walls = {}
    if not args.report_only:
        from sanav_mj.eval.campaign import CampaignInterrupted

        try:
            walls = run_campaign(args.out, sweeps, args.seeds_envelope, args.seeds_beyond, args.workers,
                                 args.time_limit, args.resume)
        except CampaignInterrupted as exc:
            print(f"robustness_campaign: {exc}; run the same command with --resume to finish", file=sys.stderr)
            return 130
    args_line = "python scripts/robustness_campaign.py " + " ".join(argv if argv is not None else sys.argv[1:])
    path = write_report(args.out, list(CAMPAIGN), walls, args_line)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
