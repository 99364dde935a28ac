"""Compiled code without a compiler (fallback to IPOPT, one line) and the first-compile notice."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sanav_mj.control.backends import make_backend
from sanav_mj.control.codegen import CACHE_ENV, LOGGER, NoCompilerError, find_compiler
from sanav_mj.control.problem import build_tracking_ocp
from sanav_mj.control.solver import SolverSettings

ROOT = Path(__file__).resolve().parents[2]


def test_find_compiler_honours_cc_and_names_it_when_missing(monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.raises(NoCompilerError, match="CC='/nonexistent/cc'"):
        find_compiler()


def test_a_compile_into_an_empty_cache_is_announced_once_with_its_folder(tmp_path, caplog):
    cache = tmp_path / "cache"
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        be = make_backend("panoc", build_tracking_ocp(2, 0.1), SolverSettings(), cache)
        again = make_backend("panoc", build_tracking_ocp(3, 0.1), SolverSettings(), cache)  # another miss
        cached = make_backend("panoc", build_tracking_ocp(2, 0.1), SolverSettings(), cache)  # a hit
    assert be.compiled and again.compiled and not cached.compiled
    notices = [r.getMessage() for r in caplog.records if r.name == LOGGER]
    assert notices == [f"compiling the solver code once (about 10 s, then cached in {cache})"]


def test_run_without_a_compiler_falls_back_to_ipopt_with_one_stderr_line(tmp_path):
    env = dict(os.environ, CC="/nonexistent/cc", PYTHONPATH=str(ROOT))
    env[CACHE_ENV] = str(tmp_path / "empty")
    code = "import sys; from sanav_mj.cli import main; sys.exit(main(['run', 'single_rect', '--seed', '0']))"
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "no C compiler: CC='/nonexistent/cc'" in lines[0] and "IPOPT" in lines[0], lines
    assert "single_rect / sa-mpc seed 0: goal" in proc.stdout
    assert not list((tmp_path / "empty").glob("*.so"))  # nothing was compiled
