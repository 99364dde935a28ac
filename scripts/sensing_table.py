"""Known map vs lidar: a markdown table from two ``sanav-mj bench`` folders.

    sanav-mj bench single_rect double_rect u_shape v_shape complex --controllers sa-mpc --runs 5 \
        --workers 1 --out out/map
    sanav-mj bench ... --sensing lidar --out out/lidar
    PYTHONPATH=$PWD python scripts/sensing_table.py out/map out/lidar

Per scenario and mode: runs, success %, collisions (runs with any), mean simulated time to the
goal [s] (successful runs), mean replans, map update mean and p99 [ms] (mean over runs of the
per-run figures), per-step pipeline mean and p99 [ms] (the same). Wall-clock figures depend on
the machine load; ``meta.json`` of each folder holds the load average at the end.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path


def rows(folder: Path) -> list[dict]:
    path = folder / "runs.jsonl"
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise SystemExit(f"sensing_table: {path}: {exc.strerror or exc}") from None
    return [json.loads(line)["row"] for line in lines if line.strip()]


def table(folders: list[Path]) -> str:
    out = ["| scenario | sensing | runs | success % | collisions | time to goal s | replans | "
           "map update mean / p99 ms | pipeline mean / p99 ms |",
           "|---|---|---|---|---|---|---|---|---|"]
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    order: list[tuple[str, str]] = []
    for folder in folders:
        for r in rows(folder):
            key = (r["scenario"], r.get("sensing", "map"))
            if key not in groups:
                order.append(key)
            groups[key].append(r)
    order.sort()

    def mean(xs):
        xs = [x for x in xs if x is not None]
        return sum(xs) / len(xs) if xs else float("nan")

    for key in order:
        g = groups[key]
        ok = [r for r in g if r.get("success")]
        mu = [r.get("map_update_ms") or {} for r in g]
        pipe = [r.get("pipeline_ms") or {} for r in g]
        lidar = key[1] == "lidar"
        out.append(
            f"| {key[0]} | {key[1]} | {len(g)} | {100 * len(ok) / len(g):.0f} | "
            f"{sum(1 for r in g if r.get('collisions'))} | {mean([r['sim_time_s'] for r in ok]):.1f} | "
            + (f"{mean([r.get('replans') for r in g]):.1f} | "
               f"{mean([m.get('mean') for m in mu]):.2f} / {mean([m.get('p99') for m in mu]):.2f} | "
               if lidar else "- | - | ")
            + f"{mean([p.get('mean') for p in pipe]):.2f} / "
            + (f"{mean([p.get('p99') for p in pipe]):.2f} |" if lidar else "- |"))
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path, help="bench output folders (with runs.jsonl)")
    args = ap.parse_args(argv)
    sys.stdout.write(table(args.folders))
    return 0


if __name__ == "__main__":
    sys.exit(main())
