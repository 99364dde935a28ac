"""Run many independent episodes in worker processes with a progress bar, losing nothing.

Shared by ``bench`` and ``robustness``: a job is a small picklable :class:`Job`; each worker
process loads (and caches) scenarios and their maps once, runs its jobs and returns the
JSON summaries without the trace (traces stay in the worker unless asked for).

Nothing finished is lost:

- **Journal.** With ``journal=PATH`` every finished row is appended to ``PATH`` (one JSON
  line ``{"key": ..., "row": ...}``, flushed and synced) as soon as it arrives.
  ``resume=True`` reads the journal first and runs only the jobs it does not hold (rows
  whose run raised are run again); the rows returned are the journal's plus the new ones
  in the order of the jobs, the same as an uninterrupted campaign (every row, new or
  journalled, goes through one JSON round trip). ``resume=False`` starts a new journal.
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
import os
import signal
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

#: ``reason`` of a row whose run raised (a failure of the tool, not an outcome of the controller)
ERROR_REASON = "error"
#: file name of the journal inside a campaign's output folder
JOURNAL_NAME = "runs.jsonl"


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
    """

    scenario: str
    controller: str
    seed: int
    mismatch: tuple[str, ...] = ()
    time_limit_s: float = 60.0
    rrd: str | None = None
    tags: tuple[tuple[str, Any], ...] = field(default_factory=tuple)


