"""Campaigns on Ray: files that travel with the tasks, and the same rows as the process pool on
a real local Ray with two CPUs (started once for this module)."""

from __future__ import annotations

import csv
import json
import logging
import shutil
import sys

import pytest

from sanav_mj.eval.bench import run_bench
from sanav_mj.eval.campaign import CampaignInterrupted, ClusterError, Job, read_journal, run_jobs
from sanav_mj.eval.ray_runner import RayExecutor, ray_session, scenario_bundle, unpack
from sanav_mj.eval.robustness import parse_sweep, run_robustness
from sanav_mj.resources import robot_model_path, scenarios_dir
from sanav_mj.scene import load_scenario

#: columns that hold wall-clock measurements (differ between any two executions)
WALL_CLOCK = ("solve_mean_ms", "solve_max_ms", "solve_std_ms", "solve_p99_ms",
              "pipeline_mean_ms", "pipeline_max_ms", "pipeline_std_ms")


def _user_scenario(folder, absolute=False):
    """A user's scenario outside the package: ``folder/maps/narrow.xml`` including
    ``folder/robots/diff_drive.xml`` by a relative path (or by its absolute path)."""
    (folder / "maps").mkdir(parents=True)
    (folder / "robots").mkdir()
    shutil.copy(robot_model_path(), folder / "robots" / "diff_drive.xml")
    text = (scenarios_dir() / "single_rect.xml").read_text()
    include = str(folder / "robots" / "diff_drive.xml") if absolute else "../robots/diff_drive.xml"
    assert "../models/diff_drive.xml" in text
    (folder / "maps" / "narrow.xml").write_text(text.replace("../models/diff_drive.xml", include))
    return folder / "maps" / "narrow.xml"


@pytest.mark.parametrize("absolute", [False, True])
def test_a_bundle_runs_without_the_users_files(tmp_path, absolute):
    path = _user_scenario(tmp_path / "user", absolute)
    bundle = scenario_bundle(str(path))
    assert bundle.main == "maps/narrow.xml"
    assert [name for name, _ in bundle.files] == ["maps/narrow.xml", "robots/diff_drive.xml"]
    original = load_scenario(str(path))
    shutil.rmtree(tmp_path / "user")  # the node has none of the user's files
    copy = load_scenario(str(unpack(bundle)))
    assert copy.name == original.name == "narrow"
    assert copy.model.nbody == original.model.nbody and copy.model.ngeom == original.model.ngeom
    assert (copy.model.geom_size == original.model.geom_size).all()
    assert (copy.model.geom_pos == original.model.geom_pos).all()
    assert scenario_bundle("single_rect").main == "scenarios/single_rect.xml"  # a built-in travels too


def test_without_ray_the_option_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    from sanav_mj.cli import main

    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed: import ray raises ImportError
    with pytest.raises(ClusterError, match=r"Ray is not installed; install it with python -m pip install -e"):
        with ray_session():
            pass
    out = tmp_path / "b"
    assert main(["bench", "single_rect", "--controllers", "dwa", "--runs", "1", "--out", str(out), "--ray"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("sanav-mj: error: --ray: Ray is not installed")
    assert '".[cluster]"' in err
    assert not (out / "meta.json").exists() and not (out / "runs.jsonl").exists()  # nothing written


def test_the_cli_starts_a_local_ray_quietly(tmp_path):
    """Ray's start-up and shut-down print nothing on the command's stderr (only the progress bar)."""
    import os
    import subprocess

    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [os.getcwd(), os.environ.get("PYTHONPATH")])))
    out = tmp_path / "b"
    proc = subprocess.run([sys.executable, "-m", "sanav_mj.cli", "bench", "single_rect", "--controllers", "dwa",
                           "--runs", "1", "--out", str(out), "--ray"], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.replace("\r", "\n").splitlines() if line.strip()]
    assert lines and all(line.startswith("bench:") for line in lines), lines  # tqdm's bar, nothing else
    assert json.loads((out / "meta.json").read_text())["executor"] == "ray"
    assert len(read_journal(out / "runs.jsonl")) == 1


# --------------------------------------------------------------------------- on a real local Ray

@pytest.fixture(scope="module")
def session():
    import ray

    # "local": a new instance even where a cluster runs (or a stale /tmp/ray/ray_current_cluster remains)
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False,
             logging_level=logging.ERROR)
    try:
        with ray_session() as s:  # uses the running instance, leaves it open
            assert s.cpus == 2
            yield s
    finally:
        ray.shutdown()


def _csv(path, drop=WALL_CLOCK):
    with open(path, newline="") as fh:
        return [{k: v for k, v in r.items() if k not in drop} for r in csv.DictReader(fh)]


def _journal(path):
    return {k: {f: v for f, v in r.items() if f not in ("solve_ms", "pipeline_ms")}
            for k, r in read_journal(path).items()}


