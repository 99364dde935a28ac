"""``sanav-mj bench``: pooled statistics, the summary, the Markdown table and a tiny real campaign."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from sanav_mj.eval.bench import (
    TABLE_HEADER,
    markdown_table,
    pooled,
    run_bench,
    summarise,
)


def _row(samples_solve, samples_pipe, **kw):
    """A results row as :func:`sanav_mj.eval.bench.flatten` makes it, from raw per-step samples."""
    a, b = np.asarray(samples_solve, float), np.asarray(samples_pipe, float)
    row = {
        "scenario": "s", "controller": "c", "seed": 0, "success": True, "reason": "goal",
        "steps": len(a), "collisions": 0,
        "solve_mean_ms": a.mean() if len(a) else 0.0, "solve_max_ms": a.max() if len(a) else 0.0,
        "solve_std_ms": a.std() if len(a) else 0.0,
        "pipeline_mean_ms": b.mean() if len(b) else 0.0, "pipeline_max_ms": b.max() if len(b) else 0.0,
        "pipeline_std_ms": b.std() if len(b) else 0.0,
    }
    row.update(kw)
    return row


def test_pooled_equals_the_statistics_of_the_concatenated_samples():
    rng = np.random.default_rng(3)
    runs = [rng.gamma(2.0, 5.0, n) for n in (1, 7, 40, 123)]
    pipes = [r + rng.uniform(0, 3, len(r)) for r in runs]
    rows = [_row(r, p) for r, p in zip(runs, pipes)]
    rows.append(_row([], []))  # a run without steps (e.g. no_path) carries no samples
    for prefix, samples in (("solve", runs), ("pipeline", pipes)):
        allv = np.concatenate(samples)
        mean, mx, std = pooled(rows, prefix)
        assert mean == pytest.approx(allv.mean(), rel=1e-12)
        assert mx == allv.max()
        assert std == pytest.approx(allv.std(), rel=1e-9)


def test_pooled_known_answer_and_empty():
    # run A: samples 1, 3 (mean 2, std 1); run B: sample 5 -> pooled 1, 3, 5: mean 3, std sqrt(8/3)
    rows = [_row([1.0, 3.0], [1.0, 3.0]), _row([5.0], [5.0])]
    mean, mx, std = pooled(rows, "solve")
    assert (mean, mx) == (3.0, 5.0)
    assert std == pytest.approx(np.sqrt(8.0 / 3.0), rel=1e-12)
    assert pooled([_row([], [])], "solve") == (0.0, 0.0, 0.0)


def test_summarise_known_answers():
    rows = [
        _row([2.0, 2.0], [3.0, 3.0], scenario="a", controller="x", steps=2),
        _row([4.0, 4.0, 4.0, 4.0], [5.0] * 4, scenario="a", controller="x", success=False, reason="stuck", collisions=0),
        _row([1.0] * 6, [1.0] * 6, scenario="a", controller="x", success=True, reason="goal"),
        _row([9.0], [9.0], scenario="b", controller="x", success=False, reason="collision", collisions=3),
        _row([1.0, 1.0], [1.0, 1.0], scenario="a", controller="y"),
    ]
    out = summarise(rows)
    assert [(s["scenario"], s["controller"]) for s in out] == [("a", "x"), ("b", "x"), ("a", "y")]
    ax = out[0]
    assert ax["runs"] == 3
    assert ax["success_rate"] == pytest.approx(200.0 / 3.0)
    assert ax["steps"] == 4.0  # mean over the two successful runs: (2 + 6) / 2
    assert ax["solve_mean_ms"] == pytest.approx((2 * 2 + 4 * 4 + 6 * 1) / 12)
    assert ax["solve_max_ms"] == 4.0
    assert ax["collision_runs"] == 0 and ax["collision_rate"] == 0.0
    assert ax["reasons"] == "goal 2, stuck 1"
    bx = out[1]
    assert bx["steps"] is None and bx["success_rate"] == 0.0
    assert bx["collision_runs"] == 1 and bx["collision_rate"] == 100.0
    assert bx["reasons"] == "collision 1"


def test_markdown_table_shape():
    rows = [_row([1.0, 2.0], [2.0, 3.0], scenario=s, controller=c) for s in ("a", "b") for c in ("x", "y", "z")]
    rows[0].update(success=False, reason="timeout")
    rows[1].update(success=False, reason="stuck")
    rows[5].update(collisions=2)
    text = markdown_table(summarise(rows))
    lines = text.splitlines()
    assert text.endswith("\n") and len(lines) == 2 + 6
    cells = [line.strip("|").split("|") for line in lines]
    assert all(len(c) == len(TABLE_HEADER) for c in cells)
    assert [c.strip() for c in cells[0]] == list(TABLE_HEADER)
    assert set(lines[1]) <= set("|-")
    first = [c.strip() for c in cells[2]]
    assert first[:3] == ["a", "x", "1"]
    assert first[3] == "1.50 / 2.00 / 0.50" and first[4] == "2.50 / 3.00 / 0.50"
    assert first[5] == "-" and first[6] == "0" and first[7] == "0" and first[8] == "timeout 1"
    last = [c.strip() for c in cells[-1]]
    assert last[:2] == ["b", "z"] and last[5] == "2" and last[6] == "100" and last[7] == "1"


def test_tiny_real_bench_writes_the_three_outputs(tmp_path):
    summary = run_bench(["single_rect"], ["dwa", "dqn"], runs=1, workers=1, out=tmp_path, time_limit_s=20.0)
    assert [(s["scenario"], s["controller"], s["runs"]) for s in summary] == [
        ("single_rect", "dwa", 1), ("single_rect", "dqn", 1)
    ]
    with open(tmp_path / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["scenario"], r["controller"], r["seed"]) for r in rows] == [
        ("single_rect", "dwa", "0"), ("single_rect", "dqn", "0")
    ]
    for r in rows:
        assert int(r["steps"]) > 0 and r["reason"] in {"goal", "collision", "timeout", "stuck"}
        assert float(r["solve_max_ms"]) >= float(r["solve_mean_ms"]) > 0.0
    table = (tmp_path / "table.md").read_text().splitlines()
    assert len(table) == 4 and table[2].startswith("| single_rect | dwa | 1 |") and "| dqn |" in table[3]
    png = (tmp_path / "success.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["controllers"] == ["dwa", "dqn"] and meta["seeds"] == [0] and meta["wall_time_s"] > 0


# --------------------------------------------------------------------------- journal, resume, runs that raise


def _fake_doc(job):
    """A run document that is a known function of the job (no simulation); seed 1 of dwa raises."""
    if job.controller == "dwa" and job.seed == 1:
        raise RuntimeError("solver exploded\nbadly")
    k = job.seed + (10 if job.controller == "dwa" else 0)
    stats = {"mean": 1.0 + 0.1 * k, "max": 2.0 + k, "std": 0.5, "p50": 1.0, "p99": 2.0}
    return {
        "scenario": job.scenario, "controller": job.controller, "seed": job.seed, "success": k % 3 != 2,
        "reason": "goal" if k % 3 != 2 else "stuck", "steps": 10 + k, "sim_time_s": 1.0 + k, "path_length_m": 2.0,
        "min_clearance_m": 0.1 + 0.01 * k, "collisions": 0, "safe_area_violations": 0, "solver_failures": 0,
        "solve_ms": stats, "pipeline_ms": stats, "mismatch": {},
    }


@pytest.fixture
def fake_runs(monkeypatch):
    """Replace the simulation by :func:`_fake_doc`; returns the list of jobs whose run finished."""
    from sanav_mj.eval import campaign

    finished = []
    state = {"interrupt_at": None, "calls": 0}

    def run(job):
        state["calls"] += 1
        if state["calls"] == state["interrupt_at"]:
            raise KeyboardInterrupt
        doc = _fake_doc(job)
        finished.append((job.scenario, job.controller, job.seed))
        return doc

    monkeypatch.setattr(campaign, "run_job", run)
    return finished, state


OUTPUTS = ("results.csv", "table.md", "success.png")


def test_resume_runs_no_job_twice_and_equals_an_uninterrupted_bench(tmp_path, fake_runs):
    from sanav_mj.eval.campaign import CampaignInterrupted, read_journal

    finished, state = fake_runs
    args = (["single_rect", "u_shape"], ["sa-mpc", "dwa"], 3)
    whole = run_bench(*args, workers=1, out=tmp_path / "whole")
    assert len(finished) == 2 * 2 * 3 - 2  # dwa seed 1 raises in both scenarios
    finished.clear()

    state.update(calls=0, interrupt_at=6)
    out = tmp_path / "resumed"
    with pytest.raises(CampaignInterrupted) as info:
        run_bench(*args, workers=1, out=out)
    assert (info.value.saved, info.value.total) == (5, 12)
    assert len(read_journal(out / "runs.jsonl")) == 5
    assert not (out / "results.csv").exists()
    assert json.loads((out / "meta.json").read_text())["wall_time_s"] is None  # written before the runs
    first = list(finished)

    state.update(calls=0, interrupt_at=None)
    resumed = run_bench(*args, workers=1, out=out, resume=True)
    # no finished run ran again (the one that raised is run again, and raises again)
    assert len(finished) == len(set(finished)) == len(first) + 6
    assert resumed == whole
    for name in OUTPUTS:
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes(), name
    meta = json.loads((out / "meta.json").read_text())
    assert len(meta["earlier_sessions"]) == 1 and meta["earlier_sessions"][0]["wall_time_s"] is None


def test_runs_that_raise_are_rows_counted_apart(tmp_path, fake_runs):
    summary = run_bench(["single_rect"], ["dwa"], 5, workers=1, out=tmp_path)
    (s,) = summary
    assert (s["runs"], s["errors"]) == (4, 1)
    # seeds 0, 2, 3, 4 (k = 10, 12, 13, 14): goal, goal, goal, stuck; seed 1 is not a failure of dwa
    assert s["success_rate"] == 75.0 and s["reasons"] == "goal 3, stuck 1"
    assert s["steps"] == (20 + 22 + 23) / 3
    with open(tmp_path / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    bad = rows[1]
    assert (bad["seed"], bad["success"], bad["reason"]) == ("1", "False", "error")
    assert bad["error"] == "RuntimeError: solver exploded badly"
    assert bad["steps"] == "" and bad["solve_mean_ms"] == ""
    assert rows[0]["error"] == ""
    table = (tmp_path / "table.md").read_text()
    assert "| single_rect | dwa | 4 (+1 raised) |" in table
    assert "1 run(s) raised an exception" in table


def test_a_pair_whose_runs_all_raise_has_no_rate(tmp_path, fake_runs, monkeypatch):
    from sanav_mj.eval import campaign

    def boom(job):
        raise OSError("disk gone")

    monkeypatch.setattr(campaign, "run_job", boom)
    (s,) = run_bench(["single_rect"], ["dwa"], 2, workers=1, out=tmp_path)
    assert (s["runs"], s["errors"], s["success_rate"], s["collision_rate"]) == (0, 2, None, None)
    assert "| single_rect | dwa | 0 (+2 raised) |" in (tmp_path / "table.md").read_text()
    assert not (tmp_path / "success.png").exists()


def test_resume_refuses_other_settings(tmp_path, fake_runs):
    from sanav_mj.eval.campaign import JournalError

    run_bench(["single_rect"], ["sa-mpc"], 2, workers=1, out=tmp_path)
    before = (tmp_path / "meta.json").read_text()
    for kwargs, fragment in (({"runs": 3}, "runs=2"), ({"controllers": ["dwa"]}, "controllers="),
                             ({"time_limit_s": 30.0}, "time_limit_s=60.0")):
        args = {"scenarios": ["single_rect"], "controllers": ["sa-mpc"], "runs": 2} | kwargs
        with pytest.raises(JournalError, match=fragment):
            run_bench(**args, workers=1, out=tmp_path, resume=True)
    assert (tmp_path / "meta.json").read_text() == before
    # a journal without its meta.json cannot be checked
    (tmp_path / "meta.json").unlink()
    with pytest.raises(JournalError, match="missing"):
        run_bench(["single_rect"], ["sa-mpc"], 2, workers=1, out=tmp_path, resume=True)


# --------------------------------------------------------------------------- streamed, atomic outputs


def _reference_summarise(rows):
    """The summary as the former all-rows-in-memory code computed it (the reference for the streamed one)."""
    import math

    from sanav_mj.eval.campaign import is_error

    def ref_pooled(rs, prefix):
        rs = [r for r in rs if not is_error(r) and int(r["steps"]) > 0]
        n = sum(int(r["steps"]) for r in rs)
        if n == 0:
            return 0.0, 0.0, 0.0
        mean = sum(r[f"{prefix}_mean_ms"] * int(r["steps"]) for r in rs) / n
        second = sum((r[f"{prefix}_std_ms"] ** 2 + r[f"{prefix}_mean_ms"] ** 2) * int(r["steps"]) for r in rs) / n
        return mean, max(r[f"{prefix}_max_ms"] for r in rs), math.sqrt(max(second - mean**2, 0.0))

    groups = {}
    for r in rows:
        groups.setdefault((r["scenario"], r["controller"]), []).append(r)
    out = []
    for (scenario, controller), all_rows in groups.items():
        rs = [r for r in all_rows if not is_error(r)]
        sm, sx, ss = ref_pooled(rs, "solve")
        pm, px, ps = ref_pooled(rs, "pipeline")
        ok = [r for r in rs if r["success"]]
        collided = sum(int(r["collisions"]) > 0 for r in rs)
        counts = {}
        for r in rs:
            counts[r["reason"]] = counts.get(r["reason"], 0) + 1
        out.append({
            "scenario": scenario, "controller": controller, "runs": len(rs),
            "solve_mean_ms": sm, "solve_max_ms": sx, "solve_std_ms": ss,
            "pipeline_mean_ms": pm, "pipeline_max_ms": px, "pipeline_std_ms": ps,
            "steps": (sum(r["steps"] for r in ok) / len(ok)) if ok else None,
            "success_rate": 100.0 * len(ok) / len(rs) if rs else None,
            "collision_runs": collided, "collision_rate": 100.0 * collided / len(rs) if rs else None,
            "reasons": ", ".join(f"{k} {v}" for k, v in sorted(counts.items())),
            "errors": len(all_rows) - len(rs),
        })
    return out


def test_running_sum_is_the_builtin_sum_bit_for_bit():
    from sanav_mj.eval.bench import RunningSum

    rng = np.random.default_rng(5)
    for _ in range(200):
        xs = (rng.standard_normal(rng.integers(0, 60)) * 10.0 ** rng.integers(-8, 9, size=1)).tolist()
        xs += [1e16, 1.0, -1e16][: rng.integers(0, 4)]  # cancellation, where compensation matters
        acc = RunningSum()
        for x in xs:
            acc.add(x)
        assert acc.value == sum(xs) and repr(acc.value) == repr(sum(xs))


def test_the_streamed_summary_equals_the_all_rows_one_exactly():
    from sanav_mj.eval.bench import BenchSummary

    rng = np.random.default_rng(7)
    rows = []
    for i in range(400):
        steps = int(rng.integers(0, 300)) if i % 17 else 0
        r = {"scenario": f"s{rng.integers(3)}", "controller": f"c{rng.integers(2)}", "seed": i,
             "success": bool(rng.random() < 0.6), "reason": str(rng.choice(["goal", "stuck", "collision"])),
             "steps": steps, "collisions": int(rng.integers(0, 3))}
        for p in ("solve", "pipeline"):
            r.update({f"{p}_mean_ms": float(rng.gamma(2.0, 3.0)), f"{p}_max_ms": float(rng.gamma(5.0, 9.0)),
                      f"{p}_std_ms": float(rng.gamma(1.0, 1.0))})
        if i % 23 == 5:  # a run that raised: no metrics
            r = {"scenario": r["scenario"], "controller": r["controller"], "seed": i, "success": False,
                 "reason": "error", "error": "RuntimeError: x"}
        rows.append(r)
    acc = BenchSummary()
    for r in rows:
        acc.add(r)
    streamed, reference = acc.rows(), _reference_summarise(rows)
    assert streamed == reference and repr(streamed) == repr(reference)  # the same floats, bit for bit
    assert markdown_table(streamed) == markdown_table(reference)


def _left(folder):
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize("name", ["results.csv", "table.md"])
def test_an_output_cut_by_a_full_disk_is_named_and_the_others_are_written(tmp_path, fake_runs, fill_disk, name):
    fill_disk(keep=300, ending=name)
    with pytest.raises(OSError) as info:
        run_bench(["single_rect"], ["sa-mpc", "dwa"], 6, workers=1, out=tmp_path)
    assert info.value.filename == str(tmp_path / name) and "No space left on device" in str(info.value)
    others = {"meta.json", "results.csv", "runs.jsonl", "success.png", "table.md"} - {name}
    assert _left(tmp_path) == sorted(others)  # no cut file, no temporary file
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["wall_time_s"] > 0  # the final meta.json, written after the failure
    if name != "results.csv":
        assert len((tmp_path / "results.csv").read_text().splitlines()) == 1 + 12


def test_meta_json_before_the_runs_is_written_whole_or_not_at_all(tmp_path, fake_runs, fill_disk):
    finished, _ = fake_runs
    fill_disk(keep=100, ending="meta.json")
    with pytest.raises(OSError) as info:
        run_bench(["single_rect"], ["sa-mpc"], 2, workers=1, out=tmp_path)
    assert info.value.filename == str(tmp_path / "meta.json")
    assert _left(tmp_path) == [] and finished == []  # nothing ran, nothing half-written


def test_ctrl_c_mid_campaign_leaves_no_partial_output(tmp_path, fake_runs):
    from sanav_mj.eval.campaign import CampaignInterrupted

    _, state = fake_runs
    state.update(interrupt_at=5)
    with pytest.raises(CampaignInterrupted):
        run_bench(["single_rect"], ["sa-mpc"], 8, workers=1, out=tmp_path)
    assert _left(tmp_path) == ["meta.json", "runs.jsonl"]  # results.csv was being written: gone, no .part


def test_a_full_disk_in_the_cli_is_exit_2_naming_the_file(tmp_path, fake_runs, fill_disk, capsys):
    from sanav_mj.cli import main

    fill_disk(keep=200, ending="results.csv")
    code = main(["bench", "single_rect", "--controllers", "sa-mpc", "--runs", "3", "--workers", "1",
                 "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.endswith(f"sanav-mj: error: {tmp_path / 'results.csv'}: No space left on device\n")
    assert err.splitlines()[-1].startswith("sanav-mj: error:") and "Traceback" not in err  # after the progress bar
    assert "results.csv" not in _left(tmp_path) and "table.md" in _left(tmp_path)
