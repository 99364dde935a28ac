"""The one registry of solver back-ends of the tracking problem, and the process-wide cache.

Names (the ``solver`` field of the MPC configs): ``"panoc"``, ``"pantr"``, ``"zerofpr"``
(alpaqa, compiled C, :mod:`sanav_mj.control.backend_alpaqa`), ``"ipopt"`` (CasADi, no
compiler, :mod:`sanav_mj.control.backend_ipopt`) and ``"sqp"`` (compiled C + DAQP,
:mod:`sanav_mj.control.sqp`). Each module is imported only when its back-end is built.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from sanav_mj.control.problem import TrackingOCP
from sanav_mj.control.solver import Backend, SolverSettings

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


def get_backend(ocp: TrackingOCP, solver: str, settings: SolverSettings, cache_dir: Path | None) -> Backend:
    """Return the back-end for this problem structure and settings, building it on first use.

    Back-ends hold no episode state (every solve sets all parameters and bounds), so the
    controllers of one process share them; they are not safe for concurrent threads.
    """
    key = (ocp.key, solver, settings, str(cache_dir))
    be = _BUILT.get(key)
    if be is None:
        be = make_backend(solver, ocp, settings, cache_dir)
        _BUILT[key] = be
    return be
