"""Record or compare the run JSON of a fixed set of runs (behaviour-preservation check).

    PYTHONPATH=$PWD python scripts/compare_runs.py record DIR   # write DIR/<run>.json
    PYTHONPATH=$PWD python scripts/compare_runs.py compare DIR  # rerun, compare with DIR

The set: SA-MPC on the five built-in scenarios seed 0, and the mismatch corner
``wheel_radius=1.1 track=0.9 friction=0.3 delay=1 pos_noise=0.02 yaw_noise=0.035`` on
v_shape seeds 0-1. Wall-clock fields (``solve_ms``, ``pipeline_ms``, ``timing*``) are
ignored; everything else must be equal. Exit 1 when a run differs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sanav_mj.cli import main as cli_main

CORNER = ["wheel_radius=1.1", "track=0.9", "friction=0.3", "delay=1", "pos_noise=0.02", "yaw_noise=0.035"]
RUNS = [(f"{s}_seed0", [s, "--seed", "0"]) for s in ("single_rect", "double_rect", "u_shape", "v_shape", "complex")]
RUNS += [(f"v_shape_corner_seed{k}", ["v_shape", "--seed", str(k), "--mismatch", *CORNER]) for k in (0, 1)]
WALL_CLOCK = ("solve_ms", "pipeline_ms", "timing")


def strip(doc):
    if isinstance(doc, dict):
        return {k: strip(v) for k, v in doc.items() if not k.startswith(WALL_CLOCK)}
    if isinstance(doc, list):
        return [strip(v) for v in doc]
    return doc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("record", "compare"))
    ap.add_argument("folder", type=Path)
    args = ap.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    bad = 0
    for name, argv in RUNS:
        ref = args.folder / f"{name}.json"
        out = ref if args.mode == "record" else args.folder / f"{name}.new.json"
        cli_main(["run", *argv, "--json", str(out)])
        if args.mode == "compare":
            same = strip(json.loads(ref.read_text())) == strip(json.loads(out.read_text()))
            bad += not same
            print(f"{name}: {'identical' if same else 'DIFFERENT'}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