class JournalError(ValueError):
    """A journal that cannot be resumed (unreadable, or written for other settings); one line."""


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
    time limit [s] as compact JSON (the recording path and the tags are not part of it)."""
    return json.dumps([job.scenario, job.controller, int(job.seed), list(job.mismatch), float(job.time_limit_s)],
                      separators=(",", ":"))


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


_PREPARED: dict[str, Any] = {}


def run_job(job: Job) -> dict[str, Any]:
    """Run one job in this process; returns the run JSON without its trace, plus the tags."""
    from sanav_mj.eval.episode import prepare, run_scenario
    from sanav_mj.sim.mismatch import parse_mismatch

    if job.scenario not in _PREPARED:
        _PREPARED[job.scenario] = prepare(job.scenario)
    out = run_scenario(
        _PREPARED[job.scenario],
        controller=job.controller,
        seed=job.seed,
        mismatch=parse_mismatch(list(job.mismatch)),
        time_limit_s=job.time_limit_s,
        rrd=Path(job.rrd) if job.rrd else None,
    )
    doc = {k: v for k, v in out.document.items() if k != "trace"}
    for key, value in job.tags:
        doc[key] = value
    return doc


def _init_worker() -> None:
    # One BLAS / OpenMP thread per worker: the workers are the parallelism.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    # Ctrl-C reaches the whole process group: the parent alone handles it (no worker tracebacks).
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _round_trip(row: dict[str, Any]) -> dict[str, Any]:
    """``row`` as it reads back from the journal (tuples become lists), so new and resumed rows are alike."""
    return json.loads(json.dumps(row))


def read_journal(path: Path) -> dict[str, dict[str, Any]]:
    """The rows of a journal by :func:`job_key` (a later line for a key replaces an earlier one).

    A last line cut short (the process was killed while writing it) is ignored.

    Raises:
        JournalError: a line other than the last is not a journal entry.
    """
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        return {}
    except (OSError, UnicodeDecodeError) as exc:
        raise JournalError(f"{path}: cannot read the journal ({exc})") from None
    rows: dict[str, dict[str, Any]] = {}
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
            key, row = entry["key"], entry["row"]
            if not isinstance(key, str) or not isinstance(row, dict):
                raise TypeError
        except (ValueError, KeyError, TypeError):
            if i == len(lines) - 1:
                break  # a last line cut short
            raise JournalError(f"{path}:{i + 1}: not a journal line (expected {{\"key\": ..., \"row\": ...}})") from None
        rows[key] = row
    return rows


class _Journal:
    """Append-only JSON-lines writer; every line is flushed and synced before the next job counts."""

    def __init__(self, path: Path, keep: dict[str, dict[str, Any]]) -> None:
        # rewrite the kept entries first (drops a cut-short last line), atomically
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w") as fh:
            fh.writelines(json.dumps({"key": key, "row": row}) + "\n" for key, row in keep.items())
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        self._fh = open(path, "a")  # noqa: SIM115 - open for the whole campaign, closed by close()

    def append(self, key: str, row: dict[str, Any]) -> None:
        self._fh.write(json.dumps({"key": key, "row": row}) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()


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


def run_jobs(
    jobs: Iterable[Job],
    workers: int = 2,
    desc: str = "runs",
    *,
    journal: Path | None = None,
    resume: bool = False,
    runner: Callable[[Job], dict[str, Any]] | None = None,
) -> list[dict[str, Any]]:
    """Run ``jobs`` on ``workers`` processes (1: in this process), with a tqdm progress bar.

    Args:
        jobs: the campaign; two jobs with the same :func:`job_key` are not allowed with a journal.
        workers: worker processes (<= 1 runs in this process).
        desc: progress-bar label.
        journal: JSON-lines file that receives each finished row as it arrives (None: none).
        resume: keep the rows already in ``journal`` for the jobs of this campaign and run
            only the others (and those whose journalled row is an error row).
        runner: the function that runs one job (module level, so workers can import it);
            None: :func:`run_job`.

    Returns:
        One row per job, in the order of ``jobs``: the run JSON without trace plus the tags,
        or an :func:`error_row` when the run raised. Rows have been through a JSON round trip.

    Raises:
        JournalError: with ``resume``, the journal cannot be read or holds runs that are not
            jobs of this campaign (written for other settings); or two jobs share a key.
        CampaignInterrupted: Ctrl-C; the rows finished so far are in the journal.
    """
    runner = run_job if runner is None else runner
    jobs = list(jobs)
    keys = [job_key(j) for j in jobs]
    done: dict[str, dict[str, Any]] = {}
    if journal is not None:
        if len(set(keys)) != len(keys):
            raise JournalError("jobs: two jobs with the same scenario, controller, seed, mismatch and time limit")
        if resume:
            done = read_journal(journal)
            foreign = set(done) - set(keys)
            if foreign:
                raise JournalError(f"{journal}: holds {len(foreign)} run(s) that are not part of this campaign "
                                   f"(e.g. {min(foreign)}); it was written for other settings")
            done = {k: r for k, r in done.items() if not is_error(r)}
    rows: list[dict[str, Any] | None] = [done.get(k) for k in keys]
    todo = [i for i, r in enumerate(rows) if r is None]
    writer = _Journal(journal, done) if journal is not None else None
    saved = len(done)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc=desc, unit="run", dynamic_ncols=True)

    def finish(i: int, row: dict[str, Any]) -> None:
        nonlocal saved
        row = _round_trip(row)
        if writer is not None:
            writer.append(keys[i], row)
            saved += 1
        rows[i] = row
        bar.update()

    try:
        if workers <= 1:
            for i in todo:
                try:
                    row = runner(jobs[i])
                except Exception as exc:  # noqa: BLE001 - a failing run is a row, not the end of the campaign
                    row = error_row(jobs[i], exc)
                finish(i, row)
        elif todo:
            pool = ProcessPoolExecutor(max_workers=workers, initializer=_init_worker)
            try:
                futures: dict[Future, int] = {pool.submit(runner, jobs[i]): i for i in todo}
                for fut in as_completed(futures):
                    i = futures[fut]
                    try:
                        row = fut.result()
                    except BrokenProcessPool as exc:
                        row = error_row(jobs[i], RuntimeError(f"a worker process died ({exc})"))
                    except Exception as exc:  # noqa: BLE001 - as above
                        row = error_row(jobs[i], exc)
                    finish(i, row)
            except BaseException:
                _stop_pool(pool)
                raise
            pool.shutdown(wait=True)
    except KeyboardInterrupt:
        raise CampaignInterrupted(saved if writer is not None else 0, len(jobs), journal) from None
    finally:
        bar.close()
        if writer is not None:
            writer.close()
    return [r for r in rows if r is not None]


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
