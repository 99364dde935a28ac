"""``run_jobs``: the journal, resuming, runs that raise and Ctrl-C, with tiny fake jobs (no simulation)."""

from __future__ import annotations

import json
import os

import pytest

from sanav_mj.eval import campaign
from sanav_mj.eval.campaign import (
    ERROR_REASON,
    CampaignInterrupted,
    Job,
    JournalError,
    check_meta,
    error_row,
    is_error,
    job_key,
    read_journal,
    run_jobs,
)


def fake_run(job: Job) -> dict:
    """A run document that is a known function of the job; seed 3 raises (module level: workers import it)."""
    if job.seed == 3:
        raise ValueError(f"bad seed\n{job.seed}")
    return {"scenario": job.scenario, "controller": job.controller, "seed": job.seed,
            "success": job.seed % 2 == 0, "reason": "goal" if job.seed % 2 == 0 else "stuck",
            "steps": 10 + job.seed, "pid": os.getpid(), **dict(job.tags)}


def _jobs(n=6, **kw):
    return [Job("single_rect", "dwa", k, ("mass=1.5",), 12.5, None, (("cell", (k, 0)),), **kw) for k in range(n)]


def _strip(rows):
    return [{k: v for k, v in r.items() if k != "pid"} for r in rows]


def test_rows_in_job_order_with_the_failure_as_a_row(tmp_path):
    journal = tmp_path / "runs.jsonl"
    rows = run_jobs(_jobs(), workers=1, journal=journal, runner=fake_run)
    assert [r["seed"] for r in rows] == [0, 1, 2, 3, 4, 5]
    bad = rows[3]
    assert is_error(bad) and bad["reason"] == ERROR_REASON and bad["success"] is False
    assert bad["error"] == "ValueError: bad seed 3"  # one line
    assert bad["mismatch"] == {"mass": "1.5"} and bad["cell"] == [3, 0]
    assert [is_error(r) for r in rows].count(True) == 1
    assert rows[0]["cell"] == [0, 0]  # tags after the JSON round trip, as read back from the journal
    # every row is in the journal, keyed by the job
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    assert sorted(e["key"] for e in entries) == sorted(job_key(j) for j in _jobs())
    assert read_journal(journal) == {job_key(j): r for j, r in zip(_jobs(), rows)}


def test_worker_processes_turn_an_exception_into_a_row(tmp_path):
    rows = run_jobs(_jobs(), workers=2, journal=tmp_path / "runs.jsonl", runner=fake_run)
    assert [r["seed"] for r in rows] == [0, 1, 2, 3, 4, 5]
    assert [r["reason"] for r in rows] == ["goal", "stuck", "goal", "error", "goal", "stuck"]
    assert rows[3]["error"] == "ValueError: bad seed 3"
    assert {r["pid"] for r in rows if not is_error(r)} != {os.getpid()}  # ran in workers
    assert len(read_journal(tmp_path / "runs.jsonl")) == 6


def test_job_key_is_the_identity_of_the_run():
    a = Job("u_shape", "sa-mpc", 2, ("delay=1",), 60.0)
    assert job_key(a) == job_key(Job("u_shape", "sa-mpc", 2, ("delay=1",), 60, "x.rrd", (("t", 1),)))
    for other in (Job("v_shape", "sa-mpc", 2, ("delay=1",)), Job("u_shape", "mpc", 2, ("delay=1",)),
                  Job("u_shape", "sa-mpc", 3, ("delay=1",)), Job("u_shape", "sa-mpc", 2, ("delay=2",)),
                  Job("u_shape", "sa-mpc", 2, ("delay=1",), 30.0)):
        assert job_key(other) != job_key(a)


def test_resume_runs_each_job_once_and_equals_an_uninterrupted_campaign(tmp_path, monkeypatch):
    jobs = _jobs(8)
    whole = run_jobs(jobs, workers=1, journal=tmp_path / "whole.jsonl", runner=fake_run)

    calls: list[int] = []

    def counted(job):
        calls.append(job.seed)
        if len(calls) == 5:
            raise KeyboardInterrupt  # Ctrl-C during the fifth run
        return fake_run(job)

    journal = tmp_path / "runs.jsonl"
    with pytest.raises(CampaignInterrupted) as info:
        run_jobs(jobs, workers=1, journal=journal, runner=counted)
    assert (info.value.saved, info.value.total, info.value.journal) == (4, 8, journal)
    assert len(read_journal(journal)) == 4
    assert calls == [0, 1, 2, 3, 4]

    calls.clear()
    resumed = run_jobs(jobs, workers=1, journal=journal, resume=True, runner=lambda j: calls.append(j.seed)
                       or fake_run(j))
    # seed 3 raised in the first session: an error row is run again; 0-2 are not
    assert calls == [3, 4, 5, 6, 7]
    assert _strip(resumed) == _strip(whole)
    assert read_journal(journal).keys() == read_journal(tmp_path / "whole.jsonl").keys()

    # a third session has nothing left but the run that raises again
    calls.clear()
    again = run_jobs(jobs, workers=1, journal=journal, resume=True, runner=lambda j: calls.append(j.seed)
                     or fake_run(j))
    assert calls == [3] and _strip(again) == _strip(whole)


