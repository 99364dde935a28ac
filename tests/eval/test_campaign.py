"""``run_jobs``: the journal, resuming, runs that raise and Ctrl-C, with tiny fake jobs (no simulation)."""

from __future__ import annotations

import json
import math
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
from sanav_mj.sim.mismatch import parse_mismatch


def fake_run(job: Job) -> dict:
    """A run document that is a known function of the job; seed 3 raises (module level: workers import it)."""
    if job.seed == 3:
        raise ValueError(f"bad seed\n{job.seed}")
    return {**_metrics(job), "success": job.seed % 2 == 0, "reason": "goal" if job.seed % 2 == 0 else "stuck",
            "steps": 10 + job.seed, "pid": os.getpid(), **dict(job.tags)}


def _metrics(job: Job) -> dict:
    """The fields every run row has (see check_row), with values that are a function of the job."""
    stats = {"mean": 1.0, "max": 2.0, "std": 0.5, "p50": 1.0, "p99": 2.0}
    return {"scenario": job.scenario, "controller": job.controller, "seed": job.seed, "success": True,
            "reason": "goal", "steps": 10, "sim_time_s": 1.0, "path_length_m": 2.0 + job.seed,
            "min_clearance_m": 0.1, "collisions": 0, "safe_area_violations": 0, "solver_failures": 0,
            "solve_ms": stats, "pipeline_ms": stats,
            "mismatch": parse_mismatch(list(job.mismatch)).changed()}


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


def test_ctrl_c_with_workers_stops_the_pool_and_keeps_the_finished_rows(tmp_path, ctrl_c_after):
    """Ctrl-C arrives in the parent (here: from the progress bar after the second row)."""
    ctrl_c_after(2)
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


# --------------------------------------------------------------------------- journal rows are checked before any run

def _journal_of(tmp_path, n=4):
    journal = tmp_path / "runs.jsonl"
    run_jobs(_jobs(n), workers=1, journal=journal, runner=fake_run)
    return journal, [json.loads(line) for line in journal.read_text().splitlines()]


def _write(journal, entries):
    journal.write_text("".join(json.dumps(e) + "\n" for e in entries) + '{"key": "cut')  # a cut last line too


def _edit(entry, **changes):
    row = dict(entry["row"])
    for k, v in changes.items():
        if v is KeyError:
            row.pop(k)
        else:
            row[k] = v
    return {"key": entry["key"], "row": row}


@pytest.mark.parametrize("changes, fragment", [
    ({"steps": KeyError}, "row has no 'steps'"),
    ({"min_clearance_m": KeyError}, "row has no 'min_clearance_m'"),
    ({"steps": "12"}, "row 'steps': expected a whole number >= 0, got \"12\""),
    ({"success": 1}, "row 'success': expected true or false, got 1"),
    ({"solve_ms": {"mean": 1.0}}, "row 'solve_ms': expected an object with numbers mean, max, std, p50, p99"),
    ({"seed": 7}, "row 'seed': expected 2 as in its key, got 7"),
    ({"controller": "mpc"}, "row 'controller': expected \"dwa\" as in its key"),
    ({"mismatch": {"mass": 2.0}}, "row 'mismatch': expected {\"mass\": 1.5} as its key's mismatch gives"),
    ({"cell": [0, 0]}, "row 'cell': expected [2, 0] as its job has, got [0, 0]"),
])
def test_resume_refuses_a_bad_row_naming_its_line_before_any_run(tmp_path, changes, fragment):
    journal, entries = _journal_of(tmp_path)
    entries[2] = _edit(entries[2], **changes)
    _write(journal, entries)
    calls = []
    with pytest.raises(JournalError) as err:
        run_jobs(_jobs(6), workers=1, journal=journal, resume=True, runner=lambda j: calls.append(j) or fake_run(j))
    assert str(err.value).startswith(f"{journal}:3: ") and fragment in str(err.value)
    assert "\n" not in str(err.value)
    assert calls == []  # nothing ran
    assert journal.read_text().endswith('{"key": "cut')  # and the journal is untouched


