"""Robustness sweeps: ``parse_sweep``, the sweep outputs, and every mismatch key's effect on the plant."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from sanav_mj.control.base import Command
from sanav_mj.eval import robustness
from sanav_mj.eval.robustness import parse_sweep, run_robustness
from sanav_mj.scene import load_scenario
from sanav_mj.sim.mismatch import MismatchError, mismatched_model, parse_mismatch
from sanav_mj.sim.plant import Plant
from sanav_mj.sim.runner import RunConfig, run_episode

PNGS = ("success_rate.png", "collision_rate.png", "min_clearance.png")

# --------------------------------------------------------------------------- parse_sweep


def test_parse_sweep_known_answers():
    assert parse_sweep(["wheel_radius=0.9,1.0,1.1"]) == [("wheel_radius", [0.9, 1.0, 1.1])]
    assert parse_sweep(["friction=0.3,1", "delay=0,1,2"]) == [("friction", [0.3, 1.0]), ("delay", [0, 1, 2])]
    (_, fr), (_, de) = parse_sweep(["friction=1", "delay=2.0"])
    assert type(fr[0]) is float and type(de[0]) is int  # integer keys stay integers (CSV, JSON, titles)
    assert parse_sweep(["pos_noise=0.02"]) == [("pos_noise", [0.02])]
    assert parse_sweep([" mass =2, 3"]) == [("mass", [2.0, 3.0])]


@pytest.mark.parametrize(
    "items, fragment",
    [
        ([], "one or two"),
        (["mass=1", "track=1", "delay=1"], "one or two"),
        (["wheel_radius"], "expected KEY=V1,V2"),
        (["wheel_radius="], "expected KEY=V1,V2"),
        (["bogus=1,2"], "unknown key 'bogus'"),
        (["mass=1", "mass=2"], "given twice"),
        (["mass=1,x"], "comma-separated numbers"),
        (["mass=1,2,1.0"], "a value is given twice"),
        (["mass=1,,2"], "comma-separated numbers"),
        (["wheel_radius=0.9,9"], "expected 0.5 <= value <= 1.5"),
        (["delay=0,1.5"], "whole number"),
        (["friction=nan"], "finite number"),
    ],
)
def test_parse_sweep_errors_are_one_line(items, fragment):
    with pytest.raises(MismatchError) as err:
        parse_sweep(items)
    assert fragment in str(err.value)
    assert "\n" not in str(err.value)


# --------------------------------------------------------------------------- the sweep


def _read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _assert_pngs(out):
    for name in PNGS:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n", name


def test_tiny_real_sweep_writes_rows_and_heat_maps(tmp_path):
    out = tmp_path / "rb"
    summary = run_robustness(["single_rect"], parse_sweep(["wheel_radius=0.9,1.1"]), seeds=1,
                             controller="sa-mpc", workers=1, out=out, time_limit_s=30.0)
    runs = _read(out / "robustness.csv")
    assert [float(r["wheel_radius"]) for r in runs] == [0.9, 1.1]
    assert {r["scenario"] for r in runs} == {"single_rect"} and {r["seed"] for r in runs} == {"0"}
    cells = _read(out / "summary.csv")
    assert [float(c["wheel_radius"]) for c in cells] == [0.9, 1.1]
    for run, cell, row in zip(runs, cells, summary):
        assert int(cell["runs"]) == 1
        assert float(cell["success_rate"]) == (100.0 if run["success"] == "True" else 0.0)
        assert float(cell["collision_rate"]) == (100.0 if int(run["collisions"]) > 0 else 0.0)
        assert float(cell["min_clearance_m"]) == pytest.approx(float(run["min_clearance_m"]))
        assert cell["reasons"] == f"{run['reason']} 1"
        assert row["runs"] == 1
    _assert_pngs(out)


def _fake_doc(job):
    """A run document whose outcome is a known function of the job (no simulation)."""
    tags = dict(job.tags)
    x, y = tags["mass"], tags["delay"]
    success = not (y == 1 and job.seed == 0)
    collided = x == 2.0 and y == 1 and job.seed == 1
    reason = "goal" if success else "stuck"
    if collided:
        success, reason = False, "collision"
    stats = {"mean": 1.0, "max": 2.0, "std": 0.5, "p50": 1.0, "p99": 2.0}
    return {
        "scenario": job.scenario, "controller": job.controller, "seed": job.seed, "success": success,
        "reason": reason, "steps": 10, "sim_time_s": 1.0, "path_length_m": 1.0,
        "min_clearance_m": -0.01 if collided else 0.1 * x + 0.01 * job.seed, "collisions": int(collided),
        "safe_area_violations": 0, "solver_failures": 0, "solve_ms": stats, "pipeline_ms": stats,
        "mismatch": parse_mismatch(list(job.mismatch)).changed(),
        **tags,
    }


def test_two_key_aggregation_known_answers(tmp_path, fake_campaign_runs):
    seen = fake_campaign_runs(_fake_doc)
    out = tmp_path / "rb"
    summary = run_robustness(["single_rect"], parse_sweep(["mass=1,2", "delay=0,1"]), seeds=3,
                             controller="sa-mpc", workers=1, out=out,
                             fixed=parse_mismatch(["friction=0.5"]))
    assert len(seen) == 2 * 2 * 3
    assert {j.mismatch for j in seen} == {
        ("mass=1.0", "delay=0", "friction=0.5"), ("mass=2.0", "delay=0", "friction=0.5"),
        ("mass=1.0", "delay=1", "friction=0.5"), ("mass=2.0", "delay=1", "friction=0.5"),
    }
    by_cell = {(r["mass"], r["delay"]): r for r in summary}
    assert by_cell[(1.0, 0.0)]["success_rate"] == 100.0
    assert by_cell[(1.0, 1.0)]["success_rate"] == pytest.approx(200 / 3)
    assert by_cell[(2.0, 1.0)]["success_rate"] == pytest.approx(100 / 3)
    assert by_cell[(2.0, 1.0)]["collision_rate"] == pytest.approx(100 / 3)
    assert by_cell[(2.0, 1.0)]["reasons"] == "collision 1, goal 1, stuck 1"
    assert by_cell[(1.0, 0.0)]["min_clearance_m"] == pytest.approx(0.1)
    assert by_cell[(2.0, 0.0)]["min_clearance_m"] == pytest.approx(0.2)
    assert by_cell[(2.0, 1.0)]["min_clearance_m"] == pytest.approx(-0.01)
    runs = _read(out / "robustness.csv")
    assert len(runs) == 12
    # the folder says what it ran under: each run's whole mismatch, and meta.json
    assert {r["mismatch"] for r in runs} == {"friction=0.5", "mass=2.0 friction=0.5", "friction=0.5 delay=1",
                                              "mass=2.0 friction=0.5 delay=1"}  # the keys a run changes
    meta = json.loads((out / "meta.json").read_text())
    assert meta["fixed"] == {"friction": 0.5}
    assert meta["sweep"] == {"mass": [1.0, 2.0], "delay": [0.0, 1.0]}
    assert meta["scenarios"] == ["single_rect"] and meta["controllers"] == ["sa-mpc"]
    assert meta["runs"] == 3 and meta["time_limit_s"] == 60.0 and meta["wall_time_s"] >= 0.0
    assert [(float(c["mass"]), float(c["delay"])) for c in _read(out / "summary.csv")] == [
        (1.0, 0.0), (2.0, 0.0), (1.0, 1.0), (2.0, 1.0)]
    _assert_pngs(out)


def test_fixed_mismatch_must_not_repeat_a_swept_key(tmp_path):
    with pytest.raises(MismatchError, match="both swept and fixed"):
        run_robustness(["single_rect"], parse_sweep(["mass=1,2"]), seeds=1, controller="sa-mpc",
                       workers=1, out=tmp_path, fixed=parse_mismatch(["mass=2"]))


# --------------------------------------------------------------------------- each key in the plant

DT = 0.02  # [s] command period of the open-loop drives


@pytest.fixture
def open_floor(write_scenario):
    """A large empty floor (one far-away post: the plant needs no obstacles, the loader wants a world)."""
    floor = '<geom name="floor" type="plane" pos="0 0 0" size="50 50 0.1"/>'
    post = '<geom name="post" type="box" pos="45 45 0.5" size="0.1 0.1 0.5"/>'
    return load_scenario(write_scenario(post, floor=floor))


def _drive(scenario, items, v, w, duration_s):
    """Hold (v, w) [m/s, rad/s] from rest; returns (S, 2) measured body (v, w) and the plant."""
    m = parse_mismatch(items)
    plant = Plant(scenario, mismatched_model(scenario, m) if m.physical else None)
    plant.reset(np.zeros(3))
    out = []
    for _ in range(int(round(duration_s / DT))):
        plant.set_wheel_command(v, w)
        plant.advance(DT)
        out.append(plant.body_velocity())
    return np.array(out), plant


@pytest.mark.parametrize("scale", [0.9, 1.1])
def test_wheel_radius_scales_the_speed_and_keeps_the_chassis_height(open_floor, scale):
    nominal, p0 = _drive(open_floor, [], 0.5, 0.0, 2.0)
    scaled, p1 = _drive(open_floor, [f"wheel_radius={scale}"], 0.5, 0.0, 2.0)
    ratio = scaled[-10:, 0].mean() / nominal[-10:, 0].mean()
    assert ratio == pytest.approx(scale, abs=0.01)
    # wheels on the floor, chassis at its nominal height (a smaller wheel used to hang in
    # the air with the robot resting on its casters: ratio 0)
    assert p1.pose()[:2] != pytest.approx(p0.pose()[:2])
    assert p1.data.qpos[2] == pytest.approx(p0.data.qpos[2], abs=2e-3)


def test_track_scales_the_yaw_rate_inversely(open_floor):
    nominal, _ = _drive(open_floor, [], 0.0, 1.0, 2.0)
    wide, _ = _drive(open_floor, ["track=1.1"], 0.0, 1.0, 2.0)
    assert wide[-10:, 1].mean() / nominal[-10:, 1].mean() == pytest.approx(1 / 1.1, abs=0.01)


def test_low_friction_breaks_a_fast_turn(open_floor):
    # 1.4 m/s at 2.5 rad/s needs 3.5 m/s^2 of lateral grip: fine at mu = 1, not at mu = 0.3
    nominal, _ = _drive(open_floor, [], 1.4, 2.5, 4.0)
    slippery, _ = _drive(open_floor, ["friction=0.3"], 1.4, 2.5, 4.0)
    err_nominal = np.abs(nominal[-25:] - (1.4, 2.5)).mean(axis=0)
    err_slippery = np.abs(slippery[-25:] - (1.4, 2.5)).mean(axis=0)
    assert err_nominal[0] < 0.02 and err_nominal[1] < 0.03
    assert err_slippery[1] > 0.1 and err_slippery[0] > 0.3


@pytest.mark.parametrize("items", [["mass=2"], ["torque_limit=0.3"]])
def test_mass_and_torque_limit_slow_the_acceleration(open_floor, items):
    nominal, _ = _drive(open_floor, [], 1.0, 0.0, 0.2)
    heavy, _ = _drive(open_floor, items, 1.0, 0.0, 0.2)
    assert nominal[-1, 0] > 0.95
    assert heavy[-1, 0] < 0.75 * nominal[-1, 0]


def test_actuator_gain_slows_the_servo(open_floor):
    # a small step keeps the servo out of its torque limit, where only the gain matters
    nominal, _ = _drive(open_floor, [], 0.05, 0.0, 0.06)
    soft, _ = _drive(open_floor, ["actuator_gain=0.3"], 0.05, 0.0, 0.06)
    assert soft[-1, 0] < 0.85 * nominal[-1, 0]


class _Script:
    """Ramps v to 1 m/s over 10 steps at a constant yaw rate; records nothing itself."""

    name = "script"
    dt = 0.1
    needs_ranges = False

    def __init__(self):
        self.k = 0

    def reset(self, pose):
        self.k = 0

    def step(self, obs):
        self.k += 1
        return Command(v=min(0.1 * self.k, 1.0), w=0.3, solve_ms=0.0)


def _episode(scenario, items, seed=1):
    return run_episode(Plant(scenario), _Script(), np.zeros(3), np.array([40.0, 40.0]),
                       RunConfig(time_limit_s=10.0), parse_mismatch(items), np.random.default_rng(seed))


@pytest.mark.parametrize("delay", [1, 3])
def test_delay_applies_each_command_that_many_steps_late(open_floor, delay):
    tr = _episode(open_floor, [f"delay={delay}"]).trace
    cmd, applied = np.array(tr.cmd), np.array(tr.applied)
    assert np.all(applied[:delay] == 0.0)
    np.testing.assert_array_equal(applied[delay:], cmd[:-delay])


def test_pose_noise_has_the_requested_std(open_floor):
    tr = _episode(open_floor, ["pos_noise=0.05", "yaw_noise=0.035"]).trace
    err = np.array(tr.measured) - np.array(tr.pose)
    assert err.shape == (100, 3)
    # 200 / 100 samples: the sample std is within 15 % of the true one with high probability
    assert err[:, :2].std() == pytest.approx(0.05, rel=0.15)
    assert err[:, 2].std() == pytest.approx(0.035, rel=0.2)
    assert abs(err[:, :2].mean()) < 0.015


def test_jitter_spreads_the_control_period(open_floor):
    tr = _episode(open_floor, ["jitter=0.3"]).trace
    periods = np.diff(tr.t)
    assert periods.min() >= 0.07 - 1e-9 and periods.max() <= 0.13 + 1e-9
    # uniform on [0.07, 0.13] s, rounded to the 2 ms physics step: std 0.1 * 0.3 / sqrt(3)
    assert periods.std() == pytest.approx(0.03 / math.sqrt(3), rel=0.2)
    assert np.diff(_episode(open_floor, []).trace.t) == pytest.approx(0.1)


def test_solve_budget_reaches_the_solver():
    from sanav_mj.control.factory import make_controller
    from sanav_mj.eval.prepare import prepare

    prep = prepare("single_rect")
    ctrl = make_controller("sa-mpc", prep.scenario, prep.grid, prep.areas, prep.plan, solve_budget_ms=0.5)
    assert ctrl.config.solve_budget_ms == 0.5
    assert ctrl.config.solver_settings().budget_ms == 0.5


# --------------------------------------------------------------------------- journal, resume, runs that raise

OUTPUTS = ("robustness.csv", "summary.csv", *PNGS)


def _sweep_args(out, **kw):
    return {"scenarios": ["single_rect"], "sweep": parse_sweep(["mass=1,2", "delay=0,1"]), "seeds": 3,
            "controller": "sa-mpc", "workers": 1, "out": out, "fixed": parse_mismatch(["friction=0.5"])} | kw


def test_resumed_sweep_equals_an_uninterrupted_one(tmp_path, monkeypatch):
    from sanav_mj.eval import campaign
    from sanav_mj.eval.campaign import CampaignInterrupted

    finished = []
    state = {"calls": 0, "interrupt_at": None}

    def run(job):
        state["calls"] += 1
        if state["calls"] == state["interrupt_at"]:
            raise KeyboardInterrupt
        finished.append(campaign.job_key(job))
        return _fake_doc(job)

    monkeypatch.setattr(campaign, "run_job", run)
    whole = run_robustness(**_sweep_args(tmp_path / "whole"))
    finished.clear()
    state.update(calls=0, interrupt_at=8)
    out = tmp_path / "rb"
    with pytest.raises(CampaignInterrupted) as info:
        run_robustness(**_sweep_args(out))
    assert (info.value.saved, info.value.total) == (7, 12)
    state.update(calls=0, interrupt_at=None)
    resumed = run_robustness(**_sweep_args(out), resume=True)
    assert len(finished) == len(set(finished)) == 12  # 7 before the interrupt, 5 after
    assert resumed == whole
    for name in OUTPUTS:
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes(), name


def test_resume_refuses_another_sweep_or_fixed_mismatch(tmp_path, monkeypatch):
    from sanav_mj.eval import campaign
    from sanav_mj.eval.campaign import JournalError

    monkeypatch.setattr(campaign, "run_job", _fake_doc)
    run_robustness(**_sweep_args(tmp_path))
    for kw, fragment in (({"sweep": parse_sweep(["mass=1,3", "delay=0,1"])}, "sweep="),
                         ({"fixed": parse_mismatch(["friction=0.4"])}, "fixed="),
                         ({"seeds": 2}, "runs=3"), ({"controller": "mpc"}, "controllers=")):
        with pytest.raises(JournalError, match=fragment):
            run_robustness(**_sweep_args(tmp_path, **kw), resume=True)
    # the worker count is not a setting of the results: a complete folder resumes with nothing to run
    monkeypatch.setattr(campaign, "run_job", None)
    run_robustness(**_sweep_args(tmp_path, workers=2), resume=True)


def test_runs_that_raise_are_left_out_of_the_rates(tmp_path, monkeypatch):
    from sanav_mj.eval import campaign

    def run(job):
        tags = dict(job.tags)
        if tags["mass"] == 2.0 and (tags["delay"] == 0 or job.seed == 2):
            raise RuntimeError("boom")
        return _fake_doc(job)

    monkeypatch.setattr(campaign, "run_job", run)
    out = tmp_path / "rb"
    summary = run_robustness(**_sweep_args(out))
    by_cell = {(r["mass"], r["delay"]): r for r in summary}
    assert [by_cell[(1.0, d)]["errors"] for d in (0.0, 1.0)] == [0, 0]
    cell = by_cell[(2.0, 1.0)]  # seeds 0 (stuck) and 1 (collision) ran; seed 2 raised
    assert (cell["runs"], cell["errors"]) == (2, 1)
    assert cell["success_rate"] == 0.0 and cell["collision_rate"] == 50.0
    assert cell["reasons"] == "collision 1, stuck 1"
    blank = by_cell[(2.0, 0.0)]  # every run raised: no rate, no clearance
    assert (blank["runs"], blank["errors"]) == (0, 3)
    assert math.isnan(blank["success_rate"]) and math.isnan(blank["collision_rate"])
    assert math.isnan(blank["min_clearance_m"])
    runs = _read(out / "robustness.csv")
    bad = [r for r in runs if r["reason"] == "error"]
    assert len(bad) == 4 and {r["error"] for r in bad} == {"RuntimeError: boom"}
    assert {(r["mass"], r["delay"], r["mismatch"]) for r in bad} == {
        ("2.0", "0", "mass=2.0 delay=0 friction=0.5"), ("2.0", "1", "mass=2.0 delay=1 friction=0.5")}
    cells = _read(out / "summary.csv")
    assert [c["errors"] for c in cells] == ["0", "3", "0", "1"]
    _assert_pngs(out)


# --------------------------------------------------------------------------- outputs: integers, per scenario, no path


def _capture_heat_maps(monkeypatch):
    from sanav_mj.eval import plots

    maps = {}
    real = plots.plot_heatmap

    def spy(values, x_key, x_values, y_key, y_values, title, path, **kw):
        maps[path.relative_to(path.parent.parent) if path.parent.name == "per_scenario" else path.name] = (
            np.asarray(values, dtype=float), list(x_values), list(y_values or []), title)
        return real(values, x_key, x_values, y_key, y_values, title, path, **kw)

    monkeypatch.setattr(plots, "plot_heatmap", spy)
    return maps


def test_integer_keys_are_written_as_integers(tmp_path, monkeypatch, fake_campaign_runs):
    fake_campaign_runs(_fake_doc)
    maps = _capture_heat_maps(monkeypatch)
    out = tmp_path / "rb"
    run_robustness(**_sweep_args(out))
    assert {r["delay"] for r in _read(out / "robustness.csv")} == {"0", "1"}
    assert [c["delay"] for c in _read(out / "summary.csv")] == ["0", "0", "1", "1"]
    assert json.loads((out / "meta.json").read_text())["sweep"] == {"mass": [1.0, 2.0], "delay": [0, 1]}
    _, xs, ys, title = maps["success_rate.png"]
    assert ys == ["0", "1"] and xs == ["1.0", "2.0"]
    assert title.startswith("single_rect / sa-mpc: success rate [%]")


def test_summary_and_heat_maps_per_scenario_and_pooled(tmp_path, monkeypatch, fake_campaign_runs):
    def doc(job):
        d = _fake_doc(job)
        if job.scenario == "u_shape":  # every u_shape run fails: the pooled rate is the mean of the two
            d.update(success=False, reason="stuck")
        return d

    fake_campaign_runs(doc)
    maps = _capture_heat_maps(monkeypatch)
    out = tmp_path / "rb"
    summary = run_robustness(**_sweep_args(out, scenarios=["single_rect", "u_shape"]))
    pooled = [r for r in summary if r["scenario"] == robustness.POOLED]
    per = {(r["scenario"], r["mass"], r["delay"]): r for r in summary if r["scenario"] != robustness.POOLED}
    assert len(pooled) == 4 and len(per) == 8
    cell = {(r["mass"], r["delay"]): r for r in pooled}[(1.0, 0)]
    assert (cell["runs"], cell["success_rate"]) == (6, 50.0)
    assert per[("single_rect", 1.0, 0)]["success_rate"] == 100.0 and per[("u_shape", 1.0, 0)]["success_rate"] == 0.0
    assert per[("u_shape", 1.0, 0)]["runs"] == 3
    by = _read(out / "summary_by_scenario.csv")
    assert [(c["scenario"], c["success_rate"]) for c in by if (c["mass"], c["delay"]) == ("1.0", "0")] == [
        ("single_rect", "100.0"), ("u_shape", "0.0")]
    assert {c["scenario"] for c in _read(out / "summary.csv")} == {"all"}
    assert maps["success_rate.png"][3].startswith("single_rect, u_shape / sa-mpc: success rate [%]")
    for name, rate in (("single_rect", 100.0), ("u_shape", 0.0)):
        values, _, _, title = maps[Path("per_scenario") / f"{name}_success_rate.png"]
        assert title.startswith(f"{name} / sa-mpc: success rate [%]")
        assert values[0, 0] == rate
        assert (out / "per_scenario" / f"{name}_min_clearance.png").read_bytes()[:4] == b"\x89PNG"


def test_runs_without_a_clearance_give_an_empty_field_not_inf(tmp_path, fake_campaign_runs):
    """A goal with no path: the run never moved and has no clearance (None); the point has none either."""
    def doc(job):
        d = _fake_doc(job)
        d.update(success=False, reason="no_path", steps=0, min_clearance_m=None)
        return d

    fake_campaign_runs(doc)
    out = tmp_path / "rb"
    summary = run_robustness(**_sweep_args(out))
    assert all(math.isnan(r["min_clearance_m"]) and r["success_rate"] == 0.0 for r in summary)
    cells = _read(out / "summary.csv")
    assert [c["min_clearance_m"] for c in cells] == [""] * 4
    assert "inf" not in (out / "summary.csv").read_text()
    assert {r["min_clearance_m"] for r in _read(out / "robustness.csv")} == {""}
    _assert_pngs(out)


@pytest.mark.parametrize("name", ["robustness.csv", "summary.csv", "summary_by_scenario.csv"])
def test_an_output_cut_by_a_full_disk_is_named_and_the_others_are_written(tmp_path, monkeypatch, fill_disk, name):
    from sanav_mj.eval import campaign

    monkeypatch.setattr(campaign, "run_job", _fake_doc)
    fill_disk(keep=150, ending=name)
    out = tmp_path / "rb"
    with pytest.raises(OSError) as info:
        run_robustness(**_sweep_args(out, scenarios=["single_rect", "u_shape"]))
    assert info.value.filename == str(out / name) and "No space left on device" in str(info.value)
    expected = {"meta.json", "runs.jsonl", "robustness.csv", "summary.csv", "summary_by_scenario.csv", *PNGS,
                "per_scenario"} - {name}
    assert sorted(p.name for p in out.iterdir()) == sorted(expected)  # no cut file, no temporary file
    assert len(list((out / "per_scenario").iterdir())) == 2 * len(PNGS)
    assert json.loads((out / "meta.json").read_text())["wall_time_s"] > 0


def test_the_streamed_sweep_summary_equals_a_grouping_of_all_rows():
    """:class:`SweepSummary` (fed row by row) against a plain grouping of every row."""
    from sanav_mj.eval.robustness import SweepSummary

    rng = np.random.default_rng(3)
    names = {"a": "a", "b": "b"}
    rows = []
    for i in range(600):
        cell = (int(rng.integers(2)), int(rng.integers(3)))
        r = {"scenario": str(rng.choice(["a", "b"])), "success": bool(rng.random() < 0.5),
             "reason": str(rng.choice(["goal", "stuck"])), "collisions": int(rng.integers(0, 2)),
             "min_clearance_m": None if i % 7 == 0 else float(rng.uniform(-0.1, 1.0)), "_cell": cell}
        if i % 19 == 0:
            r = {"scenario": r["scenario"], "success": False, "reason": "error", "_cell": cell}
        rows.append(r)
    acc = SweepSummary(names)
    for r in rows:
        acc.add(r, r["_cell"])
    for scenario in (None, "a", "b"):
        got = acc.cells("mass", [1.0, 2.0, 3.0], "delay", [0, 1], scenario)
        for row, (yi, xi) in got:
            cell = [r for r in rows if r["_cell"] == (yi, xi) and scenario in (None, r["scenario"])]
            ran = [r for r in cell if r["reason"] != "error"]
            clear = [r["min_clearance_m"] for r in ran if r.get("min_clearance_m") is not None]
            assert (row["runs"], row["errors"]) == (len(ran), len(cell) - len(ran))
            assert row["success_rate"] == 100.0 * sum(r["success"] for r in ran) / len(ran)
            assert row["collision_rate"] == 100.0 * sum(r["collisions"] > 0 for r in ran) / len(ran)
            assert row["min_clearance_m"] == min(clear)
            counts = {k: sum(r["reason"] == k for r in ran) for k in ("goal", "stuck")}
            assert row["reasons"] == ", ".join(f"{k} {v}" for k, v in counts.items() if v)


def test_the_campaign_scripts_report_aggregates_as_summary_csv(tmp_path, monkeypatch, fake_campaign_runs):
    """scripts/robustness_campaign.py reads robustness.csv back through :class:`CellSummary`:
    over one grid point its numbers are summary.csv's, a run that raised left out (it used to
    stop the report on the error row's empty ``collisions``)."""
    import importlib.util
    import sys

    from sanav_mj.eval.campaign import error_row

    spec = importlib.util.spec_from_file_location(
        "robustness_campaign", Path(__file__).resolve().parents[2] / "scripts" / "robustness_campaign.py")
    script = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, script)  # its dataclasses look their module up
    spec.loader.exec_module(script)

    def doc(job):
        if job.seed == 0:
            return error_row(job, RuntimeError("boom"))
        d = _fake_doc(job)
        if job.seed == 1:
            d.update(success=False, reason="collision", collisions=2, min_clearance_m=-0.02)
        if job.seed == 2:
            d.update(success=False, reason="no_path", steps=0, min_clearance_m=None)
        return d

    fake_campaign_runs(doc)
    out = tmp_path / "rb"
    (cell,) = run_robustness(["single_rect"], parse_sweep(["mass=1", "delay=0"]), seeds=4, controller="sa-mpc", workers=1,
                             out=out)
    rows = _read(out / "robustness.csv")
    assert len(rows) == 4 and rows[0]["collisions"] == ""  # the error row, with no metrics
    n, succ, coll, clear = script._aggregate(rows)
    assert (n, succ, coll, clear) == (cell["runs"], cell["success_rate"], cell["collision_rate"],
                                      cell["min_clearance_m"])
    assert (n, succ, coll, clear) == (3, 100.0 / 3, 100.0 / 3, -0.02)
    assert script._aggregate([]) == (0, 0.0, 0.0, script._aggregate([])[3]) and math.isnan(script._aggregate([])[3])
    acc = script._cell(rows)
    assert (acc.all, acc.success, acc.reasons) == (4, 1, {"collision": 1, "no_path": 1, "goal": 1})
