"""Command line: every bad-input path gives one line on stderr and exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from sanav_mj.cli import main


def _run(argv, capsys):
    code = main(argv)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


BAD = [
    (["run", "no_such_scenario"], "no_such_scenario"),
    (["run", "u_shape", "--seed", "-1"], "--seed"),
    (["run", "u_shape", "--seed", "x"], "--seed"),
    (["run", "u_shape", "--yaw", "nan"], "--yaw"),
    (["run", "u_shape", "--controller", "ppo"], "--controller"),
    (["run", "u_shape", "--resolution", "0"], "--resolution"),
    (["run", "u_shape", "--resolution", "5"], "--resolution"),
    (["run", "u_shape", "--time-limit", "-3"], "--time-limit"),
    (["run", "u_shape", "--mismatch", "bogus=1"], "unknown key 'bogus'"),
    (["run", "u_shape", "--mismatch", "wheel_radius=3"], "wheel_radius"),
    (["run", "u_shape", "--mismatch", "delay"], "KEY=VALUE"),
    (["areas", "u_shape", "--resolution", "abc"], "--resolution"),
    (["bench", "--runs", "0"], "--runs"),
    (["bench", "--workers", "0"], "--workers"),
    (["bench", "nowhere.xml"], "nowhere.xml"),
    (["robustness", "u_shape", "--sweep", "bogus=1,2"], "unknown key 'bogus'"),
    (["robustness", "u_shape", "--sweep", "friction=a,b"], "comma-separated numbers"),
    (["robustness", "u_shape", "--sweep", "friction=0.3", "track=1", "mass=1"], "one or two"),
    (["robustness", "u_shape", "--sweep", "friction=0.3", "friction=0.5"], "given twice"),
    (["robustness", "u_shape", "--sweep", "friction=9"], "friction"),
    (["robustness", "u_shape", "--fixed", "bogus=1"], "--fixed 'bogus=1': unknown key 'bogus'"),
    (["robustness", "u_shape", "--fixed", "friction=9"], "--fixed: mismatch friction"),
    (["robustness", "u_shape", "--fixed", "delay"], "--fixed 'delay': expected KEY=VALUE"),
    (["robustness", "u_shape", "--fixed", "delay=1", "delay=2"], "--fixed 'delay=2': key 'delay' given twice"),
    (["robustness", "u_shape", "--fixed"], "--fixed"),
    (["robustness", "u_shape", "--sweep", "friction=0.3,1", "--fixed", "friction=0.5"],
     "--fixed 'friction=0.5': key 'friction' is also swept"),
    (["robustness", "u_shape", "--sweep", "delay=0,1", "--fixed", "delay=0"], "key 'delay' is also swept"),
    (["robustness", "u_shape", "--time-limit", "0"], "--time-limit"),
    (["robustness", "u_shape", "--time-limit", "soon"], "--time-limit"),
    (["robustness", "u_shape", "--time-limit", "inf"], "--time-limit"),
    (["robustness", "u_shape", "--time-limit", "1e308"], "--time-limit: expected 0 < S <= 86400"),
    (["robustness", "no_such_scenario"], "no_such_scenario"),
    (["run", "u_shape", "--time-limit", "1e308"], "--time-limit"),
    (["frobnicate"], "invalid choice"),
    ([], "required"),
]


@pytest.mark.parametrize("argv, fragment", BAD, ids=[" ".join(a) or "<none>" for a, _ in BAD])
def test_bad_input_exit_2_one_line(argv, fragment, capsys):
    code, out, err = _run(argv, capsys)
    assert code == 2
    assert err.startswith("sanav-mj")
    assert err.count("\n") == 1, err
    assert fragment in err
    assert "Traceback" not in err


def test_bad_scenario_file(tmp_path, capsys):
    bad = tmp_path / "broken.xml"
    bad.write_text("<mujoco><worldbody><geom type='box'")
    code, _, err = _run(["areas", str(bad)], capsys)
    assert code == 2 and "broken.xml" in err and err.count("\n") == 1


def test_output_in_unwritable_place(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = _run(["areas", "single_rect", "--json", str(blocker / "sub" / "a.json")], capsys)
    assert code == 2 and "a.json" in err and err.count("\n") == 1


def test_output_path_is_a_folder(tmp_path, capsys):
    code, _, err = _run(["areas", "single_rect", "--json", str(tmp_path)], capsys)
    assert code == 2 and "folder" in err


def test_areas_json_contract(tmp_path, capsys):
    out = tmp_path / "a.json"
    code, stdout, _ = _run(["areas", "u_shape", "--json", str(out)], capsys)
    assert code == 0
    doc = json.loads(out.read_text())
    assert set(doc) >= {"scenario", "grid", "leaves", "rects", "edges", "corridor", "reference", "timing_ms"}
    assert set(doc["timing_ms"]) >= {"rasterise", "quadtree", "merge", "graph", "total"}
    assert doc["scenario"] == "u_shape"
    assert len(doc["grid"]["shape"]) == 2 and doc["grid"]["resolution"] == pytest.approx(0.05)
    n = len(doc["rects"])
    assert n > 1 and all(0 <= i < n and 0 <= j < n and w > 0 for i, j, w in doc["edges"])
    assert doc["corridor"] and all(0 <= i < n for i in doc["corridor"])
    assert len(doc["reference"]) > 10 and all(len(p) == 3 for p in doc["reference"])
    assert "safe areas" in stdout


def test_console_script_module_entry():
    """``python -m sanav_mj.cli`` behaves like the console script (exit 2 on bad input)."""
    proc = subprocess.run([sys.executable, "-m", "sanav_mj.cli", "run", "nope"], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


def _fake_doc(job):
    """A run document (no simulation): success unless the run has a delay."""
    from sanav_mj.sim.mismatch import parse_mismatch

    mismatch = dict(item.split("=") for item in job.mismatch)
    stats = {"mean": 1.0, "max": 2.0, "std": 0.5, "p50": 1.0, "p99": 2.0}
    return {
        "scenario": job.scenario, "controller": job.controller, "seed": job.seed,
        "success": "delay" not in mismatch, "reason": "goal" if "delay" not in mismatch else "stuck",
        "steps": 10, "sim_time_s": 1.0, "path_length_m": 1.0, "min_clearance_m": 0.2, "collisions": 0,
        "safe_area_violations": 0, "solver_failures": 0, "solve_ms": stats, "pipeline_ms": stats,
        "mismatch": parse_mismatch(list(job.mismatch)).changed(),  # as a run writes it (resume checks it)
        **dict(job.tags),
    }


def test_robustness_fixed_and_time_limit_reach_every_run(tmp_path, capsys, fake_campaign_runs):
    seen = fake_campaign_runs(_fake_doc)
    out = tmp_path / "rb"
    code, stdout, err = _run(["robustness", "single_rect", "--sweep", "wheel_radius=0.9,1.1", "--seeds", "2",
                              "--fixed", "friction=0.3", "delay=1", "--time-limit", "12.5", "--out", str(out)], capsys)
    assert code == 0, err
    assert len(seen) == 4
    assert {j.mismatch for j in seen} == {("wheel_radius=0.9", "friction=0.3", "delay=1"),
                                          ("wheel_radius=1.1", "friction=0.3", "delay=1")}
    assert {j.time_limit_s for j in seen} == {12.5}
    meta = json.loads((out / "meta.json").read_text())
    assert meta["fixed"] == {"friction": 0.3, "delay": 1}
    assert meta["sweep"] == {"wheel_radius": [0.9, 1.1]}
    assert meta["time_limit_s"] == 12.5 and meta["runs"] == 2 and meta["controllers"] == ["sa-mpc"]
    assert "wrote" in stdout and "success_rate=0" in stdout


def test_robustness_defaults_without_fixed(tmp_path, capsys, fake_campaign_runs):
    seen = fake_campaign_runs(_fake_doc)
    code, _, err = _run(["robustness", "single_rect", "--seeds", "1", "--out", str(tmp_path / "rb")], capsys)
    assert code == 0, err
    assert {j.time_limit_s for j in seen} == {60.0}
    assert {j.mismatch for j in seen} == {("wheel_radius=0.9",), ("wheel_radius=1.0",), ("wheel_radius=1.1",)}
    assert json.loads((tmp_path / "rb" / "meta.json").read_text())["fixed"] == {}


@pytest.mark.parametrize("command", [["robustness", "single_rect", "--seeds", "1"],
                                     ["bench", "single_rect", "--runs", "1", "--controllers", "dwa"],
                                     ["demo", "--no-rrd"]])
def test_out_folder_that_is_a_file_or_under_one(tmp_path, capsys, command):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for out, fragment in ((blocker, "expected a folder, got a file"), (blocker / "sub", "cannot create the folder")):
        code, _, err = _run(command + ["--out", str(out)], capsys)
        assert code == 2, err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert f"--out {out}: {fragment}" in err
    assert blocker.read_text() == "x"


def test_bad_scenario_creates_no_out_folder(tmp_path, capsys):
    for command in (["robustness", "nowhere.xml"], ["bench", "nowhere.xml"]):
        code, _, err = _run(command + ["--out", str(tmp_path / "o")], capsys)
        assert code == 2 and "nowhere.xml" in err
        assert not (tmp_path / "o").exists()


needs_dev_full = pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (a device that is always full)")


@needs_dev_full
def test_areas_output_that_fails_to_write_is_one_line_and_the_other_output_is_kept(tmp_path, capsys):
    png = tmp_path / "a.png"
    code, _, err = _run(["areas", "single_rect", "--json", "/dev/full", "--plot", str(png)], capsys)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "/dev/full: cannot write" in err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@needs_dev_full
def test_run_result_is_printed_and_kept_when_an_output_fails(tmp_path, capsys):
    js = tmp_path / "r.json"
    code, out, err = _run(["run", "single_rect", "--controller", "dwa", "--time-limit", "0.5",
                           "--json", str(js), "--plot", "/dev/full"], capsys)
    assert code == 2
    assert err.count("\n") == 1 and "/dev/full: cannot write" in err and "Traceback" not in err
    assert "single_rect / dwa seed 0: timeout" in out  # the result line is not lost
    assert json.loads(js.read_text())["reason"] == "timeout"


def test_an_os_error_mid_way_is_one_line(tmp_path, monkeypatch, capsys):
    from sanav_mj.eval import demo

    def full_disk(out, record, sensing="map", footprint="disc"):  # raised by run_demo itself (not an output it notes)
        raise OSError(28, "No space left on device", "out/demo/u_shape.json")

    monkeypatch.setattr(demo, "run_demo", full_disk)
    code, _, err = _run(["demo", "--no-rrd", "--out", str(tmp_path)], capsys)
    assert code == 2
    assert err == "sanav-mj: error: out/demo/u_shape.json: No space left on device\n"


@needs_dev_full
def test_recording_that_cannot_be_written_is_one_line(capsys):
    code, _, err = _run(["run", "single_rect", "--controller", "dwa", "--time-limit", "0.5", "--rrd", "/dev/full"],
                        capsys)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "/dev/full: cannot write the recording" in err


@pytest.mark.parametrize("argv", [["run", "u_shape", "--json", "{d}/x", "--plot", "{d}/x"],
                                  ["run", "u_shape", "--rrd", "{d}/x", "--json", "{d}/./x"],
                                  ["areas", "u_shape", "--json", "{d}/x", "--plot", "{d}/sub/../x"]])
def test_two_outputs_in_one_file_is_bad_input(tmp_path, capsys, argv):
    (tmp_path / "sub").mkdir()
    code, _, err = _run([a.format(d=tmp_path) for a in argv], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "the same file as" in err
    assert not (tmp_path / "x").exists()  # found before any work or output


def test_closed_stdout_stops_quietly():
    """``sanav-mj areas u_shape | head -0``: no traceback, no error line, exit 141 (SIGPIPE)."""
    proc = subprocess.Popen([sys.executable, "-m", "sanav_mj.cli", "areas", "u_shape"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # before the child prints its summary line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert err == ""


# --------------------------------------------------------------------------- campaigns: journal, resume, errors


def _messages(err):
    """The sanav-mj lines of stderr (the progress bar writes there too)."""
    return [line for line in err.replace("\r", "\n").splitlines() if line.startswith("sanav-mj")]


@pytest.fixture
def fake_campaign(monkeypatch):
    """Runs are :func:`_fake_doc` (seed 1 raises); ``state["interrupt_at"]``: the call that gets Ctrl-C."""
    from sanav_mj.eval import campaign

    state = {"calls": 0, "interrupt_at": None, "finished": []}

    def run(job):
        state["calls"] += 1
        if state["calls"] == state["interrupt_at"]:
            raise KeyboardInterrupt
        if job.seed == 1:
            raise RuntimeError("worker fell over")
        state["finished"].append(campaign.job_key(job))
        return _fake_doc(job)

    monkeypatch.setattr(campaign, "run_job", run)
    return state


@pytest.mark.parametrize("command", [["bench", "single_rect", "--controllers", "dwa", "mpc", "--runs", "3"],
                                     ["robustness", "single_rect", "--sweep", "delay=0,1", "--seeds", "3"]])
def test_campaign_interrupt_resume_and_raised_runs(tmp_path, capsys, fake_campaign, command):
    out = tmp_path / "o"
    argv = command + ["--workers", "1", "--out", str(out)]
    fake_campaign["interrupt_at"] = 4
    code, stdout, err = _run(argv, capsys)
    assert code == 130 and "Traceback" not in err
    assert _messages(err) == [(f"sanav-mj: interrupted: 3 of 6 runs saved in {out / 'runs.jsonl'}; "
                              "run the same command with --resume to finish")]
    assert len((out / "runs.jsonl").read_text().splitlines()) == 3

    # --resume: only the other runs; seed 1 raised, so it runs again (and raises again): exit 3
    fake_campaign.update(calls=0, interrupt_at=None)
    code, stdout, err = _run(argv + ["--resume"], capsys)
    csv_name = "results.csv" if command[0] == "bench" else "robustness.csv"
    assert code == 3
    assert _messages(err) == [(f"sanav-mj: 2 run(s) raised; see the rows with reason 'error' in {out / csv_name} "
                              "(left out of the rates; --resume runs them again)")]
    assert len(fake_campaign["finished"]) == len(set(fake_campaign["finished"])) == 4
    assert "wrote" in stdout
    rows = (out / csv_name).read_text().splitlines()
    assert len(rows) == 7 and sum("RuntimeError: worker fell over" in r for r in rows) == 2

    # other settings: one line, exit 2, nothing run
    fake_campaign["finished"].clear()
    other = [a if a != "3" else "2" for a in argv]  # --runs / --seeds 2
    code, _, err = _run(other + ["--resume"], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"sanav-mj: error: --resume: {out} was run with runs=3, this command has runs=2")
    assert fake_campaign["finished"] == []

    # a journal line that is not one (not the last): one line, exit 2
    journal = out / "runs.jsonl"
    journal.write_text("{oops\n" + journal.read_text())
    code, _, err = _run(argv + ["--resume"], capsys)
    assert code == 2 and err.count("\n") == 1 and "runs.jsonl:1: not a journal line" in err


# --------------------------------------------------------------------------- runs that cannot succeed

#: four walls around the goal (6, 0): no corridor reaches it
WALLED = "".join(f'<geom name="w{i}" type="box" pos="{x} {y} 0.25" size="{sx} {sy} 0.25"/>'
                 for i, (x, y, sx, sy) in enumerate([(6, 1, 1.1, 0.1), (6, -1, 1.1, 0.1), (5, 0, 0.1, 1.1),
                                                     (7, 0, 0.1, 1.1)]))


def test_a_goal_that_cannot_be_reached_is_an_outcome_line_and_exit_1(tmp_path, capsys, write_scenario):
    scenario = write_scenario(WALLED, name="walled", goal="6 0")
    js = tmp_path / "w.json"
    code, out, err = _run(["run", str(scenario), "--json", str(js)], capsys)
    assert (code, err) == (1, "")
    assert out == ("walled / sa-mpc seed 0: no_path: no corridor of safe areas joins the start to the goal; "
                   "the robot did not move\n")
    doc = json.loads(js.read_text())
    assert doc["reason"] == "no_path" and doc["steps"] == 0
    # the robot stayed at its start (0, 0): the nearest wall face is x = 4.9, 4.9 m away, beyond
    # the plant's 2 m distance cap, so the clearance is the cap, a number (DESIGN: not null)
    assert doc["min_clearance_m"] == 2.0
    code, out, err = _run(["areas", str(scenario)], capsys)
    assert (code, err) == (0, "") and "no path from the start to the goal" in out


# --------------------------------------------------------------------------- the run line shows trouble


def _doc(**kw):
    stats = {"mean": 1.25, "max": 2.0, "std": 0.5, "p50": 1.0, "p99": 1.75}
    return {"scenario": "u_shape", "controller": "sa-mpc", "seed": 3, "success": True, "reason": "goal", "steps": 200,
            "sim_time_s": 20.0, "path_length_m": 8.5, "min_clearance_m": 0.125, "collisions": 0,
            "safe_area_violations": 0, "solver_failures": 0, "solve_ms": stats, "mismatch": {}} | kw


def test_run_line_shows_violations_failures_and_the_mismatch():
    from sanav_mj.cli import run_line

    clean = run_line(_doc())
    assert clean == ("u_shape / sa-mpc seed 3: goal after 200 steps (20.0 s), path 8.50 m, min clearance 0.125 m, "
                     "collisions 0, solve 1.25 ms mean / 1.75 ms p99")
    line = run_line(_doc(safe_area_violations=10, solver_failures=24, mismatch={"delay": 1, "friction": 0.3}))
    assert line == ("u_shape / sa-mpc seed 3: goal after 200 steps (20.0 s), path 8.50 m, min clearance 0.125 m, "
                    "collisions 0, safe-area violations 10, solver failures 24, mismatch delay=1 friction=0.3, "
                    "solve 1.25 ms mean / 1.75 ms p99")
    assert "min clearance n/a," in run_line(_doc(min_clearance_m=None, reason="timeout"))


# --------------------------------------------------------------------------- outputs: formats, ~, no empty files


def test_plot_format_from_the_extension_and_others_refused_before_any_run(tmp_path, capsys, monkeypatch):
    from sanav_mj.eval import episode

    for ext, magic in ((".pdf", b"%PDF"), (".svg", b"<?xml"), (".png", b"\x89PNG"), ("", b"\x89PNG")):
        path = tmp_path / f"map{ext}"
        code, _, err = _run(["areas", "single_rect", "--plot", str(path)], capsys)
        assert code == 0, err
        assert path.read_bytes()[:len(magic)] == magic, ext
    monkeypatch.setattr(episode, "run_scenario", lambda *a, **k: pytest.fail("ran before refusing --plot"))
    code, _, err = _run(["run", "single_rect", "--plot", str(tmp_path / "r.txt"), "--json", str(tmp_path / "r.json")],
                        capsys)
    assert code == 2 and err.count("\n") == 1
    assert f"--plot: {tmp_path / 'r.txt'}: expected a figure file ending in one of" in err and "'.txt'" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map", "map.pdf", "map.png", "map.svg"]


def test_output_paths_expand_the_home_folder(tmp_path, capsys, monkeypatch):
    home, cwd = tmp_path / "home", tmp_path / "cwd"
    home.mkdir()
    cwd.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(cwd)
    code, _, err = _run(["areas", "single_rect", "--json", "~/x.json", "--plot", "~/sub/x.png"], capsys)
    assert code == 0, err
    assert json.loads((home / "x.json").read_text())["scenario"] == "single_rect"
    assert (home / "sub" / "x.png").exists()
    assert list(cwd.iterdir()) == []  # no folder named "~"


def test_a_run_that_fails_or_is_interrupted_leaves_no_output_file(tmp_path, capsys, monkeypatch):
    from sanav_mj.eval import episode

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(episode, "run_scenario", interrupted)
    out = tmp_path / "sub"
    code, _, err = _run(["run", "single_rect", "--json", str(out / "r.json"), "--rrd", str(out / "r.rrd"),
                         "--plot", str(out / "r.png")], capsys)
    assert code == 130 and err == "sanav-mj: interrupted\n"
    assert not out.exists()  # no empty file, not even the folder


def test_a_recording_cut_short_by_a_full_disk_is_exit_2_and_the_rest_is_kept(tmp_path, capsys, fill_disk):
    fill_disk(keep=4096, ending=".rrd")
    rrd, js, png = tmp_path / "r.rrd", tmp_path / "r.json", tmp_path / "r.png"
    code, out, err = _run(["run", "single_rect", "--controller", "dwa", "--time-limit", "0.5", "--rrd", str(rrd),
                           "--json", str(js), "--plot", str(png)], capsys)
    assert code == 2
    assert err == f"sanav-mj: error: {rrd}: cannot write the recording (No space left on device)\n"
    assert out.startswith("single_rect / dwa seed 0: timeout")
    assert json.loads(js.read_text())["reason"] == "timeout" and png.read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json", "r.png"]  # no cut file, no .part file


# --------------------------------------------------------------------------- the command line as people read it


def test_every_option_says_its_default_and_mismatch_lists_every_key_with_its_range():
    import argparse

    from sanav_mj.cli import build_parser
    from sanav_mj.sim.mismatch import mismatch_keys

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    checked = 0
    for name, p in sub.choices.items():
        for action in p._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"{name} {action.dest}: no help"
            if action.option_strings:
                assert "default" in action.help, f"{name} {action.option_strings[0]}: no default in {action.help!r}"
                checked += 1
    assert checked >= 25
    text = next(a for a in sub.choices["run"]._actions if a.dest == "mismatch").help
    for key, (lo, hi, meaning) in mismatch_keys().items():
        assert f"{key} {lo:g}..{hi:g} ({meaning})" in text


def test_version_and_python_m_sanav_mj(capsys):
    from importlib.metadata import version

    code, out, err = _run(["--version"], capsys)
    assert (code, out, err) == (0, f"sanav-mj {version('sanav-mj')}\n", "")
    proc = subprocess.run([sys.executable, "-m", "sanav_mj", "--version"], capture_output=True, text=True)
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, out, "")
    proc = subprocess.run([sys.executable, "-m", "sanav_mj", "run", "nope"], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "nope" in proc.stderr


def test_robustness_says_what_it_sweeps(tmp_path, capsys, fake_campaign_runs):
    fake_campaign_runs(_fake_doc)
    code, out, err = _run(["robustness", "single_rect", "--seeds", "1", "--out", str(tmp_path / "a")], capsys)
    assert code == 0, err
    assert out.splitlines()[0] == ("robustness: sweeping wheel_radius = 0.9, 1, 1.1 (the default; choose with "
                                   "--sweep KEY=V1,V2,...), 1 seed(s) per point and scenario, controller sa-mpc")
    code, out, err = _run(["robustness", "single_rect", "--seeds", "2", "--sweep", "delay=0,2", "friction=0.5,1",
                           "--out", str(tmp_path / "b")], capsys)
    assert code == 0, err
    assert out.splitlines()[0] == ("robustness: sweeping delay = 0, 2 x friction = 0.5, 1, 2 seed(s) per point and "
                                   "scenario, controller sa-mpc")
    assert "scenario=all  delay=2  friction=0.5  runs=2" in out


def test_demo_without_recordings_does_not_say_it_wrote_them(tmp_path, capsys, monkeypatch):
    from sanav_mj.eval import demo

    seen = {}

    def fake(out, record, sensing="map", footprint="disc"):
        seen["record"] = record
        return demo.DemoResult(rows=[{k: v for k, v in _doc().items()}])

    monkeypatch.setattr(demo, "run_demo", fake)
    code, out, err = _run(["demo", "--no-rrd", "--out", str(tmp_path)], capsys)
    assert (code, err, seen["record"]) == (0, "", False)
    assert out.splitlines()[-1] == f"wrote plots (.png) and JSON (no recordings: --no-rrd) to {tmp_path}/"
    code, out, err = _run(["demo", "--out", str(tmp_path)], capsys)
    assert seen["record"] is True
    assert out.splitlines()[-1] == f"wrote recordings (.rrd), plots (.png) and JSON to {tmp_path}/"


def test_demo_output_that_fails_is_one_line_after_the_table(tmp_path, capsys, monkeypatch):
    from sanav_mj.eval import demo

    def fake(out, record, sensing="map", footprint="disc"):
        return demo.DemoResult(rows=[_doc()], written=[out / "a.json"],
                               failed=[OSError(28, "No space left on device", str(out / "u_shape.rrd"))])

    monkeypatch.setattr(demo, "run_demo", fake)
    code, out, err = _run(["demo", "--out", str(tmp_path)], capsys)
    assert code == 2 and "| u_shape | goal |" in out
    assert err == f"sanav-mj: error: {tmp_path / 'u_shape.rrd'}: cannot write (No space left on device)\n"


@pytest.mark.parametrize("argv, fragment", [
    (["bench", "single_rect", "--sensing", "lidar"], "--sensing lidar"),  # default controllers: all four
    (["robustness", "single_rect", "--sensing", "lidar", "--controller", "mpc"], "--controller mpc"),
    (["run", "single_rect", "--sensing", "lidar", "--controller", "dqn"], "sa-mpc"),
    (["run", "single_rect", "--sensing", "sonar"], "--sensing"),
    (["demo", "--sensing", "both"], "--sensing"),
])
def test_sensing_option_bad_input_exit_2_one_line(argv, fragment, capsys, tmp_path):
    code, out, err = _run(argv + (["--out", str(tmp_path / "o")] if argv[0] in ("bench", "robustness", "demo")
                                  else []), capsys)
    assert code == 2 and err.count("\n") == 1 and fragment in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_bench_and_robustness_pass_sensing_to_every_run(tmp_path, capsys, monkeypatch):
    from sanav_mj.eval import bench

    seen = []

    def fake(jobs, workers, desc, **kw):  # bench and robustness both stream through bench.run_jobs
        jobs = list(jobs)
        seen.extend(jobs)
        return [{**_fake_doc(j), "sensing": j.sensing, "replans": 2,
                 "map_update_ms": {"mean": 1.0, "max": 2.0, "p99": 2.0}} for j in jobs]

    monkeypatch.setattr(bench, "run_jobs", fake)
    code, _, err = _run(["bench", "single_rect", "--controllers", "sa-mpc", "--runs", "2", "--sensing", "lidar",
                         "--out", str(tmp_path / "b")], capsys)
    assert code == 0, err
    code, _, err = _run(["robustness", "single_rect", "--seeds", "1", "--sweep", "delay=0,1", "--sensing", "lidar",
                         "--out", str(tmp_path / "r")], capsys)
    assert code == 0, err
    assert len(seen) == 4 and {j.sensing for j in seen} == {"lidar"}
    for folder in ("b", "r"):
        assert json.loads((tmp_path / folder / "meta.json").read_text())["sensing"] == "lidar"
    # map-mode journal keys are unchanged; lidar keys say so
    from sanav_mj.eval.campaign import Job, job_key

    assert job_key(Job("u_shape", "sa-mpc", 0)) == '["u_shape","sa-mpc",0,[],60.0]'
    assert job_key(Job("u_shape", "sa-mpc", 0, sensing="lidar")) == '["u_shape","sa-mpc",0,[],60.0,"lidar"]'


def test_run_is_a_thin_layer_over_the_python_api(tmp_path, capsys, monkeypatch):
    """``run`` calls :func:`sanav_mj.api.run_scenario` and writes its ``to_dict()``: the two cannot diverge."""
    import sanav_mj.api as api

    results, real = [], api.run_scenario

    def spy(*a, **k):
        results.append(real(*a, **k))
        return results[-1]

    monkeypatch.setattr(api, "run_scenario", spy)
    js = tmp_path / "r.json"
    code, out, _ = _run(["run", "single_rect", "--controller", "dwa", "--seed", "2", "--time-limit", "0.5",
                         "--mismatch", "delay=1", "--json", str(js)], capsys)
    assert len(results) == 1 and code == (0 if results[0].success else 1)
    assert json.loads(js.read_text()) == results[0].to_dict()  # wall-clock fields included: the same object
    assert results[0].to_dict()["mismatch"] == {"delay": 1} and results[0].controller == "dwa"
    assert out.startswith("single_rect / dwa seed 2:")


@pytest.mark.parametrize("argv, fragment", [
    (["bench", "single_rect", "--footprint", "discs"], "--footprint discs: supported for the sa-mpc controller only"),
    (["robustness", "single_rect", "--footprint", "discs", "--controller", "dwa"], "--controller dwa"),
    (["run", "single_rect", "--footprint", "discs", "--controller", "mpc"], "--controller mpc"),
    (["run", "single_rect", "--footprint", "discs", "--sensing", "lidar"], "--sensing map only"),
    (["demo", "--footprint", "discs", "--sensing", "lidar"], "--sensing map only"),
    (["run", "single_rect", "--footprint", "rectangle"], "--footprint"),
])
def test_footprint_option_bad_input_exit_2_one_line(argv, fragment, capsys, tmp_path):
    code, out, err = _run(argv + (["--out", str(tmp_path / "o")] if argv[0] in ("bench", "robustness", "demo")
                                  else []), capsys)
    assert code == 2 and err.count("\n") == 1 and fragment in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_bench_and_robustness_pass_the_footprint_to_every_run(tmp_path, capsys, fake_campaign_runs):
    from sanav_mj.eval.campaign import Job, job_key

    seen = fake_campaign_runs(_fake_doc)
    code, _, err = _run(["bench", "single_rect", "--controllers", "sa-mpc", "--runs", "2", "--footprint", "discs",
                         "--out", str(tmp_path / "b")], capsys)
    assert code == 0, err
    code, out, err = _run(["robustness", "single_rect", "--seeds", "1", "--sweep", "delay=0,1", "--footprint",
                           "discs", "--out", str(tmp_path / "r")], capsys)
    assert code == 0, err
    assert "footprint discs" in out
    assert len(seen) == 4 and {j.footprint for j in seen} == {"discs"}
    for folder in ("b", "r"):
        assert json.loads((tmp_path / folder / "meta.json").read_text())["footprint"] == "discs"
    # default journal keys are unchanged; discs keys say so
    assert job_key(Job("u_shape", "sa-mpc", 0)) == '["u_shape","sa-mpc",0,[],60.0]'
    assert job_key(Job("u_shape", "sa-mpc", 0, footprint="discs")) == '["u_shape","sa-mpc",0,[],60.0,"footprint=discs"]'
    # and without --footprint the jobs are the default ones
    seen.clear()
    code, _, err = _run(["bench", "single_rect", "--controllers", "sa-mpc", "--runs", "1", "--out",
                         str(tmp_path / "d")], capsys)
    assert code == 0 and {j.footprint for j in seen} == {"disc"}
    assert "footprint" not in json.loads((tmp_path / "d" / "meta.json").read_text())


def test_run_footprint_reaches_the_controller_spec(capsys, monkeypatch):
    import sanav_mj.api as api

    specs = []

    def fake(scenario, controller="sa-mpc", **kw):
        specs.append(controller)
        raise KeyboardInterrupt  # stop before any simulation

    monkeypatch.setattr(api, "run_scenario", fake)
    for flag in ([], ["--footprint", "disc"], ["--footprint", "discs"]):
        assert _run(["run", "single_rect"] + flag, capsys)[0] == 130
    from sanav_mj.control.spec import ControllerSpec

    assert specs[0] == ControllerSpec("sa-mpc") and specs[1] == ControllerSpec("sa-mpc")
    assert specs[2].sa_mpc.footprint == "discs" and specs[2].name == "sa-mpc"


def test_demo_passes_the_footprint(tmp_path, capsys, monkeypatch):
    from sanav_mj.eval import demo

    seen = []

    def fake(out, record, sensing="map", footprint="disc"):
        seen.append(footprint)
        return demo.DemoResult(rows=[{k: v for k, v in _doc().items()}])

    monkeypatch.setattr(demo, "run_demo", fake)
    for flag in ([], ["--footprint", "discs"]):
        assert _run(["demo", "--no-rrd", "--out", str(tmp_path)] + flag, capsys)[0] == 0
    assert seen == ["disc", "discs"]


@pytest.mark.parametrize("argv,name", [
    (["run", "single_rect", "--seed", "x"], "--seed"),
    (["run", "single_rect", "--resolution", "5"], "--resolution"),
    (["bench", "single_rect", "--runs", "0"], "--runs"),
])
def test_argument_error_names_the_argument_once(argv, name, capsys):
    # argparse's "argument NAME: " prefix and our own "NAME: " gave "--seed: --seed: ..."
    code, _, err = _run(argv, capsys)
    assert code == 2
    assert err.count(name) == 1, err
    assert err.startswith(f"sanav-mj: error: {argv[0]}: {name}: expected"), err