def test_a_bad_error_row_and_a_bad_key_are_refused(tmp_path):
    journal, entries = _journal_of(tmp_path)
    assert entries[3]["row"]["reason"] == "error"
    _write(journal, entries[:3] + [_edit(entries[3], error=None)])
    with pytest.raises(JournalError, match=r"runs.jsonl:4: row 'error': expected a string"):
        read_journal(journal)
    _write(journal, [{"key": '["single_rect","dwa","0",["mass=1.5"],12.5]', "row": entries[0]["row"]}])
    with pytest.raises(JournalError, match=r"runs.jsonl:1: key .* expected \[str, str, int"):
        read_journal(journal)


def test_nan_is_written_as_strict_json_and_read_back(tmp_path):
    def nan_run(job):
        row = fake_run(job)
        row.update(min_clearance_m=float("nan"), path_length_m=float("inf"))
        row["solve_ms"] = dict(row["solve_ms"], std=float("-inf"))
        return row

    journal = tmp_path / "runs.jsonl"
    jobs = [j for j in _jobs(3) if j.seed != 3]
    rows = run_jobs(jobs, workers=1, journal=journal, runner=nan_run)
    for line in journal.read_text().splitlines():  # strict JSON: no NaN / Infinity tokens
        json.loads(line, parse_constant=lambda name: pytest.fail(f"{name} in the journal"))
    assert '{"$float": "nan"}' in journal.read_text()
    back = read_journal(journal)[job_key(jobs[0])]
    assert math.isnan(back["min_clearance_m"]) and back["path_length_m"] == math.inf
    assert back["solve_ms"]["std"] == -math.inf
    assert math.isnan(rows[0]["min_clearance_m"])
    resumed = run_jobs(jobs, workers=1, journal=journal, resume=True, runner=None)  # nothing left to run
    assert resumed[1]["path_length_m"] == math.inf
    # a journal written before, with bare NaN tokens, still resumes, and is rewritten strictly
    journal.write_text(journal.read_text().replace('{"$float": "nan"}', "NaN"))
    assert "NaN" in journal.read_text()
    assert math.isnan(run_jobs(jobs, workers=1, journal=journal, resume=True, runner=None)[0]["min_clearance_m"])
    assert "NaN" not in journal.read_text() and '{"$float": "nan"}' in journal.read_text()


def test_resume_cli_exit_2_one_line_naming_the_line(tmp_path, monkeypatch, capsys):
    from sanav_mj.cli import main

    stats = {"mean": 1.0, "max": 2.0, "std": 0.5, "p50": 1.0, "p99": 2.0}
    monkeypatch.setattr(campaign, "run_job", lambda job: {**_metrics(job), "solve_ms": stats})
    out = tmp_path / "b"
    assert main(["bench", "single_rect", "--controllers", "dwa", "--runs", "3", "--workers", "1",
                 "--out", str(out)]) == 0
    journal = out / "runs.jsonl"
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    entries[1]["row"]["collisions"] = -1
    _write(journal, entries)
    capsys.readouterr()
    assert main(["bench", "single_rect", "--controllers", "dwa", "--runs", "3", "--workers", "1",
                 "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert err == f"sanav-mj: error: {journal}:2: row 'collisions': expected a whole number >= 0, got -1\n"


# --------------------------------------------------------------------------- lazy jobs, bounded in flight

@pytest.mark.parametrize("workers", [1, 2])
def test_a_huge_lazy_campaign_is_taken_only_as_far_as_it_runs(tmp_path, workers, ctrl_c_after, endless_jobs):
    jobs, taken = endless_jobs(10**12, 12.5)
    ctrl_c_after(5, total=10**12)  # Ctrl-C after the fifth finished row
    with pytest.raises(CampaignInterrupted) as info:
        run_jobs(jobs, workers=workers, journal=tmp_path / "runs.jsonl", runner=fake_plain)
    assert (info.value.saved, info.value.total) == (5, 10**12)
    # in this process one job at a time; with the pool at most 2 x workers in flight beyond the finished
    assert len(taken) <= 5 + (0 if workers == 1 else 2 * workers)


def fake_plain(job: Job) -> dict:
    """A valid run row, no exception (module level: workers import it)."""
    return _metrics(job)


# --------------------------------------------------------------------------- workers die with their parent

_KILL_SCRIPT = r"""
import os, sys, time
from pathlib import Path
from sanav_mj.eval.campaign import Job, run_jobs

def slow(job):
    Path(sys.argv[1], f"{os.getpid()}").write_text("")
    time.sleep(120)
    return {}

if __name__ == "__main__":
    run_jobs([Job("single_rect", "dwa", k) for k in range(8)], workers=2, runner=slow)
"""


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its reaper does not run)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc to see the worker processes")
def test_workers_exit_when_the_parent_is_killed_with_sigkill(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "campaign.py"
    script.write_text(_KILL_SCRIPT)
    pids = tmp_path / "pids"
    pids.mkdir()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [os.getcwd(), os.environ.get("PYTHONPATH")])))
    parent = subprocess.Popen([sys.executable, str(script), str(pids)], env=env, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while len(list(pids.iterdir())) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = [int(p.name) for p in pids.iterdir()]
        assert len(workers) == 2 and all(_alive(p) for p in workers)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in workers if _alive(p)]
    finally:
        parent.kill()
        parent.wait()


