"""``sanav-mj robustness``: sweep one or two mismatch keys over a grid with several seeds.

Outputs in ``--out``: ``robustness.csv`` (one row per run, with the swept values and the
run's whole mismatch, fixed keys included), ``summary.csv`` (one row per grid point, pooled
over the scenarios: success rate, collision rate, min clearance, reasons), heat maps
``success_rate.png``, ``collision_rate.png``, ``min_clearance.png`` (titled with the
scenario names, the controller and the fixed mismatch); with more than one scenario also
``summary_by_scenario.csv`` (the same per scenario, ``scenario`` column) and
``per_scenario/NAME_success_rate.png`` etc. Integer keys (``delay``) are written as
integers; a quantity with no value (no run of the point ran to an outcome, or no run has a
clearance: a goal with no path) is an empty CSV field and a blank ("n/a") cell, never ``inf``.
Every file is written whole or not at all (:mod:`sanav_mj.outputs`).
``meta.json``: what the folder ran under (scenarios, controller, seeds, time limit, the
sweep, the fixed mismatch, commit, machine, load, wall time; see :func:`run_robustness`)
and ``runs.jsonl``, the journal of finished runs that ``resume=True`` continues from.

A run that raised (a failure of the tool) is a row with reason ``error`` and its message in
the ``error`` column; each grid point counts those in ``errors`` and leaves them out of
``runs`` and of the rates and clearance (a point where every run raised is blank, "n/a").
"""

from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from sanav_mj.eval.bench import (
    CSV_COLUMNS,
    _load_average,
    begin_campaign,
    flatten,
    run_metadata,
    write_csv,
)
from sanav_mj.eval.campaign import JOURNAL_NAME, Job, is_error, run_jobs
from sanav_mj.outputs import atomic_path, write_text
from sanav_mj.sim.mismatch import Mismatch, MismatchError, mismatch_keys


def parse_sweep(items: list[str]) -> list[tuple[str, list[float]]]:
    """Parse ``["wheel_radius=0.9,1.0,1.1", "friction=0.3,1.0"]`` into keys with their values.

    Raises:
        MismatchError: malformed item, unknown key, repeated key or value, more than two
            keys, or a value out of the key's range.

    Values of integer keys (:func:`integer_key`: ``delay``) are returned as ``int``.
    """
    if not 1 <= len(items) <= 2:
        raise MismatchError(f"--sweep: expected one or two KEY=V1,V2,... items, got {len(items)}")
    keys = mismatch_keys()
    out: list[tuple[str, list[float]]] = []
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not raw.strip():
            raise MismatchError(f"--sweep {item!r}: expected KEY=V1,V2,...")
        if key not in keys:
            raise MismatchError(f"--sweep {item!r}: unknown key {key!r}; expected one of {', '.join(keys)}")
        if any(key == k for k, _ in out):
            raise MismatchError(f"--sweep {item!r}: key {key!r} given twice")
        try:
            numbers = [float(v) for v in raw.split(",")]
        except ValueError:
            raise MismatchError(f"--sweep {item!r}: expected comma-separated numbers, got {raw!r}") from None
        if len(set(numbers)) != len(numbers):
            raise MismatchError(f"--sweep {item!r}: a value is given twice")
        for v in numbers:
            Mismatch(**{key: int(v) if integer_key(key) and v == int(v) else v})  # validates range and type
        out.append((key, [_value(key, v) for v in numbers]))
    return out


def integer_key(key: str) -> bool:
    """Whether mismatch ``key`` takes whole numbers (its :class:`Mismatch` field is an ``int``: ``delay``)."""
    f = Mismatch.__dataclass_fields__[key]
    return f.type in (int, "int")


def _value(key: str, value: float) -> int | float:
    """A swept value as its key's type: ``delay=1`` is the integer 1 (in CSV, JSON, titles), others floats."""
    return int(value) if integer_key(key) else float(value)


def _fmt(key: str, value: float) -> str:
    return str(int(value)) if integer_key(key) else repr(float(value))


#: the ``scenario`` of the pooled rows (all scenarios of the sweep together)
POOLED = "all"


def _scenario_names(scenarios: list[str]) -> dict[str, str]:
    """Scenario argument (and name) -> the scenario's name (as the run rows carry it)."""
    from sanav_mj.scene import load_scenario

    names: dict[str, str] = {}
    for spec in scenarios:
        name = load_scenario(spec).name
        names[spec] = name
        names[name] = name
    return names


