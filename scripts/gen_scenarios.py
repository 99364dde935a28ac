"""Write seeded random clutter scenarios (MJCF) for campaigns.

    python scripts/gen_scenarios.py --count 100 --seed 0 --out runs/clutter

writes ``clutter_0000.xml`` ... ``clutter_0099.xml`` (seeds 0..99) into ``--out``, each
including the packaged robot by a path relative to the file. Every map is solvable for the
robot's footprint (see :mod:`sanav_mj.generate`).

    python scripts/gen_scenarios.py --kind barn --count 40 --seed 0 --out runs/barn

writes BARN-like cylinder fields ``barn_0000.xml`` ... (:class:`sanav_mj.generate.BarnConfig`),
each passable for the robot's real rectangular footprint (configuration-space check).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from sanav_mj.generate import ClutterConfig, write_barn_scenario, write_scenario


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=100, help="number of scenarios (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="first seed; files use seeds seed..seed+count-1")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument("--kind", choices=("clutter", "barn"), default="clutter",
                        help="clutter (random boxes/cylinders/capsules) or barn (BARN-like cylinder fields)")
    parser.add_argument("--prefix", default=None, help="file name prefix (default: the kind)")
    parser.add_argument("--n-min", type=int, default=None, help="fewest obstacles per map")
    parser.add_argument("--n-max", type=int, default=None, help="most obstacles per map")
    args = parser.parse_args(argv)
    if args.count < 1 or args.seed < 0:
        print(f"gen_scenarios: --count must be >= 1 and --seed >= 0, got {args.count} and {args.seed}",
              file=sys.stderr)
        return 2
    prefix = args.prefix or args.kind
    if args.kind == "barn":
        if args.n_min is not None or args.n_max is not None:
            print("gen_scenarios: --n-min/--n-max apply to --kind clutter only", file=sys.stderr)
            return 2
        try:
            written = [write_barn_scenario(seed, args.out / f"{prefix}_{seed:04d}.xml")
                       for seed in range(args.seed, args.seed + args.count)]
        except ValueError as err:
            print(f"gen_scenarios: {err}", file=sys.stderr)
            return 2
        print(f"wrote {len(written)} scenarios (seeds {args.seed}..{args.seed + args.count - 1}) to {args.out}")
        return 0
    config = ClutterConfig()
    try:
        changes = {k: v for k, v in (("n_min", args.n_min), ("n_max", args.n_max)) if v is not None}
        config = replace(config, **changes)
        written = [
            write_scenario(seed, args.out / f"{prefix}_{seed:04d}.xml", config)
            for seed in range(args.seed, args.seed + args.count)
        ]
    except ValueError as err:
        print(f"gen_scenarios: {err}", file=sys.stderr)
        return 2
    print(f"wrote {len(written)} scenarios (seeds {args.seed}..{args.seed + args.count - 1}) to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
