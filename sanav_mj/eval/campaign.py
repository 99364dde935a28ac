"""Run many independent episodes in worker processes with a progress bar.

Shared by ``bench`` and ``robustness``: a job is a small picklable :class:`Job`; each worker
process loads (and caches) scenarios and their maps once, runs its jobs and returns the
JSON summaries without the trace (traces stay in the worker unless asked for).
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from tqdm import tqdm


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


def run_jobs(jobs: Iterable[Job], workers: int = 2, desc: str = "runs") -> list[dict[str, Any]]:
    """Run ``jobs`` on ``workers`` processes (1: in this process), with a tqdm progress bar.

    Returns the result rows in the order of ``jobs``.
    """
    jobs = list(jobs)
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    bar = tqdm(total=len(jobs), desc=desc, unit="run", dynamic_ncols=True)
    try:
        if workers <= 1:
            for i, job in enumerate(jobs):
                rows[i] = run_job(job)
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker) as pool:
                futures = {pool.submit(run_job, job): i for i, job in enumerate(jobs)}
                for fut in as_completed(futures):
                    rows[futures[fut]] = fut.result()
                    bar.update()
    finally:
        bar.close()
    return [r for r in rows if r is not None]
