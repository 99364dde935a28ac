"""``sanav-mj bench``: the paper's comparison (Table I and Fig. 6) in our simulator.

Every (scenario, controller, seed) is one episode through the same runner; seeds randomise
the initial yaw. Outputs in ``--out``: ``results.csv`` (one row per run), ``table.md`` (per
scenario and method: solve and full-pipeline ms mean/max/std pooled over all steps of all
runs, mean steps of the successful runs, success %, runs with a collision),
``success.png`` (grouped bars), ``meta.json`` (what was run, where and on which commit; written
before the runs and again at the end) and ``runs.jsonl``, the journal of finished runs that
``resume=True`` (``sanav-mj bench --resume``) continues from (see :mod:`sanav_mj.eval.campaign`).

A run that raised (a failure of the tool, not of the controller) is a row with reason
``error`` and the message in the ``error`` column of ``results.csv``; the summary counts it
apart (``errors``) and leaves it out of ``runs``, the success and collision rates and the
timing.

What the timing columns hold (see :mod:`sanav_mj.eval.metrics` and
:mod:`sanav_mj.eval.episode`): ``solve`` is the controller's own report per step
(``Command.solve_ms``); ``pipeline`` is the wall time of the controller's whole ``step``
call, with the one-off preparation of the run (the re-plan from the seed's start pose; the
map is built once per scenario and worker, see :mod:`sanav_mj.eval.campaign`) added to the
first step.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from sanav_mj.eval.campaign import (
    JOURNAL_NAME,
    Job,
    JobSet,
    check_meta,
    is_error,
    read_journal,
    run_jobs,
)
from sanav_mj.outputs import OutputFailures, StreamedFile, write_text

CSV_COLUMNS = (
    "scenario", "controller", "seed", "success", "reason", "steps", "sim_time_s", "path_length_m",
    "min_clearance_m", "collisions", "safe_area_violations", "solver_failures",
    "solve_mean_ms", "solve_max_ms", "solve_std_ms", "solve_p99_ms",
    "pipeline_mean_ms", "pipeline_max_ms", "pipeline_std_ms", "error",
)

#: meta.json keys that must match for ``--resume`` (missing counts as None): they decide the
#: jobs and what the results mean; workers, commit, machine and dates may differ
RESUME_SETTINGS = ("command", "scenarios", "controllers", "runs", "time_limit_s", "sweep", "fixed")


def flatten(doc: dict[str, Any]) -> dict[str, Any]:
    """One CSV row from a run JSON document (without trace).

    The row of a run that raised (:func:`sanav_mj.eval.campaign.is_error`) keeps its
    scenario, controller, seed, success (False), reason (``error``) and ``error`` message and
    has no metrics.
    """
    row = {k: doc.get(k) for k in CSV_COLUMNS if k in doc}
    if is_error(doc):
        return row
    row["solve_mean_ms"] = doc["solve_ms"]["mean"]
    row["solve_max_ms"] = doc["solve_ms"]["max"]
    row["solve_std_ms"] = doc["solve_ms"]["std"]
    row["solve_p99_ms"] = doc["solve_ms"]["p99"]
    row["pipeline_mean_ms"] = doc["pipeline_ms"]["mean"]
    row["pipeline_max_ms"] = doc["pipeline_ms"]["max"]
    row["pipeline_std_ms"] = doc["pipeline_ms"]["std"]
    return row


class RunningSum:
    """A sum of floats added one at a time that equals the builtin :func:`sum` over the same
    values in the same order, bit for bit (Python >= 3.12 sums floats with Neumaier's
    compensation, earlier versions left to right): so the streamed summaries of a campaign
    are the figures the former all-rows-in-memory code printed."""

    __slots__ = ("total", "comp", "count")
    _COMPENSATED = sys.version_info >= (3, 12)

    def __init__(self) -> None:
        self.total = 0.0
        self.comp = 0.0
        self.count = 0

    def add(self, x: float) -> None:
        x = float(x)
        if self.count == 0:
            self.total = 0 + x  # sum() starts from the integer 0
        elif self._COMPENSATED:
            t = self.total + x
            if abs(self.total) >= abs(x):
                self.comp += (self.total - t) + x
            else:
                self.comp += (x - t) + self.total
            self.total = t
        else:
            self.total += x
        self.count += 1

    @property
    def value(self) -> float:
        """The sum (0 when nothing was added)."""
        if self.count == 0:
            return 0
        if self._COMPENSATED and self.comp and math.isfinite(self.comp):
            return self.total + self.comp
        return self.total


class PooledTiming:
    """:func:`pooled` fed one row at a time: memory independent of the number of rows."""

    __slots__ = ("prefix", "n", "mean_sum", "second_sum", "max")

    def __init__(self, prefix: str) -> None:
        self.prefix = prefix
        self.n = 0
        self.mean_sum = RunningSum()
        self.second_sum = RunningSum()
        self.max: float | None = None

    def add(self, row: dict[str, Any]) -> None:
        """Take one CSV row (:func:`flatten`); rows of runs that raised or without steps are left out."""
        if is_error(row) or int(row["steps"]) <= 0:
            return
        steps = int(row["steps"])
        mean, std, mx = row[f"{self.prefix}_mean_ms"], row[f"{self.prefix}_std_ms"], row[f"{self.prefix}_max_ms"]
        self.n += steps
        self.mean_sum.add(mean * steps)
        self.second_sum.add((std**2 + mean**2) * steps)
        if self.max is None or mx > self.max:
            self.max = mx

    def result(self) -> tuple[float, float, float]:
        """Mean, max and (population) std [ms]; all zeros without samples."""
        if self.n == 0:
            return 0.0, 0.0, 0.0
        mean = self.mean_sum.value / self.n
        second = self.second_sum.value / self.n
        return mean, self.max, math.sqrt(max(second - mean**2, 0.0))


def pooled(rows: Sequence[dict[str, Any]], prefix: str) -> tuple[float, float, float]:
    """Mean, max and (population) std [ms] over all steps of all runs.

    Exact from the per-run ``{prefix}_mean_ms``, ``{prefix}_std_ms`` (population std, as
    :func:`sanav_mj.eval.metrics.timing_stats`), ``{prefix}_max_ms`` and ``steps`` (the
    number of samples): the pooled second moment is the step-weighted mean of
    ``std^2 + mean^2``. Runs without steps carry no samples and are left out (all zeros
    when no run has one), and so are the rows of runs that raised. Streamed by
    :class:`PooledTiming`.
    """
    acc = PooledTiming(prefix)
    for r in rows:
        acc.add(r)
    return acc.result()


class _PairSummary:
    """The running aggregates of one (scenario, controller) pair of :class:`BenchSummary`."""

    __slots__ = ("all", "runs", "solve", "pipeline", "ok", "ok_steps", "collided", "reasons")

    def __init__(self) -> None:
        self.all = 0
        self.runs = 0
        self.solve = PooledTiming("solve")
        self.pipeline = PooledTiming("pipeline")
        self.ok = 0
        self.ok_steps = 0
        self.collided = 0
        self.reasons: dict[str, int] = {}


class BenchSummary:
    """:func:`summarise` fed one CSV row at a time (:meth:`add`), for a campaign streamed row
    by row: it holds a handful of counters, sums and maxima per (scenario, controller), not
    the rows. Every figure is exact (counts, integer sums, maxima, and float sums that equal
    :func:`sum`'s, :class:`RunningSum`); no median or percentile is computed across runs."""

    def __init__(self) -> None:
        self._pairs: dict[tuple[str, str], _PairSummary] = {}

    def add(self, row: dict[str, Any]) -> None:
        """Take one row (:func:`flatten`)."""
        p = self._pairs.setdefault((row["scenario"], row["controller"]), _PairSummary())
        p.all += 1
        if is_error(row):
            return
        p.runs += 1
        p.solve.add(row)
        p.pipeline.add(row)
        if row["success"]:
            p.ok += 1
            p.ok_steps += row["steps"]
        p.collided += int(row["collisions"]) > 0
        p.reasons[row["reason"]] = p.reasons.get(row["reason"], 0) + 1

    def rows(self) -> list[dict[str, Any]]:
        """The summary rows, as :func:`summarise` describes them."""
        out = []
        for (scenario, controller), p in self._pairs.items():
            sm, sx, ss = p.solve.result()
            pm, px, ps = p.pipeline.result()
            n = p.runs
            out.append({
                "scenario": scenario,
                "controller": controller,
                "runs": n,
                "solve_mean_ms": sm, "solve_max_ms": sx, "solve_std_ms": ss,
                "pipeline_mean_ms": pm, "pipeline_max_ms": px, "pipeline_std_ms": ps,
                "steps": (p.ok_steps / p.ok) if p.ok else None,
                "success_rate": 100.0 * p.ok / n if n else None,
                "collision_runs": p.collided,
                "collision_rate": 100.0 * p.collided / n if n else None,
                "reasons": ", ".join(f"{k} {v}" for k, v in sorted(p.reasons.items())),
                "errors": p.all - n,
            })
        return out


def summarise(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (scenario, controller) summary rows, in first-seen order (:class:`BenchSummary`).

    Keys: ``scenario``, ``controller``, ``runs``; ``solve_{mean,max,std}_ms`` and
    ``pipeline_{mean,max,std}_ms`` [ms] pooled over all steps (:func:`pooled`); ``steps``
    mean steps of the successful runs (None when none succeeded); ``success_rate`` [%];
    ``collision_runs`` runs with at least one robot-obstacle contact and
    ``collision_rate`` [%] of them; ``reasons`` the outcome counts, e.g. ``"goal 9, stuck 1"``;
    ``errors`` the runs that raised. Those are failures of the tool, not of the controller:
    they are not in ``runs``, the rates, the timing or ``reasons`` (the rates are None when
    every run of the pair raised).
    """
    acc = BenchSummary()
    for r in rows:
        acc.add(r)
    return acc.rows()


#: Header cells of :func:`markdown_table`.
TABLE_HEADER = (
    "scenario", "method", "runs", "solve mean / max / std (ms)", "full pipeline mean / max / std (ms)",
    "steps", "success %", "runs with collision", "outcomes",
)


def markdown_table(summary: Sequence[dict[str, Any]]) -> str:
    """The timing/success table in Markdown (the paper's Table I layout), one row per summary row.

    Runs that raised (``errors``) show as ``runs (+N raised)`` and add a note below the
    table: they are left out of every other column.
    """
    lines = ["| " + " | ".join(TABLE_HEADER) + " |", "|" + "---|" * len(TABLE_HEADER)]
    for s in summary:
        steps = "-" if s["steps"] is None else f"{s['steps']:.0f}"
        success = "-" if s["success_rate"] is None else f"{s['success_rate']:.0f}"
        errors = s.get("errors", 0)
        runs = f"{s['runs']} (+{errors} raised)" if errors else f"{s['runs']}"
        lines.append(
            f"| {s['scenario']} | {s['controller']} | {runs} | {s['solve_mean_ms']:.2f} / {s['solve_max_ms']:.2f} / "
            f"{s['solve_std_ms']:.2f} | {s['pipeline_mean_ms']:.2f} / {s['pipeline_max_ms']:.2f} / "
            f"{s['pipeline_std_ms']:.2f} | {steps} | {success} | {s['collision_runs']} "
            f"| {s['reasons']} |"
        )
    raised = sum(s.get("errors", 0) for s in summary)
    if raised:
        note = (f"{raised} run(s) raised an exception (reason `error` in results.csv, with the message in "
                "its `error` column): failures of the tool, not of the controller, left out of runs, "
                "success %, collisions, timing and outcomes.")
        lines += ["", note]
    return "\n".join(lines) + "\n"


def write_csv(rows: list[dict[str, Any]], path: Path, columns: tuple[str, ...] = CSV_COLUMNS) -> None:
    """Write result rows (dicts) to CSV with the given leading columns (extra keys appended),
    whole or not at all (:mod:`sanav_mj.outputs`)."""
    extra = sorted({k for r in rows for k in r} - set(columns))
    out = CsvStream(path, (*columns, *extra))
    try:
        for r in rows:
            out.add(r)
    except BaseException:
        out.discard()
        raise
    out.commit()


class CsvStream:
    """A CSV output written row by row as a campaign's rows arrive, put in place whole at
    the end (:class:`sanav_mj.outputs.StreamedFile`): ``add(row)`` writes one row (keys
    not in ``columns`` are ignored), ``commit()`` renames the finished file onto ``path``
    (raising the first write error, naming ``path``), ``discard()`` drops it."""

    def __init__(self, path: Path, columns: Sequence[str]) -> None:
        self._file = StreamedFile(path)
        self._writer = csv.DictWriter(self._file, fieldnames=list(columns), extrasaction="ignore")
        self._writer.writeheader()

    def add(self, row: dict[str, Any]) -> None:
        self._writer.writerow(row)

    def commit(self) -> Path:
        return self._file.commit()

    def discard(self) -> None:
        self._file.discard()


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


@contextlib.contextmanager
def campaign_executor(ray: Any) -> Iterator[Any]:
    """:func:`sanav_mj.eval.ray_runner.campaign_executor` when ``ray`` asks for Ray, else
    None (the process pool) without importing the Ray runner."""
    if ray is None or ray is False:
        yield None
        return
    from sanav_mj.eval.ray_runner import campaign_executor as on_ray

    with on_ray(ray) as executor:
        yield executor


def describe(ray: Any) -> str | None:
    """How a campaign ran, for ``meta.json["executor"]``: None (the process pool), ``"ray"``
    (a local Ray) or ``"ray ADDRESS"``."""
    if ray is None or ray is False:
        return None
    from sanav_mj.eval.ray_runner import describe as on_ray

    return on_ray(ray)


def begin_campaign(out: Path, meta: dict[str, Any], resume: bool) -> None:
    """Write ``out/meta.json`` before the runs; with ``resume`` and a journal in ``out``, first
    check that the folder was run with the same :data:`RESUME_SETTINGS`.

    The earlier sessions of a resumed folder are kept in ``meta["earlier_sessions"]``
    (commit, dirty, date, wall time of each), so a folder measured on two commits says so.
    ``meta["wall_time_s"]`` is None until the campaign ends.

    Raises:
        sanav_mj.eval.campaign.JournalError: the journal is unreadable, or ``meta.json`` is
            missing or differs in a setting.
    """
    path = out / "meta.json"
    if resume and read_journal(out / JOURNAL_NAME):
        check_meta(path, {k: meta.get(k) for k in RESUME_SETTINGS})
        previous = json.loads(path.read_text())
        meta["earlier_sessions"] = list(previous.get("earlier_sessions", [])) + [
            {k: previous.get(k) for k in ("commit", "dirty", "dirty_files", "date_utc", "wall_time_s")}]
    meta["wall_time_s"] = None
    write_text(path, json.dumps(meta, indent=1))


def stream_campaign(jobs: JobSet, workers: int, desc: str, out: Path, resume: bool, executor: Any,
                    per_run: CsvStream, take: Callable[[dict[str, Any]], None]) -> None:
    """Run ``jobs`` (:func:`sanav_mj.eval.campaign.run_jobs` on ``workers`` processes or
    ``executor``, journalled in ``out/runs.jsonl``, continued from it with ``resume``; ``desc``
    labels the progress bar), handing each row to ``take`` in job order as it arrives; no row
    is kept. ``take`` writes the row to ``per_run`` (and to running summaries); if the campaign
    stops (an exception, Ctrl-C) ``per_run``'s temporary file is dropped and the exception goes on."""
    try:
        for doc in run_jobs(jobs, workers, desc=desc, journal=out / JOURNAL_NAME, resume=resume,
                            executor=executor, on_row=take):
            take(doc)  # none: run_jobs hands every row to take
    except BaseException:
        per_run.discard()
        raise


def run_bench(
    scenarios: list[str],
    controllers: list[str],
    runs: int,
    workers: int,
    out: Path,
    record: bool = False,
    time_limit_s: float = 60.0,
    resume: bool = False,
    ray: str | bool | Any = None,
    sensing: str = "map",
    footprint: str = "disc",
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
        resume: keep the finished runs of ``out/runs.jsonl`` (an interrupted campaign with
            the same settings) and run only the others; the outputs are the same as those of
            an uninterrupted campaign. Without it the journal starts empty.
        ray: run on Ray instead of the process pool (see
            :func:`sanav_mj.eval.ray_runner.campaign_executor`): True for a local Ray, an
            address (``"auto"``, ``"HOST:PORT"``, ``"ray://HOST:PORT"``) for a cluster, or an
            open :class:`~sanav_mj.eval.ray_runner.RaySession`; None: the pool of ``workers``.
            The rows, outputs and journal are the same either way.
        sensing: ``"map"`` or ``"lidar"`` for every run (lidar: SA-MPC only).
        footprint: SA-MPC's ``"disc"`` or ``"discs"`` for every run (``meta.json`` names it
            when not ``"disc"``; :func:`sanav_mj.eval.prepare.footprint_spec`).

    Returns:
        The per (scenario, controller) summary rows (also written to ``table.md``); their
        ``errors`` count the runs that raised.

    Also writes ``meta.json`` (:func:`run_metadata` plus ``command`` = "bench", the wall
    time of this session and the load average at its end: the timings are wall times on a
    possibly shared machine; see :func:`begin_campaign`) and the journal ``runs.jsonl``.

    Raises:
        sanav_mj.eval.campaign.JournalError: ``resume`` into a folder run with other settings.
        sanav_mj.eval.campaign.CampaignInterrupted: Ctrl-C; finished runs are in the journal.
        sanav_mj.eval.ray_runner.ClusterError: ``ray`` given but Ray is missing or unreachable.
        OSError: an output could not be written (``filename`` the first such file; ``meta.json``
            before the runs stops the campaign, one at the end is raised after every other
            output was written). Each output is written whole or not at all.

    Memory does not grow with the campaign: rows are streamed to ``results.csv`` and to
    running aggregates (:class:`BenchSummary`) in job order (see ``on_row`` in
    :func:`sanav_mj.eval.campaign.run_jobs`).
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
    jobs = JobSet(lambda: (
        Job(
            scenario=s, controller=c, seed=k, time_limit_s=time_limit_s,
            rrd=str(out / "rrd" / f"{Path(s).stem}_{c}_{k}.rrd") if record else None, sensing=sensing,
            footprint=footprint,
        )
        for s in names for c in controllers for k in range(runs)
    ), len(names) * len(controllers) * runs,
        distinct=len(set(names)) == len(names) and len(set(controllers)) == len(controllers))
    with campaign_executor(ray) as executor:
        meta = {"command": "bench", **run_metadata(names, controllers, runs, workers, time_limit_s)}
        if sensing != "map":
            meta["sensing"] = sensing
        if footprint != "disc":
            meta["footprint"] = footprint
        meta["executor"] = describe(ray)
        begin_campaign(out, meta, resume)
        t0 = time.perf_counter()
        # streamed: each row goes to results.csv (a temporary file until the end) and the
        # running summary as it arrives, in the order of the jobs; no row is kept
        results = CsvStream(out / "results.csv", CSV_COLUMNS)
        acc = BenchSummary()

        def take(doc: dict[str, Any]) -> None:
            row = flatten(doc)
            results.add(row)
            acc.add(row)

        stream_campaign(jobs, workers, "bench", out, resume, executor, results, take)
    meta["wall_time_s"] = time.perf_counter() - t0
    meta["load_average_end"] = _load_average()
    failures = OutputFailures()  # every output whole or not at all; one failing does not stop the others
    failures.attempt(out / "results.csv", results.commit)
    failures.attempt(out / "meta.json", lambda: write_text(out / "meta.json", json.dumps(meta, indent=1)))
    summary = acc.rows()
    failures.attempt(out / "table.md", lambda: write_text(out / "table.md", markdown_table(summary)))
    rated = [{"scenario": s["scenario"], "controller": s["controller"], "success_rate": s["success_rate"]}
             for s in summary if s["success_rate"] is not None]
    if rated:  # pairs whose every run raised leave a gap
        failures.attempt(out / "success.png", lambda: plot_success_bars(rated, out / "success.png"))
    else:  # no rate at all: no figure (and none left from an earlier campaign)
        (out / "success.png").unlink(missing_ok=True)
    failures.check()
    return summary
