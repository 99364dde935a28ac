"""Compile C into a shared library once and cache it on disk (used by control and mapping).

A low-level module with no package imports, so that every layer may use it without reaching
backwards: :mod:`sanav_mj.control.codegen` compiles CasADi-generated solver code with it and
:mod:`sanav_mj.mapping.beam_kernel` its beam-traversal loop, each with its own flags.

The library lands in ``<cache>/<prefix>_<hash>.so`` (``$SANAV_MJ_CACHE`` or
``~/.cache/sanav-mj``); the hash covers the caller's key (its source or serialised
functions, versions), the flags and the processor (:func:`cpu_id`: ``-march=native`` code
runs only on the processor it was built for). It is compiled in a temporary folder inside the
cache and renamed into place, so concurrent processes compiling the same key never load a
half-written file: the last rename wins and every process loads a complete library.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

#: Environment variable overriding the on-disk cache of compiled code.
CACHE_ENV = "SANAV_MJ_CACHE"

#: (cache folder, notice) pairs already announced in this process.
_announced: set[tuple[str, str]] = set()


class NoCompilerError(RuntimeError):
    """No C compiler to compile generated code (one line: what was looked for)."""


class CompileError(RuntimeError):
    """The C compiler ran and failed (the message holds the start of its stderr)."""


def default_cache_dir() -> Path:
    """Folder for compiled code: ``$SANAV_MJ_CACHE`` or ``~/.cache/sanav-mj``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "sanav-mj"


def find_compiler() -> str:
    """The C compiler to use: ``$CC`` when set (and only it), else the first of cc, gcc, clang.

    Raises:
        NoCompilerError: ``$CC`` names no executable, or none of the defaults is installed.
    """
    cc = os.environ.get("CC")
    if cc:
        if shutil.which(cc):
            return cc
        raise NoCompilerError(f"no C compiler: CC={cc!r} is not an executable")
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return name
    raise NoCompilerError("no C compiler found (cc, gcc, clang; set CC or install gcc)")


def cpu_id() -> str:
    """The processor model and feature flags (Linux), part of the cache key of native code."""
    parts = [platform.machine()]
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key = line.split(":", 1)[0].strip()
                if key in ("model name", "flags", "Features", "CPU part"):
                    parts.append(line.strip())
                if len(parts) >= 3:
                    break
    except OSError:
        parts.append(platform.processor())
    return "\n".join(parts)


def library_path(prefix: str, key: Sequence[str], flags: Sequence[str], cache_dir: Path | None = None) -> Path:
    """Where :func:`compile_cached` keeps the library of ``key`` compiled with ``flags``.

    ``<cache>/<prefix>_<20 hex digits of sha256(key..., " ".join(flags), cpu_id())>.so``.
    """
    h = hashlib.sha256()
    for part in (*key, " ".join(flags), cpu_id()):
        h.update(part.encode())
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return root / f"{prefix}_{h.hexdigest()[:20]}.so"


