"""The ``sanav-mj`` command line (see the design contract for the commands and JSON).

Exit codes: 0 success; 1 a run ended without reaching the goal; 2 bad input (one line on
stderr naming the file or argument and what is wrong, no traceback), which includes an output
file or folder that cannot be created or written (``run`` prints its result line and writes
its other outputs first) and a ``--resume`` into a folder run with other settings; 3
``bench`` / ``robustness`` finished and wrote their outputs, but some runs raised an
exception (rows with reason ``error``; one line on stderr says how many); 130 interrupted
(``bench`` / ``robustness``: one line says how many runs are saved in the journal and how to
resume); 141 stdout closed early (``| head``), quietly.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import NoReturn

from sanav_mj.control.spec import CONTROLLER_NAMES as CONTROLLERS


class BadInput(Exception):
    """Bad input from the user: reported as one line on stderr with exit code 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message: str) -> NoReturn:  # noqa: D401 - argparse API
        raise BadInput(f"{self.prog}: {message}")


def _float_arg(name: str, positive: bool = False):
    """argparse type: a finite float (and > 0 when ``positive``), errors naming ``name``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name}: expected a number, got {text!r}") from None
        if not math.isfinite(value) or (positive and value <= 0):
            rule = "a finite number > 0" if positive else "a finite number"
            raise argparse.ArgumentTypeError(f"{name}: expected {rule}, got {text!r}")
        return value

    return parse


def _resolution(text: str) -> float:
    value = _float_arg("--resolution", positive=True)(text)
    if not 0.005 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"--resolution: expected 0.005 <= M <= 1.0 metres, got {text!r}")
    return value


#: [s] largest accepted ``--time-limit`` (one simulated day; larger values overflow the step count)
MAX_TIME_LIMIT_S = 86_400.0


def _time_limit(text: str) -> float:
    value = _float_arg("--time-limit", positive=True)(text)
    if value > MAX_TIME_LIMIT_S:
        raise argparse.ArgumentTypeError(
            f"--time-limit: expected 0 < S <= {MAX_TIME_LIMIT_S:g} simulated seconds, got {text!r}")
    return value


def _count(name: str, lo: int = 1, hi: int = 10_000):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name}: expected a whole number, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{name}: expected {lo} <= N <= {hi}, got {text!r}")
        return value

    return parse


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``sanav-mj``."""
    p = _Parser(prog="sanav-mj", description="Quadtree safe-area MPC navigation in MuJoCo.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    d = sub.add_parser("demo", help="all built-in scenarios with SA-MPC: .rrd + .png + summary table")
    d.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    d.add_argument("--no-rrd", action="store_true", help="skip the rerun recordings")

    a = sub.add_parser("areas", help="grid, quadtree, safe areas, graph and reference of a scenario")
    a.add_argument("scenario", help="MJCF file or built-in scenario name")
    a.add_argument("--json", type=Path, help="write the areas JSON here")
    a.add_argument("--plot", type=Path, help="write a PNG of the map here")
    a.add_argument("--resolution", type=_resolution, default=0.05, help="grid cell size [m] (default 0.05)")

    r = sub.add_parser("run", help="one closed-loop run")
    r.add_argument("scenario", help="MJCF file or built-in scenario name")
    r.add_argument("--controller", choices=CONTROLLERS, default="sa-mpc")
    r.add_argument("--seed", type=_count("--seed", 0, 2**31 - 1), default=0)
    r.add_argument("--yaw", type=_float_arg("--yaw"), default=None, help="initial yaw [rad] (default: from the seed)")
    r.add_argument("--resolution", type=_resolution, default=0.05)
    r.add_argument("--json", type=Path)
    r.add_argument("--rrd", type=Path)
    r.add_argument("--plot", type=Path)
    r.add_argument("--mismatch", nargs="+", default=[], metavar="KEY=VALUE")
    r.add_argument("--time-limit", type=_time_limit, default=60.0, help="[s] simulated time limit (default 60)")

    b = sub.add_parser("bench", help="the paper's comparison: success rates and timing table")
    b.add_argument("scenarios", nargs="*", help="scenarios (default: all built-in)")
    b.add_argument("--controllers", nargs="+", choices=CONTROLLERS, default=list(CONTROLLERS))
    b.add_argument("--runs", type=_count("--runs"), default=10)
    b.add_argument("--workers", type=_count("--workers", 1, 64), default=2)
    b.add_argument("--out", type=Path, default=Path("out/bench"))
    b.add_argument("--rrd", action="store_true", help="also record each run to OUT/rrd/")
    b.add_argument("--resume", action="store_true",
                   help="keep the finished runs journalled in OUT/runs.jsonl (same settings) and run the rest")

    rb = sub.add_parser("robustness", help="sweep model mismatch over a grid with several seeds")
    rb.add_argument("scenarios", nargs="+")
    rb.add_argument("--sweep", nargs="+", default=["wheel_radius=0.9,1.0,1.1"], metavar="KEY=V1,V2,...",
                    help="one or two keys with their grid values")
    rb.add_argument("--seeds", type=_count("--seeds"), default=5)
    rb.add_argument("--controller", choices=CONTROLLERS, default="sa-mpc")
    rb.add_argument("--workers", type=_count("--workers", 1, 64), default=2)
    rb.add_argument("--fixed", nargs="+", default=[], metavar="KEY=VALUE",
                    help="mismatch applied at every grid point (keys as --mismatch; not a swept key)")
    rb.add_argument("--time-limit", type=_time_limit, default=60.0,
                    help="[s] simulated time limit of each run (default 60)")
    rb.add_argument("--out", type=Path, default=Path("out/robustness"))
    rb.add_argument("--resume", action="store_true",
                    help="keep the finished runs journalled in OUT/runs.jsonl (same settings) and run the rest")
    return p


def _write_json(path: Path, doc: dict) -> None:
    _prepare_output(path)
    text = json.dumps(doc, indent=1, allow_nan=False)
    try:
        path.write_text(text)
    except OSError as exc:
        raise BadInput(f"{path}: cannot write ({exc.strerror})") from None


def _write_outputs(writers: list[tuple[Path | None, object]]) -> None:
    """Call each ``(path, write)`` whose path is set; one failure does not stop the others.

    Raises:
        BadInput: naming the first output that could not be written (and how many failed).
    """
    failed: list[str] = []
    for path, write in writers:
        if path is None:
            continue
        try:
            write()
        except BadInput as exc:
            failed.append(str(exc))
        except OSError as exc:
            failed.append(f"{path}: cannot write ({exc.strerror or exc})")
    if failed:
        more = f" (and {len(failed) - 1} more output(s) not written)" if len(failed) > 1 else ""
        raise BadInput(failed[0] + more)


def _prepare_output(path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"{path}: cannot create the output folder ({exc.strerror})") from None
    if path.exists() and path.is_dir():
        raise BadInput(f"{path}: expected a file path, got a folder")


def _check_out_dir(path: Path, name: str = "--out") -> None:
    """Create the output folder ``path`` (and its parents) or fail with one line naming it."""
    if path.exists() and not path.is_dir():
        raise BadInput(f"{name} {path}: expected a folder, got a file")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"{name} {path}: cannot create the folder ({exc.strerror})") from None
    probe = path / ".sanav-mj-write-test"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise BadInput(f"{name} {path}: cannot write in the folder ({exc.strerror})") from None