# --------------------------------------------------------------------------- streaming rows (on_row)


class _StragglerExecutor(campaign.Executor):
    """Finishes every job at once, in reverse order of submission, except job 0 (seed 0),
    which finishes only when it is the last job in flight: rows arrive out of order."""

    slots = 4

    def __init__(self) -> None:
        self.jobs: dict[int, Job] = {}
        self.submitted = 0
        self.submitted_before_first_done: int | None = None

    def submit(self, job):
        self.submitted += 1
        self.jobs[self.submitted] = job
        return self.submitted

    def wait(self, handles):
        ready = [h for h in handles if self.jobs[h].seed != 0] or handles
        if any(self.jobs[h].seed == 0 for h in ready):
            self.submitted_before_first_done = self.submitted
        return [(h, _metrics(self.jobs.pop(h))) for h in sorted(ready, reverse=True)]


def test_on_row_gets_the_rows_in_job_order_and_none_are_kept(tmp_path):
    jobs = campaign.JobSet(lambda: (Job("single_rect", "dwa", k) for k in range(500)), 500, distinct=True)
    got = []
    ex = _StragglerExecutor()
    kept = run_jobs(jobs, executor=ex, journal=tmp_path / "runs.jsonl", on_row=got.append)
    assert kept == []
    assert [r["seed"] for r in got] == list(range(500))
    assert len(read_journal(tmp_path / "runs.jsonl")) == 500
    # rows finished ahead of the straggler are held at most REORDER_WINDOW x slots: no job
    # further ahead is started (without the window all 500 would run before it finishes)
    assert ex.submitted_before_first_done == campaign.REORDER_WINDOW * ex.slots


def test_on_row_rows_equal_the_returned_rows_also_on_resume(tmp_path):
    jobs = _jobs(8)
    whole = run_jobs(jobs, workers=1, runner=fake_run)
    journal = tmp_path / "runs.jsonl"
    run_jobs(jobs[:5], workers=1, runner=fake_run, journal=journal)
    streamed = []
    assert run_jobs(jobs, workers=1, runner=fake_run, journal=journal, resume=True, on_row=streamed.append) == []
    strip = [{k: v for k, v in r.items() if k != "pid"} for r in whole]
    assert [{k: v for k, v in r.items() if k != "pid"} for r in streamed] == strip


def test_a_distinct_jobset_keeps_no_keys_but_a_plain_one_refuses_duplicates(tmp_path):
    twice = [Job("single_rect", "dwa", 0), Job("single_rect", "dwa", 0)]
    with pytest.raises(JournalError, match="two jobs"):
        run_jobs(campaign.JobSet(lambda: iter(twice), 2), workers=1, runner=fake_run, journal=tmp_path / "a.jsonl")