def compile_cached(
    prefix: str,
    key: Sequence[str],
    generate: Callable[[Path], str],
    flags: Sequence[str],
    what: str,
    cache_dir: Path | None = None,
    notice: tuple[str, str] | None = None,
) -> tuple[Path, bool]:
    """Compile generated C into ``<cache>/<prefix>_<hash>.so`` once, or return the cached library.

    Args:
        prefix: file name prefix (``"alpaqa"``, ``"sqp"``, ``"beams"``).
        key: strings identifying the code (source, serialised functions, versions); the hash
            also covers ``flags`` and :func:`cpu_id` (see :func:`library_path`).
        generate: ``generate(folder: Path) -> str`` writes the C source into ``folder`` and
            returns its path (called only on a cache miss).
        flags: compiler flags (``-shared``, ``-fPIC`` included); ``-lm`` is appended.
        what: what is compiled, for the error message.
        cache_dir: folder of the cache (default :func:`default_cache_dir`).
        notice: ``(logger name, message)`` logged at WARNING level before the first compile
            into a folder, once per process and message; ``%s`` in the message is the folder.
            None: compile silently.

    Returns:
        (path of the shared library, True when it was compiled by this call).

    Raises:
        NoCompilerError: a miss and no C compiler (see :func:`find_compiler`).
        CompileError: the compiler failed (the first 2000 characters of its stderr).
        OSError: the cache folder cannot be created or written.
    """
    target = library_path(prefix, key, flags, cache_dir)
    if target.is_file():
        return target, False
    compiler = find_compiler()
    root = target.parent
    if notice is not None and (str(root), notice[1]) not in _announced:
        _announced.add((str(root), notice[1]))
        logging.getLogger(notice[0]).warning(notice[1], root)
    root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root, prefix="build_") as tmp:
        src = generate(Path(tmp))
        out = Path(tmp) / "lib.so"
        proc = subprocess.run([compiler, *flags, src, "-o", str(out), "-lm"], capture_output=True, text=True,
                              check=False)
        if proc.returncode != 0:
            raise CompileError(f"compiling {what} with {compiler} failed: {proc.stderr.strip()[:2000]}")
        os.replace(out, target)  # atomic: a concurrent process sees no file or a complete one
    return target, True


#: compiler flags of the small C kernels (:func:`load_c_kernel`): IEEE arithmetic, no FMA
#: contraction, so the kernels give the same bits as their NumPy references.
KERNEL_FLAGS = ("-O2", "-fPIC", "-shared", "-std=c99", "-ffp-contract=off", "-fno-fast-math")


def load_c_kernel(prefix: str, source: str, what: str, disable_env: str) -> ctypes.CDLL | None:
    """Compile (once, into the shared cache: :func:`compile_cached`) and load a C kernel
    written as one source string, or None when the environment variable ``disable_env`` is
    set to anything but ``""`` / ``"0"``, there is no compiler, the compile fails or the
    cache cannot be written (the caller then uses its NumPy path).

    Args:
        prefix: the library's file name prefix (``"beams"``, ``"areas"``).
        source: the C source (compiled with :data:`KERNEL_FLAGS`).
        what: what is compiled, for the compiler's error message.
        disable_env: the environment variable that switches the kernel off.
    """
    if os.environ.get(disable_env, "") not in ("", "0"):
        return None

    def write(folder: Path) -> str:
        src = folder / f"{prefix}.c"
        src.write_text(source)
        return str(src)

    try:
        target, _ = compile_cached(prefix, (source,), write, KERNEL_FLAGS, what)
        return ctypes.CDLL(str(target))
    except (NoCompilerError, CompileError, OSError):
        return None


#: Environment variable: set to ``1`` to run the NumPy paths of the compiled kernels
#: (beams, safe areas, scan match, rectangle test, rectangle growth, corridor assignment,
#: disc-centre assignment and relaxation, footprint-reference repair) even where C compiles.
NO_KERNEL_ENV = "SANAV_MJ_NO_CKERNEL"

#: a compiled function's ctypes signature: (restype, argtypes)
Signature = tuple[object, Sequence[object]]


def kernel_loader(prefix: str, source: str, what: str, disable_env: str,
                  signatures: dict[str, Signature]) -> Callable[[], ctypes.CDLL | None]:
    """A loader of a C kernel that compiles and loads it on its first call only
    (:func:`load_c_kernel`) and sets the ``restype`` / ``argtypes`` of each function named in
    ``signatures``; every later call returns the same library, or None when the first found
    no compiler, a failed compile, an unwritable cache or the kernel switched off by
    ``disable_env`` (the caller then uses its NumPy path)."""

    @functools.cache
    def load() -> ctypes.CDLL | None:
        lib = load_c_kernel(prefix, source, what, disable_env)
        if lib is None:
            return None
        for name, (restype, argtypes) in signatures.items():
            f = getattr(lib, name)
            f.restype = restype
            f.argtypes = list(argtypes)
        return lib

    return load
