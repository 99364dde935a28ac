"""Profile: where a lidar control step's time goes, per phase (issue 16).

Runs ``run SCENARIO --sensing lidar`` (seed 0 unless ``--seed``) in the given footprint
mode(s) with wrappers timing the pipeline's phases (``time.perf_counter`` around each call:
localisation and its scan match, the map update and its parts, the body clearing, the
replan check, the replans and their ``plan()`` calls, adopting a plan and, within it, the
SA-MPC's plan replacement, the discs mode's footprint reference and chain growth, the
SA-MPC step and its solver call) and prints each phase's time per control step (mean over
the run's steps) and its call count. Each run is repeated ``--repeat`` times in the process;
the run with the smallest pipeline mean is printed (the first run also pays the imports and
compiles). Nested phases are indented under their parent; a wrapper costs about 1 us a call.

    PYTHONPATH=$PWD python scripts/profile_sensing.py single_rect complex --footprint disc discs

Measures the tree on ``PYTHONPATH``, nothing else; the run JSONs are those of ``run``.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import sys
import time
from collections import defaultdict

# (module, attribute path, label): a class method as "Class.method", a module function as "name";
# module functions are patched where they are looked up (the caller's module)
PHASES = [
    ("sanav_mj.control.sensing", "SensingSAMPC.step", "step (pipeline without the lidar cast)"),
    ("sanav_mj.control.localisation", "ScanLocaliser.localise", "  localisation"),
    ("sanav_mj.mapping.sensed_map", "scan_points", "    scan points"),
    ("sanav_mj.mapping.scan_match", "ScanMatcher._refine", "    Gauss-Newton"),
    ("sanav_mj.mapping.scan_match", "ScanMatcher._search", "    correlative search"),
    ("sanav_mj.mapping.scan_match", "ScanMatcher.costs", "    consistency costs"),
    ("sanav_mj.mapping.sensed_map", "SensedMap.integrate", "  map update"),
    ("sanav_mj.mapping.live_grid", "LiveGrid.integrate", "    grid (beams, log-odds, counts)"),
    ("sanav_mj.mapping.incremental", "IncrementalSafeAreas.update_cells", "    safe + route area updates"),
    ("sanav_mj.mapping.scan_match", "LikelihoodField.add_points", "    likelihood field"),
    ("sanav_mj.control.sensing", "SensingSAMPC._clear_body", "  body clearing"),
    ("sanav_mj.control.sensing", "SensingSAMPC._replan_reason", "  replan check"),
    ("sanav_mj.control.sensing", "SensingSAMPC._plan_inputs", "  replan inputs (kept rects, snapshots)"),
    ("sanav_mj.control.sensing", "SensingSAMPC._compute", "  replans: planning"),
    ("sanav_mj.control.sensing", "make_plan", "    plan() calls"),
    ("sanav_mj.control.sensing", "SensingSAMPC._adopt", "  replans: adopting the plan"),
    ("sanav_mj.control.sa_mpc", "SAMPC.replace_plan", "    SAMPC.replace_plan"),
    ("sanav_mj.control.sa_mpc", "footprint_reference", "      discs: footprint reference"),
    ("sanav_mj.mapping.grow", "grow_rect", "      chain growth (grow_rect)"),
    ("sanav_mj.control.tracking", "TrackingMPC.step", "  SA-MPC step"),
    ("sanav_mj.control.tracking", "TrackingMPC.solve", "    solve (solver call and its set-up)"),
]

_INHERITED = object()  # marks a method a class inherits (restored by deleting the wrapper)


def _patch(acc: dict, cnt: dict) -> tuple[list[str], list[tuple]]:
    """Wrap every phase found in the tree on the path.

    Returns the labels of the phases not found and the ``(owner, name, original)`` triples
    that :func:`_unpatch` puts back (the wrappers are process-wide while they are in place).
    """
    missing: list[str] = []
    undo: list[tuple] = []
    for mod_name, path, label in PHASES:
        mod = importlib.import_module(mod_name)
        owner, _, name = path.rpartition(".")
        obj = getattr(mod, owner) if owner else mod
        f = getattr(obj, name, None)
        if f is None:
            missing.append(label.strip())
            continue
        # a class keeps its own attribute (staticmethod etc. as stored); an inherited one is deleted again
        undo.append((obj, name, obj.__dict__.get(name, _INHERITED) if isinstance(obj, type) else f))

        def make(f, label):
            @functools.wraps(f)
            def g(*a, **k):
                t = time.perf_counter()
                try:
                    return f(*a, **k)
                finally:
                    acc[label] += time.perf_counter() - t
                    cnt[label] += 1
            return g
        setattr(obj, name, make(f, label))
    return missing, undo


def _unpatch(undo: list[tuple]) -> None:
    """Put back what :func:`_patch` wrapped, last first."""
    for obj, name, original in reversed(undo):
        if original is _INHERITED:
            delattr(obj, name)
        else:
            setattr(obj, name, original)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenarios", nargs="+", help="scenario paths or built-in names")
    p.add_argument("--footprint", nargs="+", choices=("disc", "discs"), default=["disc"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeat", type=int, default=2, help="runs per scenario and mode (the fastest is printed)")
    a = p.parse_args(argv)
    if a.repeat < 1:
        print(f"profile_sensing: --repeat: expected an integer >= 1, got {a.repeat}", file=sys.stderr)
        return 2
    acc: dict = defaultdict(float)
    cnt: dict = defaultdict(int)
    missing, undo = _patch(acc, cnt)
    try:
        return _profile(a, acc, cnt, missing)
    except (FileNotFoundError, ValueError) as e:
        print(f"profile_sensing: {e}", file=sys.stderr)
        return 2
    finally:
        _unpatch(undo)


def _profile(a: argparse.Namespace, acc: dict, cnt: dict, missing: list[str]) -> int:
    """Run and print every scenario and footprint mode of ``a`` (see the module docstring)."""
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.prepare import footprint_spec

    print(f"load average {os.getloadavg()[0]:.2f}; ms per control step (mean over the run's steps), calls")
    if missing:
        print(f"(not in this tree: {', '.join(missing)})")
    for fp in a.footprint:
        for name in a.scenarios:
            best = None
            for _ in range(a.repeat):
                acc.clear()
                cnt.clear()
                d = run_scenario(name, seed=a.seed, controller_spec=footprint_spec("sa-mpc", fp),
                                 sensing="lidar").document
                n = max(1, cnt[PHASES[0][2]])
                row = ({lab: (1e3 * acc[lab] / n, cnt[lab]) for _, _, lab in PHASES if cnt[lab]},
                       d["pipeline_ms"]["mean"], d["replans"], d["reason"], n)
                if best is None or row[1] < best[1]:
                    best = row
            phases, pipe, replans, reason, n = best
            print(f"{name} {fp}: {n} steps, {replans} replans, {reason}; run JSON pipeline_ms mean {pipe:.2f}")
            for lab, (ms, c) in phases.items():
                print(f"  {lab:42s} {ms:6.3f}  {c:5d}")
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
