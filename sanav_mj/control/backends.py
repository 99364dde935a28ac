"""The one registry of solver back-ends of the tracking problem, and the process-wide cache.

Names (the ``solver`` field of the MPC configs): ``"panoc"``, ``"pantr"``, ``"zerofpr"``
(alpaqa, compiled C, :mod:`sanav_mj.control.backend_alpaqa`), ``"ipopt"`` (CasADi, no
compiler, :mod:`sanav_mj.control.backend_ipopt`) and ``"sqp"`` (compiled C + DAQP,
:mod:`sanav_mj.control.sqp`). Each module is imported only when its back-end is built.
"""

from __future__ import annotations

import importlib
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from sanav_mj.control.codegen import LOGGER, NoCompilerError, default_cache_dir
from sanav_mj.control.solver import Backend, SolverSettings

if TYPE_CHECKING:  # pragma: no cover
    from sanav_mj.control.problem import TrackingOCP

#: back-end name -> (module, class) implementing it.
BACKENDS: dict[str, tuple[str, str]] = {
    "panoc": ("sanav_mj.control.backend_alpaqa", "PanocBackend"),
    "pantr": ("sanav_mj.control.backend_alpaqa", "PantrBackend"),
    "zerofpr": ("sanav_mj.control.backend_alpaqa", "ZeroFprBackend"),
    "ipopt": ("sanav_mj.control.backend_ipopt", "IpoptBackend"),
    "sqp": ("sanav_mj.control.sqp", "SqpBackend"),
}

#: back-ends that generate and compile C (they need a C compiler on a cache miss).
COMPILED_BACKENDS = frozenset({"panoc", "pantr", "zerofpr", "sqp"})

#: the back-end used instead of a compiled one when there is no C compiler: IPOPT through
#: CasADi's SX virtual machine needs none. Measured with SA-MPC (u_shape and complex, seed
#: 0): the same outcome and number of steps as ZeroFPR, 10-18 ms per step on average (99th
#: percentile 30-62 ms) against 1.5-1.7 ms, well inside the 100 ms control period; so a
#: machine without a compiler still runs, slower, rather than failing.
NO_COMPILER_FALLBACK = "ipopt"


def backend_class(name: str) -> type:
    """The class of back-end ``name`` (one of :data:`BACKENDS`).

    Raises:
        ValueError: unknown name (the message lists the known ones).
    """
    try:
        module, cls = BACKENDS[name]
    except KeyError:
        raise ValueError(f"solver must be one of {sorted(BACKENDS)}, got {name!r}") from None
    return getattr(importlib.import_module(module), cls)


def make_backend(name: str, ocp: TrackingOCP, settings: SolverSettings, cache_dir: Path | None = None) -> Backend:
    """Construct the back-end called ``name`` (one of :data:`BACKENDS`) for ``ocp``."""
    return backend_class(name)(ocp, settings, cache_dir)


_BUILT: dict[tuple, Backend] = {}
_fell_back: list[str] = []


def get_backend(ocp: TrackingOCP, solver: str, settings: SolverSettings, cache_dir: Path | None) -> Backend:
    """Return the back-end for this problem structure and settings, building it on first use.

    Back-ends hold no episode state (every solve sets all parameters and bounds), so the
    controllers of one process share them; they are not safe for concurrent threads.
    Without a C compiler (and no cached library) a compiled back-end is replaced by
    :data:`NO_COMPILER_FALLBACK`, reported in one WARNING-level line on the
    ``sanav_mj.control`` logger (printed on stderr when logging is not configured).
    """
    key = (ocp.key, solver, settings, str(cache_dir if cache_dir is not None else default_cache_dir()))
    be = _BUILT.get(key)
    if be is None:
        try:
            be = make_backend(solver, ocp, settings, cache_dir)
        except NoCompilerError as exc:
            if solver == NO_COMPILER_FALLBACK:
                raise
            if not _fell_back:  # one line per process, however many problems fall back
                _fell_back.append(solver)
                logging.getLogger(LOGGER).warning(
                    "%s: solving with IPOPT (CasADi, no compiler needed) instead of %s, about 10x slower "
                    "(10-20 ms per step instead of 1-2 ms)", exc, solver)
            be = make_backend(NO_COMPILER_FALLBACK, ocp, settings, cache_dir)
        _BUILT[key] = be
    return be
