"""Run many independent episodes in worker processes with a progress bar, losing nothing.

Shared by ``bench`` and ``robustness``: a job is a small picklable :class:`Job`; each worker
process loads (and caches) scenarios and their maps once, runs its jobs and returns the
JSON summaries without the trace (traces stay in the worker unless asked for).

The jobs are generated lazily and at most a few per worker are in flight (see
:func:`run_jobs`), so a campaign's size costs no memory before its first run. They run on an
:class:`Executor`: this process, a process pool (default), or Ray
(:mod:`sanav_mj.eval.ray_runner`); the journal, resume, error rows and Ctrl-C below are the
same on each. Pool workers end when the parent process dies, even by SIGKILL
(:func:`exit_with_parent`).

Nothing finished is lost:

- **Journal.** With ``journal=PATH`` every finished row is appended to ``PATH`` (one JSON
  line ``{"key": ..., "row": ...}``, flushed and synced) as soon as it arrives.
  ``resume=True`` reads the journal first and runs only the jobs it does not hold (rows
  whose run raised are run again); the rows returned are the journal's plus the new ones
  in the order of the jobs, the same as an uninterrupted campaign (every row, new or
  journalled, goes through one JSON round trip). ``resume=False`` starts a new journal.
  Lines are strict JSON (:func:`dumps`: a non-finite float is ``{"$float": "nan"}``), and
  every row is checked (:func:`check_row`) before any job runs.
- **A run that raises** (any :class:`Exception` in :func:`run_job`, or a worker process
  that dies) does not stop the campaign: it becomes a row with ``reason`` ``"error"``
  (:data:`ERROR_REASON`), ``success`` False and the exception's one-line message in
  ``error``. Such a row is a failure of the tool, not of the controller: it has no
  ``steps`` or metrics, and the summaries count it apart (see :func:`is_error`).
- **Ctrl-C** (:class:`KeyboardInterrupt` in the parent): pending jobs are cancelled, the
  worker processes are stopped (they ignore SIGINT themselves, so they print nothing) and
  :class:`CampaignInterrupted` is raised carrying how many rows are saved in the journal.
"""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sized
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as futures_wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

#: ``reason`` of a row whose run raised (a failure of the tool, not an outcome of the controller)
ERROR_REASON = "error"
#: file name of the journal inside a campaign's output folder
JOURNAL_NAME = "runs.jsonl"
#: with ``on_row``, :func:`run_jobs` holds at most this many x the executor's slots of rows
#: finished ahead of an earlier, slower job (then waits for it before starting more jobs)
REORDER_WINDOW = 32


@dataclass(frozen=True)
class Job:
    """One episode to run.

    Attributes:
        scenario: scenario path or built-in name.
        controller: controller name.
        seed: run seed (initial yaw, noise).
        mismatch: ``KEY=VALUE`` items.
        time_limit_s: [s] simulated time limit.
        rrd: optional recording path.
        tags: extra columns copied into the result row (e.g. the swept values).
        sensing: ``"map"`` or ``"lidar"`` (see :func:`sanav_mj.eval.episode.run_scenario`).
        footprint: SA-MPC's ``"disc"`` or ``"discs"`` (:func:`sanav_mj.eval.prepare.footprint_spec`).
    """

    scenario: str
    controller: str
    seed: int
    mismatch: tuple[str, ...] = ()
    time_limit_s: float = 60.0
    rrd: str | None = None
    tags: tuple[tuple[str, Any], ...] = field(default_factory=tuple)
    sensing: str = "map"
    footprint: str = "disc"


class JournalError(ValueError):
    """A journal that cannot be resumed (unreadable, or written for other settings); one line."""


