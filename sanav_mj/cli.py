"""The ``sanav-mj`` command line (``sanav-mj COMMAND --help``; the JSON and campaign files
it writes are described field by field in docs/outputs.md).

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
import re
import sys
from pathlib import Path
from typing import NoReturn

from sanav_mj.control.spec import CONTROLLER_NAMES as CONTROLLERS
from sanav_mj.mapping.build import RESOLUTION_RANGE_M


class BadInput(Exception):
    """Bad input from the user: reported as one line on stderr with exit code 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message: str) -> NoReturn:  # noqa: D401 - argparse API
        # argparse prefixes a type error with "argument NAME: "; our type errors already start
        # with the argument's name, so keep it once ("--seed: expected ...")
        m = re.match(r"argument ([^:]+): (.*)$", message, re.S)
        if m and m.group(2).startswith(m.group(1) + ":"):
            message = m.group(2)
        prog = self.prog[len("sanav-mj "):] if self.prog.startswith("sanav-mj ") else self.prog
        raise BadInput(f"{prog}: {message}" if prog != "sanav-mj" else message)


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
    lo, hi = RESOLUTION_RANGE_M
    if not lo <= value <= hi:
        raise argparse.ArgumentTypeError(f"--resolution: expected {lo} <= M <= {hi} metres, got {text!r}")
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


def _output_arg(name: str):
    """argparse type: an output path, ``~`` expanded (``--json ~/x.json`` is in the home folder)."""

    def parse(text: str) -> Path:
        if not text.strip():
            raise argparse.ArgumentTypeError("expected a path, got an empty string")
        return Path(os.path.expanduser(text))

    return parse


def _plot_arg(text: str) -> Path:
    """argparse type of ``--plot``: a path whose extension is a figure format (png, pdf, svg, ...)."""
    from sanav_mj.eval.plots import figure_format

    path = _output_arg("--plot")(text)
    try:
        figure_format(path)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return path


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("sanav-mj")
    except PackageNotFoundError:  # run from a source tree that is not installed
        return "unknown (not installed)"


def mismatch_help() -> str:
    """``--mismatch`` help: every key with its range and unit, from :mod:`sanav_mj.sim.mismatch`."""
    from sanav_mj.sim.mismatch import mismatch_keys

    keys = "; ".join(f"{k} {lo:g}..{hi:g} ({meaning})" for k, (lo, hi, meaning) in mismatch_keys().items())
    return f"plant differs from the controller's model, KEY=VALUE (default: none). Keys, ranges inclusive: {keys}"


#: the sweep of ``robustness`` without ``--sweep``
DEFAULT_SWEEP = ("wheel_radius=0.9,1.0,1.1",)


#: help of ``--ray`` (bench, robustness)
RAY_HELP = ("run the campaign on Ray instead of the local process pool: a local Ray without ADDRESS, else the "
            "cluster at ADDRESS (auto, HOST:PORT or ray://HOST:PORT); needs pip install -e \".[cluster]\" (default: the local process pool)")


