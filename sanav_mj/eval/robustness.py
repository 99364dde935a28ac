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

import json
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from sanav_mj.eval.bench import (
    CSV_COLUMNS,
    CsvStream,
    _load_average,
    begin_campaign,
    campaign_executor,
    describe,
    flatten,
    run_metadata,
    stream_campaign,
)
from sanav_mj.eval.campaign import Job, JobSet, is_error
from sanav_mj.outputs import OutputFailures, write_text
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


class CellSummary:
    """Running aggregates of some runs (one grid point of one scenario, or pooled), fed one
    row at a time (:meth:`add`): ``all`` rows, ``ran`` (to an outcome: not an error row),
    ``success`` and ``collided`` (runs with a collision) among those, the smallest
    ``clearance`` [m] (None: no run has one) and the outcome counts ``reasons``
    ({reason: runs}). Exact: nothing is sampled or estimated."""

    __slots__ = ("all", "ran", "success", "collided", "clearance", "reasons")

    def __init__(self) -> None:
        self.all = 0
        self.ran = 0
        self.success = 0
        self.collided = 0
        self.clearance: float | None = None
        self.reasons: dict[str, int] = {}

    def add(self, r: dict[str, Any]) -> None:
        """Take one run row: ``reason``, and unless it is an error row (:func:`is_error`)
        ``success`` (bool), ``collisions`` (int) and ``min_clearance_m`` ([m] or None)."""
        self.all += 1
        if is_error(r):
            return
        self.ran += 1
        self.success += bool(r["success"])
        self.collided += r["collisions"] > 0
        c = r.get("min_clearance_m")
        if c is not None and (self.clearance is None or c < self.clearance):
            self.clearance = c
        self.reasons[r["reason"]] = self.reasons.get(r["reason"], 0) + 1

    def summary(self) -> dict[str, Any]:
        """``runs`` (that ran to an outcome), ``errors`` (rows of runs that raised),
        ``success_rate`` and ``collision_rate`` [%] of the runs (NaN without one),
        ``min_clearance_m`` [m] (NaN when no run has one, never inf) and ``reasons``
        ("goal 3, stuck 1": the outcome counts by reason)."""
        n = self.ran
        return dict(
            runs=n, errors=self.all - n,
            success_rate=100.0 * self.success / n if n else math.nan,
            collision_rate=100.0 * self.collided / n if n else math.nan,
            # no run with a clearance (none ran, or none moved: no path): no value, not inf
            min_clearance_m=float(self.clearance) if self.clearance is not None else math.nan,
            reasons=", ".join(f"{k} {v}" for k, v in sorted(self.reasons.items())),
        )


class SweepSummary:
    """The summaries of a sweep fed one row at a time (:meth:`add`): per grid point, pooled
    over the scenarios and per scenario, a few counters, the smallest clearance and the
    outcome counts; memory grows with the grid and the scenarios, not with the seeds."""

    def __init__(self, names: dict[str, str]) -> None:
        self._names = names
        self._cells: dict[tuple[str | None, tuple[int, int]], CellSummary] = {}

    def add(self, row: dict[str, Any], cell: tuple[int, int]) -> None:
        """Take one row (:func:`sanav_mj.eval.bench.flatten` of a run) of grid point ``cell`` = (yi, xi)."""
        cell = (int(cell[0]), int(cell[1]))
        scenario = self._names.get(row["scenario"], row["scenario"])
        for group in (None, scenario):
            acc = self._cells.get((group, cell))
            if acc is None:
                acc = self._cells[(group, cell)] = CellSummary()
            acc.add(row)

    def cells(self, xk: str, xv: list, yk: str, yv: list,
              scenario: str | None) -> list[tuple[dict[str, Any], tuple[int, int]]]:
        """Summary rows of the grid points (``scenario`` None: pooled over all scenarios), each with its cell."""
        out = []
        for yi, y in enumerate(yv):
            for xi, x in enumerate(xv):
                acc = self._cells.get((scenario, (yi, xi))) or CellSummary()
                row: dict[str, Any] = {"scenario": POOLED if scenario is None else scenario, xk: x}
                if yk:
                    row[yk] = y
                row.update(acc.summary())
                out.append((row, (yi, xi)))
        return out


def _write_summary(cells: list[tuple[dict[str, Any], tuple[int, int]]], path: Path) -> None:
    """Summary CSV; a quantity with no value (NaN: no run of the point ran, or none has a
    clearance) is an empty field."""
    rows = [{k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()} for row, _ in cells]
    out = CsvStream(path, list(rows[0]))
    for row in rows:
        out.add(row)
    out.commit()