def test_without_resume_the_journal_starts_again(tmp_path):
    journal = tmp_path / "runs.jsonl"
    run_jobs(_jobs(3), workers=1, journal=journal, runner=fake_run)
    run_jobs(_jobs(2), workers=1, journal=journal, runner=fake_run)
    assert len(read_journal(journal)) == 2


def test_resume_refuses_a_journal_of_other_jobs(tmp_path):
    journal = tmp_path / "runs.jsonl"
    run_jobs(_jobs(3), workers=1, journal=journal, runner=fake_run)
    other = [Job("single_rect", "dwa", k, ("mass=2.0",), 12.5) for k in range(3)]
    with pytest.raises(JournalError, match="3 run\\(s\\) that are not part of this campaign"):
        run_jobs(other, workers=1, journal=journal, resume=True, runner=fake_run)
    assert len(read_journal(journal)) == 3  # untouched


def test_duplicate_jobs_are_refused_with_a_journal(tmp_path):
    with pytest.raises(JournalError, match="two jobs"):
        run_jobs(_jobs(2) + _jobs(1), workers=1, journal=tmp_path / "j.jsonl", runner=fake_run)


def test_a_last_line_cut_short_is_dropped_and_a_broken_middle_line_is_an_error(tmp_path):
    journal = tmp_path / "runs.jsonl"
    rows = run_jobs(_jobs(3), workers=1, journal=journal, runner=fake_run)
    text = journal.read_text()
    journal.write_text(text + '{"key": "[\\"single_rect\\",\\"dwa\\",4')  # killed while writing
    assert len(read_journal(journal)) == 3
    resumed = run_jobs(_jobs(4), workers=1, journal=journal, resume=True, runner=fake_run)
    assert _strip(resumed[:3]) == _strip(rows)
    assert all(json.loads(line) for line in journal.read_text().splitlines())  # rewritten cleanly
    journal.write_text("garbage\n" + text)
    with pytest.raises(JournalError, match=":1: not a journal line"):
        read_journal(journal)


def test_ctrl_c_with_workers_stops_the_pool_and_keeps_the_finished_rows(tmp_path, monkeypatch):
    """Ctrl-C arrives in the parent (here: from the progress bar after the second row)."""

    class Bar:
        def __init__(self, *a, **kw):
            self.n = 0

        def update(self, k=1):
            self.n += k
            if self.n == 2:
                raise KeyboardInterrupt

        def close(self):
            pass

    monkeypatch.setattr(campaign, "tqdm", Bar)
    journal = tmp_path / "runs.jsonl"
    jobs = [j for j in _jobs(12) if j.seed != 3]
    with pytest.raises(CampaignInterrupted) as info:
        run_jobs(jobs, workers=2, journal=journal, runner=fake_run)
    assert info.value.saved == 2 and info.value.total == 11
    assert len(read_journal(journal)) == 2
    import multiprocessing

    assert not [p for p in multiprocessing.active_children() if p.is_alive()]  # the workers are gone


def test_error_row_fields():
    row = error_row(Job("u_shape", "mpc", 4, ("delay=1", "friction=0.3"), tags=(("delay", 1.0),)), RuntimeError())
    assert row == {"scenario": "u_shape", "controller": "mpc", "seed": 4, "success": False, "reason": "error",
                   "error": "RuntimeError", "mismatch": {"delay": "1", "friction": "0.3"}, "delay": 1.0}


def test_check_meta(tmp_path):
    meta = tmp_path / "meta.json"
    with pytest.raises(JournalError, match="missing"):
        check_meta(meta, {"runs": 3})
    meta.write_text(json.dumps({"command": "bench", "runs": 3, "sweep": {"mass": [1.0, 2.0]}, "commit": "abc"}))
    check_meta(meta, {"command": "bench", "runs": 3, "sweep": {"mass": [1.0, 2.0]}, "fixed": None})
    with pytest.raises(JournalError) as err:
        check_meta(meta, {"command": "bench", "runs": 5})
    assert str(err.value) == (f"--resume: {tmp_path} was run with runs=3, this command has runs=5; "
                              "use another --out or drop --resume")
    with pytest.raises(JournalError, match="command="):
        check_meta(meta, {"command": "robustness"})
    meta.write_text("{")
    with pytest.raises(JournalError, match="cannot read"):
        check_meta(meta, {})


def dying_run(job: Job) -> dict:
    """Seed 2's worker process dies outright (as on a segfault)."""
    if job.seed == 2:
        os._exit(1)
    return fake_run(job)


def test_a_worker_that_dies_gives_error_rows_not_a_crash(tmp_path):
    jobs = [j for j in _jobs(5) if j.seed != 3]
    rows = run_jobs(jobs, workers=2, journal=tmp_path / "runs.jsonl", runner=dying_run)
    assert [r["seed"] for r in rows] == [0, 1, 2, 4]
    assert is_error(rows[2]) and rows[2]["error"].startswith("RuntimeError: a worker process died")
    # the pool is gone with it: the runs still pending are error rows too (and --resume runs them again)
    assert all(not is_error(r) or "worker process died" in r["error"] for r in rows)
    assert len(read_journal(tmp_path / "runs.jsonl")) == 4