def _ray_address(text: str) -> str:
    """argparse type of ``--ray ADDRESS``: ``auto``, ``HOST:PORT`` or ``ray://HOST:PORT``."""
    if text == "auto" or re.fullmatch(r"(ray://)?[A-Za-z0-9.\-\[\]:]+:\d{1,5}", text):
        return text
    raise argparse.ArgumentTypeError(f"--ray: expected auto, HOST:PORT or ray://HOST:PORT, got {text!r} "
                                     "(a scenario? put --ray after the scenarios)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``sanav-mj``; every option's help states its default and unit."""
    p = _Parser(prog="sanav-mj", description="Quadtree safe-area MPC navigation in MuJoCo.",
                epilog="Exit codes: 0 success; 1 a run did not reach the goal; 2 bad input or an output that could "
                       "not be written; 3 some campaign runs raised; 130 interrupted; 141 stdout closed.")
    p.add_argument("--version", action="version", version=f"sanav-mj {_version()}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    scenario_help = "MJCF scenario file, or the name of a built-in scenario (e.g. u_shape)"
    resolution_help = f"grid cell size [m], {RESOLUTION_RANGE_M[0]:g}..{RESOLUTION_RANGE_M[1]:g} (default: %(default)s)"
    controller_help = "controller: sa-mpc (the paper's), mpc (obstacle-penalty NMPC), dwa, dqn (default: %(default)s)"
    workers_help = "worker processes, 1..64 (default: %(default)s)"
    # (the metavars name the unit: M metres, S seconds, RAD radians, N a count)
    sensing_help = ("map: the grid from the scenario's true geoms; lidar: the robot maps with its own lidar "
                    "as it drives (sa-mpc only) (default: %(default)s)")
    footprint_help = ("SA-MPC's robot body: disc (the circumscribed disc, the paper's) or discs (the footprint "
                      "rectangle covered by discs whose centres stay in the safe areas of a map inflated by "
                      "their radius; sa-mpc only) (default: %(default)s)")
    resume_help = ("keep the finished runs journalled in OUT/runs.jsonl (same settings) and run the rest "
                   "(default: start afresh)")

    d = sub.add_parser("demo", help="all built-in scenarios with SA-MPC: .rrd + .png + summary table")
    d.add_argument("--out", type=_output_arg("--out"), default=Path("out/demo"), metavar="DIR",
                   help="output folder (default: %(default)s)")
    d.add_argument("--no-rrd", action="store_true", help="skip the rerun recordings (default: write them)")
    d.add_argument("--sensing", choices=SENSING, default="map", help=sensing_help)
    d.add_argument("--footprint", choices=FOOTPRINTS, default="disc", help=footprint_help)

    map_help = scenario_help + ", or a ROS map_server map (.yaml) with --start and --goal"
    start_help = "start pose x [m] y [m] yaw [rad] on a ROS map (.yaml) (default: none)"
    goal_help = "goal x [m] y [m] on a ROS map (.yaml) (default: none)"

    sc = sub.add_parser("scenario", help="make a scenario MJCF from a ROS map_server map with a start and a goal")
    sc.add_argument("map", help="ROS map_server map: a YAML file naming a PGM or PNG image")
    sc.add_argument("--start", type=_float_arg("--start"), nargs=3, required=True, metavar=("X", "Y", "YAW"),
                    help="start pose x [m] y [m] yaw [rad] (required, no default)")
    sc.add_argument("--goal", type=_float_arg("--goal"), nargs=2, required=True, metavar=("X", "Y"),
                    help="goal x [m] y [m] (required, no default)")
    sc.add_argument("-o", "--out", type=_output_arg("--out"), required=True, metavar="FILE",
                    help="the scenario MJCF file to write (required, no default)")

    a = sub.add_parser("areas", help="grid, quadtree, safe areas, graph and reference of a scenario or ROS map")
    a.add_argument("scenario", help=scenario_help + ", or a ROS map_server map (.yaml; with --start and "
                                                    "--goal also the corridor and reference)")
    a.add_argument("--start", type=_float_arg("--start"), nargs=3, default=None, metavar=("X", "Y", "YAW"),
                   help=start_help)
    a.add_argument("--goal", type=_float_arg("--goal"), nargs=2, default=None, metavar=("X", "Y"), help=goal_help)
    a.add_argument("--json", type=_output_arg("--json"), metavar="FILE", help="write the areas JSON here (default: none)")
    a.add_argument("--plot", type=_plot_arg, metavar="FILE", help="write a figure of the map here; format from the extension: "
                                                  ".png (also without one), .pdf, .svg, ... (default: none)")
    a.add_argument("--resolution", type=_resolution, default=0.05, metavar="M", help=resolution_help)

    r = sub.add_parser("run", help="one closed-loop run")
    r.add_argument("scenario", help=map_help)
    r.add_argument("--start", type=_float_arg("--start"), nargs=3, default=None, metavar=("X", "Y", "YAW"),
                   help=start_help)
    r.add_argument("--goal", type=_float_arg("--goal"), nargs=2, default=None, metavar=("X", "Y"), help=goal_help)
    r.add_argument("--controller", choices=CONTROLLERS, default="sa-mpc", help=controller_help)
    r.add_argument("--seed", type=_count("--seed", 0, 2**31 - 1), default=0, metavar="N",
                   help="seed of the initial yaw, noise and jitter, 0..2^31-1 (default: %(default)s)")
    r.add_argument("--yaw", type=_float_arg("--yaw"), default=None, metavar="RAD",
                   help="initial yaw [rad] (default: drawn from the seed)")
    r.add_argument("--resolution", type=_resolution, default=0.05, metavar="M", help=resolution_help)
    r.add_argument("--json", type=_output_arg("--json"), metavar="FILE", help="write the run JSON here (default: none)")
    r.add_argument("--rrd", type=_output_arg("--rrd"), metavar="FILE", help="write a rerun recording (.rrd) here (default: none)")
    r.add_argument("--plot", type=_plot_arg, metavar="FILE", help="write a figure of the run here; format from the extension: "
                                                  ".png (also without one), .pdf, .svg, ... (default: none)")
    r.add_argument("--mismatch", nargs="+", default=[], metavar="KEY=VALUE", help=mismatch_help())
    r.add_argument("--sensing", choices=SENSING, default="map", help=sensing_help)
    r.add_argument("--footprint", choices=FOOTPRINTS, default="disc", help=footprint_help)
    r.add_argument("--time-limit", type=_time_limit, default=60.0, metavar="S",
                   help=f"simulated time limit [s], 0 < S <= {MAX_TIME_LIMIT_S:g} (default: %(default)s)")

    b = sub.add_parser("bench", help="the paper's comparison: success rates and timing table")
    b.add_argument("scenarios", nargs="*", help="scenario files or built-in names (default: all built-in)")
    b.add_argument("--controllers", nargs="+", choices=CONTROLLERS, default=list(CONTROLLERS),
                   help="controllers to compare (default: all four)")
    b.add_argument("--runs", type=_count("--runs"), default=10, metavar="N",
                   help="runs (seeds 0..N-1) per scenario and controller, 1..10000 (default: %(default)s)")
    b.add_argument("--workers", type=_count("--workers", 1, 64), default=2, metavar="N", help=workers_help)
    b.add_argument("--out", type=_output_arg("--out"), default=Path("out/bench"), metavar="DIR",
                   help="output folder (default: %(default)s)")
    b.add_argument("--rrd", action="store_true", help="also record each run to OUT/rrd/ (default: no)")
    b.add_argument("--resume", action="store_true", help=resume_help)
    b.add_argument("--sensing", choices=SENSING, default="map", help=sensing_help)
    b.add_argument("--footprint", choices=FOOTPRINTS, default="disc", help=footprint_help)
    b.add_argument("--ray", nargs="?", const=True, default=None, metavar="ADDRESS",
                   type=_ray_address, help=RAY_HELP)

    keys = ", ".join(_mismatch_key_names())
    rb = sub.add_parser("robustness", help="sweep model mismatch over a grid with several seeds")
    rb.add_argument("scenarios", nargs="+", help="scenario files or built-in names")
    rb.add_argument("--sweep", nargs="+", default=list(DEFAULT_SWEEP), metavar="KEY=V1,V2,...",
                    help=f"one or two mismatch keys with their grid values; keys: {keys} (ranges and units as "
                         f"run --mismatch) (default: {' '.join(DEFAULT_SWEEP)})")
    rb.add_argument("--seeds", type=_count("--seeds"), default=5, metavar="N",
                    help="seeds 0..N-1 per grid point and scenario, 1..10000 (default: %(default)s)")
    rb.add_argument("--controller", choices=CONTROLLERS, default="sa-mpc", help=controller_help)
    rb.add_argument("--workers", type=_count("--workers", 1, 64), default=2, metavar="N", help=workers_help)
    rb.add_argument("--fixed", nargs="+", default=[], metavar="KEY=VALUE",
                    help="mismatch applied at every grid point (keys as run --mismatch; not a swept key) "
                         "(default: none)")
    rb.add_argument("--time-limit", type=_time_limit, default=60.0, metavar="S",
                    help=f"simulated time limit of each run [s], 0 < S <= {MAX_TIME_LIMIT_S:g} (default: %(default)s)")
    rb.add_argument("--out", type=_output_arg("--out"), default=Path("out/robustness"), metavar="DIR",
                    help="output folder (default: %(default)s)")
    rb.add_argument("--resume", action="store_true", help=resume_help)
    rb.add_argument("--sensing", choices=SENSING, default="map", help=sensing_help)
    rb.add_argument("--footprint", choices=FOOTPRINTS, default="disc", help=footprint_help)
    rb.add_argument("--ray", nargs="?", const=True, default=None, metavar="ADDRESS",
                   type=_ray_address, help=RAY_HELP)
    return p


def _mismatch_key_names() -> list[str]:
    from sanav_mj.sim.mismatch import mismatch_keys

    return list(mismatch_keys())


def _write_json(path: Path, doc: dict) -> None:
    from sanav_mj.outputs import write_text

    write_text(path, json.dumps(doc, indent=1, allow_nan=False))


def _write_outputs(writers: list[tuple[Path | None, object]]) -> None:
    """Call each ``(path, write)`` whose path is set; one failure does not stop the others.

    Every output is written whole or not at all (:mod:`sanav_mj.outputs`).

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
            failed.append(f"{exc.filename or path}: cannot write ({exc.strerror or exc})")
    if failed:
        more = f" (and {len(failed) - 1} more output(s) not written)" if len(failed) > 1 else ""
        raise BadInput(failed[0] + more)


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


def _check_outputs(named: dict[str, Path | None]) -> None:
    """Fail early (before any long work) when an output path is unusable; creates nothing.

    The output (and its folder) is written only at the end, once complete: no empty file is
    left by a run that fails or is interrupted.
    """
    for name, path in named.items():
        if path is None:
            continue
        if path.is_dir():
            raise BadInput(f"{name} {path}: expected a file path, got a folder")
        folder = path.parent
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        if not folder.is_dir():
            raise BadInput(f"{name} {path}: cannot create the output folder ({folder} is not a folder)")
        if path.exists() and not os.access(path, os.W_OK):
            raise BadInput(f"{name} {path}: cannot write (permission denied)")
        if not path.exists() and not os.access(folder, os.W_OK | os.X_OK):
            raise BadInput(f"{name} {path}: cannot write in {folder} (permission denied)")


#: the ``--sensing`` choices
SENSING = ("map", "lidar")

#: the ``--footprint`` choices (:attr:`sanav_mj.control.config.MPCConfig.footprint`)
FOOTPRINTS = ("disc", "discs")


def _check_footprint(footprint: str, controllers: list[str], option: str = "--controller") -> None:
    """``--footprint discs`` is an SA-MPC setting (with the known map or the lidar): any other
    controller is bad input (exit 2)."""
    if footprint == "disc":
        return
    other = [c for c in controllers if c != "sa-mpc"]
    if other:
        raise BadInput(f"--footprint {footprint}: supported for the sa-mpc controller only, got {option} {' '.join(other)}")




def _check_sensing(sensing: str, controllers: list[str], option: str = "--controller") -> None:
    """``--sensing lidar`` runs SA-MPC only; any other controller is bad input (exit 2)."""
    other = [c for c in controllers if c != "sa-mpc"]
    if sensing == "lidar" and other:
        raise BadInput(f"--sensing lidar: supported for the sa-mpc controller only, got {option} {' '.join(other)}")


def _scenario_of(args):
    """The scenario argument: a path or name as given, or the Scenario made from a ROS map
    with ``--start`` / ``--goal`` (both required then; both refused for an MJCF scenario)."""
    from sanav_mj.eval.maps import is_ros_map, scenario_from_ros_map

    given = [o for o, v in (("--start", args.start), ("--goal", args.goal)) if v is not None]
    if not is_ros_map(args.scenario):
        if given:
            raise BadInput(f"{' and '.join(given)}: only for a ROS map (.yaml); {args.scenario} is a scenario "
                           "with its own start and goal")
        return args.scenario
    missing = [o for o in ("--start", "--goal") if o not in given]
    if missing:
        raise BadInput(f"{args.scenario}: a ROS map needs {' and '.join(missing)} to make a scenario")
    return scenario_from_ros_map(args.scenario, args.start, args.goal)


def _cmd_scenario(args) -> int:
    from sanav_mj.eval.maps import is_ros_map, ros_scenario_xml, scenario_from_ros_map
    from sanav_mj.outputs import write_text

    if not is_ros_map(args.map):
        raise BadInput(f"{args.map}: expected a ROS map_server map (.yaml)")
    _check_outputs({"--out": args.out})
    sc = scenario_from_ros_map(args.map, args.start, args.goal)  # checks start and goal first
    xml = ros_scenario_xml(args.map, args.start, args.goal)
    write_text(args.out, xml)
    print(f"{args.out}: scenario {sc.name} from {args.map}, {len(sc.obstacles)} obstacles, workspace "
          f"{sc.bounds[2] - sc.bounds[0]:.2f} x {sc.bounds[3] - sc.bounds[1]:.2f} m")
    return 0


def _cmd_areas(args) -> int:
    from sanav_mj.eval.prepare import areas_document, prepare
    from sanav_mj.eval.maps import is_ros_map, ros_areas_document

    outputs = {"--json": args.json, "--plot": args.plot}
    _distinct_outputs(outputs)
    _check_outputs(outputs)
    if is_ros_map(args.scenario) and args.start is None and args.goal is None:
        if args.plot is not None:
            raise BadInput("--plot: a ROS map is plotted with its corridor; give --start and --goal")
        doc = ros_areas_document(args.scenario)
        t = doc["timing_ms"]
        try:
            print(f"{doc['scenario']}: grid {doc['grid']['shape'][1]}x{doc['grid']['shape'][0]} @ "
                  f"{doc['grid']['resolution']} m (the map's), leaves {doc['leaves']['free']} free / "
                  f"{doc['leaves']['occupied']} occupied, {len(doc['rects'])} safe areas, {len(doc['edges'])} edges, "
                  f"{t['total']:.2f} ms")
        finally:
            _write_outputs([(args.json, lambda: _write_json(args.json, doc))])
        return 0
    prep = prepare(_scenario_of(args), resolution=args.resolution)
    doc = areas_document(prep)

    def plot() -> None:
        from sanav_mj.eval.plots import plot_areas

        plot_areas(prep, args.plot)

    try:  # the result line first: a failing output file must not lose it
        t = doc["timing_ms"]
        route = f"corridor {len(doc['corridor'])} areas" if doc["corridor"] else "no path from the start to the goal"
        print(
            f"{doc['scenario']}: grid {doc['grid']['shape'][1]}x{doc['grid']['shape'][0]} @ "
            f"{doc['grid']['resolution']} m, leaves {doc['leaves']['free']} free / {doc['leaves']['occupied']} "
            f"occupied, {len(doc['rects'])} safe areas, {len(doc['edges'])} edges, {route}, {t['total']:.2f} ms"
        )
    finally:
        _write_outputs([(args.json, lambda: _write_json(args.json, doc)), (args.plot, plot)])
    return 0


def _cmd_run(args) -> int:
    from sanav_mj.api import run_scenario  # the CLI is a thin layer over the Python API
    from sanav_mj.eval.prepare import footprint_spec
    from sanav_mj.sim.mismatch import parse_mismatch

    mismatch = parse_mismatch(args.mismatch)
    _check_sensing(args.sensing, [args.controller])
    _check_footprint(args.footprint, [args.controller])
    outputs = {"--json": args.json, "--rrd": args.rrd, "--plot": args.plot}
    _distinct_outputs(outputs)
    _check_outputs(outputs)
    out = run_scenario(
        _scenario_of(args),
        controller=footprint_spec(args.controller, args.footprint),
        seed=args.seed,
        yaw=args.yaw,
        resolution=args.resolution,
        mismatch=mismatch,
        time_limit_s=args.time_limit,
        sensing=args.sensing,
        record_sensing=args.rrd is not None,
    )
    doc = out.to_dict()  # exactly what ``run_scenario(...).to_dict()`` gives

    def plot() -> None:
        from sanav_mj.eval.plots import plot_run

        plot_run(out, args.plot)

    def record() -> None:
        from sanav_mj.record import record_episode

        try:
            record_episode(args.rrd, out)
        except OSError as exc:
            raise BadInput(f"{exc.filename or args.rrd}: cannot write the recording ({exc.strerror or exc})") from None
        except RuntimeError as exc:  # raised inside the rerun SDK
            if not _raised_in_rerun(exc):
                raise
            first = (str(exc).strip().splitlines() or ["no message"])[0]
            raise BadInput(f"{args.rrd}: cannot write the recording ({first})") from None

    try:  # the result line first: a failing output file must not lose it
        print(run_line(doc))
    finally:
        _write_outputs([(args.json, lambda: _write_json(args.json, doc)), (args.rrd, record), (args.plot, plot)])
    return 0 if doc["success"] else 1


def _raised_in_rerun(exc: BaseException) -> bool:
    """Whether ``exc`` was raised by the rerun SDK (its innermost frame is in the package)."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and "/rerun/" in tb.tb_frame.f_code.co_filename.replace("\\", "/")


def _num(value) -> str:
    """A mismatch value as given: ``delay=1``, ``friction=0.3``."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def run_line(doc: dict) -> str:
    """The one-line result of ``run``: outcome, steps, time, path, clearance, collisions, and,
    when non-zero, safe-area violations and solver failures; the mismatch applied; solve times.

    Every field may be missing or None (a run that never moved has no clearance): shown as n/a.
    """
    def num(key: str, fmt: str) -> str:
        v = doc.get(key)
        return "n/a" if v is None else format(v, fmt)

    head = f"{doc.get('scenario')} / {doc.get('controller')} seed {doc.get('seed')}: {doc.get('reason')}"
    if doc.get("reason") == "no_path" and not doc.get("steps"):
        return f"{head}: no corridor of safe areas joins the start to the goal; the robot did not move"
    parts = [f"{head} after {num('steps', 'd')} steps ({num('sim_time_s', '.1f')} s)",
             f"path {num('path_length_m', '.2f')} m", f"min clearance {num('min_clearance_m', '.3f')}" + (" m" if doc.get("min_clearance_m") is not None else ""),
             f"collisions {num('collisions', 'd')}"]
    for key, label in (("safe_area_violations", "safe-area violations"), ("solver_failures", "solver failures")):
        if doc.get(key):
            parts.append(f"{label} {doc[key]}")
    if doc.get("mismatch"):
        parts.append("mismatch " + " ".join(f"{k}={_num(v)}" for k, v in doc["mismatch"].items()))
    if doc.get("sensing") == "lidar":
        mu, pipe = doc.get("map_update_ms") or {}, doc.get("pipeline_ms") or {}
        parts.append(f"lidar: {doc.get('replans')} replans, map update {mu.get('mean', float('nan')):.2f} ms mean, "
                     f"pipeline {pipe.get('mean', float('nan')):.2f} ms mean / {pipe.get('p99', float('nan')):.2f} ms p99")
    solve = doc.get("solve_ms") or {}
    if doc.get("steps") and solve.get("mean") is not None:
        parts.append(f"solve {solve['mean']:.2f} ms mean / {solve.get('p99', float('nan')):.2f} ms p99")
    return ", ".join(parts)


def _cmd_demo(args) -> int:
    from sanav_mj.eval.demo import run_demo, summary_table

    _check_footprint(args.footprint, ["sa-mpc"])
    _check_out_dir(args.out)
    result = run_demo(args.out, record=not args.no_rrd, sensing=args.sensing, footprint=args.footprint)
    print(summary_table(result.rows), end="")
    kinds = "recordings (.rrd), plots (.png) and JSON" if not args.no_rrd else "plots (.png) and JSON (no recordings: --no-rrd)"
    print(f"wrote {kinds} to {args.out}/" if not result.failed else
          f"wrote {len(result.written)} files to {args.out}/")
    if result.failed:
        exc = result.failed[0]
        more = f" (and {len(result.failed) - 1} more output(s) not written)" if len(result.failed) > 1 else ""
        raise BadInput(f"{exc.filename}: cannot write ({exc.strerror or exc}){more}")
    return 0 if all(r["success"] for r in result.rows) else 1


def _cmd_bench(args) -> int:
    from sanav_mj.eval.bench import markdown_table, run_bench

    _check_sensing(args.sensing, args.controllers, "--controllers")
    _check_footprint(args.footprint, args.controllers, "--controllers")
    _check_scenarios(args.scenarios)
    _check_out_dir(args.out)
    summary = run_bench(args.scenarios, args.controllers, args.runs, args.workers, args.out, record=args.rrd,
                        resume=args.resume, ray=args.ray, sensing=args.sensing, footprint=args.footprint)
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
    from sanav_mj.eval.robustness import POOLED, parse_sweep, run_robustness

    sweep = parse_sweep(args.sweep)
    fixed = _parse_fixed(args.fixed, sweep)
    _check_sensing(args.sensing, [args.controller])
    _check_footprint(args.footprint, [args.controller])
    _check_scenarios(args.scenarios)
    _check_out_dir(args.out)
    default = " (the default; choose with --sweep KEY=V1,V2,...)" if args.sweep == list(DEFAULT_SWEEP) else ""
    grid = " x ".join(f"{k} = {', '.join(_num(v) for v in vals)}" for k, vals in sweep)
    print(f"robustness: sweeping {grid}{default}, {args.seeds} seed(s) per point and scenario, controller "
          f"{args.controller}" + (f", footprint {args.footprint}" if args.footprint != "disc" else "")
          + (f", fixed {' '.join(args.fixed)}" if args.fixed else ""), flush=True)
    summary = run_robustness(args.scenarios, sweep, args.seeds, args.controller, args.workers, args.out,
                             time_limit_s=args.time_limit, fixed=fixed, resume=args.resume, ray=args.ray,
                             sensing=args.sensing, footprint=args.footprint)
    for row in summary:  # a quantity with no value (NaN: no run ran, or none has a clearance) is n/a
        print("  ".join(f"{k}={'n/a' if math.isnan(v) else format(v, '.3g')}" if isinstance(v, float) else f"{k}={v}"
                        for k, v in row.items()))
    per = " (pooled; per scenario in summary_by_scenario.csv and per_scenario/)" if any(
        r["scenario"] != POOLED for r in summary) else ""
    print(f"wrote {args.out}/robustness.csv, summary.csv and heat maps{per}")
    return _raised_runs([r for r in summary if r["scenario"] == POOLED], args.out / "robustness.csv")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``sanav-mj`` console script; returns the exit code."""
    from sanav_mj.eval.campaign import CampaignInterrupted, ClusterError, JournalError
    from sanav_mj.scene import ScenarioError
    from sanav_mj.sim.mismatch import MismatchError

    try:
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as exc:  # --help, --version: printed; exit 0
            sys.stdout.flush()
            return int(exc.code or 0)
        handler = {
            "areas": _cmd_areas,
            "scenario": _cmd_scenario,
            "run": _cmd_run,
            "demo": _cmd_demo,
            "bench": _cmd_bench,
            "robustness": _cmd_robustness,
        }[args.command]
        return handler(args)
    except (BadInput, ScenarioError, MismatchError, JournalError, ClusterError) as exc:
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