def _check_scenarios(names: list[str]) -> None:
    """Load each scenario once (ScenarioError on a bad one) before any output is created."""
    from sanav_mj.scene import load_scenario

    for name in names:
        load_scenario(name)


def _distinct_outputs(named: dict[str, Path | None]) -> None:
    """Two output options naming the same file would overwrite each other: bad input."""
    seen: dict[Path, str] = {}
    for name, path in named.items():
        if path is None:
            continue
        key = path.resolve()
        if key in seen:
            raise BadInput(f"{name} {path}: the same file as {seen[key]}; give each output its own file")
        seen[key] = name


def _check_outputs(*paths: Path | None) -> None:
    """Fail early (before any long work) when an output path is unusable."""
    for path in paths:
        if path is None:
            continue
        _prepare_output(path)
        try:
            with open(path, "ab"):
                pass
        except OSError as exc:
            raise BadInput(f"{path}: cannot write ({exc.strerror})") from None


def _cmd_areas(args) -> int:
    from sanav_mj.eval.episode import areas_document, prepare

    _distinct_outputs({"--json": args.json, "--plot": args.plot})
    _check_outputs(args.json, args.plot)
    prep = prepare(args.scenario, resolution=args.resolution)
    doc = areas_document(prep)

    def plot() -> None:
        from sanav_mj.eval.plots import plot_areas

        plot_areas(prep, args.plot)

    _write_outputs([(args.json, lambda: _write_json(args.json, doc)), (args.plot, plot)])
    t = doc["timing_ms"]
    print(
        f"{doc['scenario']}: grid {doc['grid']['shape'][1]}x{doc['grid']['shape'][0]} @ {doc['grid']['resolution']} m, "
        f"leaves {doc['leaves']['free']} free / {doc['leaves']['occupied']} occupied, {len(doc['rects'])} safe areas, "
        f"{len(doc['edges'])} edges, corridor {len(doc['corridor'])} areas, {t['total']:.2f} ms"
    )
    return 0