def _heat_maps(cells: list[tuple[dict[str, Any], tuple[int, int]]], label: str, folder: Path, prefix: str, *,
               xk: str, xv: list, yk: str, yv: list, controller: str, base_items: tuple[str, ...],
               failures: OutputFailures) -> None:
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
        path = folder / f"{prefix}{name}.png"
        failures.attempt(path, lambda: plot_heatmap(grids[key], xk, xlabels, yk, ylabels,
                                                    f"{label} / {controller}: {what}{note}", path))


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
    ray: str | bool | Any = None,
    sensing: str = "map",
    footprint: str = "disc",
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
        ray: run on Ray instead of the process pool, as in
            :func:`sanav_mj.eval.bench.run_bench` (True: a local Ray; an address: a cluster;
            None: the pool of ``workers``); the rows, outputs and journal are the same.
        sensing: ``"map"`` or ``"lidar"`` for every run (lidar: SA-MPC only).
        footprint: SA-MPC's ``"disc"`` or ``"discs"`` for every run (``meta.json`` names it
            when not ``"disc"``).

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
        OSError: an output could not be written (``filename`` the first such file), raised
            after every other output was written; ``meta.json`` before the runs stops the
            campaign. Each output is written whole or not at all.

    Memory does not grow with the number of runs: rows are streamed to ``robustness.csv``
    and to running aggregates per grid point (:class:`SweepSummary`) in job order.
    """
    names = _scenario_names(scenarios)  # loads each (ScenarioError on a bad one) before any output
    base = fixed.changed()
    for key, _ in sweep:
        if key in base:
            raise MismatchError(f"mismatch {key}: both swept and fixed (fixed {key}={base[key]!r})")
    base_items = tuple(f"{k}={_fmt(k, v)}" for k, v in base.items())
    out.mkdir(parents=True, exist_ok=True)
    (xk, xv), (yk, yv) = sweep[0], (sweep[1] if len(sweep) > 1 else ("", [math.nan]))

    def make_jobs() -> Iterator[Job]:  # lazily: a campaign's size does not cost memory up front
        for yi, y in enumerate(yv):
            for xi, x in enumerate(xv):
                items = (f"{xk}={_fmt(xk, x)}",) + ((f"{yk}={_fmt(yk, y)}",) if yk else ()) + base_items
                tags = ((xk, x),) + (((yk, y),) if yk else ()) + (("_cell", (yi, xi)),)
                for s in scenarios:
                    for k in range(seeds):
                        yield Job(s, controller, k, items, time_limit_s, None, tags, sensing, footprint)

    n_jobs = len(yv) * len(xv) * len(scenarios) * seeds
    # keys are distinct by construction when the scenarios and each key's values are
    unique = (len(set(scenarios)) == len(scenarios)
              and all(len({_fmt(k, v) for v in vals}) == len(vals) for k, vals in sweep))
    jobs = JobSet(make_jobs, n_jobs, distinct=unique)
    # the CSV's columns: the swept keys, the run columns, then the extra key of the rows
    # (``mismatch``; :func:`sanav_mj.eval.bench.write_csv` would append it as the one key it does not know)
    columns = (xk,) + ((yk,) if yk else ()) + CSV_COLUMNS + (("mismatch",) if n_jobs else ())
    with campaign_executor(ray) as executor:
        meta = {"command": "robustness", **run_metadata(scenarios, [controller], seeds, workers, time_limit_s)}
        if sensing != "map":
            meta["sensing"] = sensing
        if footprint != "disc":
            meta["footprint"] = footprint
        meta["sweep"] = {k: [_value(k, v) for v in vals] for k, vals in sweep}
        meta["fixed"] = dict(base)
        meta["executor"] = describe(ray)
        begin_campaign(out, meta, resume)
        t0 = time.perf_counter()
        # streamed: each row goes to robustness.csv (a temporary file until the end) and the
        # running summaries as it arrives, in the order of the jobs; no row is kept
        per_run = CsvStream(out / "robustness.csv", columns)
        acc = SweepSummary(names)

        def take(d: dict[str, Any]) -> None:
            r = flatten(d)
            r[xk] = d[xk]
            if yk:
                r[yk] = d[yk]
            r["mismatch"] = " ".join(f"{k}={v}" for k, v in d.get("mismatch", {}).items())
            per_run.add(r)
            acc.add(r, tuple(d["_cell"]))

        stream_campaign(jobs, workers, "robustness", out, resume, executor, per_run, take)
    meta["wall_time_s"] = time.perf_counter() - t0
    meta["load_average_end"] = _load_average()
    failures = OutputFailures()  # every output whole or not at all; one failing does not stop the others
    failures.attempt(out / "meta.json", lambda: write_text(out / "meta.json", json.dumps(meta, indent=1)))
    failures.attempt(out / "robustness.csv", per_run.commit)

    pooled = acc.cells(xk, xv, yk, yv, scenario=None)
    failures.attempt(out / "summary.csv", lambda: _write_summary(pooled, out / "summary.csv"))
    heat = dict(xk=xk, xv=xv, yk=yk, yv=yv, controller=controller, base_items=base_items)
    distinct = list(dict.fromkeys(names[s] for s in scenarios))
    _heat_maps(pooled, ", ".join(distinct), out, "", failures=failures, **heat)
    summary = [row for row, _ in pooled]
    if len(distinct) > 1:  # per scenario as well as pooled
        per = []
        for name in distinct:
            cells = acc.cells(xk, xv, yk, yv, scenario=name)
            per.extend(cells)
            _heat_maps(cells, name, out / "per_scenario", f"{_file_part(name)}_", failures=failures, **heat)
        failures.attempt(out / "summary_by_scenario.csv", lambda: _write_summary(per, out / "summary_by_scenario.csv"))
        summary.extend(row for row, _ in per)
    failures.check()
    return summary
