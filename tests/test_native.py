"""The shared compile-and-cache routine: compile once then hit, no compiler, a failing compile,
the first-compile notice, and two processes compiling the same key at once."""

from __future__ import annotations

import ctypes
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sanav_mj.native import (
    CompileError,
    NoCompilerError,
    compile_cached,
    find_compiler,
    kernel_loader,
    library_path,
)

ROOT = Path(__file__).resolve().parents[1]
SOURCE = "long long sanav_test_mul(long long a, long long b) { return a * b + 1; }\n"
FLAGS = ("-O1", "-fPIC", "-shared")


def _writer(text: str, calls: list | None = None):
    def generate(folder: Path) -> str:
        if calls is not None:
            calls.append(folder)
        src = folder / "t.c"
        src.write_text(text)
        return str(src)

    return generate


def _call(path: Path) -> int:
    f = ctypes.CDLL(str(path)).sanav_test_mul
    f.restype, f.argtypes = ctypes.c_longlong, [ctypes.c_longlong, ctypes.c_longlong]
    return f(6, 7)


def test_a_kernel_loader_compiles_on_its_first_call_only_and_sets_the_signatures(tmp_path, monkeypatch):
    try:
        find_compiler()
    except NoCompilerError:
        pytest.skip("no C compiler on this machine")
    monkeypatch.setenv("SANAV_MJ_CACHE", str(tmp_path))
    monkeypatch.delenv("SANAV_TEST_NO_KERNEL", raising=False)
    load = kernel_loader("ktest", SOURCE, "the test kernel", "SANAV_TEST_NO_KERNEL",
                         {"sanav_test_mul": (ctypes.c_longlong, [ctypes.c_longlong, ctypes.c_longlong])})
    lib = load()
    assert lib is not None and load() is lib  # loaded once
    # the signature is set: 64-bit operands and result (without it ctypes would pass and return C ints)
    assert lib.sanav_test_mul.restype is ctypes.c_longlong
    assert lib.sanav_test_mul(3 << 32, 2) == (6 << 32) + 1
    assert len(list(tmp_path.glob("ktest_*"))) == 1
    # switched off: None, and nothing compiled
    monkeypatch.setenv("SANAV_TEST_NO_KERNEL", "1")
    off = kernel_loader("koff", SOURCE, "the test kernel", "SANAV_TEST_NO_KERNEL", {})
    assert off() is None and off() is None and not list(tmp_path.glob("koff_*"))


def test_compiles_once_then_returns_the_cached_library(tmp_path):
    calls: list = []
    path, compiled = compile_cached("t", (SOURCE,), _writer(SOURCE, calls), FLAGS, "a test", tmp_path)
    again, compiled_again = compile_cached("t", (SOURCE,), _writer(SOURCE, calls), FLAGS, "a test", tmp_path)
    assert compiled and not compiled_again and again == path and len(calls) == 1
    assert path == library_path("t", (SOURCE,), FLAGS, tmp_path) and path.parent == tmp_path
    assert path.name.startswith("t_") and path.suffix == ".so"
    assert _call(path) == 43
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no build folder left
    # other flags or another key: another library
    assert library_path("t", (SOURCE,), ("-O2", "-fPIC", "-shared"), tmp_path) != path
    assert library_path("t", (SOURCE + " ",), FLAGS, tmp_path) != path


def test_no_compiler_raises_the_dedicated_error_and_writes_nothing(tmp_path, monkeypatch):
    cached, _ = compile_cached("t", (SOURCE,), _writer(SOURCE), FLAGS, "a test", tmp_path / "warm")
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.raises(NoCompilerError, match="CC='/nonexistent/cc'"):
        find_compiler()
    with pytest.raises(NoCompilerError, match="no C compiler"):
        compile_cached("t", (SOURCE,), _writer(SOURCE), FLAGS, "a test", tmp_path / "cold")
    assert not (tmp_path / "cold").exists()
    # a cached library needs no compiler
    assert compile_cached("t", (SOURCE,), _writer(SOURCE), FLAGS, "a test", tmp_path / "warm") == (cached, False)


def test_a_failing_compile_names_what_and_leaves_no_library(tmp_path):
    with pytest.raises(CompileError, match="compiling the broken code with .* failed: .*error"):
        compile_cached("t", ("broken",), _writer("int f( {"), FLAGS, "the broken code", tmp_path)
    assert not list(tmp_path.iterdir())


def test_the_first_compile_into_a_folder_is_announced_once(tmp_path, caplog):
    notice = ("sanav_mj.test_native", "compiling test code once (cached in %s)")
    with caplog.at_level(logging.WARNING, logger=notice[0]):
        for text in (SOURCE, SOURCE + "\n", SOURCE):  # miss, miss, hit
            compile_cached("t", (text,), _writer(text), FLAGS, "a test", tmp_path / "a", notice=notice)
        compile_cached("t", (SOURCE,), _writer(SOURCE), FLAGS, "a test", tmp_path / "b")  # silent
    msgs = [r.getMessage() for r in caplog.records if r.name == notice[0]]
    assert msgs == [f"compiling test code once (cached in {tmp_path / 'a'})"]


_RACER = r"""
import sys, time
from pathlib import Path
from sanav_mj.native import compile_cached
cache, me, other, source = Path(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]

def generate(folder):
    # both processes get here (both missed the cache) before either compiles
    (cache.parent / me).touch()
    deadline = time.monotonic() + 120
    while not (cache.parent / other).exists():
        if time.monotonic() > deadline:
            raise SystemExit("the other process never reached the compile")
        time.sleep(0.01)
    (folder / "t.c").write_text(source)
    return str(folder / "t.c")

path, compiled = compile_cached("t", (source,), generate, ("-O1", "-fPIC", "-shared"), "a test", cache)
print(path, compiled)
"""


def test_two_processes_compiling_the_same_key_leave_one_valid_library(tmp_path):
    cache = tmp_path / "cache"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    procs = [subprocess.Popen([sys.executable, "-c", _RACER, str(cache), me, other, SOURCE], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for me, other in (("a", "b"), ("b", "a"))]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [o[1] for o in outs]
    lines = [o[0].split() for o in outs]
    expect = library_path("t", (SOURCE,), FLAGS, cache)
    assert lines == [[str(expect), "True"]] * 2  # both compiled (they raced), same target
    assert sorted(p.name for p in cache.iterdir()) == [expect.name]  # one library, no build folders
    assert _call(expect) == 43
