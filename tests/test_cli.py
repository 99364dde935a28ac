"""Command line: every bad-input path gives one line on stderr and exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys

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
