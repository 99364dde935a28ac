"""Smoke tests of the sensing benchmark scripts (small runs; no timing asserted)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_bench_incremental_small_run(capsys):
    mod = _load("bench_incremental")
    assert mod.main(["--maps", "barn", "--scans", "3", "--tile", "16"]) == 0
    out = capsys.readouterr().out
    assert "barn: 300 x 100 cells" in out
    for row in ("map update", "incremental update", "compact snapshot", "rebuild"):
        assert row in out
    assert mod.main(["--scans", "1"]) == 2


def test_bench_sensing_one_scenario(capsys):
    mod = _load("bench_sensing")
    assert mod.main(["single_rect"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    row = lines[-1].split()
    assert row[0] == "single_rect" and int(row[1]) > 50
    assert float(row[-1]) == 0.0  # the lidar map's safe cells lie in the known map's free cells
    assert mod.main(["no_such_scenario"]) == 2


def test_lidar_stall_trace_short_run(capsys, tmp_path):
    mod = _load("lidar_stall_trace")
    assert mod.main(["single_rect", "--time-limit", "2", "--every", "1", "--png", str(tmp_path / "m.png")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("single_rect seed 0: ")
    assert "t=  0.00" in out and "scan_turn" in out  # the turn on the spot before the first plan
    assert (tmp_path / "m.png").stat().st_size > 0
    assert mod.main(["single_rect", "--every", "0"]) == 2
    assert mod.main(["single_rect", "--png", str(tmp_path / "no" / "m.png")]) == 2
    assert mod.main(["no_such_scenario"]) == 2


def test_profile_sensing_every_phase_found_and_restored(capsys):
    import sanav_mj.control.sensing as sensing
    import sanav_mj.control.tracking as tracking

    mod = _load("profile_sensing")
    before = (sensing.SensingSAMPC.step, tracking.TrackingMPC.solve, sensing.make_plan)
    assert mod.main(["single_rect", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "not in this tree" not in out  # every profiled phase still exists under its name
    assert "single_rect disc: " in out and " replans, goal; " in out
    step = next(line for line in out.splitlines() if "step (pipeline without the lidar cast)" in line)
    assert int(step.split()[-1]) > 50  # calls: one per control step
    # the wrappers are taken off again: the process runs unprofiled code afterwards
    assert (sensing.SensingSAMPC.step, tracking.TrackingMPC.solve, sensing.make_plan) == before
    assert mod.main(["single_rect", "--repeat", "0"]) == 2
    assert mod.main(["no_such_scenario", "--repeat", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("profile_sensing: --repeat") and err[1].startswith("profile_sensing: ")