class ClusterError(ValueError):
    """``ray=`` / ``--ray``: Ray is not installed, or the cluster cannot be reached (one line;
    raised by :mod:`sanav_mj.eval.ray_runner`)."""


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_jobs`; the finished rows are in the journal.

    Attributes:
        saved: rows in the journal (journalled before this session plus finished in it).
        total: jobs of the campaign.
        journal: the journal path, or None when the campaign had none.
    """

    def __init__(self, saved: int, total: int, journal: Path | None) -> None:
        super().__init__(f"interrupted: {saved} of {total} runs saved" + (f" in {journal}" if journal else ""))
        self.saved = saved
        self.total = total
        self.journal = journal


def job_key(job: Job) -> str:
    """The identity of ``job`` in a journal: scenario, controller, seed, mismatch items and
    time limit [s] as compact JSON, the sensing mode when it is not ``"map"`` and the footprint
    when it is not ``"disc"`` (so journals of default campaigns keep their keys); the recording path and the tags are not part of it."""
    key: list[Any] = [job.scenario, job.controller, int(job.seed), list(job.mismatch), float(job.time_limit_s)]
    if job.sensing != "map":
        key.append(job.sensing)
    if job.footprint != "disc":
        key.append(f"footprint={job.footprint}")
    return json.dumps(key, separators=(",", ":"))


def is_error(row: Mapping[str, Any]) -> bool:
    """Whether ``row`` is the row of a run that raised (reason :data:`ERROR_REASON`)."""
    return row.get("reason") == ERROR_REASON


def error_row(job: Job, exc: BaseException) -> dict[str, Any]:
    """The row of a run of ``job`` that raised ``exc``: scenario, controller, seed, ``success``
    False, ``reason`` :data:`ERROR_REASON`, ``error`` (``"Type: message"`` on one line), the
    mismatch as ``{KEY: VALUE}`` strings and the job's tags; no metrics."""
    message = " ".join(str(exc).split())
    row: dict[str, Any] = {
        "scenario": job.scenario, "controller": job.controller, "seed": job.seed,
        "success": False, "reason": ERROR_REASON,
        "error": f"{type(exc).__name__}: {message}" if message else type(exc).__name__,
        "mismatch": {k.strip(): v.strip() for k, _, v in (item.partition("=") for item in job.mismatch)},
    }
    for key, value in job.tags:
        row[key] = value
    return row


_PREPARED: dict[tuple[str, str], Any] = {}


def run_job(job: Job) -> dict[str, Any]:
    """Run one job in this process; returns the run JSON without its trace, plus the tags."""
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.prepare import footprint_spec, prepare
    from sanav_mj.sim.mismatch import parse_mismatch

    spec = footprint_spec(job.controller, job.footprint)
    key = (job.scenario, job.footprint)  # the map depends on the footprint mode
    if key not in _PREPARED:
        _PREPARED[key] = prepare(job.scenario, controller=spec)
    out = run_scenario(
        _PREPARED[key],
        controller=job.controller,
        controller_spec=spec,
        seed=job.seed,
        mismatch=parse_mismatch(list(job.mismatch)),
        time_limit_s=job.time_limit_s,
        rrd=Path(job.rrd) if job.rrd else None,
        sensing=job.sensing,
    )
    doc = {k: v for k, v in out.document.items() if k != "trace"}
    for key, value in job.tags:
        doc[key] = value
    return doc


def _init_worker() -> None:
    """Initializer of every worker process: one BLAS thread, no SIGINT, and die with the parent."""
    # One BLAS / OpenMP thread per worker: the workers are the parallelism.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    # Ctrl-C reaches the whole process group: the parent alone handles it (no worker tracebacks).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent()


#: [s] how often the portable fallback of :func:`exit_with_parent` looks at the parent
PARENT_POLL_S = 0.5
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def exit_with_parent(poll_s: float = PARENT_POLL_S) -> None:
    """Make this (worker) process end when its parent process ends, even by SIGKILL.

    A parent killed with SIGKILL runs no cleanup, and a pool worker blocked waiting for its
    next job would live on. On Linux the kernel sends this process SIGKILL when the parent
    dies (``prctl(PR_SET_PDEATHSIG)``); everywhere, a daemon thread also checks every
    ``poll_s`` [s] whether the parent changed (``os.getppid()``, which becomes the reaper's
    pid) and then ends the process with ``os._exit(1)``.
    """
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="sanav-mj-parent-watch", daemon=True).start()


# --------------------------------------------------------------------------- journal encoding

_NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def _encode(value: Any) -> Any:
    """``value`` with every non-finite float replaced by ``{"$float": "nan" | "inf" | "-inf"}``."""
    if isinstance(value, float) and not math.isfinite(value):
        return {"$float": "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")}
    if isinstance(value, dict):
        return {k: _encode(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    return value


def _decode_object(obj: dict[str, Any]) -> Any:
    if len(obj) == 1 and "$float" in obj and obj["$float"] in _NONFINITE:
        return _NONFINITE[obj["$float"]]
    return obj


def dumps(value: Any) -> str:
    """Strict JSON of a journal value (no ``NaN``/``Infinity`` tokens): a non-finite float is
    written as the object ``{"$float": "nan"}`` (or ``"inf"``, ``"-inf"``); :func:`loads`
    reads it back as the float."""
    return json.dumps(_encode(value), allow_nan=False)


def loads(text: str) -> Any:
    """Read what :func:`dumps` wrote (``{"$float": ...}`` becomes the float again). The bare
    ``NaN`` / ``Infinity`` tokens of journals written before are read too."""
    return json.loads(text, object_hook=_decode_object)


def _round_trip(row: dict[str, Any]) -> dict[str, Any]:
    """``row`` as it reads back from the journal (tuples become lists), so new and resumed rows are alike."""
    return loads(dumps(row))


# --------------------------------------------------------------------------- journal rows

_NUMBER = (int, float)
_TIMING_KEYS = {"solve_ms": ("mean", "max", "std", "p50", "p99"), "pipeline_ms": ("mean", "max", "std")}
_INT_FIELDS = ("steps", "collisions", "safe_area_violations", "solver_failures")
_FLOAT_FIELDS = ("sim_time_s", "path_length_m")


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, _NUMBER) and not isinstance(v, bool)


def parse_key(key: str) -> tuple[str, str, int, tuple[str, ...], float]:
    """The fields of a :func:`job_key`: (scenario, controller, seed, mismatch items, time limit [s]).

    Raises:
        ValueError: ``key`` is not a job key (the message says what is wrong).
    """
    try:
        fields = json.loads(key)
    except ValueError:
        raise ValueError(f"key {key!r} is not JSON") from None
    if not (isinstance(fields, list) and len(fields) == 5):
        raise ValueError(f"key {key!r}: expected [scenario, controller, seed, [mismatch...], time_limit_s]")
    scenario, controller, seed, items, limit = fields
    if not (isinstance(scenario, str) and isinstance(controller, str) and _is_int(seed)
            and isinstance(items, list) and all(isinstance(i, str) for i in items)
            and _is_number(limit) and math.isfinite(limit) and limit > 0):
        raise ValueError(f"key {key!r}: expected [str, str, int, [str...], number > 0]")
    return scenario, controller, seed, tuple(items), float(limit)


def check_row(key: str, row: Any) -> None:
    """Check that ``row`` is a journal row of the job ``key`` (:func:`job_key`).

    A row is a dict holding ``scenario`` (the key's scenario, or its file stem as the run
    JSON names it), ``controller`` and ``seed`` equal to the key's, ``success`` (bool) and
    ``reason`` (str). An error row (:func:`is_error`) also holds ``error`` (str) and a
    ``mismatch`` of the key's items as strings; any other row holds the run JSON's metrics
    with their types (``steps``, ``collisions``, ``safe_area_violations``,
    ``solver_failures``: int; ``sim_time_s``, ``path_length_m``: number;
    ``min_clearance_m``: number or null; ``solve_ms`` / ``pipeline_ms``: objects of numbers)
    and the mismatch the key's items give.

    Raises:
        ValueError: the first field that is missing, of the wrong type or contradicts the key.
    """
    from sanav_mj.sim.mismatch import MismatchError, parse_mismatch

    scenario, controller, seed, items, _ = parse_key(key)
    if not isinstance(row, dict):
        raise ValueError(f"expected the row to be an object, got {type(row).__name__}")

    def need(name: str, ok, what: str) -> Any:
        if name not in row:
            raise ValueError(f"row has no {name!r} (expected {what})")
        if not ok(row[name]):
            raise ValueError(f"row {name!r}: expected {what}, got {json.dumps(_encode(row[name]))}")
        return row[name]

    need("scenario", lambda v: v in (scenario, Path(scenario).stem), f"{json.dumps(scenario)} as in its key")
    need("controller", lambda v: v == controller, f"{json.dumps(controller)} as in its key")
    need("seed", lambda v: _is_int(v) and v == seed, f"{seed} as in its key")
    need("success", lambda v: isinstance(v, bool), "true or false")
    need("reason", lambda v: isinstance(v, str), "a string")
    given = {k.strip(): v.strip() for k, _, v in (item.partition("=") for item in items)}
    if is_error(row):
        need("success", lambda v: v is False, "false in a row whose run raised")
        need("error", lambda v: isinstance(v, str), "a string")
        need("mismatch", lambda v: v == given, f"{json.dumps(given)} as in its key")
        return
    for name in _INT_FIELDS:
        need(name, lambda v: _is_int(v) and v >= 0, "a whole number >= 0")
    for name in _FLOAT_FIELDS:
        need(name, _is_number, "a number")
    need("min_clearance_m", lambda v: v is None or _is_number(v), "a number or null")
    for name, stats in _TIMING_KEYS.items():
        need(name, lambda v, stats=stats: isinstance(v, dict) and all(_is_number(v.get(s)) for s in stats),
             f"an object with numbers {', '.join(stats)}")
    try:
        want = _round_trip(parse_mismatch(list(items)).changed())
    except MismatchError:
        want = None
    need("mismatch", lambda v: isinstance(v, dict) and v == want, f"{json.dumps(want)} as its key's mismatch gives")


def read_journal(path: Path) -> dict[str, dict[str, Any]]:
    """The rows of a journal by :func:`job_key` (a later line for a key replaces an earlier one).

    Every row is checked (:func:`check_row`) as it is read. A last line cut short (the process
    was killed while writing it) is ignored.

    Raises:
        JournalError: the file cannot be read, or a line (other than a cut-short last one) is
            not a journal entry or holds a bad row: ``"PATH:LINE: what is wrong"``.
    """
    return _read_journal(path)[0]


def _read_journal(path: Path) -> tuple[dict[str, dict[str, Any]], dict[str, int]]:
    """:func:`read_journal` plus the line number (1-based) of each key's row."""
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        return {}, {}
    except (OSError, UnicodeDecodeError) as exc:
        raise JournalError(f"{path}: cannot read the journal ({exc})") from None
    rows: dict[str, dict[str, Any]] = {}
    where: dict[str, int] = {}
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            entry = loads(line)
            if not isinstance(entry, dict) or set(entry) != {"key", "row"} or not isinstance(entry["key"], str):
                raise TypeError
        except (ValueError, TypeError):
            if i == len(lines) - 1:
                break  # a last line cut short
            raise JournalError(f"{path}:{i + 1}: not a journal line (expected {{\"key\": ..., \"row\": ...}})") from None
        try:
            check_row(entry["key"], entry["row"])
        except ValueError as exc:
            raise JournalError(f"{path}:{i + 1}: {exc}") from None
        rows[entry["key"]] = entry["row"]
        where[entry["key"]] = i + 1
    return rows, where


class _Journal:
    """Append-only JSON-lines writer; every line is flushed and synced before the next job counts."""

    def __init__(self, path: Path, keep: dict[str, dict[str, Any]]) -> None:
        # rewrite the kept entries first (drops a cut-short last line), atomically
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w") as fh:
            fh.writelines(dumps({"key": key, "row": row}) + "\n" for key, row in keep.items())
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        self._fh = open(path, "a")  # noqa: SIM115 - open for the whole campaign, closed by close()

    def append(self, key: str, row: dict[str, Any]) -> None:
        self._fh.write(dumps({"key": key, "row": row}) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()


# --------------------------------------------------------------------------- executors

class Executor:
    """Where the jobs of :func:`run_jobs` run: submit a job, wait for finished ones, stop.

    ``submit(job)`` returns a handle; ``wait(handles)`` blocks until at least one of them has
    finished and returns ``[(handle, row)]`` for the finished ones (a row is the runner's
    result, or an :func:`error_row` when it raised); ``stop()`` drops everything in flight at
    once (Ctrl-C); ``close()`` shuts down after the last job. ``slots`` is how many jobs
    :func:`run_jobs` keeps in flight.
    """

    slots: int = 1

    def submit(self, job: Job) -> Any:  # pragma: no cover - interface
        raise NotImplementedError

    def wait(self, handles: list[Any]) -> list[tuple[Any, dict[str, Any]]]:  # pragma: no cover - interface
        raise NotImplementedError

    def stop(self) -> None:
        """Drop the jobs in flight now."""

    def close(self) -> None:
        """Shut down after the last job."""


class _InProcess(Executor):
    """Runs each job in this process when it is submitted."""

    slots = 1

    def __init__(self, runner: Callable[[Job], dict[str, Any]]) -> None:
        self._runner = runner
        self._done: dict[int, dict[str, Any]] = {}
        self._n = 0

    def submit(self, job: Job) -> int:
        try:
            row = self._runner(job)
        except Exception as exc:  # noqa: BLE001 - a failing run is a row, not the end of the campaign
            row = error_row(job, exc)
        self._n += 1
        self._done[self._n] = row
        return self._n

    def wait(self, handles):
        return [(h, self._done.pop(h)) for h in handles]


class _Pool(Executor):
    """A :class:`ProcessPoolExecutor` of ``workers`` processes (replaced when one dies)."""

    def __init__(self, runner: Callable[[Job], dict[str, Any]], workers: int, slots: int | None = None) -> None:
        self._runner = runner
        self._workers = workers
        self.slots = slots or 2 * workers
        self._pool = self._new_pool()
        self._jobs: dict[Future, Job] = {}

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self._workers, initializer=_init_worker)

    def submit(self, job: Job) -> Future:
        try:
            fut = self._pool.submit(self._runner, job)
        except BrokenProcessPool:  # a worker died earlier: go on with a new pool
            _stop_pool(self._pool)
            self._pool = self._new_pool()
            fut = self._pool.submit(self._runner, job)
        self._jobs[fut] = job
        return fut

    def wait(self, handles):
        done, _ = futures_wait(handles, return_when=FIRST_COMPLETED)
        out = []
        for fut in done:
            job = self._jobs.pop(fut)
            try:
                row = fut.result()
            except BrokenProcessPool as exc:
                row = error_row(job, RuntimeError(f"a worker process died ({exc})"))
            except Exception as exc:  # noqa: BLE001 - as above
                row = error_row(job, exc)
            out.append((fut, row))
        return out

    def stop(self) -> None:
        _stop_pool(self._pool)

    def close(self) -> None:
        self._pool.shutdown(wait=True)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel what has not started and stop the workers now (their current runs are dropped)."""
    # the worker processes (a private attribute: Python < 3.14 has no public way to stop them;
    # shutdown() forgets them, so take them first)
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        try:
            proc.terminate()
        except (OSError, AttributeError, ValueError):
            pass
    for proc in procs:
        try:
            proc.join(timeout=5)
        except (OSError, AttributeError, AssertionError, ValueError):
            pass


# --------------------------------------------------------------------------- the campaign loop

def _check_resume(jobs: Iterable[Job], done: dict[str, dict[str, Any]], where: dict[str, int], journal: Path) -> None:
    """Before any job runs: every journalled row belongs to a job of ``jobs`` and carries that
    job's tags. One pass over ``jobs`` that keeps nothing but the count of matched keys."""
    matched: set[str] = set()
    for job in jobs:
        key = job_key(job)
        row = done.get(key)
        if row is None:
            continue
        matched.add(key)
        for name, value in job.tags:
            want = _round_trip({"v": value})["v"]
            if name not in row or row[name] != want:
                got = json.dumps(_encode(row.get(name))) if name in row else "nothing"
                raise JournalError(f"{journal}:{where[key]}: row {name!r}: expected {json.dumps(_encode(want))} "
                                   f"as its job has, got {got}; the journal was written for other settings")
    if len(matched) != len(done):
        first = min(set(done) - matched, key=lambda k: where[k])
        raise JournalError(f"{journal}:{where[first]}: holds {len(done) - len(matched)} run(s) that are not part of "
                           f"this campaign (e.g. {first}); it was written for other settings")


def run_jobs(
    jobs: Iterable[Job],
    workers: int = 2,
    desc: str = "runs",
    *,
    journal: Path | None = None,
    resume: bool = False,
    runner: Callable[[Job], dict[str, Any]] | None = None,
    total: int | None = None,
    executor: Executor | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run ``jobs`` on ``workers`` processes (1: in this process), with a tqdm progress bar.

    The jobs are taken from ``jobs`` lazily, only as far as there is room in flight (the
    executor's ``slots``, 2 x workers for the process pool): a campaign of any size starts at
    once and holds only the jobs in flight plus the rows already finished.

    Args:
        jobs: the campaign, an iterable of :class:`Job`. With ``resume`` and a non-empty
            journal it is iterated twice (once to check the journal before any job runs),
            so pass a re-iterable (a list, :class:`JobSet`), not a one-shot iterator. Two
            jobs with the same :func:`job_key` are not allowed with a journal.
        workers: worker processes (<= 1 runs in this process); ignored with ``executor``.
        desc: progress-bar label.
        journal: JSON-lines file that receives each finished row as it arrives (None: none).
        resume: keep the rows already in ``journal`` for the jobs of this campaign and run
            only the others (and those whose journalled row is an error row). Every row of
            the journal is checked (:func:`check_row`, and the tags of its job) before any
            job runs.
        runner: the function that runs one job (module level, so workers can import it);
            None: :func:`run_job`.
        total: jobs in the campaign, for the progress bar and :class:`CampaignInterrupted`
            (default ``len(jobs)`` when it has one).
        executor: where the jobs run (e.g. :class:`sanav_mj.eval.ray_runner.RayExecutor`);
            None: a process pool of ``workers`` (or this process).
        on_row: called with each row, in the order of ``jobs``, as soon as it and every
            row before it are finished; the rows are then not kept (a campaign's memory
            does not grow with its size) and none is returned. Rows finished ahead of an
            earlier one wait for it, at most :data:`REORDER_WINDOW` x the executor's slots:
            no job further ahead is started until the earlier one finishes.

    Returns:
        One row per job, in the order of ``jobs`` (none with ``on_row``): the run JSON
        without trace plus the tags, or an :func:`error_row` when the run raised. Rows have
        been through a JSON round trip.

    Raises:
        JournalError: with ``resume``, the journal cannot be read, holds a bad row (message
            ``PATH:LINE: ...``) or runs that are not jobs of this campaign (written for
            other settings); or two jobs share a key.
        CampaignInterrupted: Ctrl-C; the rows finished so far are in the journal.
    """
    runner = run_job if runner is None else runner
    if total is None:
        total = len(jobs) if isinstance(jobs, Sized) else None
    done: dict[str, dict[str, Any]] = {}
    if journal is not None and resume:
        done, where = _read_journal(journal)
        if done:
            if iter(jobs) is jobs:
                raise TypeError("run_jobs: resume needs a re-iterable jobs (a list or JobSet), got an iterator")
            _check_resume(jobs, done, where, journal)
        done = {k: r for k, r in done.items() if not is_error(r)}
    writer = _Journal(journal, done) if journal is not None else None
    saved = len(done)
    rows: list[dict[str, Any]] = []
    emit = rows.append if on_row is None else on_row
    ahead: dict[int, dict[str, Any]] = {}  # rows finished before an earlier one, by job index
    emitted = 0  # jobs whose row went to ``emit``
    taken = 0  # jobs taken from ``jobs``
    # the duplicate-key check keeps every key; a JobSet whose keys are distinct by
    # construction skips it (its memory would grow with the campaign)
    seen: set[str] | None = None if getattr(jobs, "distinct", False) else set()
    bar = tqdm(total=total, desc=desc, unit="run", dynamic_ncols=True)
    owned = executor is None
    if executor is None:
        executor = _InProcess(runner) if workers <= 1 else _Pool(runner, workers)
    in_flight: dict[Any, tuple[int, str]] = {}
    source = iter(jobs)
    window = REORDER_WINDOW * max(int(executor.slots), 1)

    def deliver(i: int, row: dict[str, Any]) -> None:
        nonlocal emitted
        ahead[i] = row
        while emitted in ahead:
            emit(ahead.pop(emitted))
            emitted += 1

    def finish(i: int, key: str, row: dict[str, Any]) -> None:
        nonlocal saved
        row = _round_trip(row)
        if writer is not None:
            writer.append(key, row)
            saved += 1
        bar.update()
        deliver(i, row)

    try:
        try:
            exhausted = False
            while True:
                while not exhausted and len(in_flight) < executor.slots and taken - emitted < window:
                    job = next(source, None)
                    if job is None:
                        exhausted = True
                        break
                    key = job_key(job)
                    if journal is not None and seen is not None:
                        if key in seen:
                            raise JournalError(f"jobs: two jobs with the same scenario, controller, seed, mismatch "
                                               f"and time limit ({key})")
                        seen.add(key)
                    i = taken
                    taken += 1
                    kept = done.pop(key, None)
                    if kept is not None:
                        bar.update()
                        deliver(i, kept)
                        continue
                    in_flight[executor.submit(job)] = (i, key)
                if not in_flight:
                    break
                for handle, row in executor.wait(list(in_flight)):
                    i, key = in_flight.pop(handle)
                    finish(i, key, row)
        except BaseException:
            if owned or in_flight:
                executor.stop()
            raise
        if owned:
            executor.close()
    except KeyboardInterrupt:
        raise CampaignInterrupted(saved if writer is not None else 0, total if total is not None else taken,
                                  journal) from None
    finally:
        bar.close()
        if writer is not None:
            writer.close()
    return rows


@dataclass(frozen=True)
class JobSet:
    """A re-iterable, lazily generated campaign: ``make()`` yields the jobs afresh on each
    iteration, ``size`` is their number (``len``); ``distinct``: the maker guarantees that no
    two jobs share a :func:`job_key`, so :func:`run_jobs` does not keep every key to check it."""

    make: Callable[[], Iterator[Job]]
    size: int
    distinct: bool = False

    def __iter__(self) -> Iterator[Job]:
        return iter(self.make())

    def __len__(self) -> int:
        return self.size


def check_meta(path: Path, settings: Mapping[str, Any]) -> None:
    """Refuse to resume a campaign folder written for other settings.

    Args:
        path: the folder's ``meta.json``.
        settings: the settings of this campaign that decide its jobs and results (e.g.
            command, scenarios, controllers, runs, time limit, sweep, fixed mismatch); each
            must equal the value stored in ``path`` (JSON-normalised; missing counts as None).

    Raises:
        JournalError: ``path`` is missing or unreadable, or a setting differs (the message
            names the first one and both values).
    """
    try:
        stored = json.loads(path.read_text())
    except FileNotFoundError:
        raise JournalError(f"{path}: missing, so the journal beside it cannot be checked; run without --resume") from None
    except (OSError, ValueError) as exc:
        raise JournalError(f"{path}: cannot read ({exc})") from None
    if not isinstance(stored, dict):
        raise JournalError(f"{path}: expected a JSON object")
    for key, value in settings.items():
        want = _round_trip({"v": value})["v"]
        if stored.get(key) != want:
            raise JournalError(f"--resume: {path.parent} was run with {key}={json.dumps(stored.get(key))}, "
                               f"this command has {key}={json.dumps(want)}; use another --out or drop --resume")