def test_bench_on_ray_gives_the_pools_rows(tmp_path, session):
    scenario = str(_user_scenario(tmp_path / "user"))
    args = ([scenario, "u_shape"], ["sa-mpc", "dwa"], 2)
    pool = run_bench(*args, workers=2, out=tmp_path / "pool", time_limit_s=15.0)
    ray = run_bench(*args, workers=2, out=tmp_path / "ray", time_limit_s=15.0, ray=session, record=True)
    rows = _csv(tmp_path / "ray" / "results.csv")
    assert rows == _csv(tmp_path / "pool" / "results.csv")
    assert [(r["scenario"], r["controller"], r["seed"]) for r in rows][:2] == [("narrow", "sa-mpc", "0"),
                                                                               ("narrow", "sa-mpc", "1")]
    assert all(int(r["steps"]) > 0 for r in rows)
    assert _journal(tmp_path / "ray" / "runs.jsonl") == _journal(tmp_path / "pool" / "runs.jsonl")
    drop = ("solve_mean_ms", "solve_max_ms", "solve_std_ms", "pipeline_mean_ms", "pipeline_max_ms", "pipeline_std_ms")
    assert [{k: v for k, v in s.items() if k not in drop} for s in ray] == \
        [{k: v for k, v in s.items() if k not in drop} for s in pool]
    # recordings made on the workers arrive on the driver
    rrds = sorted(p.name for p in (tmp_path / "ray" / "rrd").iterdir())
    assert rrds == sorted(f"{s}_{c}_{k}.rrd" for s in ("narrow", "u_shape") for c in ("sa-mpc", "dwa") for k in (0, 1))
    assert all((tmp_path / "ray" / "rrd" / name).stat().st_size > 0 for name in rrds)
    meta = json.loads((tmp_path / "ray" / "meta.json").read_text())
    assert meta["executor"] == "ray" and json.loads((tmp_path / "pool" / "meta.json").read_text())["executor"] is None


def test_error_rows_and_robustness_on_ray_equal_the_pools(tmp_path, session):
    jobs = [Job("single_rect", "dwa", 0, ("delay=-1",), 5.0), Job("single_rect", "dwa", 1, ("friction=0.5",), 5.0)]
    on_ray = run_jobs(jobs, executor=RayExecutor(session))
    on_pool = run_jobs(jobs, workers=2)
    assert on_ray[0]["reason"] == "error" and on_ray[0] == on_pool[0]  # the same error row
    assert {k: v for k, v in on_ray[1].items() if k not in ("solve_ms", "pipeline_ms")} == \
        {k: v for k, v in on_pool[1].items() if k not in ("solve_ms", "pipeline_ms")}
    args = {"scenarios": ["single_rect"], "sweep": parse_sweep(["mass=1,1.5"]), "seeds": 2, "controller": "dwa",
            "workers": 2, "time_limit_s": 15.0}
    run_robustness(**args, out=tmp_path / "pool")
    run_robustness(**args, out=tmp_path / "ray", ray=session)
    assert _csv(tmp_path / "ray" / "robustness.csv") == _csv(tmp_path / "pool" / "robustness.csv")
    assert (tmp_path / "ray" / "summary.csv").read_text() == (tmp_path / "pool" / "summary.csv").read_text()


def test_ctrl_c_on_ray_cancels_the_tasks_keeps_the_finished_and_resumes(tmp_path, session, monkeypatch, ctrl_c_after):
    args = (["single_rect", "u_shape"], ["dwa"], 3)
    ctrl_c_after(2)  # Ctrl-C when the second row has been journalled
    out = tmp_path / "b"
    with pytest.raises(CampaignInterrupted) as info:
        run_bench(*args, workers=2, out=out, time_limit_s=10.0, ray=session)
    assert (info.value.saved, info.value.total) == (2, 6)
    assert len(read_journal(out / "runs.jsonl")) == 2 and not (out / "results.csv").exists()
    import time

    import ray

    # the tasks in flight were cancelled: both CPUs are free again at once (the u_shape runs take seconds)
    deadline = time.monotonic() + 2
    while ray.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert ray.available_resources().get("CPU", 0) == 2
    monkeypatch.undo()
    run_bench(*args, workers=2, out=out, time_limit_s=10.0, ray=session, resume=True)
    run_bench(*args, workers=2, out=tmp_path / "whole", time_limit_s=10.0)
    assert _csv(out / "results.csv") == _csv(tmp_path / "whole" / "results.csv")


def test_the_ray_option_takes_an_address_not_a_scenario(capsys):
    from sanav_mj.cli import build_parser, main

    parse = build_parser().parse_args
    assert parse(["bench", "u_shape", "--ray"]).ray is True
    assert parse(["bench", "--ray", "auto"]).ray == "auto"
    assert parse(["robustness", "u_shape", "--ray", "ray://10.1.2.3:10001"]).ray == "ray://10.1.2.3:10001"
    assert parse(["robustness", "u_shape", "--ray", "head-node:6379"]).ray == "head-node:6379"
    assert parse(["bench", "u_shape"]).ray is None
    assert main(["bench", "--ray", "u_shape"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected auto, HOST:PORT or ray://HOST:PORT, got 'u_shape'" in err


def test_ray_takes_jobs_lazily_with_two_per_cpu_in_flight(tmp_path, session, ctrl_c_after, endless_jobs):
    jobs, taken = endless_jobs(10**9, 3.0)
    ctrl_c_after(3, total=10**9)  # Ctrl-C when the third row has been journalled
    executor = RayExecutor(session)
    assert executor.slots == 4  # 2 x the 2 CPUs
    with pytest.raises(CampaignInterrupted) as info:
        run_jobs(jobs, journal=tmp_path / "runs.jsonl", executor=executor)
    assert info.value.saved == 3 and len(read_journal(tmp_path / "runs.jsonl")) == 3
    assert 3 + 1 <= len(taken) <= 3 + executor.slots  # the finished ones plus at most 4 in flight