def _cmd_run(args) -> int:
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.sim.mismatch import parse_mismatch

    mismatch = parse_mismatch(args.mismatch)
    _distinct_outputs({"--json": args.json, "--rrd": args.rrd, "--plot": args.plot})
    _check_outputs(args.json, args.rrd, args.plot)
    try:
        out = run_scenario(
            args.scenario,
            controller=args.controller,
            seed=args.seed,
            yaw=args.yaw,
            resolution=args.resolution,
            mismatch=mismatch,
            time_limit_s=args.time_limit,
            rrd=args.rrd,
        )
    except RuntimeError as exc:
        if args.rrd is None or not _raised_in_rerun(exc):
            raise
        first = (str(exc).strip().splitlines() or ["no message"])[0]
        raise BadInput(f"{args.rrd}: cannot write the recording ({first})") from None
    doc = out.document

    def plot() -> None:
        from sanav_mj.eval.plots import plot_run

        plot_run(out, args.plot)

    try:  # the result line first: a failing output file must not lose it
        _print_run_line(doc)
    finally:
        _write_outputs([(args.json, lambda: _write_json(args.json, doc)), (args.plot, plot)])
    return 0 if doc["success"] else 1


def _raised_in_rerun(exc: BaseException) -> bool:
    """Whether ``exc`` was raised by the rerun SDK (its innermost frame is in the package)."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and "/rerun/" in tb.tb_frame.f_code.co_filename.replace("\\", "/")


def _print_run_line(doc: dict) -> None:
    print(
        f"{doc['scenario']} / {doc['controller']} seed {doc['seed']}: {doc['reason']} after {doc['steps']} steps "
        f"({doc['sim_time_s']:.1f} s), path {doc['path_length_m']:.2f} m, min clearance "
        f"{doc['min_clearance_m']:.3f} m, collisions {doc['collisions']}, solve {doc['solve_ms']['mean']:.2f} ms mean "
        f"/ {doc['solve_ms']['p99']:.2f} ms p99"
    )


def _cmd_demo(args) -> int:
    from sanav_mj.eval.demo import run_demo, summary_table

    _check_out_dir(args.out)
    rows = run_demo(args.out, record=not args.no_rrd)
    print(summary_table(rows), end="")
    print(f"wrote recordings (.rrd), plots (.png) and JSON to {args.out}/")
    return 0 if all(r["success"] for r in rows) else 1


def _cmd_bench(args) -> int:
    from sanav_mj.eval.bench import markdown_table, run_bench

    _check_scenarios(args.scenarios)
    _check_out_dir(args.out)
    summary = run_bench(args.scenarios, args.controllers, args.runs, args.workers, args.out, record=args.rrd,
                        resume=args.resume)
    print(markdown_table(summary), end="")
    print(f"wrote {args.out}/results.csv, table.md, success.png")
    return _raised_runs(summary, args.out / "results.csv")


#: exit code of a campaign that finished but had runs that raised (see the module docstring)
EXIT_RUNS_RAISED = 3


def _raised_runs(summary: list[dict], csv_path: Path) -> int:
    """Report the runs that raised (one line on stderr); the exit code of the campaign."""
    raised = sum(int(row.get("errors", 0)) for row in summary)
    if not raised:
        return 0
    print(f"sanav-mj: {raised} run(s) raised; see the rows with reason 'error' in {csv_path} "
          "(left out of the rates; --resume runs them again)", file=sys.stderr)
    return EXIT_RUNS_RAISED


def _parse_fixed(items: list[str], sweep: list[tuple[str, list[float]]]):
    """``--fixed`` items as a :class:`~sanav_mj.sim.mismatch.Mismatch`; errors name ``--fixed``."""
    from sanav_mj.sim.mismatch import MismatchError, parse_mismatch

    try:
        fixed = parse_mismatch(items)
    except MismatchError as exc:
        text = str(exc)
        text = "--fixed " + text[len("--mismatch "):] if text.startswith("--mismatch ") else f"--fixed: {text}"
        raise BadInput(text) from None
    given = {item.partition("=")[0].strip(): item for item in items}
    for key, _ in sweep:
        if key in given:
            raise BadInput(f"--fixed {given[key]!r}: key {key!r} is also swept (--sweep); a key is either swept or fixed")
    return fixed


def _cmd_robustness(args) -> int:
    from sanav_mj.eval.robustness import parse_sweep, run_robustness

    sweep = parse_sweep(args.sweep)
    fixed = _parse_fixed(args.fixed, sweep)
    _check_scenarios(args.scenarios)
    _check_out_dir(args.out)
    summary = run_robustness(args.scenarios, sweep, args.seeds, args.controller, args.workers, args.out,
                             time_limit_s=args.time_limit, fixed=fixed, resume=args.resume)
    for row in summary:
        print("  ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
    print(f"wrote {args.out}/robustness.csv, summary.csv and heat maps")
    return _raised_runs(summary, args.out / "robustness.csv")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``sanav-mj`` console script; returns the exit code."""
    from sanav_mj.eval.campaign import CampaignInterrupted, JournalError
    from sanav_mj.scene import ScenarioError
    from sanav_mj.sim.mismatch import MismatchError

    try:
        args = build_parser().parse_args(argv)
        handler = {
            "areas": _cmd_areas,
            "run": _cmd_run,
            "demo": _cmd_demo,
            "bench": _cmd_bench,
            "robustness": _cmd_robustness,
        }[args.command]
        return handler(args)
    except (BadInput, ScenarioError, MismatchError, JournalError) as exc:
        print(f"sanav-mj: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # stdout closed early (``sanav-mj ... | head``): stop quietly, as a shell tool
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return 141
    except OSError as exc:  # an output (or input) file that cannot be written or read mid-way
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"sanav-mj: error: {where}{_one_line(exc.strerror or str(exc))}", file=sys.stderr)
        return 2
    except CampaignInterrupted as exc:
        where = f" in {exc.journal}" if exc.journal else ""
        print(f"sanav-mj: interrupted: {exc.saved} of {exc.total} runs saved{where}; "
              "run the same command with --resume to finish", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("sanav-mj: interrupted", file=sys.stderr)
        return 130


def _one_line(text: str) -> str:
    return " ".join(text.split())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
