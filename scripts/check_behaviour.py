"""Record / compare the ``run --json`` documents of a fixed run set (behaviour check).

A refactor that does not mean to change behaviour must leave every run document identical
apart from wall-clock fields. This script runs the set through
:func:`sanav_mj.eval.episode.run_scenario` (the function behind ``sanav-mj run --json``; its
``document`` is exactly that JSON) and either stores the documents or compares them.

The run set (issue 13):

- ``sa-mpc`` on the five built-in scenarios x seeds 0-9 (50 runs);
- ``mpc`` (penalty MPC) on the five scenarios, seed 0 (5 runs);
- ``sa-mpc`` under the mismatch corner ``wheel_radius=1.1 track=0.9 friction=0.3 delay=1
  pos_noise=0.02 yaw_noise=0.035`` on u_shape, v_shape, complex x seeds 0-1 (6 runs).

``--set penalty10`` instead runs ``mpc`` on the five scenarios x seeds 0-9, ``--set
penalty_corner`` ``mpc`` under the mismatch corner on the five scenarios x seeds 0-4 (the
before/after measures of the penalty MPC's fallback change); ``--set quick`` ``sa-mpc`` on the
five scenarios seed 0 and one corner run (a check between steps).

Wall-clock fields excluded from the comparison (:data:`WALL_CLOCK_FIELDS`): ``solve_ms`` and
``pipeline_ms`` (per-step wall times and their statistics), and any top-level key ending in
``_ms`` (``map_update_ms`` of lidar runs). Everything else -- trace, steps, reason, clearance,
solver failures, start, mismatch -- is compared exactly (floats bit-for-bit, via their JSON
text).

Usage::

    python scripts/check_behaviour.py record DIR [--digests FILE] [--workers 2]
    python scripts/check_behaviour.py compare DIR [--workers 2]          # against DIR's documents
    python scripts/check_behaviour.py compare --digests scripts/behaviour_baseline.json
    python scripts/check_behaviour.py compare --digests F --only sa-mpc:u_shape:0 ...

``compare`` exits 0 when every run matches, 1 otherwise, listing each differing run and the
first differing keys (when full documents are available).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

SCENARIOS = ("single_rect", "double_rect", "u_shape", "v_shape", "complex")
CORNER = ("wheel_radius=1.1", "track=0.9", "friction=0.3", "delay=1", "pos_noise=0.02", "yaw_noise=0.035")
CORNER_SCENARIOS = ("u_shape", "v_shape", "complex")

#: top-level document keys that hold wall-clock times (never compared).
WALL_CLOCK_FIELDS = ("solve_ms", "pipeline_ms")


def run_set(name: str) -> list[tuple[str, str, int, tuple[str, ...]]]:
    """The runs of a set as (tag, scenario, seed, controller, mismatch items)."""
    runs = []
    if name == "default":
        runs += [("sa-mpc", s, k, ()) for s in SCENARIOS for k in range(10)]
        runs += [("mpc", s, 0, ()) for s in SCENARIOS]
        runs += [("sa-mpc", s, k, CORNER) for s in CORNER_SCENARIOS for k in range(2)]
    elif name == "penalty10":
        runs += [("mpc", s, k, ()) for s in SCENARIOS for k in range(10)]
    elif name == "penalty_corner":
        runs += [("mpc", s, k, CORNER) for s in SCENARIOS for k in range(5)]
    elif name == "quick":
        runs += [("sa-mpc", s, 0, ()) for s in SCENARIOS]
        runs += [("sa-mpc", "u_shape", 0, CORNER)]
    else:
        raise SystemExit(f"--set: expected default, penalty10, penalty_corner or quick, got {name!r}")
    return runs


def tag(controller: str, scenario: str, seed: int, mismatch: tuple[str, ...]) -> str:
    """File-name-safe key of one run, e.g. ``sa-mpc:u_shape:3`` or ``sa-mpc:u_shape:0:corner``."""
    return f"{controller}:{scenario}:{seed}" + (":corner" if mismatch else "")


def strip_wall_clock(doc: dict) -> dict:
    """The document without its wall-clock fields (see :data:`WALL_CLOCK_FIELDS`)."""
    return {k: v for k, v in doc.items() if k not in WALL_CLOCK_FIELDS and not k.endswith("_ms")}


def canonical(doc: dict) -> str:
    """Canonical JSON text of the document minus wall-clock fields (sorted keys, repr floats)."""
    return json.dumps(strip_wall_clock(doc), sort_keys=True, separators=(",", ":"), allow_nan=True)


def digest(doc: dict) -> str:
    """sha256 hex digest of :func:`canonical`."""
    return hashlib.sha256(canonical(doc).encode()).hexdigest()


def _one(job: tuple[str, str, int, tuple[str, ...]]) -> tuple[str, dict]:
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.sim.mismatch import parse_mismatch

    controller, scenario, seed, mismatch = job
    out = run_scenario(scenario, controller=controller, seed=seed, mismatch=parse_mismatch(list(mismatch)))
    return tag(*job), out.document


def run_all(jobs, workers: int) -> dict[str, dict]:
    """Run the jobs in ``workers`` processes (at most 2); returns tag -> document."""
    workers = max(1, min(2, workers))
    docs: dict[str, dict] = {}
    if workers == 1:
        results = map(_one, jobs)
    else:
        pool = ProcessPoolExecutor(workers)
        results = pool.map(_one, jobs)
    for i, (key, doc) in enumerate(results, 1):
        docs[key] = doc
        print(f"[{i}/{len(jobs)}] {key}: {doc['reason']} {doc['steps']} steps", file=sys.stderr, flush=True)
    return docs


def _fname(key: str) -> str:
    return key.replace(":", "__") + ".json"


def _first_differences(a: dict, b: dict, limit: int = 5) -> list[str]:
    a, b = strip_wall_clock(a), strip_wall_clock(b)
    out = []
    for k in sorted(set(a) | set(b)):
        if json.dumps(a.get(k), sort_keys=True) != json.dumps(b.get(k), sort_keys=True):
            if k == "trace" and isinstance(a.get(k), dict) and isinstance(b.get(k), dict):
                ta, tb = a[k], b[k]
                n = min(len(ta.get("t", [])), len(tb.get("t", [])))
                first = next((i for i in range(n) if any(ta[c][i] != tb[c][i] for c in ta)), n)
                out.append(f"trace (lengths {len(ta.get('t', []))} vs {len(tb.get('t', []))}, first differing step {first})")
            else:
                out.append(f"{k}: {a.get(k)!r} -> {b.get(k)!r}"[:160])
        if len(out) >= limit:
            break
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mode", choices=("record", "compare"))
    p.add_argument("dir", nargs="?", type=Path, help="folder of full documents (record: written; compare: read)")
    p.add_argument("--digests", type=Path, help="digest file (record: written; compare: read instead of DIR)")
    p.add_argument("--set", default="default",
                   help="run set: default (61 runs), penalty10 (50), penalty_corner (25), quick (6)")
    p.add_argument("--only", nargs="*", help="only these run tags (e.g. sa-mpc:u_shape:0, sa-mpc:v_shape:1:corner)")
    p.add_argument("--out", type=Path, help="compare: also store the new documents here")
    p.add_argument("--workers", type=int, default=2, help="worker processes (at most 2; default 2)")
    args = p.parse_args(argv)

    jobs = run_set(args.set)
    if args.only:
        jobs = [j for j in jobs if tag(*j) in set(args.only)]
        if not jobs:
            raise SystemExit(f"--only: no run of set {args.set!r} matches {args.only}")

    if args.mode == "record":
        if args.dir is None:
            raise SystemExit("record: DIR is required")
        args.dir.mkdir(parents=True, exist_ok=True)
        docs = run_all(jobs, args.workers)
        for key, doc in docs.items():
            (args.dir / _fname(key)).write_text(json.dumps(doc, indent=1))
        if args.digests is not None:
            old = json.loads(args.digests.read_text())["runs"] if args.digests.exists() else {}
            old.update({k: digest(d) for k, d in docs.items()})
            args.digests.write_text(json.dumps({
                "excluded_wall_clock_fields": list(WALL_CLOCK_FIELDS) + ["*_ms"],
                "runs": dict(sorted(old.items())),
            }, indent=1) + "\n")
        print(f"recorded {len(docs)} runs in {args.dir}")
        return 0

    if args.dir is None and args.digests is None:
        raise SystemExit("compare: give DIR or --digests FILE")
    ref_digests = json.loads(args.digests.read_text())["runs"] if args.digests else None
    docs = run_all(jobs, args.workers)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        for key, doc in docs.items():
            (args.out / _fname(key)).write_text(json.dumps(doc, indent=1))
    same, differ = 0, []
    for key, doc in docs.items():
        ref_doc = None
        if args.dir is not None and (args.dir / _fname(key)).exists():
            ref_doc = json.loads((args.dir / _fname(key)).read_text())
            ok = canonical(ref_doc) == canonical(doc)
        elif ref_digests is not None and key in ref_digests:
            ok = ref_digests[key] == digest(doc)
        else:
            print(f"{key}: no reference", file=sys.stderr)
            differ.append(key)
            continue
        if ok:
            same += 1
        else:
            differ.append(key)
            detail = "; ".join(_first_differences(ref_doc, doc)) if ref_doc is not None else "digest differs"
            print(f"DIFFERS {key}: {detail}")
    print(f"{same} of {len(docs)} runs identical apart from wall-clock fields {list(WALL_CLOCK_FIELDS) + ['*_ms']}"
          + (f"; differ: {', '.join(differ)}" if differ else ""))
    return 0 if not differ else 1


if __name__ == "__main__":
    sys.exit(main())
