"""``sanav-mj robustness``: sweep one or two mismatch keys over a grid with several seeds.

Outputs in ``--out``: ``robustness.csv`` (one row per run, with the swept values and the
run's whole mismatch, fixed keys included), ``summary.csv`` (one row per grid point: success
rate, collision rate, min clearance, reasons), heat maps ``success_rate.png``,
``collision_rate.png``, ``min_clearance.png`` (titled with the fixed mismatch),
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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from sanav_mj.eval.bench import (
    CSV_COLUMNS,
    _load_average,
    begin_campaign,
    campaign_executor,
    describe,
    flatten,
    run_metadata,
    write_csv,
)
from sanav_mj.eval.campaign import JOURNAL_NAME, Job, JobSet, is_error, run_jobs
from sanav_mj.sim.mismatch import Mismatch, MismatchError, mismatch_keys


def parse_sweep(items: list[str]) -> list[tuple[str, list[float]]]:
    """Parse ``["wheel_radius=0.9,1.0,1.1", "friction=0.3,1.0"]`` into keys with their values.

    Raises:
        MismatchError: malformed item, unknown key, repeated key or value, more than two
            keys, or a value out of the key's range.
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
            values = [float(v) for v in raw.split(",")]
        except ValueError:
            raise MismatchError(f"--sweep {item!r}: expected comma-separated numbers, got {raw!r}") from None
        if len(set(values)) != len(values):
            raise MismatchError(f"--sweep {item!r}: a value is given twice")
        for v in values:
            Mismatch(**{key: int(v) if key == "delay" and v == int(v) else v})  # validates range
        out.append((key, values))
    return out


def _fmt(key: str, value: float) -> str:
    return str(int(value)) if key == "delay" else repr(float(value))


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

    Returns:
        One summary row per grid point: the swept value(s), ``runs`` (that ran to an
        outcome), ``errors`` (runs that raised), ``success_rate`` and ``collision_rate`` [%]
        (NaN when no run of the point ran to an outcome), ``min_clearance_m`` [m] and
        ``reasons``.

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
    from sanav_mj.eval.plots import plot_heatmap
    from sanav_mj.scene import load_scenario

    for name in scenarios:
        load_scenario(name)
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
                        yield Job(s, controller, k, items, time_limit_s, None, tags)

    jobs = JobSet(make_jobs, len(yv) * len(xv) * len(scenarios) * seeds)
    with campaign_executor(ray) as executor:
        meta = {"command": "robustness", **run_metadata(scenarios, [controller], seeds, workers, time_limit_s)}
        meta["sweep"] = {k: [float(v) for v in vals] for k, vals in sweep}
        meta["fixed"] = dict(base)
        meta["executor"] = describe(ray)
        begin_campaign(out, meta, resume)
        t0 = time.perf_counter()
        docs = run_jobs(jobs, workers, desc="robustness", journal=out / JOURNAL_NAME, resume=resume,
                        executor=executor)
    meta["wall_time_s"] = time.perf_counter() - t0
    meta["load_average_end"] = _load_average()
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    rows = []
    for d in docs:
        r = flatten(d)
        r[xk] = d[xk]
        if yk:
            r[yk] = d[yk]
        r["_cell"] = d["_cell"]
        r["mismatch"] = " ".join(f"{k}={v}" for k, v in d.get("mismatch", {}).items())
        rows.append(r)
    write_csv([{k: v for k, v in r.items() if k != "_cell"} for r in rows], out / "robustness.csv",
              columns=(xk,) + ((yk,) if yk else ()) + CSV_COLUMNS)

    shape = (len(yv), len(xv))
    success = np.zeros(shape)
    collision = np.zeros(shape)
    clearance = np.full(shape, np.inf)
    count = np.zeros(shape)
    errors = np.zeros(shape, dtype=int)
    for r in rows:
        yi, xi = r["_cell"]
        if is_error(r):
            errors[yi, xi] += 1
            continue
        count[yi, xi] += 1
        success[yi, xi] += bool(r["success"])
        collision[yi, xi] += r["collisions"] > 0
        if r["min_clearance_m"] is not None:
            clearance[yi, xi] = min(clearance[yi, xi], r["min_clearance_m"])
    with np.errstate(invalid="ignore", divide="ignore"):  # a point whose every run raised: NaN
        success = np.where(count > 0, 100 * success / np.maximum(count, 1), np.nan)
        collision = np.where(count > 0, 100 * collision / np.maximum(count, 1), np.nan)
        clearance = np.where(count > 0, clearance, np.nan)
    summary = []
    for yi, y in enumerate(yv):
        for xi, x in enumerate(xv):
            cell = [r for r in rows if tuple(r["_cell"]) == (yi, xi) and not is_error(r)]
            reasons: dict[str, int] = {}
            for r in cell:
                reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
            row = {xk: x}
            if yk:
                row[yk] = y
            row.update(runs=int(count[yi, xi]), errors=int(errors[yi, xi]), success_rate=float(success[yi, xi]),
                       collision_rate=float(collision[yi, xi]), min_clearance_m=float(clearance[yi, xi]),
                       reasons=", ".join(f"{k} {v}" for k, v in sorted(reasons.items())))
            summary.append(row)
    with open(out / "summary.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(summary[0]))
        w.writeheader()
        w.writerows(summary)
    ylabels = [_fmt(yk, y) for y in yv] if yk else [""]
    xlabels = [_fmt(xk, x) for x in xv]
    note = f"\nwith {' '.join(base_items)}" if base_items else ""
    for values, name, title in (
        (success, "success_rate", f"{controller}: success rate [%]{note}"),
        (collision, "collision_rate", f"{controller}: collision rate [%]{note}"),
        (clearance, "min_clearance", f"{controller}: min clearance [m]{note}"),
    ):
        plot_heatmap(values, xk, xlabels, yk, ylabels, title, out / f"{name}.png")
    return summary
