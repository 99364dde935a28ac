"""Packaging: built-in scenarios and the robot resolve from an installed wheel too."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(ROOT)],
        capture_output=True, text=True,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    wheels = list(out.glob("sanav_mj-*.whl"))
    assert len(wheels) == 1
    return wheels[0]


def test_wheel_ships_models_and_scenarios(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "sanav_mj/models/diff_drive.xml" in names
    assert "sanav_mj/models/dqn/policy.npz" in names
    for s in ("single_rect", "double_rect", "u_shape", "v_shape", "complex"):
        assert f"sanav_mj/scenarios/{s}.xml" in names


def test_builtin_names_load_from_the_installed_wheel(wheel, tmp_path):
    target = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
        capture_output=True, text=True,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    code = (
        "import sanav_mj, sanav_mj.resources as r; from sanav_mj.scene import load_scenario;"
        "s = load_scenario('u_shape'); print(sanav_mj.__file__); print(r.scenarios_dir()); print(len(s.obstacles))"
    )
    env = dict(os.environ, PYTHONPATH=str(target))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    pkg_file, scen_dir, n_obstacles = proc.stdout.split()
    assert Path(pkg_file).is_relative_to(target)
    assert Path(scen_dir) == target / "sanav_mj" / "scenarios"
    assert int(n_obstacles) >= 3


def test_every_test_runs_by_default():
    """No marker deselects tests by default: pytest's addopts carries no ``-m`` filter (a
    ``slow`` marker that selected nothing was dropped; CI runs ``python -m pytest -q``)."""
    import tomllib

    root = Path(__file__).resolve().parents[1]
    opts = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert "-m" not in opts.get("addopts", "").split()
    assert "--strict-markers" in opts.get("addopts", "").split()
