"""``sanav-mj bench``: pooled statistics, the summary, the Markdown table and a tiny real campaign."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from sanav_mj.eval.bench import TABLE_HEADER, markdown_table, pooled, run_bench, summarise


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