def _file_part(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "scenario"


def _aggregate(rows: list[dict[str, Any]], xk: str, xv: list, yk: str, yv: list, scenario: str | None,
               names: dict[str, str]) -> list[tuple[dict[str, Any], tuple[int, int]]]:
    """Summary rows of the grid points (``scenario`` None: pooled over all scenarios), each with its cell."""
    cells: dict[tuple[int, int], list[dict[str, Any]]] = {}
    for r in rows:
        if scenario is not None and names.get(r["scenario"], r["scenario"]) != scenario:
            continue
        cells.setdefault(tuple(r["_cell"]), []).append(r)
    out = []
    for yi, y in enumerate(yv):
        for xi, x in enumerate(xv):
            cell = cells.get((yi, xi), [])
            ran = [r for r in cell if not is_error(r)]
            n = len(ran)
            reasons: dict[str, int] = {}
            for r in ran:
                reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
            clear = [r["min_clearance_m"] for r in ran if r.get("min_clearance_m") is not None]
            row: dict[str, Any] = {"scenario": POOLED if scenario is None else scenario, xk: x}
            if yk:
                row[yk] = y
            row.update(
                runs=n, errors=len(cell) - n,
                success_rate=100.0 * sum(bool(r["success"]) for r in ran) / n if n else math.nan,
                collision_rate=100.0 * sum(r["collisions"] > 0 for r in ran) / n if n else math.nan,
                # no run with a clearance (none ran, or none moved: no path): no value, not inf
                min_clearance_m=float(min(clear)) if clear else math.nan,
                reasons=", ".join(f"{k} {v}" for k, v in sorted(reasons.items())),
            )
            out.append((row, (yi, xi)))
    return out


def _write_summary(cells: list[tuple[dict[str, Any], tuple[int, int]]], path: Path) -> None:
    """Summary CSV; a quantity with no value (NaN: no run of the point ran, or none has a
    clearance) is an empty field."""
    rows = [{k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()} for row, _ in cells]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _heat_maps(cells: list[tuple[dict[str, Any], tuple[int, int]]], label: str, folder: Path, prefix: str, *,
               xk: str, xv: list, yk: str, yv: list, controller: str, base_items: tuple[str, ...]) -> None:
    """``success_rate``, ``collision_rate`` and ``min_clearance`` heat maps of ``cells``, titled with ``label``."""
    from sanav_mj.eval.plots import plot_heatmap

    shape = (len(yv), len(xv))
    grids = {k: np.full(shape, np.nan) for k in ("success_rate", "collision_rate", "min_clearance_m")}
    for row, (yi, xi) in cells:
        for k, g in grids.items():
            g[yi, xi] = row[k]
    ylabels = [_fmt(yk, y) for y in yv] if yk else [""]
    xlabels = [_fmt(xk, x) for x in xv]
    note = f"\nwith {' '.join(base_items)}" if base_items else ""
    for key, name, what in (("success_rate", "success_rate", "success rate [%]"),
                            ("collision_rate", "collision_rate", "collision rate [%]"),
                            ("min_clearance_m", "min_clearance", "min clearance [m]")):
        plot_heatmap(grids[key], xk, xlabels, yk, ylabels, f"{label} / {controller}: {what}{note}",
                     folder / f"{prefix}{name}.png")


def run_robustness(
    scenarios: list[str],
    sweep: list[tuple[str, list[float]]],
    seeds: int,
    controller: str,
    workers: int,
    out: Path,
    time_limit_s: float = 60.0,
    fixed: Mismatch = Mismatch(),
    resume: bool = False,
) -> list[dict[str, Any]]:
    """Run the sweep and write CSVs and heat maps into ``out``.

    Args:
        scenarios: scenario paths/names.
        sweep: one or two (key, values) pairs from :func:`parse_sweep`.
        seeds: seeds 0..seeds-1 at every grid point and scenario.
        controller: controller name.
        workers: worker processes.
        out: output folder (created).
        time_limit_s: [s] simulated time limit of each run.
        fixed: mismatch applied at every grid point in addition to the swept keys (e.g. a
            sweep of friction x delay on a robot whose wheels are also 10 % small); it may
            not set a swept key.
        resume: keep the finished runs of ``out/runs.jsonl`` (an interrupted sweep with the
            same settings) and run only the others; the outputs are the same as those of an
            uninterrupted sweep. Without it the journal starts empty.

    Returns:
        One summary row per grid point pooled over the scenarios (``scenario`` =
        :data:`POOLED`), then, with more than one scenario, one per grid point and scenario
        (``scenario`` = its name): the swept value(s) (integers for integer keys),
        ``runs`` (that ran to an outcome), ``errors`` (runs that raised), ``success_rate``
        and ``collision_rate`` [%] (NaN when no run of the point ran to an outcome),
        ``min_clearance_m`` [m] (NaN when no run has one) and ``reasons``.

    Also writes ``meta.json``: :func:`sanav_mj.eval.bench.run_metadata` (scenarios,
    ``controllers`` = [controller], ``runs`` = seeds, workers, ``time_limit_s``, commit,
    machine, versions, load) plus ``command`` = "robustness", ``sweep`` ({key: [values]}),
    ``fixed`` ({key: value}, the keys of ``fixed`` that differ from no mismatch),
    ``wall_time_s`` (of this session) and ``load_average_end``; it is written before the
    runs too, so an interrupted folder says what it ran.

    Raises:
        MismatchError: ``fixed`` sets a swept key.
        sanav_mj.eval.campaign.JournalError: ``resume`` into a folder run with other settings.
        sanav_mj.eval.campaign.CampaignInterrupted: Ctrl-C; finished runs are in the journal.
    """
    names = _scenario_names(scenarios)  # loads each (ScenarioError on a bad one) before any output
    base = fixed.changed()
    for key, _ in sweep:
        if key in base:
            raise MismatchError(f"mismatch {key}: both swept and fixed (fixed {key}={base[key]!r})")
    base_items = tuple(f"{k}={_fmt(k, v)}" for k, v in base.items())
    out.mkdir(parents=True, exist_ok=True)
    (xk, xv), (yk, yv) = sweep[0], (sweep[1] if len(sweep) > 1 else ("", [math.nan]))
    jobs = []
    for yi, y in enumerate(yv):
        for xi, x in enumerate(xv):
            items = [f"{xk}={_fmt(xk, x)}"] + ([f"{yk}={_fmt(yk, y)}"] if yk else []) + list(base_items)
            for s in scenarios:
                for k in range(seeds):
                    jobs.append(Job(s, controller, k, tuple(items), time_limit_s, None,
                                    ((xk, x),) + (((yk, y),) if yk else ()) + (("_cell", (yi, xi)),)))
    meta = {"command": "robustness", **run_metadata(scenarios, [controller], seeds, workers, time_limit_s)}
    meta["sweep"] = {k: [_value(k, v) for v in vals] for k, vals in sweep}
    meta["fixed"] = dict(base)
    begin_campaign(out, meta, resume)
    t0 = time.perf_counter()
    docs = run_jobs(jobs, workers, desc="robustness", journal=out / JOURNAL_NAME, resume=resume)
    meta["wall_time_s"] = time.perf_counter() - t0
    meta["load_average_end"] = _load_average()
    write_text(out / "meta.json", json.dumps(meta, indent=1))
    rows = []
    for d in docs:
        r = flatten(d)
        r[xk] = d[xk]
        if yk:
            r[yk] = d[yk]
        r["_cell"] = d["_cell"]
        r["mismatch"] = " ".join(f"{k}={v}" for k, v in d.get("mismatch", {}).items())
        rows.append(r)
    with atomic_path(out / "robustness.csv") as tmp:
        write_csv([{k: v for k, v in r.items() if k != "_cell"} for r in rows], tmp,
                  columns=(xk,) + ((yk,) if yk else ()) + CSV_COLUMNS)

    pooled = _aggregate(rows, xk, xv, yk, yv, scenario=None, names=names)
    _write_summary(pooled, out / "summary.csv")
    heat = dict(xk=xk, xv=xv, yk=yk, yv=yv, controller=controller, base_items=base_items)
    distinct = list(dict.fromkeys(names[s] for s in scenarios))
    _heat_maps(pooled, ", ".join(distinct), out, "", **heat)
    summary = [row for row, _ in pooled]
    if len(distinct) > 1:  # per scenario as well as pooled
        per = []
        for name in distinct:
            cells = _aggregate(rows, xk, xv, yk, yv, scenario=name, names=names)
            per.extend(cells)
            _heat_maps(cells, name, out / "per_scenario", f"{_file_part(name)}_", **heat)
        _write_summary(per, out / "summary_by_scenario.csv")
        summary.extend(row for row, _ in per)
    return summary
